"""The parts of a scene: bodies with a shape, a pose and a material (no file I/O, no Scene)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Optional

from pydantic import BeforeValidator, ConfigDict, Field, field_validator
from pydantic.dataclasses import dataclass as pyd_dataclass
from typing_extensions import Annotated

from ..frames import Pose
from .shapes import SHAPES, Real, Shape, _real, tessellate_cached
from .surface import Surface

__all__ = ["Texture", "Material", "Body", "View", "SceneError", "BOTTOM_TYPE_NAMES"]

_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False)
Unit = Annotated[float, BeforeValidator(_real), Field(ge=0.0, le=1.0)]
RGB = tuple[Unit, Unit, Unit]

#: The seabeds of thesis Table 2.2 (``optiacoustic.sonar.BOTTOM_TYPES``; the scene layer does not import
#: the sonar's, a test keeps the two equal). Names compare case-insensitively, ``_``/``-`` for a space.
BOTTOM_TYPE_NAMES = ("sand/shell", "coarse sand", "posidonia", "mud", "medium sand", "shells")


class SceneError(ValueError):
    """A scene that cannot be built; the message names file, body and field."""


@pyd_dataclass(frozen=True, config=_CONFIG)
class Texture:
    """A procedural optical texture, evaluated in the body frame.

    On planes it uses the body's x-y coordinates; on solids, the two coordinates across
    the body axis nearest to the surface normal (so a box's every face is checkered).
    ``checker``: squares of side ``size`` alternating ``color`` and ``color2``.
    ``grid``: lines of width ``line_width`` every ``size`` metres in ``color2`` on ``color``.
    """

    kind: Literal["checker", "grid"]
    size: Annotated[float, BeforeValidator(_real), Field(gt=0.0)]
    color2: RGB = (0.05, 0.05, 0.05)
    line_width: Annotated[float, BeforeValidator(_real), Field(gt=0.0)] = 0.02


@pyd_dataclass(frozen=True, config=_CONFIG)
class Material:
    """Surface properties.

    Attributes
    ----------
    reflectivity : float in [0, 1]
        Acoustic reflectivity ``R_k`` of eq. (2.10).
    color : (3,) floats in [0, 1]
        Diffuse optical albedo per R, G, B channel (linear).
    texture : Texture, optional
        Procedural optical texture (modulates ``color``).
    bottom_type : str, optional
        Marks a seabed: reverberation statistics of this bottom type (Table 2.2:
        ``sand/shell``, ``coarse sand``, ``posidonia``, ``mud``, ``medium sand``,
        ``shells``) are applied to its echoes by the sonar's noise model.
    """

    reflectivity: Unit = 0.5
    color: RGB = (0.5, 0.5, 0.5)
    texture: Optional[Texture] = None
    bottom_type: Optional[str] = None

    @field_validator("bottom_type")
    @classmethod
    def _known_bottom(cls, v):
        # checked here, not when a sonar first meets the body (that error named neither file nor body)
        if v is not None and v.strip().lower().replace("_", " ").replace("-", " ") not in BOTTOM_TYPE_NAMES:
            raise ValueError(f"unknown seabed {v!r}; expected one of {list(BOTTOM_TYPE_NAMES)}")
        return v


@pyd_dataclass(frozen=True, config=_CONFIG)
class View:
    """A suggested sensor placement for a scene: ``eye`` aimed at ``target`` (world, m)."""

    eye: tuple[Real, Real, Real]
    target: tuple[Real, Real, Real] = (0.0, 0.0, 0.0)


@dataclass(frozen=True, eq=False)
class Body:
    """A named rigid body: ``shape`` in its own frame, placed by ``pose`` (body -> world)."""

    name: str
    shape: Shape
    pose: Pose = field(default_factory=Pose.identity)
    material: Material = field(default_factory=Material)

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            raise SceneError(f"body name must be a non-empty string, got {self.name!r}")
        if type(self.shape) not in SHAPES.values():
            raise SceneError(f"body '{self.name}': shape must be one of {sorted(SHAPES)}, got {self.shape!r}")
        if not isinstance(self.pose, Pose):
            raise SceneError(f"body '{self.name}': pose must be a Pose, got {type(self.pose).__name__}")
        if not isinstance(self.material, Material):
            raise SceneError(f"body '{self.name}': material must be a Material")

    def surface(self) -> Surface:
        """The body's tessellated surface in world coordinates."""
        return tessellate_cached(self.shape).transformed(self.pose)
