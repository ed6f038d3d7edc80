"""Helpers shared by the sonar tests."""

from __future__ import annotations


def both_kernel_paths(monkeypatch, fn):
    """``fn()`` on the compiled kernels and on the pure numpy reference (``OAS_KERNELS``):
    ``(numba_result, numpy_result)``, for tests that compare the two paths on the same inputs."""
    out = {}
    for k in ("numba", "numpy"):
        monkeypatch.setenv("OAS_KERNELS", k)
        out[k] = fn()
    return out["numba"], out["numpy"]
