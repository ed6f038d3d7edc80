"""Two-view consistency of opti-acoustic matches (thesis ch. 6: the rig moved by a known motion).

A correct match of view 1 reconstructs a scene point that view 2's rig sees too: moved by the
motion ``P'_o = R_o P_o + t_o`` (camera frame of view 1 to view 2, as
:class:`optiacoustic.geometry.motion.MotionResult` gives it), it must land near a point that
view 2's own matches reconstruct. A wrong match puts its point at the wrong elevation on its
arc; seen from elsewhere, that point falls where view 2 found nothing.
"""

from __future__ import annotations

import numpy as np

from .._validate import as_array

__all__ = ["motion_arrays", "consistent"]


def motion_arrays(motion) -> tuple[np.ndarray, np.ndarray]:
    """``(R_o, t_o)`` from a MotionResult (``.R_o``, ``.t_o``), a Pose (``.R``, ``.t``) or a tuple."""
    if hasattr(motion, "R_o") and hasattr(motion, "t_o"):
        R, t = motion.R_o, motion.t_o
    elif hasattr(motion, "R") and hasattr(motion, "t"):
        R, t = motion.R, motion.t
    elif isinstance(motion, (tuple, list)) and len(motion) == 2:
        R, t = motion
    else:
        raise ValueError(f"motion: expected a MotionResult, a Pose or (R_o, t_o), got {type(motion).__name__}")
    R = as_array(R, "motion R_o", (3, 3))
    t = as_array(t, "motion t_o", (3,))
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError("motion R_o: not a rotation matrix")
    return R, t


def consistent(points_1, points_2, motion, *, tolerance: float = 0.08, relative: float = 0.01) -> np.ndarray:
    """Which view-1 points have a view-2 point within tolerance once moved into view 2's camera frame.

    Parameters
    ----------
    points_1 : array_like, shape (N, 3)
        Points reconstructed from view 1's matches (camera frame of view 1, m).
    points_2 : array_like, shape (M, 3)
        Points reconstructed from view 2's matches (camera frame of view 2, m).
    motion : MotionResult, Pose or (R_o, t_o)
        ``P_2 = R_o P_1 + t_o``.
    tolerance : float
        Absolute 3D tolerance (m): the ML reconstructions' own error is a few cm.
    relative : float
        Plus this fraction of the point's depth.

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    from scipy.spatial import cKDTree

    R, t = motion_arrays(motion)
    p1 = np.asarray(points_1, float).reshape(-1, 3)
    p2 = np.asarray(points_2, float).reshape(-1, 3)
    if p1.shape[0] == 0 or p2.shape[0] == 0:
        return np.zeros(p1.shape[0], bool)
    moved = p1 @ R.T + t
    ok2 = np.all(np.isfinite(p2), -1)
    tree = cKDTree(p2[ok2])
    d, _ = tree.query(np.nan_to_num(moved, nan=1e9), k=1)
    return np.isfinite(d) & (d <= tolerance + relative * np.abs(moved[:, 2]))
