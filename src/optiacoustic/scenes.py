"""Built-in scenes of the thesis.

``names()`` lists them, ``get(name)`` builds one. Each carries a suggested ``view`` (the
sensor placement the thesis uses). ``oas scene NAME --export file.yaml`` writes one out
as a starting point for your own.
"""

from __future__ import annotations

from typing import Callable

from .frames import Pose
from .scene import Body, Box, Cylinder, Ellipsoid, KleinBottle, Material, Plane, Scene, Sphere, Texture, View

__all__ = ["names", "get", "describe"]

SEABED = Material(reflectivity=0.3, color=(0.55, 0.50, 0.40), bottom_type="sand/shell")


def _seabed(size: float = 40.0, material: Material = SEABED) -> Body:
    return Body("seabed", Plane(size=(size, size)), Pose.identity(), material)


def _at(x, y, z, rx=0.0, ry=0.0, rz=0.0) -> Pose:
    return Pose.from_euler_deg((x, y, z), (rx, ry, rz))


def thesis_scene1() -> Scene:
    """Seabed with cuboids, spheres, an ellipsoid and cylinders (thesis Fig. 2.15)."""
    m = lambda refl, rgb: Material(reflectivity=refl, color=rgb)  # noqa: E731
    bodies = [
        _seabed(),
        Body("cuboid_red", Box(size=(1.0, 0.8, 0.6)), _at(-1.6, 0.2, 0.3, rz=20), m(0.8, (0.80, 0.18, 0.12))),
        Body("cuboid_yellow", Box(size=(0.6, 0.6, 1.0)), _at(1.4, 1.9, 0.5, rz=-15), m(0.8, (0.90, 0.80, 0.20))),
        Body("sphere_white", Sphere(radius=0.45), _at(0.5, -0.8, 0.45), m(0.9, (0.90, 0.90, 0.90))),
        Body("sphere_green", Sphere(radius=0.3), _at(-0.5, 2.3, 0.3), m(0.7, (0.20, 0.70, 0.30))),
        Body("ellipsoid_orange", Ellipsoid(radii=(0.7, 0.35, 0.3)), _at(-0.3, 0.8, 0.3, rz=30), m(0.7, (0.95, 0.50, 0.10))),
        Body("cylinder_standing", Cylinder(radius=0.25, height=1.2), _at(2.1, -0.2, 0.6), m(0.85, (0.70, 0.70, 0.75))),
        Body("cylinder_lying", Cylinder(radius=0.2, height=1.4), _at(0.7, 3.3, 0.2, rx=90, rz=60), m(0.75, (0.55, 0.30, 0.65))),
    ]
    return Scene(
        bodies,
        name="thesis_scene1",
        description="Seabed with cuboids, spheres, an ellipsoid and cylinders (thesis Fig. 2.15); "
        "sonar at (0, -6, 2) aimed at the origin, camera 0.25 m to its left.",
        view=View(eye=(0.0, -6.0, 2.0), target=(0.0, 0.0, 0.0)),
    )


def flat_seabed() -> Scene:
    """A flat seabed only: the analytic reference case of the sonar's echo profile."""
    return Scene(
        [_seabed(60.0)],
        name="flat_seabed",
        description="A flat 60 x 60 m seabed (z = 0).",
        view=View(eye=(0.0, -6.0, 2.0), target=(0.0, 0.0, 0.0)),
    )


def klein_bottle() -> Scene:
    """A Klein bottle in open water (thesis Fig. 5.4), 0.5 m tall, centred on the origin."""
    return Scene(
        [Body("klein_bottle", KleinBottle(height=0.5), Pose.identity(), Material(reflectivity=0.8, color=(0.85, 0.75, 0.35)))],
        name="klein_bottle",
        description="A 0.5 m Klein bottle in open water (thesis Fig. 5.4), for reconstruction experiments.",
        view=View(eye=(0.0, -1.25, 0.0), target=(0.0, 0.0, 0.0)),
    )


