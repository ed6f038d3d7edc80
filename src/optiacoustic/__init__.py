"""optiacoustic: opti-acoustic stereo imaging.

Simulate a forward-looking imaging sonar and an underwater camera, relate their images
(epipolar curves, reconstruction, motion, calibration) and fuse them. Conventions are in
docs/conventions.md: metres and radians, world Z up, sonar X right / Y forward / Z up,
camera X right / Y down / Z forward, rig ``P_s = R P_o + t``.
"""

from typing import TYPE_CHECKING

# Public names load on first use (PEP 562) so that `import optiacoustic` and `oas --help` stay
# fast: scipy, OpenCV, matplotlib and Embree are imported only by the code that needs them.
_LAZY = {
    "Body": ".scene", "Material": ".scene", "Scene": ".scene",
    "Light": ".optical", "OpticalFrame": ".optical", "OpticalOptions": ".optical", "Water": ".optical",
    "simulate_optical": ".optical",
    "PinholeCamera": ".camera",
    "Pose": ".frames",
    "Rig": ".rig",
    "SonarFrame": ".sonar", "SonarOptions": ".sonar", "SonarSpec": ".sonar", "simulate_sonar": ".sonar",
}
_SUBMODULES = ("fusion", "geometry", "io", "matching", "scenes")

if TYPE_CHECKING:  # for type checkers and IDEs only
    from . import fusion, geometry, io, matching, scenes
    from .camera import PinholeCamera
    from .frames import Pose
    from .optical import Light, OpticalFrame, OpticalOptions, Water, simulate_optical
    from .rig import Rig
    from .scene import Body, Material, Scene
    from .sonar import SonarFrame, SonarOptions, SonarSpec, simulate_sonar


def __getattr__(name: str):
    import importlib

    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    elif name in _SUBMODULES:
        value = importlib.import_module(f".{name}", __name__)
    else:
        raise AttributeError(f"module 'optiacoustic' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))


__version__ = "0.1.0"

__all__ = [
    "Body",
    "Light",
    "OpticalFrame",
    "OpticalOptions",
    "Water",
    "simulate_optical",
    "Material",
    "PinholeCamera",
    "Pose",
    "Rig",
    "Scene",
    "SonarFrame",
    "SonarOptions",
    "SonarSpec",
    "fusion",
    "geometry",
    "io",
    "matching",
    "scenes",
    "simulate_sonar",
    "__version__",
]
