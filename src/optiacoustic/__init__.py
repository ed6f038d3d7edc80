"""optiacoustic: opti-acoustic stereo imaging.

Simulate a forward-looking imaging sonar and an underwater camera, relate their images
(epipolar curves, reconstruction, motion, calibration) and fuse them. Conventions are in
docs/conventions.md: metres and radians, world Z up, sonar X right / Y forward / Z up,
camera X right / Y down / Z forward, rig ``P_s = R P_o + t``.
"""

from . import fusion, geometry, scenes
from .camera import PinholeCamera
from .frames import Pose
from .optical import Light, OpticalFrame, OpticalOptions, Water, simulate_optical
from .rig import Rig
from .scene import Body, Material, Scene
from .sonar import SonarFrame, SonarOptions, SonarSpec, simulate_sonar

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
    "scenes",
    "simulate_sonar",
    "__version__",
]
