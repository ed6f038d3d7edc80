"""Camera features: Shi-Tomasi corners (OpenCV) with sub-pixel refinement and pixel uncertainty."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CameraFeatures", "KeypointOptions", "detect_camera_features", "to_gray8"]


@dataclass(frozen=True)
class KeypointOptions:
    """Options of :func:`detect_camera_features`.

    Attributes
    ----------
    max_corners : int
        ``cv2.goodFeaturesToTrack`` maxCorners (an integer >= 0; 0: no limit, as in OpenCV).
    quality : float
        Its qualityLevel (relative to the strongest corner), in (0, 1].
    min_distance : float
        Its minDistance (px, >= 0).
    clahe_clip : float
        CLAHE clip limit applied first (>= 0; 0: no limit, as in OpenCV): underwater images are
        low-contrast and their contrast falls with distance, so corners are found on local, not
        global, contrast.

    Raises
    ------
    ValueError
        Naming the field and its value when it is outside those ranges.
    """

    max_corners: int = 6000
    quality: float = 0.001
    min_distance: float = 2.0
    clahe_clip: float = 2.0

    def __post_init__(self):
        from .._validate import as_positive, is_integer

        m = self.max_corners
        if not is_integer(m) or m < 0:
            raise ValueError(f"KeypointOptions.max_corners: expected an integer >= 0 (0: no limit), got {m!r}")
        q = as_positive(self.quality, "KeypointOptions.quality")
        if q > 1:
            raise ValueError(f"KeypointOptions.quality: expected a fraction of the strongest corner in (0, 1], "
                             f"got {q!r}")
        as_positive(self.min_distance, "KeypointOptions.min_distance", allow_zero=True)
        as_positive(self.clahe_clip, "KeypointOptions.clahe_clip", allow_zero=True)


@dataclass(frozen=True, eq=False)
class CameraFeatures:
    """Corner features of a camera image.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        ``(u, v)`` image pixels (OpenCV convention, origin at the top-left pixel's centre).
    sigma_pixel : ndarray, shape (N,)
        1-sigma localisation uncertainty (px).
    response : ndarray, shape (N,)
        Minimum eigenvalue of the structure tensor (corner strength, gray levels^2).
    """

    pixels: np.ndarray
    sigma_pixel: np.ndarray
    response: np.ndarray

    def __len__(self) -> int:
        return int(self.pixels.shape[0])


def to_gray8(image) -> np.ndarray:
    """An ``(H, W, 3)`` or ``(H, W)`` image as 8-bit gray, stretched to its 0.5-99.5 percentiles."""
    img = np.asarray(image, np.float64)
    if img.ndim == 3:
        if img.shape[2] not in (3, 4):
            raise ValueError(f"camera_image: expected (H, W, 3), got shape {img.shape}")
        img = img[..., :3].mean(-1)
    elif img.ndim != 2:
        raise ValueError(f"camera_image: expected (H, W, 3), got shape {img.shape}")
    if not np.all(np.isfinite(img)):
        raise ValueError("camera_image: contains NaN or infinite values")
    lo, hi = np.percentile(img, [0.5, 99.5])
    if hi <= lo:
        return np.zeros(img.shape, np.uint8)
    return np.clip((img - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8)


def detect_camera_features(image, options: KeypointOptions = KeypointOptions()) -> CameraFeatures:
    """Shi-Tomasi corners after CLAHE, refined with ``cv2.cornerSubPix``.

    Parameters
    ----------
    image : array_like, shape (H, W, 3) or (H, W)
        Linear radiance (any scale) or 8-bit.
    options : KeypointOptions

    Returns
    -------
    CameraFeatures
        The pixel sigma is the cornerSubPix precision on a noisy corner, taken as
        ``max(0.3, 2 / sqrt(response))`` px: weak corners localise worse.
    """
    import cv2

    if not isinstance(options, KeypointOptions):
        raise ValueError(f"options: expected a KeypointOptions, got {type(options).__name__}")
    g8 = to_gray8(image)
    empty = CameraFeatures(np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    if g8.max() == g8.min():
        return empty
    g8 = cv2.createCLAHE(clipLimit=options.clahe_clip, tileGridSize=(8, 8)).apply(g8)
    pts = cv2.goodFeaturesToTrack(g8, options.max_corners, options.quality, options.min_distance, blockSize=5)
    if pts is None or len(pts) == 0:
        return empty
    pts = cv2.cornerSubPix(g8, pts.astype(np.float32), (3, 3), (-1, -1),
                           (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.03))[:, 0].astype(float)
    eig = cv2.cornerMinEigenVal(g8, 5)
    ui = np.clip(np.round(pts).astype(int), 0, [g8.shape[1] - 1, g8.shape[0] - 1])
    resp = eig[ui[:, 1], ui[:, 0]].astype(float) * 255.0 ** 2
    sig = np.maximum(0.3, 2.0 / np.sqrt(np.maximum(resp, 1e-6)))
    return CameraFeatures(pts, np.minimum(sig, 3.0), resp)
