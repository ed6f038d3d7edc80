"""Ctrl-C for the command line: always one line and exit status 130, never lost, never a traceback.

Python turns SIGINT into ``KeyboardInterrupt`` raised in whatever Python code the main thread
runs at that moment. Usually that unwinds to :func:`optiacoustic.cli.main`. Two places lose it:

- a ``__del__`` or a ctypes callback: the exception is "ignored", printed as a traceback, and
  the run goes on as if no key was pressed. On a fresh machine numba compiles the kernels
  during the first frame, and LLVM calls back into Python while it does (llvmlite's object
  finalizers, numba's object-code notifier); CI saw a Ctrl-C vanish there and 400 frames run
  on.
- the code around such a callback then fails on its own (numba: ``RuntimeError: no compiled
  object yet``), a traceback for what was a Ctrl-C.

So :func:`install` records every Ctrl-C; a lost one is delivered again from a helper thread
(every :data:`REDELIVER_S` seconds until it surfaces in ordinary code), and :func:`main` treats
any failure after a Ctrl-C as the interrupt.
"""

from __future__ import annotations

import signal
import sys
import threading

REDELIVER_S = 0.2
_state = {"interrupted": False, "delivered": False, "thread": None}


def interrupted() -> bool:
    """Whether Ctrl-C was pressed since :func:`install`."""
    return _state["interrupted"]


def delivered() -> None:
    """Called where the interrupt is handled: stop re-sending it."""
    _state["delivered"] = True


def _on_sigint(signum, frame):
    _state["interrupted"] = True
    _state["delivered"] = False
    raise KeyboardInterrupt


def _redeliver():
    import _thread
    import time

    while True:
        time.sleep(REDELIVER_S)
        if not _state["delivered"]:
            _thread.interrupt_main(signal.SIGINT)


def _unraisable(unraisable):
    if unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt):
        _state["interrupted"] = True
        if _state["thread"] is None:
            _state["thread"] = threading.Thread(target=_redeliver, name="oas-redeliver-ctrl-c", daemon=True)
            _state["thread"].start()
        return
    sys.__unraisablehook__(unraisable)


def install() -> None:
    """Record Ctrl-C and re-send one that a finalizer or callback swallowed (the main thread only)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, _on_sigint)
    sys.unraisablehook = _unraisable
