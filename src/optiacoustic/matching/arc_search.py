"""Camera pixels chosen for the sonar: a dense search along each sonar feature's arc.

Camera corners rarely sit where the sonar's echoes come from: a sonar feature is a surface
facing the sonar (a box's front face, a sphere's near side), and there the camera sees a
smooth, corner-free patch; its corners lie on silhouettes and edges, where the depth jumps
and the pixel's true point is somewhere else. So instead of gating detected corners, every
sonar feature ``(r, theta)`` searches its own epipolar curve (the arc
``r (cos phi sin theta, cos phi cos theta, sin phi)`` projected into the image) inside the
elevation interval ``[low, high]`` that the seabed and the acoustic shadow allow
(:func:`.acoustic.elevation_maps`). Along that stretch the surface the echo comes from is
imaged as a run of pixels with no image edge (no depth discontinuity, no change of surface):
the longest edge-free run inside the interval is taken and one of its pixels is the match
(the middle for echo peaks; 70% of the way up for echo onsets, the nearest point of a
surface seen from above being its top: fitted on the training scenes 5000-5009, where the
choice is flat between 0.45 and 0.75).
The run's length, the interval's width and where the run sits in it are the evidence the
score uses.

Everything is vectorised over (feature, elevation sample); the run lengths come from
cumulative maxima, not loops.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ArcChoice", "gradient_image", "pixel_values", "search_arcs", "stretched"]


@dataclass(frozen=True, eq=False)
class ArcChoice:
    """The pixel each sonar feature's arc search chose.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        Chosen pixel ``(u, v)``; NaN where nothing was found.
    elevations : ndarray, shape (N,)
        Elevation (rad, sonar frame) of the chosen arc point.
    run_px : ndarray, shape (N,)
        Length (px) of the edge-free run the pixel is the middle of.
    position : ndarray, shape (N,)
        Where the chosen elevation sits in ``[low, high]`` (0 = low, 1 = high; 0.5 when the
        interval is a single elevation).
    visible_px : ndarray, shape (N,)
        Length (px) of the arc's stretch inside the interval and the image.
    found : ndarray of bool, shape (N,)
    contrast : ndarray, shape (N,)
        RGB distance (of the [0, 1] stretched image) between the chosen pixel and the seabed
        just in front (NaN without ``colours`` or where that seabed point is not in the image).
    run_low, run_high : ndarray, shape (N,)
        Elevations (rad) of the run's two ends (NaN where nothing was found).
    top_pixels : ndarray, shape (N, 2)
        Pixel of the run's upper end (its highest elevation; NaN where nothing was found).
    top_edge : ndarray, shape (N,)
        Largest gradient (gray levels per px) of the 5 arc samples just above the run: how
        sharp the edge that ends it is (0 where the run reaches the interval's top).
    """

    pixels: np.ndarray
    elevations: np.ndarray
    run_px: np.ndarray
    position: np.ndarray
    visible_px: np.ndarray
    found: np.ndarray
    contrast: np.ndarray = None
    run_low: np.ndarray = None
    run_high: np.ndarray = None
    top_pixels: np.ndarray = None
    top_edge: np.ndarray = None


def gradient_image(camera_image, sigma: float = 1.0) -> np.ndarray:
    """Gradient magnitude (gray levels per px, of the 0-255 stretched gray image), shape (H, W).

    The image is stretched to its percentiles (:func:`.camera_features.to_gray8`), blurred
    by a Gaussian of ``sigma`` px against sensor noise and differentiated by Sobel (OpenCV).
    """
    import cv2

    from .camera_features import to_gray8

    g = to_gray8(camera_image).astype(np.float32)
    if sigma > 0:
        g = cv2.GaussianBlur(g, (0, 0), sigma)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return np.hypot(gx, gy)


def pixel_values(image: np.ndarray, uv) -> np.ndarray:
    """``image`` at the nearest pixel of each ``uv`` ``(..., 2)`` (px; clamped into the image, NaN read
    as 0): the lookup every stage of the matcher makes at its candidates' pixels. Returns
    ``image[v, u]`` with ``uv``'s leading shape (and ``image``'s trailing channels)."""
    uv = np.asarray(uv, float)
    H, W = image.shape[:2]
    ui = np.clip(np.rint(np.nan_to_num(uv[..., 0])).astype(int), 0, W - 1)
    vi = np.clip(np.rint(np.nan_to_num(uv[..., 1])).astype(int), 0, H - 1)
    return image[vi, ui]


def stretched(camera_image) -> np.ndarray:
    """The camera image scaled to [0, 1] between its 0.5 and 99.5 percentiles (all channels together), float32."""
    img = np.asarray(camera_image, np.float32)[..., :3]
    lo, hi = np.percentile(img, [0.5, 99.5])
    return np.clip((img - lo) / max(float(hi - lo), 1e-12), 0.0, 1.0)


def _longest_runs(flat: np.ndarray):
    """Start and length of the longest run of True in each row of ``flat`` ``(N, n)``."""
    n = flat.shape[1]
    idx = np.arange(n)[None, :]
    last_false = np.maximum.accumulate(np.where(~flat, idx, -1), axis=1)
    length = np.where(flat, idx - last_false, 0)
    end = np.argmax(length, axis=1)
    best = length[np.arange(flat.shape[0]), end]
    return end - best + 1, best


def search_arcs(rig, ranges, azimuths, low, high, gradient, *, fraction=0.5,
                margin: float = float(np.deg2rad(0.25)), threshold: float = 3.0, n_samples: int = 400,
                colours=None, min_contrast: float = 0.0) -> ArcChoice:
    """For every sonar feature, a pixel of the longest edge-free run of its arc inside ``[low, high]``.

    Parameters
    ----------
    rig : Rig
        With the sonar attached (its elevation aperture bounds the search).
    ranges, azimuths : array_like, shape (N,)
        Sonar features (m, rad).
    low, high : array_like, shape (N,)
        Elevation interval of each feature (rad), widened by ``margin`` each side.
    gradient : ndarray, shape (H, W)
        :func:`gradient_image` of the camera image.
    fraction : float or array_like, shape (N,)
        Where in the run (0 = its lowest elevation, 1 = its highest) the pixel is taken.
    margin : float
        Slack on the interval (rad): the seabed plane is known to about 0.1 deg.
    threshold : float
        A sample is edge-free when the gradient there is below this (gray levels per px).
    n_samples : int
        Elevation samples across the whole aperture.
    colours : ndarray, shape (H, W, 3), optional
        The camera image stretched to [0, 1] (:func:`stretched`): with ``min_contrast``,
        pixels whose colour is within ``min_contrast`` (RGB distance) of the seabed's just
        below the interval (at ``low - 0.5 deg``, in front of the object) are not taken: they
        show the seabed, not the echo's surface.
    min_contrast : float

    Returns
    -------
    ArcChoice
    """
    from ..geometry.projection import camera_from_sonar

    r = np.asarray(ranges, float).reshape(-1)
    th = np.asarray(azimuths, float).reshape(-1)
    N = r.size
    nan = np.full(N, np.nan)
    if N == 0:
        return ArcChoice(np.zeros((0, 2)), nan, nan, nan, nan, np.zeros(0, bool), nan, nan, nan, np.zeros((0, 2)), nan)
    half = rig.fov_elevation / 2
    phis = np.linspace(-half, half, n_samples)
    P = camera_from_sonar(rig, r[:, None], th[:, None], phis[None, :])  # (N, n, 3)
    cam = rig.camera
    uv = cam.project(P)
    seen = (P[..., 2] > 0) & cam.in_image(uv)
    lo = np.asarray(low, float).reshape(-1)[:, None] - margin
    hi = np.asarray(high, float).reshape(-1)[:, None] + margin
    inside = seen & (phis[None, :] >= lo) & (phis[None, :] <= hi)
    H, W = gradient.shape
    ui = np.clip(np.rint(np.nan_to_num(uv[..., 0])).astype(int), 0, W - 1)
    vi = np.clip(np.rint(np.nan_to_num(uv[..., 1])).astype(int), 0, H - 1)
    flat = inside & (gradient[vi, ui] < threshold)
    contrast = np.full(N, np.nan)
    if colours is not None:
        P_ref = camera_from_sonar(rig, r, th, np.clip(lo[:, 0] + margin - np.deg2rad(0.5), -half, half))
        uv_ref = cam.project(P_ref)
        ok_ref = (P_ref[:, 2] > 0) & cam.in_image(uv_ref)
        ur = np.clip(np.rint(np.nan_to_num(uv_ref[:, 0])).astype(int), 0, W - 1)
        vr = np.clip(np.rint(np.nan_to_num(uv_ref[:, 1])).astype(int), 0, H - 1)
        ref = colours[vr, ur]  # (N, 3)
        dist = np.linalg.norm(colours[vi, ui] - ref[:, None, :], axis=-1)  # (N, n)
        if min_contrast > 0:
            flat &= ~ok_ref[:, None] | (dist > min_contrast)
    start, length = _longest_runs(flat)
    found = length > 0
    frac = np.broadcast_to(np.asarray(fraction, float), (N,))
    mid = np.clip(start + np.rint(frac * (length - 1)).astype(int), 0, n_samples - 1)
    rows = np.arange(N)
    # Pixel length of the run and of the visible stretch: step length along the curve.
    step = np.linalg.norm(np.diff(np.nan_to_num(uv), axis=1), axis=-1)
    step = np.concatenate([step, step[:, -1:]], axis=1)
    cum = np.cumsum(np.where(flat, step, 0.0), axis=1)
    end = np.clip(start + length - 1, 0, n_samples - 1)
    run_px = np.where(found, cum[rows, end] - cum[rows, np.clip(start, 0, n_samples - 1)] + step[rows, end], 0.0)
    visible_px = np.sum(np.where(inside, step, 0.0), axis=1)
    phi = np.where(found, phis[mid], np.nan)
    width = (hi - lo)[:, 0] - 2 * margin
    with np.errstate(invalid="ignore", divide="ignore"):
        pos = np.where(width > 1e-9, (phi - lo[:, 0] - margin) / width, 0.5)
    px = np.where(found[:, None], uv[rows, mid], np.nan)
    if colours is not None:
        contrast = np.where(ok_ref & found, dist[rows, mid], np.nan)
    top = np.where(found[:, None], uv[rows, end], np.nan)
    run_low = np.where(found, phis[np.clip(start, 0, n_samples - 1)], np.nan)
    run_high = np.where(found, phis[end], np.nan)
    above = np.clip(end[:, None] + np.arange(1, 6)[None, :], 0, n_samples - 1)
    g_above = np.where(inside[rows[:, None], above], gradient[vi[rows[:, None], above], ui[rows[:, None], above]], 0.0)
    top_edge = np.where(found, g_above.max(axis=1), np.nan)
    return ArcChoice(px, phi, run_px, pos, visible_px, found, contrast, run_low, run_high, top, top_edge)
