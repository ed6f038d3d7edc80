"""Opti-acoustic geometry: epipolar curves, reconstruction, motion, calibration, two-view sonar.

Nothing here imports the simulators: it works on measurements (pixels, ranges, azimuths)
and a :class:`~optiacoustic.rig.Rig`. Submodules:

* :mod:`.projection` - camera and sonar projections through the rig, back-projections.
* :mod:`.epipolar` - sonar-to-optical conics and optical-to-sonar curves (thesis ch. 4).
* :mod:`.reconstruct` - closed-form and maximum-likelihood 3D reconstruction, CRLB (ch. 5).
* :mod:`.stereo` - the stereo-optical baseline of sec. 5.1.
* :mod:`.motion` - motion from opti-acoustic image pairs with metric scale (ch. 6).
* :mod:`.sonar_stereo` - 3D points from two sonar views (appendix B).
* :mod:`.calibrate` - the rig's extrinsics from views of a planar grid (appendix A).
"""

from . import calibrate, epipolar, motion, projection, reconstruct, sonar_stereo, stereo
from .calibrate import CalibrationResult, CalibrationView
from .calibrate import extrinsics as calibrate_extrinsics
from .epipolar import (
    Epipole,
    conic,
    conic_type,
    epipole,
    optical_to_sonar_curves,
    sampson_distance,
    sonar_range,
    sonar_to_optical_curves,
)
from .motion import MonocularSolution, MotionResult, MotionStage, sonar_motion
from .motion import estimate as estimate_motion
from .projection import RigProjection, cos_sin_roots
from .projection import project as project_rig
from .reconstruct import (
    ClosedFormSolution,
    FirstOrderError,
    Refinement,
    azimuth_solution,
    combined_solution,
    crlb,
    first_order_mse,
    range_solution,
    refine,
)
from .sonar_stereo import SonarTriangulation
from .sonar_stereo import triangulate as triangulate_sonar
from .stereo import StereoRig, triangulate_linear, triangulate_optimal

__all__ = [
    "CalibrationResult",
    "CalibrationView",
    "ClosedFormSolution",
    "Epipole",
    "FirstOrderError",
    "MonocularSolution",
    "MotionResult",
    "MotionStage",
    "Refinement",
    "RigProjection",
    "SonarTriangulation",
    "StereoRig",
    "azimuth_solution",
    "calibrate",
    "calibrate_extrinsics",
    "combined_solution",
    "conic",
    "conic_type",
    "cos_sin_roots",
    "crlb",
    "epipolar",
    "epipole",
    "estimate_motion",
    "first_order_mse",
    "motion",
    "optical_to_sonar_curves",
    "project_rig",
    "projection",
    "range_solution",
    "reconstruct",
    "refine",
    "sampson_distance",
    "sonar_motion",
    "sonar_range",
    "sonar_stereo",
    "sonar_to_optical_curves",
    "stereo",
    "triangulate_linear",
    "triangulate_optimal",
    "triangulate_sonar",
]
