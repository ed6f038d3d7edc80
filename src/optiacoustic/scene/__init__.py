"""Scenes: bodies with shapes, poses and materials; loading from YAML/JSON; tessellation."""

from .model import Body, Material, Scene, SceneError, Texture, View
from .shapes import SHAPES, Box, Cylinder, Ellipsoid, KleinBottle, Mesh, Plane, Sphere
from .surface import Surface, parametric_grid

__all__ = [
    "Body",
    "Box",
    "Cylinder",
    "Ellipsoid",
    "KleinBottle",
    "Material",
    "Mesh",
    "Plane",
    "SHAPES",
    "Scene",
    "SceneError",
    "Sphere",
    "Surface",
    "Texture",
    "View",
    "parametric_grid",
]
