"""Which implementation of the sonar's inner loops runs: compiled (numba) or the numpy reference.

``OAS_KERNELS=numpy`` selects the pure-numpy reference path; ``numba`` (the default)
the compiled kernels of :mod:`._numba_kernels`, when numba is installed. numba is imported
on the first frame only, never by ``import optiacoustic`` or ``oas --help``; the kernels
are cached on disk, so only the first run on a machine compiles them (a few seconds).
Both paths compute the same images (tests/sonar/test_kernels.py compares them).
"""

from __future__ import annotations

import threading

import numpy as np

from .. import _kernel_switch as _switch
from .._scratch import Workspace

__all__ = ["use_numba", "kernels", "truth_kernels", "split_run", "chunked_run", "take_turns", "wait_or_cancel",
           "wait_or_run_here", "workspace", "pooled", "give_back"]


def use_numba() -> bool:
    """True when the numba kernels are selected (``OAS_KERNELS``, default ``numba``) and importable."""
    return _switch.use_numba()


def kernels():
    """The compiled kernels module (imports numba)."""
    from . import _numba_kernels

    return _numba_kernels


def truth_kernels():
    """The compiled ground-truth kernels module (imports numba)."""
    from . import _truth_kernels

    return _truth_kernels


_POOL = None


def _pool(n: int):
    global _POOL
    if _POOL is None or _POOL._max_workers < n:  # noqa: SLF001 - sizing our own pool
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="oas-sonar-kernels")
    return _POOL


def split_run(fn, n: int, threads: int) -> None:
    """Run ``fn(a, b)`` over ``[0, n)`` in ``threads`` contiguous parts (one on this thread).

    For GIL-releasing kernels; the parts must write disjoint outputs.
    """
    threads = max(1, min(int(threads), n // 64 or 1))
    if threads == 1:
        fn(0, n)
        return
    bounds = [n * k // threads for k in range(threads + 1)]
    pool = _pool(threads - 1)
    futs = [pool.submit(fn, bounds[k], bounds[k + 1]) for k in range(1, threads)]
    fn(bounds[0], bounds[1])
    for k, f in enumerate(futs, start=1):
        wait_or_run_here(f, fn, bounds[k], bounds[k + 1])


def wait_or_run_here(job, fn, *args) -> None:
    """Wait for a pool ``job`` that runs ``fn(*args)``; if its worker has not started it yet (no free
    core, e.g. the noise's draws hold the other one), cancel it and run ``fn(*args)`` on this thread,
    never later than the worker would have (i14r)."""
    if job.cancel():
        fn(*args)
    else:
        job.result()


def wait_or_cancel(jobs) -> None:
    """Wait for the pool jobs of a work-sharing loop whose caller has just run out of work (every chunk
    taken): a job that has not started (its worker had no core, e.g. the noise's draws held the other
    one) is cancelled instead, since it would find nothing left to do (i14r: the caller waited up to
    0.5 ms for such a worker to be scheduled, only to return)."""
    for job in jobs:
        if not job.cancel():
            job.result()


#: Chunks per thread of :func:`chunked_run`.
_CHUNKS_PER_THREAD = 4


def chunked_run(fn, n: int, threads: int) -> None:
    """``fn(a, b)`` over ``[0, n)`` in chunks that ``threads`` workers (this thread one of them)
    take in turn as they finish the last: a thread slowed by another process, or by the noise
    draws on the second core, takes fewer (:func:`split_run`'s fixed halves waited for it). For
    GIL-releasing kernels whose chunks write disjoint outputs."""
    threads = max(1, min(int(threads), n // 64 or 1))
    if threads == 1:
        fn(0, n)
        return
    step = -(-n // (threads * _CHUNKS_PER_THREAD))
    starts = iter(range(0, n, step))  # next() on it is atomic under the GIL: each chunk goes to one worker

    def work():
        for a in starts:
            fn(a, min(a + step, n))

    take_turns(work, threads)


def take_turns(work, threads: int) -> None:
    """Run ``work()`` on this thread and on ``threads - 1`` pool workers at once; ``work`` takes items
    from a shared iterator until none is left (``next()`` is atomic under the GIL), so a slowed thread
    takes fewer. A worker that has not started when this thread runs out is cancelled
    (:func:`wait_or_cancel`)."""
    jobs = [_pool(threads - 1).submit(work) for _ in range(threads - 1)]
    work()
    wait_or_cancel(jobs)


#: per-thread scratch of this simulator's frames (see :mod:`optiacoustic._scratch`)
workspace = Workspace()


# Buffers that one frame holds from one thread to another (the noise variates, drawn on the background
# thread and read on the caller's): a per-thread workspace would be overwritten by the next frame drawn
# there before this one has read it, so they are taken from a shared pool and handed back explicitly.
_POOLED: dict = {}
_POOLED_LOCK = threading.Lock()
_POOLED_KEEP = 8  # free buffers kept per (shape, dtype): a few frames in flight at once


def pooled(shape: tuple, dtype) -> np.ndarray:
    """An uninitialised array of ``shape`` and ``dtype`` from the pool (or fresh); it belongs to the
    caller until :func:`give_back` (thread-safe). For scratch only, never for what a frame returns."""
    key = (tuple(shape), np.dtype(dtype).str)
    with _POOLED_LOCK:
        free = _POOLED.get(key)
        if free:
            return free.pop()
    return np.empty(key[0], key[1])


def give_back(*arrays) -> None:
    """Return arrays taken by :func:`pooled` (``None`` entries are skipped); the caller must not use
    them afterwards: the next :func:`pooled` of their shape may hand them to another frame."""
    with _POOLED_LOCK:
        for a in arrays:
            if a is None:
                continue
            free = _POOLED.setdefault((a.shape, a.dtype.str), [])
            if len(free) < _POOLED_KEEP and not any(b is a for b in free):
                free.append(a)
