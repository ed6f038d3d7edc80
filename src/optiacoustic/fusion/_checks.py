"""Validation of matched features shared by every mapping of :mod:`optiacoustic.fusion`.

A mapping is learned from ``N`` matches: sonar fan coordinates ``(x_s, y_s)`` (m) and the
optical pixels ``(u, v)`` of the same scene points. Degenerate layouts are caller mistakes
that scipy would otherwise report as a ``LinAlgError`` (or not at all): they raise a
``ValueError`` here, before any fit.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_array

#: Two sonar features closer than this fraction of the layout's extent count as duplicates.
DUPLICATE_RTOL = 1e-9
#: A layout whose second singular value is below this fraction of the first is collinear.
COLLINEAR_RTOL = 1e-6


def check_layout(sonar_xy, name: str = "sonar_xy", *, min_count: int = 3) -> np.ndarray:
    """Sonar features as an ``(N, 2)`` float array, or a ValueError that says what is wrong.

    Parameters
    ----------
    sonar_xy : array_like, shape (N, 2)
        Fan coordinates ``(x_s, y_s)`` (m).
    name : str
        Argument name for the messages.
    min_count : int
        Fewest features the caller's model needs.

    Raises
    ------
    ValueError
        Wrong shape, NaN or infinity, fewer than ``min_count`` features, two features at
        the same place (indices given), or all features on one line.
    """
    xy = as_array(sonar_xy, name, (None, 2))
    n = len(xy)
    if n < min_count:
        raise ValueError(f"{name}: need at least {min_count} matched features, got {n}")
    centred = xy - xy.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    extent = float(s[0]) / np.sqrt(n) if s[0] > 0 else 0.0
    if extent == 0.0:
        raise ValueError(f"{name}: all {n} features are at the same place {xy[0].tolist()}")
    pairs = cKDTree(xy).query_pairs(DUPLICATE_RTOL * max(extent, float(np.abs(xy).max())), output_type="ndarray")
    if len(pairs):
        i, j = (int(k) for k in pairs[0])
        raise ValueError(
            f"{name}: features {i} and {j} are duplicated at {xy[i].tolist()} ({len(pairs)} duplicated pair(s)); "
            f"a mapping cannot send one sonar point to two pixels: merge or drop them"
        )
    if s[1] <= COLLINEAR_RTOL * s[0]:
        raise ValueError(
            f"{name}: the {n} features are collinear (singular values {s[0]:.3g}, {s[1]:.3g}); a 2D mapping "
            f"is undetermined off their line: add features off it"
        )
    return xy


def check_matches(sonar_xy, pixels, *, min_count: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``(sonar_xy (N, 2), pixels (N, 2))`` (see :func:`check_layout`)."""
    xy = check_layout(sonar_xy, "sonar_xy", min_count=min_count)
    px = as_array(pixels, "pixels", (None, 2))
    if len(px) != len(xy):
        raise ValueError(f"pixels: expected one pixel per sonar feature ({len(xy)}), got {len(px)}")
    return xy, px


def query_points(sonar_xy, name: str = "sonar_xy") -> tuple[np.ndarray, np.ndarray, tuple]:
    """Flattened ``(M, 2)`` query points, a finite-row mask and the leading shape.

    Non-finite rows are allowed (they come back as NaN), a wrong shape is not.
    """
    xy = as_array(sonar_xy, name, ("...", 2), finite=False)
    shape = xy.shape[:-1]
    flat = xy.reshape(-1, 2)
    return flat, np.all(np.isfinite(flat), axis=-1), shape
