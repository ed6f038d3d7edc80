"""The pinhole camera model (OpenCV conventions), with optional OpenCV distortion.

Camera frame: X right, Y down, Z forward. Pixels: ``u = fx X / Z + cx``,
``v = fy Y / Z + cy``, with the top-left pixel's centre at (0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._validate import as_array, as_positive, is_integer, is_number

__all__ = ["PinholeCamera", "MAX_IMAGE_SIDE"]

MAX_IMAGE_SIDE = 32767  # px: OpenCV (remap, imwrite) limit


def _check_side(v, name: str) -> None:
    """An image side: a whole number of pixels from 1 to :data:`MAX_IMAGE_SIDE` (a ValueError naming ``name``)."""
    if not is_integer(v) or v < 1:
        raise ValueError(f"{name}: must be a positive integer, got {v!r}")
    if v > MAX_IMAGE_SIDE:  # OpenCV's remap and image writers stop at 32767 px a side
        raise ValueError(f"{name}: at most {MAX_IMAGE_SIDE} px, got {v}")


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera.

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels.
    cx, cy : float
        Principal point in pixels (top-left pixel centre = (0, 0)).
    width, height : int
        Image size in pixels.
    dist : tuple of 5 floats
        OpenCV distortion ``(k1, k2, p1, p2, k3)``; zeros for an ideal pinhole. A strong
        barrel distortion turns back inside the image (``k1 = -0.6``: the distorted radius
        peaks at 0.50 in normalised coordinates) and produces no pixel beyond that radius:
        :meth:`normalized` and :meth:`pixel_rays` give NaN there (mask: ``np.isfinite``),
        and :func:`~optiacoustic.simulate_optical` refuses such a camera.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, float, float, float, float] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    def __post_init__(self):
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not is_number(v) or not np.isfinite(v) or v <= 0:  # fx=True was a focal length of 1 px
                raise ValueError(f"PinholeCamera.{name}: must be a finite number > 0, got {v!r}")
        for name in ("cx", "cy"):
            v = getattr(self, name)
            if not is_number(v) or not np.isfinite(v):
                raise ValueError(f"PinholeCamera.{name}: must be a finite number, got {v!r}")
        for name in ("width", "height"):
            _check_side(getattr(self, name), f"PinholeCamera.{name}")
        try:
            raw = np.asarray(self.dist)
            d = tuple(float(x) for x in raw.astype(float).reshape(-1)) if raw.dtype.kind in "iuf" else None
        except (TypeError, ValueError):
            d = None
        if d is None or len(d) != 5 or not all(np.isfinite(d)):
            raise ValueError(f"PinholeCamera.dist: expected 5 finite numbers (k1, k2, p1, p2, k3), got {self.dist!r}")
        object.__setattr__(self, "dist", d)
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @classmethod
    def from_sensor(cls, width_px: int = 600, height_px: int = 400, sensor_mm=(36.0, 24.0), focal_mm: float = 50.0,
                    dist=(0.0, 0.0, 0.0, 0.0, 0.0)) -> "PinholeCamera":
        """A camera from its sensor size and lens (the thesis's: 600 x 400 px, 36 x 24 mm, 50 mm)."""
        # checked before they are divided (else a width of 0 was blamed on fx)
        _check_side(width_px, "from_sensor: width_px")
        _check_side(height_px, "from_sensor: height_px")
        sw, sh = as_array(sensor_mm, "sensor_mm", (2,))
        focal_mm = as_positive(focal_mm, "from_sensor: focal_mm")
        if sw <= 0 or sh <= 0:
            raise ValueError(f"from_sensor: sensor_mm must be > 0, got {sensor_mm!r}")
        return cls(
            fx=focal_mm * width_px / sw,
            fy=focal_mm * height_px / sh,
            cx=(width_px - 1) / 2.0,
            cy=(height_px - 1) / 2.0,
            width=width_px,
            height=height_px,
            dist=dist,
        )

    # ------------------------------------------------------------------ matrices
    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(v != 0.0 for v in self.dist)

    @property
    def fov(self) -> tuple[float, float]:
        """Horizontal and vertical field of view (rad) of the undistorted pinhole."""
        return (2 * np.arctan(self.width / (2 * self.fx)), 2 * np.arctan(self.height / (2 * self.fy)))

    # ------------------------------------------------------------------ projection
    def _distort(self, xn: np.ndarray) -> np.ndarray:
        k1, k2, p1, p2, k3 = self.dist
        x, y = xn[..., 0], xn[..., 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return np.stack([xd, yd], -1)

    def project(self, points_camera, *, distort: bool = True) -> np.ndarray:
        """Pixels ``(..., 2)`` of camera-frame points ``(..., 3)``; NaN for points with Z <= 0."""
        p = as_array(points_camera, "points_camera", ("...", 3), finite=False)
        z = p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = p[..., :2] / z[..., None]
        if distort and self.has_distortion:
            xn = self._distort(xn)
        uv = np.stack([self.fx * xn[..., 0] + self.cx, self.fy * xn[..., 1] + self.cy], -1)
        return np.where((z > 0)[..., None], uv, np.nan)

    def in_image(self, pixels) -> np.ndarray:
        """True for pixels ``(..., 2)`` inside the image (pixel centres from 0 to W-1, H-1, plus half a pixel)."""
        uv = np.asarray(pixels, float)
        with np.errstate(invalid="ignore"):
            return (
                (uv[..., 0] >= -0.5) & (uv[..., 0] <= self.width - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= self.height - 0.5)
            )

    def visible(self, points_camera) -> np.ndarray:
        """True for camera-frame points in front of the camera that project inside the image."""
        return self.in_image(self.project(points_camera))

    def _distortion_folds(self, xn: np.ndarray) -> np.ndarray:
        """True where the distortion map is not orientation-preserving at ``xn`` (..., 2): past the
        radius where a strong distortion turns back, so a pixel there is also produced nearer the axis."""
        h = 1e-6
        ex, ey = np.array([h, 0.0]), np.array([0.0, h])
        jx = (self._distort(xn + ex) - self._distort(xn - ex)) / (2 * h)
        jy = (self._distort(xn + ey) - self._distort(xn - ey)) / (2 * h)
        with np.errstate(invalid="ignore"):
            return ~(jx[..., 0] * jy[..., 1] - jx[..., 1] * jy[..., 0] > 0)

    def normalized(self, pixels) -> np.ndarray:
        """Undistorted normalised coordinates ``(X/Z, Y/Z)`` of pixels ``(..., 2)``.

        With distortion, a pixel that the distortion model cannot produce from any direction
        within its valid (unfolded) range gives NaN: the undistorted point is distorted again
        and must land within 0.01 px of the pixel. Mask: ``np.isfinite(xn[..., 0])``.
        """
        uv = as_array(pixels, "pixels", ("...", 2))
        xn = np.stack([(uv[..., 0] - self.cx) / self.fx, (uv[..., 1] - self.cy) / self.fy], -1)
        if self.has_distortion:
            import cv2

            pts = uv.reshape(-1, 1, 2).astype(np.float64)
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
            if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
                und = cv2.undistortPointsIter(pts, self.K, np.asarray(self.dist), None, None, crit)
            else:  # OpenCV 5 dropped it; undistortPoints takes the criteria (with explicit R, P)
                und = cv2.undistortPoints(pts, self.K, np.asarray(self.dist), R=np.eye(3), P=np.eye(3), criteria=crit)
            xn = und.reshape(uv.shape)
            # OpenCV's iteration returns a point for any pixel, also one the model cannot produce
            # (strong barrel distortion beyond its turning radius): check the round trip
            back = self._distort(xn)
            err = np.hypot(self.fx * back[..., 0] + self.cx - uv[..., 0], self.fy * back[..., 1] + self.cy - uv[..., 1])
            with np.errstate(invalid="ignore"):
                bad = ~(err <= 0.01) | self._distortion_folds(xn)
            if np.any(bad):
                xn = np.where(bad[..., None], np.nan, xn)
        return xn

    def pixel_rays(self, pixels=None) -> np.ndarray:
        """Unit viewing directions in the camera frame.

        ``pixels`` ``(..., 2)`` gives ``(..., 3)``; ``None`` gives every pixel centre,
        ``(height, width, 3)``.
        """
        if pixels is None:
            u, v = np.meshgrid(np.arange(self.width, dtype=float), np.arange(self.height, dtype=float))
            pixels = np.stack([u, v], -1)
        xn = self.normalized(pixels)
        d = np.concatenate([xn, np.ones(xn.shape[:-1] + (1,))], -1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def scaled(self, factor: float) -> "PinholeCamera":
        """The same camera with an image ``factor`` times larger (or smaller)."""
        if isinstance(factor, (bool, np.bool_, str, bytes)):
            raise ValueError(f"scaled: factor: expected a number, got {factor!r}")
        factor = as_positive(factor, "scaled: factor")
        if int(round(self.width * factor)) < 1 or int(round(self.height * factor)) < 1:
            raise ValueError(f"scaled: factor: {factor:g} leaves a {self.width} x {self.height} image without pixels")
        w, h = int(round(self.width * factor)), int(round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return PinholeCamera(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, w, h, self.dist)
