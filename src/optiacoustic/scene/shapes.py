"""Shapes a body can have, each tessellated to a :class:`~.surface.Surface` in its own frame.

Every shape is centred on its body's origin: a sphere of radius 0.5 posed at z = 0.5
rests on the plane z = 0; a cylinder's axis is its Z axis; a plane is z = 0 with normal
+Z. Shapes are validated pydantic dataclasses, so ``Sphere(radius=-1)`` fails with a
message naming the field, whether it comes from Python or from a scene file.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path
from typing import ClassVar, Union

import numpy as np
from pydantic import AfterValidator, BeforeValidator, ConfigDict, Field
from pydantic.dataclasses import dataclass
from typing_extensions import Annotated

from .._validate import is_number, strict_number
from .normals import merge_vertices, smooth_shading
from .surface import Surface, parametric_grid

__all__ = ["Plane", "Box", "Sphere", "Ellipsoid", "Cylinder", "Mesh", "KleinBottle", "SHAPES", "Shape", "MIN_SIZE"]

_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False)

#: Smallest size of a shape (m): a radius, an edge, a height. The ray caster (Embree) computes in float32,
#: whose smallest normal number is 1.2e-38: its ray-triangle tests multiply three edge coordinates, and for
#: sizes below 1e-12 m (a cube of 1e-36) those products go subnormal and then to zero (a sphere of radius
#: 1e-300 loaded, and became a point). Nothing a sonar or a camera sees is near this; a smaller size is a
#: units mistake. Mesh scales are free (a mesh in nm has scale 1e-9).
MIN_SIZE = 1e-12


_real = strict_number  # numbers are numbers: `true` and "2" in a scene file are refused, not read as 1 and 2


def _whole(v):
    """A count: `true` and "2" refused; a float goes on to pydantic (2.0 is 2, 2.5 an error)."""
    if not is_number(v):
        raise ValueError(f"expected an integer, not {type(v).__name__}")
    return v


def _size(v: float) -> float:
    if not v >= MIN_SIZE:
        raise ValueError(f"Input should be greater than 0 and at least MIN_SIZE = {MIN_SIZE:g} m")
    return v


Real = Annotated[float, BeforeValidator(_real)]
Size = Annotated[float, BeforeValidator(_real), AfterValidator(_size)]
PositiveFloat = Annotated[float, BeforeValidator(_real), Field(gt=0.0)]
Vec2 = tuple[Size, Size]
Vec3 = tuple[Size, Size, Size]


def _unit_sphere(subdivisions: int) -> Surface:
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = np.asarray(m.vertices, float)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return Surface(v, np.asarray(m.faces), v.copy())


@dataclass(frozen=True, config=_CONFIG)
class Plane:
    """A rectangle in the body's z = 0 plane, ``size = (x, y)`` extents (m); normal +Z."""

    size: Vec2
    kind: ClassVar[str] = "plane"

    def tessellate(self) -> Surface:
        hx, hy = self.size[0] / 2, self.size[1] / 2
        v = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]], float)
        return Surface(v, np.array([[0, 1, 2], [0, 2, 3]]), np.tile([0.0, 0.0, 1.0], (4, 1)))


@dataclass(frozen=True, config=_CONFIG)
class Box:
    """A cuboid centred on the body origin, ``size = (x, y, z)`` edge lengths (m); flat shaded."""

    size: Vec3
    kind: ClassVar[str] = "box"

    def tessellate(self) -> Surface:
        h = np.asarray(self.size, float) / 2
        verts, normals, faces = [], [], []
        for axis in range(3):
            for sign in (-1.0, 1.0):
                n = np.zeros(3)
                n[axis] = sign
                a, b = (axis + 1) % 3, (axis + 2) % 3
                quad = []
                for ca, cb in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                    p = np.zeros(3)
                    p[axis], p[a], p[b] = sign * h[axis], ca * h[a], cb * h[b]
                    quad.append(p)
                base = len(verts)
                verts += quad
                normals += [n] * 4
                # wind counter-clockwise seen from outside
                tri = [[0, 1, 2], [0, 2, 3]] if sign > 0 else [[0, 2, 1], [0, 3, 2]]
                faces += [[base + i for i in t] for t in tri]
        return Surface(np.array(verts), np.array(faces), np.array(normals))


