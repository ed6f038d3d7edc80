"""The timing helpers of the benchmarks: median wall time after a warm-up, alone or paired with a reference."""

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


def paired_ms(ref, fn, repeat: int = 15, warmup: int = 2, clock=time.perf_counter) -> tuple[float, float]:
    """Medians (ms) of ``ref()`` and ``fn()`` timed alternately, so that load that comes and goes
    falls on both alike; the ratio of the medians is the figure to quote under load.
    ``clock=time.process_time`` gives the process CPU time of all threads instead of wall time."""
    for _ in range(warmup):
        ref()
        fn()
    a, b = [], []
    for _ in range(repeat):
        t0 = clock()
        ref()
        t1 = clock()
        fn()
        t2 = clock()
        a.append(t1 - t0)
        b.append(t2 - t1)
    return 1e3 * float(np.median(a)), 1e3 * float(np.median(b))


class busy_core:
    """Context manager: one other process spins on a core while the block runs.

    Measures what a frame costs when the second core is taken (a ROS node, a viewer).
    """

    def __enter__(self):
        import subprocess
        import sys

        self._p = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        time.sleep(0.2)  # let it start spinning
        return self

    def __exit__(self, *exc):
        self._p.kill()
        self._p.wait()
        return False


class caster_threads:
    """Context manager: a :class:`~optiacoustic.raycast.RayCaster` limited to ``n`` threads, and
    ``OAS_THREADS`` set to ``n`` (what the stages that take no caster read: the fan resampling), so
    that a '1 thread' row runs on one thread throughout."""

    def __init__(self, caster, n: int):
        self.caster, self.n = caster, n

    def __enter__(self):
        import os

        self._old = self.caster.threads
        self._old_env = os.environ.get("OAS_THREADS")
        self.caster.threads = self.n
        os.environ["OAS_THREADS"] = str(self.n)
        return self.caster

    def __exit__(self, *exc):
        import os

        self.caster.threads = self._old
        if self._old_env is None:
            os.environ.pop("OAS_THREADS", None)
        else:
            os.environ["OAS_THREADS"] = self._old_env
        return False


def linear_fit(sizes, times_ms):
    """Least-squares ``t = a + b n``: returns ``(a_ms, b_ms_per_unit, max relative residual)``."""
    n = np.asarray(sizes, float)
    t = np.asarray(times_ms, float)
    A = np.stack([np.ones_like(n), n], -1)
    (a, b), *_ = np.linalg.lstsq(A, t, rcond=None)
    return float(a), float(b), float(np.max(np.abs(A @ [a, b] - t) / t))
