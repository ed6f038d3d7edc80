"""The ``oas`` command line: thin wrappers over the library.

Every module of this package whose name ends in ``_cmds`` registers its commands on
:data:`app` when imported; they are discovered here, so adding a command group means
adding a module, not editing this file.
"""

from __future__ import annotations

import os
import sys


def _exit_interrupted() -> None:
    """Ctrl-C: one line, exit status 130, and no interpreter shutdown.

    The files are already complete or removed (optiacoustic._atomic). A normal exit joins the
    simulators' worker threads (ray-cast, kernel and noise pools), and an interrupt can land
    while the main thread holds a lock one of them waits on (seen rarely in
    tests/test_interrupt.py: the message was printed, then the exit hung).
    """
    sys.stdout.flush()
    sys.stderr.write("interrupted\n")
    sys.stderr.flush()
    os._exit(130)


def _app():
    """The typer app with every ``*_cmds`` module's commands registered (imports typer, rich, ...)."""
    import importlib
    import pkgutil

    from .common import app

    for mod in sorted(m.name for m in pkgutil.iter_modules(__path__)):
        if mod.endswith("_cmds"):
            importlib.import_module(f"{__name__}.{mod}")
    return app


def __getattr__(name: str):
    # ``from optiacoustic.cli import app`` loads the commands on first use, so that `oas` can
    # catch a Ctrl-C that lands while they import (main below).
    if name == "app":
        return _app()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["app", "main"]


def main() -> None:
    """The ``oas`` entry point: Ctrl-C anywhere ends with one line and exit status 130."""
    from . import _interrupt

    _interrupt.install()
    try:
        _app()()
    except KeyboardInterrupt:
        _interrupt.delivered()
        _exit_interrupted()
    except SystemExit as exc:
        if exc.code == 130:  # the command reported the interrupt itself (cli.common.reports_errors)
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(130)
        if exc.code in (0, None) or not _interrupt.interrupted():
            raise
        _exit_interrupted()  # an error that followed a Ctrl-C (see cli._interrupt)
    except BaseException:
        if not _interrupt.interrupted():
            raise
        _exit_interrupted()