@dataclass(frozen=True, config=_CONFIG)
class Sphere:
    """A sphere of ``radius`` (m); an icosphere with exact radial normals."""

    radius: Size
    subdivisions: Annotated[int, BeforeValidator(_whole), Field(ge=1, le=7)] = 5
    kind: ClassVar[str] = "sphere"

    def tessellate(self) -> Surface:
        s = _unit_sphere(self.subdivisions)
        return Surface(s.vertices * self.radius, s.faces, s.normals)


@dataclass(frozen=True, config=_CONFIG)
class Ellipsoid:
    """An ellipsoid with semi-axes ``radii = (a, b, c)`` along the body's X, Y, Z (m)."""

    radii: Vec3
    subdivisions: Annotated[int, BeforeValidator(_whole), Field(ge=1, le=7)] = 5
    kind: ClassVar[str] = "ellipsoid"

    def tessellate(self) -> Surface:
        s = _unit_sphere(self.subdivisions)
        r = np.asarray(self.radii, float)
        # normal of x^2/a^2 + ... = 1 at p = r * u is the gradient p / r^2 = u / r
        return Surface(s.vertices * r, s.faces, s.normals / r)


@dataclass(frozen=True, config=_CONFIG)
class Cylinder:
    """A capped cylinder with axis along the body's Z, centred on the origin (m)."""

    radius: Size
    height: Size
    sections: Annotated[int, BeforeValidator(_whole), Field(ge=8, le=4096)] = 128
    kind: ClassVar[str] = "cylinder"

    def tessellate(self) -> Surface:
        n = self.sections
        a = np.linspace(0, 2 * np.pi, n, endpoint=False)
        ring = np.stack([np.cos(a), np.sin(a), np.zeros(n)], 1)
        h = self.height / 2
        r = self.radius
        # side: 2n vertices with radial normals
        side_v = np.concatenate([ring * [r, r, 0] + [0, 0, -h], ring * [r, r, 0] + [0, 0, h]])
        side_n = np.concatenate([ring, ring])
        i = np.arange(n)
        j = (i + 1) % n
        side_f = np.concatenate([np.stack([i, j, n + j], 1), np.stack([i, n + j, n + i], 1)])
        parts = [Surface(side_v, side_f, side_n)]
        for sign in (-1.0, 1.0):
            v = np.concatenate([ring * [r, r, 0] + [0, 0, sign * h], [[0, 0, sign * h]]])
            f = np.stack([i, j, np.full(n, n)], 1) if sign > 0 else np.stack([j, i, np.full(n, n)], 1)
            parts.append(Surface(v, f, np.tile([0, 0, sign], (n + 1, 1))))
        return Surface.concatenate(parts)


