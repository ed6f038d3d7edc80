"""Planes seen by a moving camera: Sampson error of plane-induced homographies, sequential RANSAC.

With the camera motion ``(R_o, t_o)`` known (metric), a plane ``m . X = 1`` (camera-1
frame) induces the homography ``H = R_o + t_o m^T`` between normalised coordinates. The
Sampson error of a match under ``H`` is the first-order approximation of its squared
reprojection error (Hartley & Zisserman, sec. 4.2.6), in closed form and vectorised over
(hypotheses x matches), which makes it the score of the plane hypotheses below.

Why sequential RANSAC and not k-means on normals: the number of planes is unknown, a
per-point normal needs a neighbourhood (and is meaningless for outliers), and k-means has no
notion of an outlier. Sequential RANSAC on triangulated points, scored in the image by the
Sampson error at the known noise level, finds the planes one at a time, stops when no plane
has enough support, and leaves outliers unlabelled.
"""

from __future__ import annotations

import numpy as np

__all__: list[str] = []


def homography_sampson(Hs, u1, u2) -> np.ndarray:
    """Sampson squared error (in the units of ``u``) of matches under homographies.

    Parameters
    ----------
    Hs : ndarray (H, 3, 3)
        Homographies mapping ``u1`` to ``u2`` (homogeneous coordinates).
    u1, u2 : ndarray (N, 2)
        Matched points.

    Returns
    -------
    ndarray (H, N)
    """
    x1 = np.concatenate([u1, np.ones((u1.shape[0], 1))], 1)  # (N, 3)
    Hx = np.einsum("hij,nj->hni", Hs, x1)  # (H, N, 3)
    x, y = u2[:, 0], u2[:, 1]
    # two rows of [x2]_x H x1: e1 = y w - z', e2 = x' - x w  (w = third, x' first, y'/z' ...)
    hx, hy, hw = Hx[..., 0], Hx[..., 1], Hx[..., 2]
    e = np.stack([y * hw - hy, hx - x * hw], -1)  # (H, N, 2)
    # Jacobian of e w.r.t. (u1x, u1y, u2x, u2y)
    h = Hs  # (H, 3, 3)
    J = np.empty(e.shape + (4,))
    J[..., 0, 0] = y * h[:, None, 2, 0] - h[:, None, 1, 0]
    J[..., 0, 1] = y * h[:, None, 2, 1] - h[:, None, 1, 1]
    J[..., 0, 2] = 0.0
    J[..., 0, 3] = hw
    J[..., 1, 0] = h[:, None, 0, 0] - x * h[:, None, 2, 0]
    J[..., 1, 1] = h[:, None, 0, 1] - x * h[:, None, 2, 1]
    J[..., 1, 2] = -hw
    J[..., 1, 3] = 0.0
    JJ = np.einsum("hnik,hnjk->hnij", J, J)
    det = JJ[..., 0, 0] * JJ[..., 1, 1] - JJ[..., 0, 1] * JJ[..., 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        q = (JJ[..., 1, 1] * e[..., 0] ** 2 - 2 * JJ[..., 0, 1] * e[..., 0] * e[..., 1] + JJ[..., 0, 0] * e[..., 1] ** 2) / det
    return np.where(np.isfinite(q) & (q >= 0), q, np.inf)


def plane_through(points) -> tuple[np.ndarray, np.ndarray]:
    """Planes ``m . X = 1`` through triples of points ``(H, 3, 3)``; ``(m (H, 3), ok (H,))``."""
    det = np.linalg.det(points)
    scale = np.prod(np.linalg.norm(points, axis=2), axis=1)
    ok = np.abs(det) > 1e-9 * scale
    m = np.full((points.shape[0], 3), np.nan)
    if ok.any():
        m[ok] = np.linalg.solve(points[ok], np.ones((int(ok.sum()), 3, 1)))[..., 0]
    return m, ok


def sequential_ransac_plane(points, score, rng, *, n_hypotheses=128, min_support=8):
    """The best plane among random triples of ``points``, scored by ``score``.

    Parameters
    ----------
    points : ndarray (N, 3)
        Triangulated points (camera-1 frame, m); rows with NaN are skipped.
    score : callable (m (H, 3)) -> (support (H,) int, cost (H,) float)
        Support (inlier count) and truncated cost of each hypothesis.
    rng : numpy.random.Generator
    n_hypotheses : int
    min_support : int

    Returns
    -------
    ndarray (3,) or None
        ``m`` of the best-supported plane (in front of the camera), or None when no
        hypothesis reaches ``min_support``.
    """
    ok = np.all(np.isfinite(points), 1) & (points[:, 2] > 0)
    idx = np.flatnonzero(ok)
    if idx.size < max(3, min_support):
        return None
    tri = np.array([rng.choice(idx, 3, replace=False) for _ in range(n_hypotheses)])
    m, good = plane_through(points[tri])
    good &= np.all(np.isfinite(m), 1)
    if not good.any():
        return None
    m = m[good]
    support, cost = score(m)
    best = np.lexsort((cost, -support))[0]
    if support[best] < min_support:
        return None
    return m[best]
