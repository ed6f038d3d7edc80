"""One switch for the compiled inner loops of both simulators.

``OAS_KERNELS=numba`` (the default) runs the sonar's and the camera's numba kernels
(:mod:`optiacoustic.sonar._numba_kernels`, :mod:`optiacoustic.optical._kernels`);
``OAS_KERNELS=numpy`` runs the pure-numpy reference paths that the tests compare them with.
Nothing here imports numba unless the kernels are asked for.
"""

from __future__ import annotations

import os

__all__ = ["ENV", "use_numba"]

ENV = "OAS_KERNELS"


def use_numba() -> bool:
    """True when the numba kernels are selected (``OAS_KERNELS``, default ``numba``) and importable.

    Raises
    ------
    ValueError
        When ``OAS_KERNELS`` holds anything but ``numba`` or ``numpy``.
    """
    mode = os.environ.get(ENV, "numba").strip().lower() or "numba"
    if mode == "numpy":
        return False
    if mode != "numba":
        raise ValueError(f"{ENV}: expected 'numba' or 'numpy', got {mode!r}")
    return _numba_installed()


_NUMBA_FOUND = None


def _numba_installed() -> bool:
    """Whether numba can be imported (looked up once per process: a lookup costs tens of us and
    the switch is read several times a frame); numba is checked, not imported."""
    global _NUMBA_FOUND
    if _NUMBA_FOUND is None:
        import importlib.util

        _NUMBA_FOUND = importlib.util.find_spec("numba") is not None  # a core dependency
    return _NUMBA_FOUND
