"""Two camera views with known motion: does a match's 3D point move in the image as the camera sees it?

A match of view 1 puts its camera pixel ``u1`` at a 3D point ``P`` (camera frame of view 1, on the
sonar feature's arc). With the rig's motion known (``P_2 = R_o P + t_o``, thesis ch. 6), that
point must appear in the second camera image at ``u2 = project(R_o P + t_o)``. Where the pixel
actually went is measured in the images alone, by dense optical flow between the two camera
frames (OpenCV's DIS flow: same modality, so correspondence is reliable where an image has
structure). The residual ``u1 + flow(u1) - u2`` projected on the direction in which ``u2`` moves
when ``P`` slides along the pixel's ray (the epipolar direction) measures how wrong ``P``'s depth
is; the perpendicular component is flow error only.

The same residual, computed along a sonar feature's whole arc, changes sign where the pixel sees
a surface at the feature's range: :func:`sweep_arcs` takes that elevation (a plane sweep along the
arc, with the sonar's range as the depth hypothesis).

What this can and cannot decide (docs/matching.md, "Two views"): a change of depth ``dZ`` moves
``u2`` by about ``f B_perp dZ / Z^2`` px along the epipolar direction (``B_perp`` the baseline
across the line of sight). At 6 m with ``f`` = 833 px and 0.3 m of baseline, one range bin
(2.5 cm) is 0.05-0.2 px, below the flow's error even on textured surfaces and far below it on
the uniform faces of the plain scenes (several px, measured), so on uniform surfaces the test
only removes matches whose point is on the wrong *surface* (decimetres to metres off); on
textured ones the sweep places the point to a few bins.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .two_view import motion_arrays

__all__ = ["ArcCorrelation", "ArcSweep", "correlate_arcs", "epipolar_residuals", "flow_field",
           "forward_backward_error", "photo_consistency", "sweep_arcs"]


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


def forward_backward_error(flow_12, flow_21) -> np.ndarray:
    """``|F12(u) + F21(u + F12(u))|`` per pixel of image 1, shape (H, W) px: where the flow is trustworthy."""
    import cv2

    H, W = flow_12.shape[:2]
    u, v = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    mx = u + flow_12[..., 0]
    my = v + flow_12[..., 1]
    back = cv2.remap(flow_21, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(1e3, 1e3))
    err = np.linalg.norm(flow_12 + back, axis=-1)
    outside = (mx < 0) | (mx > W - 1) | (my < 0) | (my > H - 1)
    return np.where(outside, np.inf, err)


@dataclass(frozen=True, eq=False)
class ArcSweep:
    """For each sonar feature, the arc pixel whose optical flow agrees with the known motion.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        ``(u, v)`` of view 1; NaN where no crossing was found.
    elevations : ndarray, shape (N,)
        Elevation (rad, sonar frame) of the chosen arc point.
    found : ndarray of bool, shape (N,)
    n_crossings : ndarray, shape (N,)
        How many places along the arc (inside the elevation interval) the residual changes sign
        smoothly: each is a surface at the feature's range as far as the flow can tell.
    fb_error : ndarray, shape (N,)
        Forward-backward flow error at the chosen pixel (px).
    slope : ndarray, shape (N,)
        ``|d residual / d elevation|`` at the crossing (px per degree): how sharply the flow
        pins the elevation.
    px_per_m : ndarray, shape (N,)
        The motion's sensitivity there (px per metre of depth).
    """

    pixels: np.ndarray
    elevations: np.ndarray
    found: np.ndarray
    n_crossings: np.ndarray
    fb_error: np.ndarray
    slope: np.ndarray
    px_per_m: np.ndarray


def sweep_arcs(rig, ranges, azimuths, low, high, flow, fb_error, motion, *, n_samples: int = 400,
               max_jump: float = 1.0, margin: float = float(np.deg2rad(0.25))) -> ArcSweep:
    """Along each sonar feature's arc, the elevation where the pixel moves as the motion says its point must.

    The arc ``r (cos phi sin theta, cos phi cos theta, sin phi)`` is sampled at ``n_samples``
    elevations across the aperture; at each sample the residual of :func:`epipolar_residuals`
    (flow against motion, along the epipolar direction) is computed. Where the pixel sees a
    surface at the feature's range the residual is zero: the residual's sign changes there.
    A sign change across a jump larger than ``max_jump`` px between neighbouring samples is a
    depth discontinuity (an occluding edge), not a crossing. Among the crossings inside
    ``[low - margin, high + margin]`` the one with the smallest forward-backward flow error
    is taken (sub-sample, by linear interpolation).

    Parameters
    ----------
    rig : Rig
        With the sonar attached.
    ranges, azimuths, low, high : array_like, shape (N,)
        Sonar features (m, rad) and their elevation intervals (rad).
    flow : ndarray, shape (H, W, 2)
        :func:`flow_field` from image 1 to image 2.
    fb_error : ndarray, shape (H, W)
        :func:`forward_backward_error`.
    motion : MotionResult, Pose or (R_o, t_o)

    Returns
    -------
    ArcSweep
    """
    N, phis, P = _arc_points(rig, ranges, azimuths, n_samples)
    nan = np.full(N, np.nan)
    if N == 0:
        return ArcSweep(np.zeros((0, 2)), nan, np.zeros(0, bool), nan, nan, nan, nan)
    cam = rig.camera
    uv = cam.project(P)
    a, sens = epipolar_residuals(cam, uv.reshape(-1, 2), P.reshape(-1, 3), flow, motion)
    a, sens = a.reshape(N, n_samples), sens.reshape(N, n_samples)
    lo = np.asarray(low, float).reshape(-1)[:, None] - margin
    hi = np.asarray(high, float).reshape(-1)[:, None] + margin
    ok = np.isfinite(a) & (phis[None, :] >= lo) & (phis[None, :] <= hi)
    a0, a1 = a[:, :-1], a[:, 1:]
    cross = ok[:, :-1] & ok[:, 1:] & (np.sign(a0) != np.sign(a1)) & (np.abs(a1 - a0) <= max_jump)
    H, W = fb_error.shape
    ui = np.clip(np.rint(np.nan_to_num(uv[..., 0])).astype(int), 0, W - 1)
    vi = np.clip(np.rint(np.nan_to_num(uv[..., 1])).astype(int), 0, H - 1)
    fb = fb_error[vi, ui]
    fb_c = np.where(cross, np.maximum(fb[:, :-1], fb[:, 1:]), np.inf)
    j = np.argmin(fb_c, axis=1)
    rows = np.arange(N)
    found = np.isfinite(fb_c[rows, j])
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.clip(a0[rows, j] / (a0[rows, j] - a1[rows, j]), 0.0, 1.0)
    frac = np.where(found, frac, 0.0)
    step = phis[1] - phis[0]
    phi = phis[j] + frac * step
    from ..geometry.projection import camera_from_sonar

    Pc = camera_from_sonar(rig, np.asarray(ranges, float).reshape(-1), np.asarray(azimuths, float).reshape(-1), phi)
    px = cam.project(Pc)
    slope = np.abs(a1[rows, j] - a0[rows, j]) / np.rad2deg(step)
    return ArcSweep(np.where(found[:, None], px, np.nan), np.where(found, phi, np.nan), found,
                    cross.sum(axis=1).astype(float), np.where(found, fb_c[rows, j], np.nan),
                    np.where(found, slope, np.nan), np.where(found, sens[rows, j], np.nan))



def _sample(gray, uv):
    """Bilinear samples of ``gray`` (H, W) float32 at ``uv`` (..., 2); NaN outside the image."""
    import cv2

    shp = uv.shape[:-1]
    flat = uv.reshape(-1, 2)
    n = flat.shape[0]
    width = 4096  # OpenCV maps must stay below 32767 px a side
    rows = max(1, -(-n // width))
    pad = np.full((rows * width, 2), -1e6, np.float32)
    pad[:n] = flat
    mx = np.ascontiguousarray(pad[:, 0].reshape(rows, width))
    my = np.ascontiguousarray(pad[:, 1].reshape(rows, width))
    out = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return out.reshape(-1)[:n].reshape(shp)


def photo_consistency(image_1, image_2, pixels_1, pixels_2, *, half_size: int = 4):
    """Normalised cross-correlation of square patches around ``pixels_1`` (image 1) and ``pixels_2`` (image 2).

    Parameters
    ----------
    image_1, image_2 : ndarray, shape (H, W, 3) or (H, W)
    pixels_1, pixels_2 : ndarray, shape (..., 2)
        Hypothesised corresponding pixels.
    half_size : int
        Patches of ``2 half_size + 1`` px a side, axis-aligned (the views differ by a small rotation).

    Returns
    -------
    ncc : ndarray, shape (...)
        In [-1, 1]; NaN where a patch leaves an image or is flat (gray sigma < 0.5 of 255).
    texture : ndarray, shape (...)
        Standard deviation of image 1's patch (gray levels of the common 0-255 stretch).
    """
    u1 = np.asarray(pixels_1, float)
    u2 = np.asarray(pixels_2, float)
    g = _gray_pair(image_1, image_2)
    if g is None:
        nan = np.full(u1.shape[:-1], np.nan)
        return nan, nan
    g1, g2 = (x.astype(np.float32) for x in g)
    offs = np.arange(-half_size, half_size + 1, dtype=float)
    dx, dy = np.meshgrid(offs, offs)
    a = np.stack([_sample(g1, u1 + o) for o in zip(dx.ravel(), dy.ravel())], -1)  # (..., K)
    b = np.stack([_sample(g2, u2 + o) for o in zip(dx.ravel(), dy.ravel())], -1)
    a = a - a.mean(-1, keepdims=True)
    b = b - b.mean(-1, keepdims=True)
    sa, sb = np.sqrt((a ** 2).mean(-1)), np.sqrt((b ** 2).mean(-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        ncc = (a * b).mean(-1) / (sa * sb)
    return np.where((sa > 0.5) & (sb > 0.5), ncc, np.nan), sa


@dataclass(frozen=True, eq=False)
class ArcCorrelation:
    """For each sonar feature, the arc pixel whose patch looks the same at its point's place in image 2.

    Attributes
    ----------
    pixels, elevations, found : as :class:`ArcSweep`.
    ncc : ndarray, shape (N,)
        Peak normalised cross-correlation.
    margin : ndarray, shape (N,)
        Peak minus the best correlation more than 0.5 deg of elevation away (uniqueness).
    texture : ndarray, shape (N,)
        Gray sigma of image 1's patch at the peak.
    px_per_m : ndarray, shape (N,)
        The motion's sensitivity there (px per metre of depth).
    """

    pixels: np.ndarray
    elevations: np.ndarray
    found: np.ndarray
    ncc: np.ndarray
    margin: np.ndarray
    texture: np.ndarray
    px_per_m: np.ndarray


def correlate_arcs(rig, ranges, azimuths, low, high, image_1, image_2, motion, *, n_samples: int = 400,
                   margin: float = float(np.deg2rad(0.25))) -> ArcCorrelation:
    """Along each sonar feature's arc, the elevation whose pixel and whose moved point look alike in both images.

    A plane sweep by photo-consistency: each arc sample ``P(phi)`` is a hypothesis; its pixel in
    image 1 and the pixel of ``R_o P + t_o`` in image 2 are compared by the normalised
    cross-correlation of 9 x 9 patches (:func:`photo_consistency`), and the peak inside
    ``[low - margin, high + margin]`` is taken where the motion gives parallax (more than 0.1 px
    per metre of depth). Unlike :func:`sweep_arcs` it needs no optical
    flow, so it follows baselines of a metre or more, where the image moves by hundreds of
    pixels; it needs texture.
    """
    R, t = motion_arrays(motion)
    N, phis, P = _arc_points(rig, ranges, azimuths, n_samples)
    nan = np.full(N, np.nan)
    if N == 0:
        return ArcCorrelation(np.zeros((0, 2)), nan, np.zeros(0, bool), nan, nan, nan, nan)
    cam = rig.camera
    u1 = cam.project(P)
    Q = P @ R.T + t
    u2 = cam.project(Q)
    lo = np.asarray(low, float).reshape(-1)[:, None] - margin
    hi = np.asarray(high, float).reshape(-1)[:, None] + margin
    ok = (P[..., 2] > 0) & (Q[..., 2] > 0) & cam.in_image(u1) & cam.in_image(u2) & (phis >= lo) & (phis <= hi)
    ncc, tex = photo_consistency(image_1, image_2, np.nan_to_num(u1), np.nan_to_num(u2))
    ncc = np.where(ok, ncc, np.nan)
    has = np.isfinite(ncc)
    found = has.any(axis=1)
    filled = np.where(has, ncc, -np.inf)
    j = np.argmax(filled, axis=1)
    rows = np.arange(N)
    away = np.abs(phis[None, :] - phis[j][:, None]) > np.deg2rad(0.5)
    second = np.max(np.where(away & has, ncc, -1.0), axis=1)
    _, sens = epipolar_residuals(cam, u1[rows, j], P[rows, j], np.zeros((cam.height, cam.width, 2), np.float32),
                                 motion)
    peak = ncc[rows, j]
    # The motion must move the point across the image: with no parallax every elevation
    # correlates alike and the peak says nothing.
    found &= np.nan_to_num(sens) > 0.1
    return ArcCorrelation(np.where(found[:, None], u1[rows, j], np.nan), np.where(found, phis[j], np.nan), found,
                          np.where(found, peak, np.nan), np.where(found, peak - second, np.nan),
                          np.where(found, tex[rows, j], np.nan), np.where(found, sens, np.nan))


def _arc_points(rig, ranges, azimuths, n_samples: int):
    """Each sonar feature's arc sampled in elevation: ``(N, phis (n_samples,) rad, P (N, n_samples, 3))``.

    ``P`` is in the camera frame (m); the samples span the sonar's elevation aperture.
    """
    from ..geometry.projection import camera_from_sonar

    r = np.asarray(ranges, float).reshape(-1)
    th = np.asarray(azimuths, float).reshape(-1)
    half = rig.fov_elevation / 2
    phis = np.linspace(-half, half, n_samples)
    P = camera_from_sonar(rig, r[:, None], th[:, None], phis[None, :]) if r.size else np.zeros((0, n_samples, 3))
    return r.size, phis, P
