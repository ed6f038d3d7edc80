"""Candidate pairs from epipolar geometry: a Mahalanobis gate on the sonar-to-optical conic.

For a sonar feature ``(r, theta)`` and a pixel ``m`` the epipolar constraint is
``g = m^T C(r, theta) m = 0`` (:func:`optiacoustic.geometry.epipolar.conic`). Its first-order
(Sampson) Mahalanobis distance over all four noisy measurements is::

    d^2 = g^2 / (sigma_u^2 g_u^2 + sigma_v^2 g_v^2 + sigma_r^2 g_r^2 + sigma_theta^2 g_theta^2)

with ``(g_u, g_v) = 2 (C m)_{1:2}``, ``g_r = -2 r (a . K^-1 m)^2`` (the only ``r`` term of
``C``) and ``g_theta`` by central differences. It is chi-square with one degree of freedom
for a true pair, and it is symmetric: the same number is the distance of the pixel to the
sonar feature's conic and of the sonar feature to the pixel's curve in the sonar image.
The conic also holds the opposite half-plane and points behind the camera; the ML
reconstruction of :func:`optiacoustic.geometry.reconstruct.refine` rejects those.
"""

from __future__ import annotations

import numpy as np

from ..geometry.epipolar import conic
from ..geometry.projection import ideal_pixels
from ..rig import Rig

__all__ = ["mahalanobis_sq"]


def _plane_normal_camera(rig: Rig, azimuths):
    c, s = np.cos(azimuths), np.sin(azimuths)
    R = rig.R
    return np.stack([c * R[0, j] - s * R[1, j] for j in range(3)], -1)


def mahalanobis_sq(rig: Rig, pixels, sigma_pixel, ranges, azimuths, sigma_range, sigma_azimuth) -> np.ndarray:
    """Squared first-order Mahalanobis distance of every (sonar feature, pixel) pair to the epipolar constraint.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (M, 2)
        Image pixels.
    sigma_pixel : array_like, shape (M,)
        Pixel sigma (px).
    ranges, azimuths : array_like, shape (N,)
        Sonar features (m, rad).
    sigma_range, sigma_azimuth : array_like, shape (N,)
        Their sigmas (m, rad).

    Returns
    -------
    ndarray, shape (N, M)
        Chi-square (1 dof) distances; ``inf`` where the gradient vanishes.
    """
    uv = ideal_pixels(rig, np.asarray(pixels, float).reshape(-1, 2))
    m = np.concatenate([uv, np.ones((uv.shape[0], 1))], -1)  # (M, 3)
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    C = conic(rig, r, th)  # (N, 3, 3)
    mT = np.ascontiguousarray(m.T)  # (3, M)
    Cm = C @ mT  # (N, 3, M)
    g = np.sum(mT * Cm, axis=1)
    cam = rig.camera
    Kinv_m = np.stack([(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy, np.ones(len(uv))], -1)
    a = _plane_normal_camera(rig, th)  # (N, 3)
    g_r = -2.0 * r[:, None] * (a @ Kinv_m.T) ** 2
    h = 1e-6
    gp = np.sum(mT * (conic(rig, r, th + h) @ mT), axis=1)
    gm = np.sum(mT * (conic(rig, r, th - h) @ mT), axis=1)
    g_t = (gp - gm) / (2 * h)
    sp = np.asarray(sigma_pixel, float)[None, :]
    var = (sp ** 2) * 4.0 * (Cm[:, 0] ** 2 + Cm[:, 1] ** 2) + (np.asarray(sigma_range, float)[:, None] * g_r) ** 2 \
        + (np.asarray(sigma_azimuth, float)[:, None] * g_t) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = np.where(var > 0, g * g / var, np.inf)
    return d2
