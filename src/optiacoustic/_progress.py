"""Progress of long loops, told to whoever listens: the CLI draws a bar, the library stays silent.

Library code wraps a long loop in :func:`track`; by default that costs nothing and prints
nothing. A front end (the CLI) installs a listener with :func:`listening` and is called with
``(label, done, total)`` as the loop advances.
"""

from __future__ import annotations

import contextlib
from typing import Callable, Iterable, Iterator, Optional, TypeVar

__all__ = ["track", "listening"]

T = TypeVar("T")
Listener = Callable[[str, int, Optional[int]], None]
_listener: Optional[Listener] = None


@contextlib.contextmanager
def listening(listener: Listener) -> Iterator[None]:
    """Call ``listener(label, done, total)`` for every step of every :func:`track` in the block."""
    global _listener
    previous, _listener = _listener, listener
    try:
        yield
    finally:
        _listener = previous


def track(items: Iterable[T], label: str, total: int | None = None) -> Iterator[T]:
    """Yield ``items`` and report each step as done under ``label`` (``total`` from ``len`` if omitted)."""
    listener = _listener
    if listener is None:
        yield from items
        return
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    listener(label, 0, total)
    for done, item in enumerate(items, 1):
        yield item
        listener(label, done, total)
