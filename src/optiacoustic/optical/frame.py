"""The result of an optical simulation, and turning linear radiance into 8-bit sRGB."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from ..camera import PinholeCamera
from ..frames import Pose

__all__ = ["OpticalFrame", "to_srgb8", "save_png", "auto_exposure", "STAGES"]

#: Image stages kept on a frame, in the order of the model.
STAGES = ("clear", "attenuated", "forward_scatter", "backscatter", "image")
Stage = Literal["clear", "attenuated", "forward_scatter", "backscatter", "image"]


def auto_exposure(image: np.ndarray, percentile: float = 99.5) -> float:
    """The radiance that maps to display white: the ``percentile`` of all channel values > 0."""
    img = np.asarray(image)
    pos = img[img > 0]
    return float(np.percentile(pos, percentile)) if pos.size else 1.0


def to_srgb8(image: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """Linear RGB ``(H, W, 3)`` -> 8-bit sRGB ``(H, W, 3)`` uint8.

    ``image / exposure`` is clipped to [0, 1] and encoded with the sRGB transfer function
    (IEC 61966-2-1). ``exposure`` (same units as ``image``) defaults to
    :func:`auto_exposure`.
    """
    img = np.asarray(image, np.float32)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"image: expected shape (H, W, 3), got {img.shape}")
    e = auto_exposure(img) if exposure is None else float(exposure)
    if not np.isfinite(e) or e <= 0:
        raise ValueError(f"exposure: must be finite and > 0, got {exposure!r}")
    x = np.clip(img / np.float32(e), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (srgb * 255 + 0.5).astype(np.uint8)


def save_png(path, image: np.ndarray, exposure: float | None = None) -> Path:
    """Write linear RGB ``(H, W, 3)`` as an 8-bit sRGB PNG (see :func:`to_srgb8`)."""
    from .._atomic import imwrite

    rgb = to_srgb8(image, exposure)
    return imwrite(path, np.ascontiguousarray(rgb[..., ::-1]))


@dataclass(frozen=True, eq=False)
class OpticalFrame:
    """One simulated underwater camera frame (thesis ch. 3).

    Every image is ``(H, W, 3)`` float32 linear RGB radiance (W m^-2 sr^-1 for lights in
    W/sr), in the camera's pixel grid (row = v, column = u).

    Attributes
    ----------
    clear : the scene without water: Lambert surfaces lit by the lights (with shadows),
        ``albedo / pi * sum I s cos(gamma) / R_s^2`` (thesis Fig. 3.7a).
    attenuated : ``clear`` with both legs attenuated, ``e^{-c R_s}`` and ``e^{-c R_c}``
        (Fig. 3.7b).
    forward_scatter : ``attenuated`` plus the forward-scattered light: the lamp's
        small-angle scattered light on the surface, and the surface's own, arriving
        through a range-dependent blur (eqs. 3.9, 3.12; Fig. 3.8a).
    backscatter : the veiling light alone (eqs. 3.10-3.13).
    image : ``forward_scatter + backscatter`` (eq. 3.7), plus sensor noise if any (Fig. 3.8b).
    depth : float32 ``(H, W)``
        Range along each pixel's ray to the surface (m), ``inf`` for open water.
    body : int32 ``(H, W)``
        Body id hit by each pixel (``body_names``), ``-1`` for open water.
    normal : float32 ``(H, W, 3)``
        World-frame unit surface normal facing the camera, NaN for open water.
    camera, pose : the camera and its world pose (camera axes).
    water : the :class:`~optiacoustic.optical.Water` it was rendered in.
    lights : tuple of world-frame :class:`~optiacoustic.optical.Light`.
    body_names : tuple of str
    elapsed : float
        Wall-clock time of the simulation (s).
    """

    clear: np.ndarray
    attenuated: np.ndarray
    forward_scatter: np.ndarray
    backscatter: np.ndarray
    image: np.ndarray
    depth: np.ndarray
    body: np.ndarray
    normal: np.ndarray
    camera: PinholeCamera
    pose: Pose
    water: object
    lights: tuple
    body_names: tuple
    elapsed: float = 0.0

    def stage(self, which: Stage) -> np.ndarray:
        """One of :data:`STAGES` by name."""
        if which not in STAGES:
            raise ValueError(f"which: expected one of {STAGES}, got {which!r}")
        return getattr(self, which)

    def exposure(self, which: Stage = "image", percentile: float = 99.5) -> float:
        """Auto exposure of a stage (see :func:`auto_exposure`)."""
        return auto_exposure(self.stage(which), percentile)

    def to_srgb8(self, which: Stage = "image", exposure: float | None = None) -> np.ndarray:
        """A stage as 8-bit sRGB ``(H, W, 3)`` uint8."""
        return to_srgb8(self.stage(which), exposure)

    def save_png(self, path, which: Stage = "image", exposure: float | None = None) -> Path:
        """Write a stage as an sRGB PNG."""
        return save_png(path, self.stage(which), exposure)

    def save_npz(self, path) -> Path:
        """Write every stage, depth, body ids, normals, K, pose and the water to an ``.npz``."""
        from .._atomic import save_npz

        path = Path(path)
        w = self.water
        save_npz(
            path,
            **{s: getattr(self, s) for s in STAGES},
            depth=self.depth,
            body=self.body,
            normal=self.normal,
            body_names=np.array(self.body_names),
            K=self.camera.K,
            dist=np.asarray(self.camera.dist),
            pose_R=self.pose.R,
            pose_t=self.pose.t,
            water_a=np.asarray(w.a),
            water_b=np.asarray(w.b),
            water_name=np.array(w.name),
            light_positions=np.array([lt.position for lt in self.lights]).reshape(-1, 3),
            light_intensities=np.array([lt.intensity for lt in self.lights]).reshape(-1, 3),
        )
        return path
