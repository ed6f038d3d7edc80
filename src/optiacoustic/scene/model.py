"""The scene model: bodies with a shape, a pose and a material."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator, Literal, Optional

import numpy as np
from pydantic import ConfigDict, Field
from pydantic.dataclasses import dataclass as pyd_dataclass
from typing_extensions import Annotated

from ..frames import Pose
from .shapes import SHAPES, Shape, tessellate_cached
from .surface import Surface

__all__ = ["Texture", "Material", "Body", "Scene", "View", "SceneError"]

_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False)
Unit = Annotated[float, Field(ge=0.0, le=1.0)]
RGB = tuple[Unit, Unit, Unit]


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
    size: Annotated[float, Field(gt=0.0)]
    color2: RGB = (0.05, 0.05, 0.05)
    line_width: Annotated[float, Field(gt=0.0)] = 0.02


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


@pyd_dataclass(frozen=True, config=_CONFIG)
class View:
    """A suggested sensor placement for a scene: ``eye`` aimed at ``target`` (world, m)."""

    eye: tuple[float, float, float]
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)


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


class Scene:
    """An immutable list of uniquely named bodies.

    Body ``i`` of :attr:`bodies` has id ``i``: the ray caster reports it, ground truth
    maps use it, and :meth:`body_names` translates it back.
    """

    def __init__(self, bodies, *, name: str = "", description: str = "", view: View | None = None):
        bodies = tuple(bodies)
        if not bodies:
            raise SceneError("a scene needs at least one body")
        seen = set()
        for b in bodies:
            if not isinstance(b, Body):
                raise SceneError(f"scene bodies must be Body objects, got {type(b).__name__}")
            if b.name in seen:
                raise SceneError(f"body names must be unique: '{b.name}' appears twice")
            seen.add(b.name)
        self._bodies = bodies
        self.name = name
        self.description = description
        self.view = view
        self._surfaces: tuple[Surface, ...] | None = None

    # ------------------------------------------------------------------ access
    @property
    def bodies(self) -> tuple[Body, ...]:
        return self._bodies

    def __len__(self) -> int:
        return len(self._bodies)

    def __iter__(self) -> Iterator[Body]:
        return iter(self._bodies)

    def __repr__(self) -> str:
        return f"Scene({self.name!r}, bodies={[b.name for b in self._bodies]})"

    def body_names(self) -> list[str]:
        return [b.name for b in self._bodies]

    def body_id(self, name: str) -> int:
        for i, b in enumerate(self._bodies):
            if b.name == name:
                return i
        raise KeyError(f"no body named {name!r}; bodies are {self.body_names()}")

    def body(self, name: str) -> Body:
        return self._bodies[self.body_id(name)]

    def surfaces(self) -> tuple[Surface, ...]:
        """World-frame surfaces of all bodies (computed once)."""
        if self._surfaces is None:
            out = []
            for b in self._bodies:
                try:
                    out.append(b.surface())
                except ValueError as exc:
                    raise SceneError(f"body '{b.name}': field 'file': {exc}") from None
            self._surfaces = tuple(out)
        return self._surfaces

    def bounds(self) -> np.ndarray:
        """Axis-aligned bounding box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (m)."""
        v = np.concatenate([s.vertices for s in self.surfaces()])
        return np.stack([v.min(0), v.max(0)])

    # ------------------------------------------------------------------ derived scenes
    def with_bodies(self, *bodies: Body) -> "Scene":
        """A new scene with ``bodies`` added."""
        return Scene(self._bodies + tuple(bodies), name=self.name, description=self.description, view=self.view)

    def without(self, *names: str) -> "Scene":
        """A new scene without the named bodies."""
        for n in names:
            self.body_id(n)
        return Scene(
            [b for b in self._bodies if b.name not in names], name=self.name, description=self.description, view=self.view
        )

    # ------------------------------------------------------------------ files
    @classmethod
    def load(cls, path) -> "Scene":
        """Load a scene from a YAML or JSON file (see docs/scenes.md for the schema)."""
        from .io import load_scene

        return load_scene(path)

    def save(self, path) -> None:
        """Write the scene as YAML (``.yaml``/``.yml``) or JSON (``.json``)."""
        from .io import save_scene

        save_scene(self, path)

    def to_dict(self, base_dir: str | None = None) -> dict:
        from .io import scene_to_dict

        return scene_to_dict(self, base_dir)
