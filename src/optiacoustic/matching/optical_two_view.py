"""Two camera views with known motion: does a match's 3D point move in the image as the camera sees it?

A match of view 1 puts its camera pixel ``u1`` at a 3D point ``P`` (camera frame of view 1, on the
sonar feature's arc). With the rig's motion known (``P_2 = R_o P + t_o``, thesis ch. 6), that
point must appear in the second camera image at ``u2 = project(R_o P + t_o)``. Where the pixel
actually went is measured in the images alone, by dense optical flow between the two camera
frames (OpenCV's DIS flow: same modality, so correspondence is reliable where an image has
structure). The residual ``u1 + flow(u1) - u2`` projected on the direction in which ``u2`` moves
when ``P`` slides along the pixel's ray (the epipolar direction) measures how wrong ``P``'s depth
is; the perpendicular component is flow error only.

What this can and cannot decide (docs/matching.md, "Two views"): a change of depth ``dZ`` moves
``u2`` by about ``f B_perp dZ / Z^2`` px along the epipolar direction (``B_perp`` the baseline
across the line of sight). At 6 m with ``f`` = 833 px and 0.3 m of baseline, one range bin
(2.5 cm) is 0.17 px, far below the flow's error on the uniform faces objects present (several
px, measured), so the test removes matches whose point is on the wrong *surface* (decimetres to
metres off: the seabed in front, the top face, a neighbouring object) but cannot place a point
to one bin along a face.
"""

from __future__ import annotations

import numpy as np

from .two_view import motion_arrays

__all__ = ["FLOW_SIGMA_PX", "flow_field", "epipolar_residuals"]

#: Robust (1.4826 MAD) error of DIS optical flow along the epipolar direction at matched pixels,
#: measured against the depth-map flow on the training scenes 5000-5009 (random vehicle motions):
#: the scale of :func:`epipolar_residuals`.
FLOW_SIGMA_PX = 1.0


def _gray_pair(image_1, image_2):
    """Both images as 8-bit gray with one common stretch (their joint 0.5-99.5 percentiles)."""
    g = []
    for img in (image_1, image_2):
        a = np.asarray(img, np.float64)
        g.append(a[..., :3].mean(-1) if a.ndim == 3 else a)
    lo, hi = np.percentile(np.concatenate([g[0].ravel(), g[1].ravel()]), [0.5, 99.5])
    if hi <= lo:
        return None
    return [np.clip((x - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8) for x in g]


def flow_field(image_1, image_2) -> np.ndarray | None:
    """Dense optical flow from camera image 1 to 2 (OpenCV DIS, medium preset), shape (H, W, 2) px.

    ``None`` when the images are blank (no structure to follow).
    """
    import cv2

    g = _gray_pair(image_1, image_2)
    if g is None:
        return None
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    return dis.calc(g[0], g[1], None)


def epipolar_residuals(camera, pixels_1, points_1, flow, motion) -> tuple[np.ndarray, np.ndarray]:
    """Where each pixel went (flow) against where its point must go (motion), in px.

    Parameters
    ----------
    camera : PinholeCamera
        The rig's camera (the same in both views).
    pixels_1 : array_like, shape (N, 2)
        Pixels ``(u, v)`` of view 1.
    points_1 : array_like, shape (N, 3)
        Their hypothesised 3D points, camera frame of view 1 (m).
    flow : ndarray, shape (H, W, 2)
        :func:`flow_field` from image 1 to image 2.
    motion : MotionResult, Pose or (R_o, t_o)
        ``P_camera2 = R_o P_camera1 + t_o``.

    Returns
    -------
    along : ndarray, shape (N,)
        Signed residual along the epipolar direction (px; positive: the point is farther than
        the flow says). NaN where the point or its image in view 2 is invalid.
    px_per_m : ndarray, shape (N,)
        How far ``u2`` moves per metre of depth along the pixel's ray (px/m): the sensitivity,
        ``f B_perp / Z^2``; a residual of ``along / px_per_m`` metres of depth.
    """
    R, t = motion_arrays(motion)
    uv1 = np.asarray(pixels_1, float).reshape(-1, 2)
    P = np.asarray(points_1, float).reshape(-1, 3)
    n = uv1.shape[0]
    nan = np.full(n, np.nan)
    if n == 0:
        return nan, nan
    H, W = flow.shape[:2]
    ok = np.all(np.isfinite(P), -1) & np.all(np.isfinite(uv1), -1) & (P[:, 2] > 0)
    Pz = np.where(ok[:, None], P, [0.0, 0.0, 1.0])
    dist = np.linalg.norm(Pz, axis=-1, keepdims=True)
    eps = 0.01  # m along the ray
    Q0 = Pz @ R.T + t
    Q1 = (Pz * (1 + eps / dist)) @ R.T + t
    u2 = camera.project(Q0)
    u2b = camera.project(Q1)
    ok &= (Q0[:, 2] > 0) & (Q1[:, 2] > 0)
    d = (u2b - u2) / eps  # px per m of depth
    speed = np.linalg.norm(d, axis=-1)
    direction = d / np.maximum(speed, 1e-12)[:, None]
    ui = np.clip(np.rint(np.nan_to_num(uv1[:, 0])).astype(int), 0, W - 1)
    vi = np.clip(np.rint(np.nan_to_num(uv1[:, 1])).astype(int), 0, H - 1)
    observed = uv1 + flow[vi, ui]
    along = np.sum((u2 - observed) * direction, axis=-1)
    ok &= np.all(np.isfinite(u2), -1) & camera.in_image(u2)
    return np.where(ok, along, np.nan), np.where(ok, speed, np.nan)
