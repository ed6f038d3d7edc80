"""Images as they travel to the browser: PNG bytes, never arrays of numbers in JSON.

The sonar is shown as its fan (``cv2.remap`` through :func:`optiacoustic.sonar.display.polar_to_fan`)
in decibels; the fan image's pixel grid is the one the page's clicks are measured in
(:class:`~optiacoustic.sonar.frame.FanImage` ``to_pixel`` / ``from_pixel``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["FAN_WIDTH", "fan_display", "png", "rgba_layer"]

#: Width (px) of the fan image shown in the page.
FAN_WIDTH = 1024
#: Gray level outside the fan.
_OUTSIDE = 24


def fan_display(sonar_image, spec, width: int = FAN_WIDTH):
    """The fan of a polar sonar image with its data mapped to [0, 1] (40 dB display).

    Returns
    -------
    FanImage
        ``data`` float32 in [0, 1] (0 outside the fan), ``mask``, ``extent``, ``pixel_size``.
    """
    from ..sonar.display import polar_to_fan, to_display
    from ..sonar.frame import FanImage

    fan = polar_to_fan(sonar_image, spec, width=width)
    img = np.asarray(sonar_image, float)
    pos = img[img > 0]
    ref = float(np.percentile(pos, 99.5)) if pos.size else 1.0
    data = np.where(fan.mask, to_display(fan.data, reference=ref), 0.0).astype(np.float32)
    return FanImage(data, fan.mask, fan.extent, fan.pixel_size)


def fan_rgb8(fan) -> np.ndarray:
    """An amber-on-black rendering of a display fan, ``(h, w, 3)`` uint8 (RGB)."""
    d = np.clip(fan.data, 0, 1)
    rgb = np.stack([d ** 0.8, d ** 1.1, d ** 2.2], -1) * 255
    rgb[~fan.mask] = _OUTSIDE
    return (rgb + 0.5).astype(np.uint8)


def png(rgb) -> bytes:
    """PNG bytes of an RGB ``(H, W, 3)`` or RGBA ``(H, W, 4)`` uint8 image."""
    import cv2

    a = np.ascontiguousarray(rgb)
    if a.ndim == 3 and a.shape[2] == 3:
        a = cv2.cvtColor(a, cv2.COLOR_RGB2BGR)
    elif a.ndim == 3 and a.shape[2] == 4:
        a = cv2.cvtColor(a, cv2.COLOR_RGBA2BGRA)
    ok, buf = cv2.imencode(".png", a, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise ValueError("cannot encode the image as PNG")
    return buf.tobytes()


def rgba_layer(echo, color=(255, 110, 30)) -> np.ndarray:
    """A coloured layer whose alpha is the echo: ``echo`` (H, W) in [0, 1], NaN transparent."""
    e = np.clip(np.nan_to_num(np.asarray(echo, float), nan=0.0), 0, 1)
    out = np.zeros(e.shape + (4,), np.uint8)
    out[..., :3] = np.asarray(color, np.uint8)
    out[..., 3] = (e * 255 + 0.5).astype(np.uint8)
    return out
