"""Pair sonar and camera frames by time."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FramePairs", "pair_frames"]


@dataclass(frozen=True)
class FramePairs:
    """Index pairs ``(sonar[k], camera[k])`` nearest in time, ``dt = t_camera - t_sonar`` (s)."""

    sonar: np.ndarray
    camera: np.ndarray
    dt: np.ndarray

    def __len__(self):
        return int(self.sonar.size)

    def __iter__(self):
        return iter(zip(self.sonar.tolist(), self.camera.tolist()))


def _times(x, name) -> np.ndarray:
    """Times (s) of a sequence of frames (their ``.time``; a lazy reader decodes each) or of numbers."""
    if isinstance(x, np.ndarray):
        arr = x
    elif hasattr(x, "times") and callable(x.times):  # a reader: times without decoding images where it can
        arr = x.times()
    else:
        items = x if isinstance(x, (list, tuple)) else list(x)
        numeric = all(isinstance(v, (int, float, np.number)) for v in items)
        arr = np.asarray(items, float) if numeric else np.array([f.time for f in items], float)
    arr = np.asarray(arr, float)
    if arr.ndim != 1:
        raise ValueError(f"{name}: expected a sequence of frames or of times (s), got shape {arr.shape}")
    return arr


def pair_frames(sonar, camera, max_dt: float) -> FramePairs:
    """Pair each sonar frame with the camera frame nearest in time, if within ``max_dt`` seconds.

    Parameters
    ----------
    sonar, camera : sequence of frames (with ``.time``) or array_like of times (s)
    max_dt : float
        Largest accepted ``|t_camera - t_sonar|`` (s). Frames with NaN time never pair.

    Returns
    -------
    FramePairs
        Sorted by sonar index; a camera frame may pair with several sonar frames.
    """
    if not np.isfinite(max_dt) or max_dt < 0:
        raise ValueError(f"max_dt: expected a finite number >= 0 (s), got {max_dt!r}")
    ts, tc = _times(sonar, "sonar"), _times(camera, "camera")
    ok_c = np.flatnonzero(np.isfinite(tc))
    if ok_c.size == 0 or ts.size == 0:
        e = np.zeros(0, int)
        return FramePairs(e, e, np.zeros(0))
    order = ok_c[np.argsort(tc[ok_c], kind="stable")]
    tcs = tc[order]
    j = np.clip(np.searchsorted(tcs, ts), 1, tcs.size) if tcs.size > 1 else np.ones(ts.size, int)
    left = np.clip(j - 1, 0, tcs.size - 1)
    right = np.clip(j, 0, tcs.size - 1)
    with np.errstate(invalid="ignore"):
        use_right = np.abs(tcs[right] - ts) < np.abs(tcs[left] - ts)
    best = np.where(use_right, right, left)
    dt = tcs[best] - ts
    keep = np.isfinite(dt) & (np.abs(dt) <= max_dt)
    return FramePairs(np.flatnonzero(keep), order[best[keep]], dt[keep])
