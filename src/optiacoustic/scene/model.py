"""The scene model: an immutable list of uniquely named bodies (parts in :mod:`.parts`, files in :mod:`.io`)."""

from __future__ import annotations

from typing import Iterator

import numpy as np

from .io import read_scene_parts, save_scene, scene_parts_from_dict, scene_to_dict
from .parts import Body, Material, SceneError, Texture, View
from .surface import Surface

__all__ = ["Texture", "Material", "Body", "Scene", "View", "SceneError"]


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
        """Load a scene from a YAML or JSON file (schema: docs/conventions.md, "Scene files")."""
        return cls(**read_scene_parts(path))

    @classmethod
    def from_dict(cls, data, source: str = "<dict>", base_dir: str = ".") -> "Scene":
        """Build a scene from the parsed contents of a scene file."""
        return cls(**scene_parts_from_dict(data, source, base_dir))

    def save(self, path) -> None:
        """Write the scene as YAML (``.yaml``/``.yml``) or JSON (``.json``)."""
        save_scene(self, path)

    def to_dict(self, base_dir: str | None = None) -> dict:
        return scene_to_dict(self, base_dir)