def _read_triangles(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(V, 3)`` float64 and faces ``(F, 3)`` of every triangle in a mesh file (trimesh's readers).

    A file of one mesh placed at the origin (PLY, STL, OFF, most OBJ) is taken as read, with
    no copy; scenes of several meshes or placed meshes (GLB, glTF) are flattened by trimesh.
    """
    import trimesh

    try:
        # process=False: trimesh's merge, hashing and copies cost three times the read;
        # vertices are merged by position below (what crease splitting needs)
        loaded = trimesh.load_scene(path, process=False)
        meshes = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        nodes = loaded.graph.nodes_geometry
        if len(meshes) == 1 and len(loaded.geometry) == 1 and len(nodes) == 1 and np.allclose(
                loaded.graph[nodes[0]][0], np.eye(4), rtol=0, atol=0):
            v, f = meshes[0].vertices, meshes[0].faces
        elif meshes:
            m = loaded.to_mesh()
            v, f = m.vertices, m.faces
        else:
            v = f = np.zeros((0, 3))
    except Exception as exc:  # trimesh raises many types; the caller adds file/body context
        raise ValueError(f"cannot read mesh {path!r}: {type(exc).__name__}: {exc}") from None
    return np.asarray(v, float), np.asarray(f)


@functools.lru_cache(maxsize=64)
def _load_mesh_file(path: str, mtime: float, smooth_angle_deg: float) -> Surface:
    v, f = _read_triangles(path)
    if len(f) == 0:
        raise ValueError(f"cannot read mesh {path!r}: no triangles found")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"cannot read mesh {path!r}: non-finite vertex coordinates")
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"cannot read mesh {path!r}: a face refers to a vertex that does not exist")
    v, f = merge_vertices(v, f)
    e1, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    if not np.any(np.cross(e1, e2).any(axis=1)):  # every triangle a line or a point: nothing to hit or shade
        raise ValueError(f"cannot read mesh {path!r}: no triangle with non-zero area ({len(f)} degenerate triangles)")
    # vectorised crease splitting and vertex normals (trimesh's smooth_shade costs ~7 us/triangle)
    v, f, n = smooth_shading(v, f, np.deg2rad(smooth_angle_deg))
    return Surface(v, f, n)


@dataclass(frozen=True, config=_CONFIG)
class Mesh:
    """A triangle mesh from a file (OBJ, STL, PLY, GLB, ...) read with trimesh.

    ``file`` is resolved against ``base_dir`` (the scene file's folder when loaded from a
    scene file). Edges sharper than ``smooth_angle_deg`` keep flat shading; smoother ones
    get interpolated normals.
    """

    file: str
    scale: Union[PositiveFloat, tuple[PositiveFloat, PositiveFloat, PositiveFloat]] = 1.0
    smooth_angle_deg: Annotated[float, BeforeValidator(_real), Field(ge=0.0, le=180.0)] = 30.0
    base_dir: str = ""
    kind: ClassVar[str] = "mesh"

    @property
    def path(self) -> str:
        p = Path(os.path.expanduser(self.file))
        return str(p if p.is_absolute() or not self.base_dir else Path(self.base_dir) / p)

    def tessellate(self) -> Surface:
        path = self.path
        if not os.path.isfile(path):
            raise ValueError(f"mesh file not found: {path!r}")
        s = _load_mesh_file(path, os.path.getmtime(path), float(self.smooth_angle_deg))
        sc = np.broadcast_to(np.asarray(self.scale, float), (3,))
        if np.all(sc == 1.0):
            return s  # surfaces are immutable: no copy of a large mesh
        n = s.normals / sc
        return Surface(s.vertices * sc, s.faces, n)


def _klein(u, v):
    """The classic 'bottle' immersion of the Klein bottle, u in [0, pi], v in [0, 2 pi]."""
    cu, su, cv, sv = np.cos(u), np.sin(u), np.cos(v), np.sin(v)
    x = -2 / 15 * cu * (3 * cv - 30 * su + 90 * cu**4 * su - 60 * cu**6 * su + 5 * cu * cv * su)
    y = (
        -1
        / 15
        * su
        * (
            3 * cv
            - 3 * cu**2 * cv
            - 48 * cu**4 * cv
            + 48 * cu**6 * cv
            - 60 * su
            + 5 * cu * cv * su
            - 5 * cu**3 * cv * su
            - 80 * cu**5 * cv * su
            + 80 * cu**7 * cv * su
        )
    )
    z = 2 / 15 * (3 + 5 * cu * su) * sv
    # Stand the bottle up: its long axis (y above, extent [0, 4.2064]) becomes the body's Z;
    # centre the bounding box on the origin and normalise the height to 1.
    span = 4.2064133
    return np.stack([x - 0.1533926, z, y - span / 2], -1) * (1.0 / span)


@dataclass(frozen=True, config=_CONFIG)
class KleinBottle:
    """The bottle-shaped immersion of a Klein bottle, about ``height`` metres tall (thesis Fig. 5.4)."""

    height: Size = 1.0
    resolution: Annotated[int, BeforeValidator(_whole), Field(ge=16, le=2048)] = 160
    kind: ClassVar[str] = "klein_bottle"

    @staticmethod
    def points(u, v, height: float = 1.0) -> np.ndarray:
        """Points ``(..., 3)`` of the surface at parameters ``u in [0, pi]``, ``v in [0, 2 pi]``."""
        return _klein(np.asarray(u, float), np.asarray(v, float)) * height

    def tessellate(self) -> Surface:
        n = self.resolution
        return parametric_grid(
            lambda u, v: self.points(u, v, self.height), (0.0, np.pi), (0.0, 2 * np.pi), n, n // 2, wrap_v=True
        )


SHAPES: dict[str, type] = {c.kind: c for c in (Plane, Box, Sphere, Ellipsoid, Cylinder, Mesh, KleinBottle)}
Shape = Union[Plane, Box, Sphere, Ellipsoid, Cylinder, Mesh, KleinBottle]


@functools.lru_cache(maxsize=256)
def tessellate_cached(shape) -> Surface:
    """Tessellate a (hashable, immutable) shape once."""
    return shape.tessellate()
