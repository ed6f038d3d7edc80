"""Ground truth for evaluating matches, from a camera depth map (never from the matcher).

A match (pixel, sonar feature) is correct when the pixel's true 3D point, read from the
camera's depth map, projects into the sonar within one range bin and one beam of the
sonar feature. The depth map is an array (a simulator's ``OpticalFrame.depth``, range along
each pixel's ray, m): nothing here imports a simulator.
"""

from __future__ import annotations

import numpy as np

from ..geometry.projection import to_sonar
from ..rig import Rig

__all__ = ["pixel_points", "correct", "true_pairs", "visible"]


def pixel_points(rig: Rig, depth_map, pixels) -> np.ndarray:
    """Camera-frame points (m) seen at ``pixels`` ``(N, 2)``, from a ``(H, W)`` range-along-ray depth map.

    The nearest pixel's range is used; NaN where the pixel sees open water or is outside.
    """
    D = np.asarray(depth_map, float)
    uv = np.asarray(pixels, float).reshape(-1, 2)
    ui = np.round(uv).astype(int)
    inside = (ui[:, 0] >= 0) & (ui[:, 0] < D.shape[1]) & (ui[:, 1] >= 0) & (ui[:, 1] < D.shape[0])
    d = np.full(len(uv), np.nan)
    d[inside] = D[ui[inside, 1], ui[inside, 0]]
    d[~np.isfinite(d)] = np.nan
    rays = rig.camera.pixel_rays(uv)
    rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    return rays * d[:, None]


def _tolerances(bin_width, beam_width):
    return float(bin_width), float(beam_width)


def correct(rig: Rig, depth_map, pixels, ranges, azimuths, *, bin_width: float, beam_width: float) -> np.ndarray:
    """Whether each match ``(pixels[i], ranges[i], azimuths[i])`` is correct, shape (N,)."""
    P = pixel_points(rig, depth_map, pixels)
    sp = to_sonar(rig, np.where(np.isfinite(P), P, 0.0))
    ok = np.all(np.isfinite(P), -1) & sp.in_fan
    return ok & (np.abs(sp.ranges - np.asarray(ranges)) <= bin_width) & \
        (np.abs(sp.azimuths - np.asarray(azimuths)) <= beam_width)


def true_pairs(rig: Rig, depth_map, pixels, ranges, azimuths, *, bin_width: float, beam_width: float) -> np.ndarray:
    """``(N_sonar, N_camera)`` bool: which (sonar feature, camera feature) pairs are correct."""
    P = pixel_points(rig, depth_map, pixels)
    sp = to_sonar(rig, np.where(np.isfinite(P), P, 0.0))
    ok = np.all(np.isfinite(P), -1) & sp.in_fan
    r = np.asarray(ranges, float)[:, None]
    a = np.asarray(azimuths, float)[:, None]
    return ok[None, :] & (np.abs(sp.ranges[None, :] - r) <= bin_width) & (np.abs(sp.azimuths[None, :] - a) <= beam_width)


def visible(rig: Rig, depth_map, ranges, azimuths, *, bin_width: float, beam_width: float,
            n_samples: int = 800) -> np.ndarray:
    """Whether each sonar feature is seen by the camera: some pixel of its arc sees a point within tolerance.

    The feature's arc ``(r, theta, phi)``, ``|phi| <= fov_elevation / 2``, is sampled at
    ``n_samples`` elevations and projected into the image; the feature is visible in both
    sensors when one of those pixels' true points (from the depth map) projects into the
    sonar within ``bin_width`` and ``beam_width`` of it. Independent of any camera feature
    detector: this is the denominator of recall.

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    from ..geometry.projection import camera_from_sonar, to_pixels

    r = np.asarray(ranges, float).reshape(-1)
    th = np.asarray(azimuths, float).reshape(-1)
    if r.size == 0:
        return np.zeros(0, bool)
    half = rig.fov_elevation / 2
    phis = np.linspace(-half, half, n_samples)
    P = camera_from_sonar(rig, r[:, None], th[:, None], phis[None, :])
    pp = to_pixels(rig, P)
    uv = np.where(pp.in_image[..., None], pp.pixels, 0.0).reshape(-1, 2)
    Pt = pixel_points(rig, depth_map, uv).reshape(P.shape)
    sp = to_sonar(rig, np.where(np.isfinite(Pt), Pt, 0.0))
    good = pp.in_image & np.all(np.isfinite(Pt), -1) & sp.in_fan & \
        (np.abs(sp.ranges - r[:, None]) <= bin_width) & (np.abs(sp.azimuths - th[:, None]) <= beam_width)
    return good.any(axis=1)
