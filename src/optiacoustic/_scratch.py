"""Per-thread scratch arrays that a simulator reuses from frame to frame.

A fresh multi-MB array costs its page faults again on every frame (the kernel zero-fills each new
page on first touch); a frame's temporaries kept per thread are faulted in once. A
:class:`Workspace` is for what a frame uses and drops only, never for what it returns: the next
frame on the same thread overwrites it (``tests/sonar/test_frame_scratch.py``,
``tests/optical/test_frame_scratch.py``). Each simulator has its own :class:`Workspace`, so a
thread that alternates sonar and camera frames keeps both sets.
"""

from __future__ import annotations

import threading

import numpy as np

__all__ = ["Workspace"]


class Workspace:
    """Named per-thread scratch arrays: ``ws(name, shape, dtype)`` returns this thread's array of
    that name, reallocated only when its shape or dtype changes (contents undefined)."""

    def __init__(self) -> None:
        self._local = threading.local()

    def __call__(self, name: str, shape: tuple, dtype) -> np.ndarray:
        cache = getattr(self._local, "arrays", None)
        if cache is None:
            cache = self._local.arrays = {}
        arr = cache.get(name)
        if arr is None or arr.shape != shape or arr.dtype != dtype:
            arr = cache[name] = np.empty(shape, dtype)
        return arr

    def arrays(self) -> list[np.ndarray]:
        """This thread's scratch arrays (for tests that check a frame's outputs share none of them)."""
        return list(getattr(self._local, "arrays", {}).values())
