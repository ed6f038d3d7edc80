"""Automatic opti-acoustic correspondence (the problem the thesis leaves open).

``match(sonar, camera_image, rig)`` finds sonar features and camera features of the same
scene points from the two images and the calibrated rig alone (see docs/matching.md).
Nothing here imports a simulator: it works on any sonar frame through the shared protocol.

Submodules: :mod:`.sonar_features` (CFAR), :mod:`.arc_search` (pixels along each arc),
:mod:`.camera_features` (OpenCV corners),
:mod:`.gating` (epipolar Mahalanobis gate), :mod:`.acoustic` (seabed and shadow evidence),
:mod:`.match` (assignment), :mod:`.optical_two_view` and :mod:`.two_view` (a second pair with known
motion: optical flow against the motion, the arc sweep, acoustic consistency), :mod:`.truth`
(ground truth from a depth map, for evaluation).
"""

from .acoustic import SeabedPlane, elevation_bounds, fit_seabed
from .camera_features import CameraFeatures, KeypointOptions, detect_camera_features
from .match import Matches, MatchNoise, MatchOptions, SeabedReliefWarning, match
from .sonar_features import CfarOptions, SonarFeatures, detect_sonar_features

__all__ = [
    "CameraFeatures",
    "CfarOptions",
    "KeypointOptions",
    "MatchNoise",
    "MatchOptions",
    "SeabedReliefWarning",
    "Matches",
    "SeabedPlane",
    "SonarFeatures",
    "detect_camera_features",
    "detect_sonar_features",
    "elevation_bounds",
    "fit_seabed",
    "match",
]
