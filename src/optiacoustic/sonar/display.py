"""Displaying sonar images: the fan transform (sec. 2.6.2.4) and intensity-to-gray mappings."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .spec import SonarSpec

__all__ = ["FanImage", "polar_to_fan", "fan_geometry", "fan_shape", "to_display", "save_png"]


@dataclass(frozen=True, eq=False)
class FanImage:
    """A sonar image resampled to Cartesian fan coordinates (sonar at the bottom centre).

    ``data[v, u]`` covers ``x_s`` in ``extent[0:2]`` (m, left to right) and ``y_s`` in
    ``extent[2:4]`` (m, bottom to top); ``mask`` is True inside the fan.
    """

    data: np.ndarray
    mask: np.ndarray
    extent: tuple[float, float, float, float]
    pixel_size: float

    def to_pixel(self, x_s, y_s) -> tuple[np.ndarray, np.ndarray]:
        """Fan-image pixel ``(u, v)`` of fan coordinates (m); pixel centres are integers."""
        u = (np.asarray(x_s, float) - self.extent[0]) / self.pixel_size - 0.5
        v = (self.extent[3] - np.asarray(y_s, float)) / self.pixel_size - 0.5
        return u, v

    def from_pixel(self, u, v) -> tuple[np.ndarray, np.ndarray]:
        """Fan coordinates ``(x_s, y_s)`` (m) of fan-image pixels ``(u, v)``."""
        x = self.extent[0] + (np.asarray(u, float) + 0.5) * self.pixel_size
        y = self.extent[3] - (np.asarray(v, float) + 0.5) * self.pixel_size
        return x, y


# peak memory of one fan image through fan_geometry, polar_to_fan, to_display and a colormap
# (measured: about 100 bytes per fan pixel on ARIS and Oculus logs), an upper estimate for check_memory
FAN_BYTES_PER_PIXEL = 128
MAX_FAN_SIDE = 32767  # px: OpenCV's limit for cv2.remap and its image writers (as camera.MAX_IMAGE_SIDE)


def _fan_layout(spec: SonarSpec, width: int):
    """``(half, extent, pixel_size, height)`` of the fan image ``width`` px wide (nothing allocated)."""
    half = spec.fov_azimuth / 2
    x_max = spec.range_max * np.sin(half)
    y_min = min(0.0, spec.range_min * np.cos(half))
    y_min = 0.0 if half < np.pi / 2 else y_min
    px = 2 * x_max / width
    height = int(np.ceil((spec.range_max - y_min) / px))
    extent = (-x_max, x_max, spec.range_max - height * px, spec.range_max)
    return half, extent, px, height


def fan_shape(spec: SonarSpec, width, *, name: str = "fan width") -> tuple[int, int]:
    """``(height, width)`` of the fan image of ``spec`` at ``width`` px, checked before anything is allocated.

    Raises a ``ValueError`` naming ``name`` (e.g. ``"--width"``) and the value when ``width`` is not an
    integer >= 16, when a side of the image would exceed OpenCV's 32767 px (``cv2.remap`` and the
    image writers stop there), or when the machine lacks the memory to build and show it.
    """
    from .._validate import check_memory, is_integer

    if not is_integer(width) or width < 16:
        raise ValueError(f"{name}: expected an integer >= 16 pixels, got {width!r}")
    width = int(width)
    if width > MAX_FAN_SIDE:
        raise ValueError(f"{name}: at most {MAX_FAN_SIDE} pixels (OpenCV's limit for an image side), got {width}")
    height = _fan_layout(spec, width)[3]
    if height > MAX_FAN_SIDE:
        most = int(MAX_FAN_SIDE * width / height)
        while most > 16 and _fan_layout(spec, most)[3] > MAX_FAN_SIDE:
            most -= 1
        raise ValueError(f"{name}: {width} px gives a fan image {height} px tall for this sonar's "
                         f"{np.rad2deg(spec.fov_azimuth):.4g} deg x {spec.range_max:.4g} m fan; at most "
                         f"{MAX_FAN_SIDE} px a side, so at most {most} px wide")
    check_memory(FAN_BYTES_PER_PIXEL * float(width) * height, f"a {width} x {height} px fan image ({name} {width})")
    return height, width


@functools.lru_cache(maxsize=32)
def fan_geometry(spec: SonarSpec, width: int):
    """Precomputed remap tables for a spec and output width (cached).

    Returns ``(map_col, map_row, mask, extent, pixel_size)``: for each fan pixel, the
    fractional beam (column) and bin (row) of the polar image to sample. ``width`` is
    checked by :func:`fan_shape` first.
    """
    fan_shape(spec, width)
    half, extent, px, height = _fan_layout(spec, int(width))
    u = np.arange(width)
    v = np.arange(height)
    x = extent[0] + (u + 0.5) * px
    y = extent[3] - (v + 0.5) * px
    X, Y = np.meshgrid(x, y)
    r = np.hypot(X, Y)
    th = np.arctan2(X, Y)
    mask = (np.abs(th) <= half) & (r >= spec.range_min) & (r <= spec.range_max)
    col = spec.beam_index(th) - 0.5
    row = spec.bin_index(r) - 0.5
    if spec.has_tables:  # beam/range tables: inside the table's outer edges, not the nominal window
        mask &= (col >= -0.5) & (col <= spec.n_beams - 0.5) & (row >= -0.5) & (row <= spec.n_bins - 0.5)
    col = np.where(mask, col, -10.0).astype(np.float32)
    row = np.where(mask, row, -10.0).astype(np.float32)
    for a in (col, row, mask):
        a.setflags(write=False)
    return col, row, mask, extent, px


@functools.lru_cache(maxsize=4)  # about 13 bytes per fan pixel each (6 MB at 800 px wide)
def _fan_taps(spec: SonarSpec, width: int):
    """The bilinear taps of :func:`fan_geometry`'s maps for ``_numba_kernels.fan_remap`` (cached):
    per fan pixel the flat index of its upper-left polar sample (-1 outside the fan), whether
    its right and lower neighbours exist (flags bits 0, 1; at the border they are the sample
    itself, as ``cv2.BORDER_REPLICATE``) and the weights ``fx``, ``fy`` (float32)."""
    col, row, mask, _, _ = fan_geometry(spec, width)
    J, B = spec.n_beams, spec.n_bins
    c, r = col.astype(np.float64).reshape(-1), row.astype(np.float64).reshape(-1)
    c0, r0 = np.floor(c), np.floor(r)
    fx, fy = (c - c0).astype(np.float32), (r - r0).astype(np.float32)
    cl, cr = np.clip(c0, 0, J - 1).astype(np.int64), np.clip(c0 + 1, 0, J - 1).astype(np.int64)
    rl, rr = np.clip(r0, 0, B - 1).astype(np.int64), np.clip(r0 + 1, 0, B - 1).astype(np.int64)
    base = np.where(mask.reshape(-1), rl * J + cl, -1).astype(np.int32)
    flags = ((cr > cl).astype(np.int8) | ((rr > rl).astype(np.int8) << 1)).astype(np.int8)
    for a in (base, flags, fx, fy):
        a.setflags(write=False)
    return base, flags, fx, fy


def polar_to_fan(image: np.ndarray, spec: SonarSpec, *, width: int = 800) -> FanImage:
    """Resample a polar ``(n_bins, n_beams)`` image to the fan, bilinear with the border replicated
    (``cv2.remap``; with the numba kernels, one pass through taps cached per spec and width)."""
    img = np.asarray(image)
    if img.shape != (spec.n_bins, spec.n_beams):
        raise ValueError(f"image: expected shape (n_bins, n_beams) = {(spec.n_bins, spec.n_beams)}, got {img.shape}")
    if isinstance(width, (float, np.floating)) and float(width).is_integer():
        width = int(width)  # 800.0 is 800; 800.5 is refused by fan_shape rather than truncated
    col, row, mask, extent, px = fan_geometry(spec, width)
    width = int(width)
    src = np.ascontiguousarray(img, dtype=np.float32)
    from ._kernels import chunked_run, kernels, use_numba

    if use_numba():
        from ..raycast import default_threads

        base, flags, fx, fy = _fan_taps(spec, int(width))
        out = np.empty(mask.shape, np.float32)
        flat_src, flat_out, kn = src.reshape(-1), out.reshape(-1), kernels()
        chunked_run(lambda p0, p1: kn.fan_remap(flat_src, base[p0:p1], flags[p0:p1], fx[p0:p1], fy[p0:p1], spec.n_beams,
                                              flat_out[p0:p1]), base.size, default_threads())
        return FanImage(out, mask, extent, px)
    import cv2

    out = cv2.remap(src, col, row, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out[~mask] = 0.0
    return FanImage(out, mask, extent, px)


def to_display(image: np.ndarray, *, mode: str = "db", dynamic_range_db: float = 40.0, reference=None,
               gamma: float = 0.5, percentile: float = 99.5) -> np.ndarray:
    """Map linear intensities to [0, 1] for display.

    ``mode="db"``: ``10 log10(I / reference)`` over ``dynamic_range_db`` (reference: the
    ``percentile`` of the positive values). ``mode="gamma"``: ``(I / reference) ** gamma``.
    """
    from .._validate import as_positive

    if mode == "db":
        dynamic_range_db = as_positive(dynamic_range_db, "to_display: dynamic_range_db")
    elif mode == "gamma":
        gamma = as_positive(gamma, "to_display: gamma")
    else:
        raise ValueError(f"to_display: mode must be 'db' or 'gamma', got {mode!r}")
    if reference is None and not (isinstance(percentile, (int, float, np.integer, np.floating))
                                  and not isinstance(percentile, bool) and 0 <= percentile <= 100):
        raise ValueError(f"to_display: percentile: expected a number in [0, 100], got {percentile!r}")
    if reference is not None:  # 0 (an empty image's percentile) is clamped below; NaN would show all black
        reference = _finite_reference(reference)
    img = np.asarray(image, float)
    pos = img[img > 0]
    if reference is None:
        reference = np.percentile(pos, percentile) if pos.size else 1.0
    reference = max(float(reference), 1e-30)
    if mode == "db":
        with np.errstate(divide="ignore"):
            db = 10 * np.log10(np.maximum(img, 1e-30) / reference)
        return np.clip(1.0 + db / dynamic_range_db, 0.0, 1.0)
    return np.clip(np.maximum(img, 0) / reference, 0, 1) ** gamma  # mode "gamma" (checked above)


def _finite_reference(reference) -> float:
    try:
        v = float(reference)
    except (TypeError, ValueError):
        raise ValueError(f"to_display: reference: expected a number, got {reference!r}") from None
    if not np.isfinite(v):
        raise ValueError(f"to_display: reference: must be finite, got {v!r}")
    return v


def save_png(path, image01: np.ndarray, *, cmap: str = "copper", mask=None) -> None:
    """Write a [0, 1] image with a matplotlib colormap as an 8-bit PNG (outside ``mask`` black)."""
    from matplotlib import colormaps

    from .._atomic import imwrite

    rgba = colormaps[cmap](np.clip(image01, 0, 1))
    rgb = (rgba[..., :3] * 255 + 0.5).astype(np.uint8)
    if mask is not None:
        rgb[~np.asarray(mask)] = 0
    imwrite(path, np.ascontiguousarray(rgb[..., ::-1]))