def planar_grid() -> Scene:
    """A rectangular grid of raised bars lying on the seabed (thesis Figs. 7.2, 7.8).

    2 x 2 m, 4 x 4 cells of 0.5 m; bars 4 cm wide and 3 cm high so that both the sonar
    (as raised edges) and the camera (as bright lines) see them.
    """
    bar = Material(reflectivity=0.95, color=(0.92, 0.92, 0.90))
    bed = Material(reflectivity=0.15, color=(0.30, 0.28, 0.25), bottom_type="mud")
    bodies = [_seabed(40.0, bed)]
    w, h, L, n = 0.04, 0.03, 2.0, 4
    for i in range(n + 1):
        c = -L / 2 + i * L / n
        bodies.append(Body(f"bar_x{i}", Box(size=(L + w, w, h)), _at(0.0, c, h / 2), bar))
        bodies.append(Body(f"bar_y{i}", Box(size=(w, L + w, h)), _at(c, 0.0, h / 2), bar))
    return Scene(
        bodies,
        name="planar_grid",
        description="A 2 x 2 m grid of raised bars (4 x 4 cells) on a muddy seabed (thesis Figs. 7.2, 7.8).",
        view=View(eye=(0.0, -3.5, 1.8), target=(0.0, 0.0, 0.0)),
    )


def cuboids() -> Scene:
    """Three cuboids of different heights on the seabed (thesis Fig. 7.4)."""
    mat = lambda rgb: Material(reflectivity=0.85, color=rgb)  # noqa: E731
    bodies = [
        _seabed(40.0, Material(reflectivity=0.2, color=(0.35, 0.33, 0.30), bottom_type="sand/shell")),
        Body("cuboid_left", Box(size=(0.6, 0.6, 0.4)), _at(-0.9, 0.0, 0.2), mat((0.85, 0.25, 0.2))),
        Body("cuboid_middle", Box(size=(0.6, 0.6, 0.7)), _at(0.0, 0.4, 0.35), mat((0.25, 0.75, 0.3))),
        Body("cuboid_right", Box(size=(0.6, 0.6, 0.25)), _at(0.9, 0.0, 0.125), mat((0.3, 0.4, 0.9))),
    ]
    return Scene(
        bodies,
        name="cuboids",
        description="Three cuboids of heights 0.4, 0.7 and 0.25 m on the seabed (thesis Fig. 7.4).",
        view=View(eye=(0.0, -3.5, 1.8), target=(0.0, 0.0, 0.2)),
    )


def perpendicular_planes() -> Scene:
    """Two perpendicular textured walls forming a corner about 1.5 m ahead (thesis Fig. 6.2)."""
    tex = Texture(kind="checker", size=0.1, color2=(0.1, 0.1, 0.12))
    wall = Material(reflectivity=0.7, color=(0.85, 0.85, 0.8), texture=tex)
    s = 0.5 ** 0.5
    bodies = [
        # the walls meet in a vertical corner line at (0, 0.7); each is 2 m long and 2 m tall
        Body("wall_left", Box(size=(2.0, 0.02, 2.0)), _at(-s, 0.7 - s, 0.0, rz=45), wall),
        Body("wall_right", Box(size=(2.0, 0.02, 2.0)), _at(s, 0.7 - s, 0.0, rz=-45), wall),
    ]
    return Scene(
        bodies,
        name="perpendicular_planes",
        description="Two perpendicular 2 x 2 m checkered walls meeting in a corner at (0, 0.7), opening "
        "towards -Y (thesis Fig. 6.2); from the suggested view the walls are 1.2-1.7 m away.",
        view=View(eye=(0.0, -1.0, 0.0), target=(0.0, 0.7, 0.0)),
    )


_BUILTINS: dict[str, Callable[[], Scene]] = {
    "thesis_scene1": thesis_scene1,
    "flat_seabed": flat_seabed,
    "klein_bottle": klein_bottle,
    "planar_grid": planar_grid,
    "cuboids": cuboids,
    "perpendicular_planes": perpendicular_planes,
}


def names() -> list[str]:
    """Names of the built-in scenes."""
    return list(_BUILTINS)


def get(name: str) -> Scene:
    """Build the built-in scene ``name``."""
    try:
        return _BUILTINS[name]()
    except KeyError:
        raise KeyError(f"unknown scene {name!r}; built-in scenes are {names()}") from None


def describe(name: str) -> str:
    """One-line description of a built-in scene."""
    return get(name).description
