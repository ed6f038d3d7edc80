"""Preview images of sonar frames (simulated or measured): polar and fan PNGs and a contact sheet.

Intensities are shown in decibels over a fixed ``dynamic_range_db`` below one reference
level for the whole set (so frames stay comparable), with a matplotlib colormap.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .display import to_display

__all__ = ["colorize", "reference_level", "write_previews"]


def reference_level(frames, percentile: float = 99.5) -> float:
    """A display reference for a set of frames: the ``percentile`` of their positive intensities."""
    vals = np.concatenate([np.asarray(f.image, np.float32).ravel() for f in frames])
    vals = vals[vals > 0]
    return float(np.percentile(vals, percentile)) if vals.size else 1.0


def colorize(image01: np.ndarray, *, cmap: str = "copper", mask=None) -> np.ndarray:
    """A [0, 1] image -> ``(H, W, 3)`` uint8 BGR (for OpenCV writers); black outside ``mask``."""
    from matplotlib import colormaps

    rgb = (colormaps[cmap](np.clip(image01, 0, 1))[..., :3] * 255 + 0.5).astype(np.uint8)
    if mask is not None:
        rgb[~np.asarray(mask)] = 0
    return np.ascontiguousarray(rgb[..., ::-1])


def _label(img: np.ndarray, text: str) -> np.ndarray:
    import cv2

    out = img.copy()
    cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def write_previews(frames, out_dir, *, indices=None, width: int = 600, dynamic_range_db: float = 50.0,
                   cmap: str = "copper", columns: int = 4) -> list[Path]:
    """Write ``polar_NNNN.png``, ``fan_NNNN.png`` per frame and ``contact_sheet.png``; return the paths.

    Parameters
    ----------
    frames : sequence of sonar frames (``.image``, ``.fan()``)
    out_dir : path-like
    indices : sequence of int, optional
        Labels (frame numbers in the source); default ``0..n-1``.
    width : int
        Fan image width (px); the polar image keeps its ``(n_bins, n_beams)`` shape,
        stretched to at least ``width / 2`` px wide so narrow fans stay visible.
    """
    import cv2

    from .._atomic import imwrite

    frames = list(frames)
    if not frames:
        raise ValueError("no frames to preview")
    indices = list(range(len(frames))) if indices is None else list(indices)
    out = Path(out_dir)
    ref = reference_level(frames)
    written, thumbs = [], []
    for k, f in zip(indices, frames):
        polar = to_display(f.image, mode="db", dynamic_range_db=dynamic_range_db, reference=ref)[::-1]  # far on top
        img = colorize(polar, cmap=cmap)
        scale = max(1, int(np.ceil(width / 2 / img.shape[1])))
        img = cv2.resize(img, (img.shape[1] * scale, img.shape[0]), interpolation=cv2.INTER_NEAREST)
        written.append(imwrite(out / f"polar_{k:04d}.png", img))
        fan = f.fan(width=width)
        fimg = colorize(to_display(fan.data, mode="db", dynamic_range_db=dynamic_range_db, reference=ref),
                        cmap=cmap, mask=fan.mask)
        written.append(imwrite(out / f"fan_{k:04d}.png", fimg))
        thumbs.append(_label(fimg, f"frame {k}"))
    th = 240
    tiles = [cv2.resize(t, (max(1, int(round(t.shape[1] * th / t.shape[0]))), th), interpolation=cv2.INTER_AREA)
             for t in thumbs]
    tw = max(t.shape[1] for t in tiles)
    tiles = [np.pad(t, ((0, 0), (0, tw - t.shape[1]), (0, 0))) for t in tiles]
    cols = min(columns, len(tiles))
    rows = -(-len(tiles) // cols)
    tiles += [np.zeros_like(tiles[0])] * (rows * cols - len(tiles))
    sheet = np.vstack([np.hstack(tiles[r * cols:(r + 1) * cols]) for r in range(rows)])
    written.append(imwrite(out / "contact_sheet.png", sheet))
    return written
