"""Fusion: map sonar features into a degraded optical image (thesis ch. 7).

* :class:`RBFMapping`: sonar fan coordinates ``(x_s, y_s)`` (m) -> optical pixels, learned
  from matched features with Gaussian radial basis functions (scipy's ``RBFInterpolator``),
  exact or smoothed; :func:`cross_validate` picks the smoothing by leave-one-out error.
* :class:`PlaneMapping`, :class:`PiecewisePlanarMapping`: the same mapping written with the
  rig and a :class:`SonarPlane` (or one plane per triangle of features): the elevation that puts
  ``(r, theta)`` on the plane (:func:`plane_elevation`), then the camera.
* :func:`overlay`, :func:`map_fan`: draw sonar points or a whole fan image into the optical
  image.

Derivations: docs/derivations.md (ch. 7). Nothing here imports the simulators.
"""

from .enhance import map_fan, overlay
from .geometric import (
    ElevationSolution,
    GeometricMap,
    PiecewisePlanarMapping,
    PlaneMapping,
    SonarPlane,
    plane_elevation,
    reconstruct_matches,
)
from .rbf import BASES, CrossValidation, IllConditionedWarning, RBFMapping, cross_validate, epsilon_from_sigma

__all__ = [
    "BASES",
    "CrossValidation",
    "ElevationSolution",
    "GeometricMap",
    "IllConditionedWarning",
    "PiecewisePlanarMapping",
    "PlaneMapping",
    "RBFMapping",
    "SonarPlane",
    "cross_validate",
    "epsilon_from_sigma",
    "map_fan",
    "overlay",
    "plane_elevation",
    "reconstruct_matches",
]
