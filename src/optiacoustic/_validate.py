"""The one validation helper used at public boundaries.

Every public function coerces its array arguments through :func:`as_array` so a caller
mistake is reported with the argument's name, the expected shape and the actual one,
instead of surfacing as a broadcasting error from deep inside numpy.
"""

from __future__ import annotations

import time

from typing import Sequence

import numpy as np

__all__ = ["as_array", "as_azimuths", "as_positive", "as_rng", "available_memory", "check_memory", "broadcast_arrays", "broadcast_points", "check_finite"]


def _shape_str(shape: Sequence[int | None | str]) -> str:
    parts = []
    for s in shape:
        parts.append("..." if s == "..." else ("N" if s is None else str(s)))
    return "(" + ", ".join(parts) + ("," if len(parts) == 1 else "") + ")"


def as_array(
    x,
    name: str,
    shape: Sequence[int | None | str] | None = None,
    *,
    finite: bool = True,
    dtype=float,
) -> np.ndarray:
    """Coerce ``x`` to an array and check its shape and finiteness.

    Parameters
    ----------
    x : array_like
        The value supplied by the caller.
    name : str
        The argument's name, used in the error message.
    shape : sequence, optional
        Expected shape. ``"..."`` as the first entry admits any leading axes; ``None``
        admits any length on that axis. ``(..., 3)`` is a batch of 3-vectors.
    finite : bool
        Reject NaN and infinity.
    dtype : numpy dtype
        Target dtype (float by default).

    Returns
    -------
    numpy.ndarray

    Raises
    ------
    ValueError
        With the expected and the actual shape, or the position of the first
        non-finite value.
    """
    if np.iscomplexobj(x) and np.dtype(dtype).kind in "fiu":
        # numpy would drop the imaginary part with only a warning
        raise ValueError(f"{name}: expected real numbers, got complex values (take np.abs or np.real explicitly)")
    try:
        arr = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected numbers, got {type(x).__name__} ({exc})") from None
    if shape is not None:
        shape = tuple(shape)
        if shape and shape[0] == "...":
            tail = shape[1:]
            ok = arr.ndim >= len(tail) and all(
                t is None or arr.shape[arr.ndim - len(tail) + i] == t for i, t in enumerate(tail)
            )
        else:
            ok = arr.ndim == len(shape) and all(t is None or a == t for a, t in zip(arr.shape, shape))
        if not ok:
            raise ValueError(
                f"{name}: expected shape {_shape_str(shape)}, got {tuple(arr.shape)}"
            )
    if finite and arr.dtype.kind == "f" and not np.isfinite(arr).all():
        bad = np.argwhere(~np.isfinite(arr))[0]
        where = tuple(int(i) for i in bad)
        raise ValueError(f"{name}: must be finite, found {arr[where] if where else arr} at index {where}")
    return arr


def as_positive(x, name: str, *, allow_zero: bool = False) -> float:
    """A finite scalar > 0 (or >= 0 with ``allow_zero``)."""
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {x!r}") from None
    if not np.isfinite(v) or (v < 0 if allow_zero else v <= 0):
        rel = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name}: must be finite and {rel}, got {v!r}")
    return v


def check_finite(arr: np.ndarray, name: str) -> None:
    """Raise a ValueError naming ``name`` if ``arr`` holds NaN or infinity."""
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: must be finite (found NaN or inf)")


def broadcast_arrays(**arrays) -> list[np.ndarray]:
    """Broadcast named arrays together, with an error that names them on failure."""
    try:
        return list(np.broadcast_arrays(*arrays.values()))
    except ValueError:
        shapes = ", ".join(f"{k}{tuple(np.shape(v))}" for k, v in arrays.items())
        raise ValueError(f"shapes do not broadcast together: {shapes}") from None


def broadcast_points(x, name: str, shape: tuple) -> np.ndarray:
    """Points ``(..., 3)`` broadcast to ``shape + (3,)`` and flattened to ``(N, 3)``.

    For optional per-point inputs such as an initial guess; NaN is allowed (the caller
    decides what an invalid point means).
    """
    arr = as_array(x, name, ("...", 3), finite=False)
    try:
        return np.broadcast_to(arr, tuple(shape) + (3,)).reshape(-1, 3)
    except ValueError:
        raise ValueError(f"{name}: expected shape {tuple(shape) + (3,)}, got {arr.shape}") from None


