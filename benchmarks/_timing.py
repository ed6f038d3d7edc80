"""The one timing helper of the benchmarks: median wall time after a warm-up."""

from __future__ import annotations

import time

import numpy as np


def median_ms(fn, repeat: int = 15, warmup: int = 2) -> float:
    """Median wall-clock time of ``fn()`` in milliseconds over ``repeat`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))