def is_number(v) -> bool:
    """A real number and not a bool (``True`` is a mistake, not 1; ``"3"`` is text, not 3)."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def is_integer(v) -> bool:
    """An integer and not a bool (``slices=True`` is a mistake, not 1 slice)."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def strict_number(v):
    """``v`` if :func:`is_number`, else a ValueError (a pydantic ``BeforeValidator``, which names the field):
    ``true`` and ``"5"`` in a file are refused, not read as 1 and 5 (an int is still a float)."""
    if not is_number(v):
        raise ValueError(f"expected a number, not {type(v).__name__}")
    return v


def check_number(name: str, v, lo: float = -np.inf, hi: float = np.inf, *, none: bool = False,
                 inf: bool = False, lo_open: bool = False, unit: str = ""):
    """``v`` if it is a real number (:func:`is_number`) within ``[lo, hi]`` (``lo_open``: ``> lo``),
    finite unless ``inf`` allows +inf (whatever ``hi``); ``None`` passes when ``none``. Else a ValueError
    naming ``name`` (``Class.field``) and the value: ``True`` is not 1 dB and ``"3"`` not 3."""
    if v is None and none:
        return v
    if not is_number(v):
        raise ValueError(f"{name}: expected a number{' or None' if none else ''}, got {v!r} ({type(v).__name__})")
    f = float(v)
    if inf and f == np.inf:  # a limit (no clustering, fully developed speckle)
        return v
    if not np.isfinite(f):
        raise ValueError(f"{name}: must be finite{' (or +inf)' if inf else ''}, got {v!r}")
    if (f <= lo if lo_open else f < lo) or f > hi:
        left = "(" if lo_open else "["
        raise ValueError(f"{name}: must lie in {left}{lo:g}, {hi:g}]{' ' + unit if unit else ''}, got {v!r}")
    return v


def as_rng(seed, name: str = "seed") -> np.random.Generator:
    """A Generator from a seed (a non-negative integer), a Generator, or None (fresh entropy).

    Floats, strings and booleans are refused rather than truncated or hashed: ``seed=1.5``
    and ``seed=True`` are mistakes, not seeds.
    """
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        return np.random.default_rng()
    if not is_integer(seed):
        raise ValueError(f"{name}: expected a non-negative integer, a numpy.random.Generator or None, "
                         f"got {seed!r} ({type(seed).__name__})")
    if seed < 0:
        raise ValueError(f"{name}: expected a non-negative integer, got {int(seed)}")
    return np.random.default_rng(int(seed))


def as_azimuths(x, name: str = "azimuths", limit: float = np.pi) -> np.ndarray:
    """Sonar azimuths (rad): finite and within ``[-limit, limit]``.

    ``atan2`` gives azimuths in ``[-pi, pi]``; a value beyond ``limit`` is a mistake, most often
    degrees passed where radians are expected (which would otherwise give empty curves or NaN
    points without a word). Pass the fan's half-width as ``limit`` where only the fan makes sense.
    """
    a = as_array(x, name)
    bad = np.abs(a) > limit
    if np.any(bad):
        i = tuple(int(k) for k in np.argwhere(bad)[0])
        v = float(a[i] if i else a)
        raise ValueError(f"{name}: azimuths are in radians within +-{limit:.4g}; got {v:g} at index {i} "
                         f"(degrees? use np.deg2rad({v:g}) = {np.deg2rad(v):.4g} rad)")
    return a


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``), or None if unknown."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        import os

        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


_LAST_AVAIL = (None, 0.0)  # check_memory's last reading: (bytes, time.monotonic())


def check_memory(nbytes: float, what: str) -> None:
    """Raise a ValueError before allocating ``nbytes`` (an upper estimate) that the machine does not have.

    ``what`` says which request and which fields set its size, e.g.
    ``"a 100000 x 100000 camera image (PinholeCamera.width x height)"``.
    """
    # a request below half of what was available a moment ago does not read /proc/meminfo again (~20-40 us
    # on every frame's serial path); anything larger always does
    global _LAST_AVAIL
    now = time.monotonic()
    last, when = _LAST_AVAIL
    if last is not None and nbytes <= 0.5 * last and now - when < 1.0:
        return
    avail = available_memory()
    _LAST_AVAIL = (avail, now)
    if avail is not None and nbytes > avail:
        raise ValueError(f"{what} needs about {nbytes / 2**30:.1f} GiB of memory; {avail / 2**30:.1f} GiB is "
                         "available. Use a smaller size.")
