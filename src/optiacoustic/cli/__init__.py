"""The ``oas`` command line: thin wrappers over the library.

Every module of this package whose name ends in ``_cmds`` registers its commands on
:data:`app` when imported; they are discovered here, so adding a command group means
adding a module, not editing this file.
"""

from __future__ import annotations

import importlib
import pkgutil

from .common import app

for _mod in sorted(m.name for m in pkgutil.iter_modules(__path__)):
    if _mod.endswith("_cmds"):
        importlib.import_module(f"{__name__}.{_mod}")

__all__ = ["app", "main"]


def main() -> None:
    """The ``oas`` entry point: Ctrl-C anywhere ends with one line and exit status 130."""
    import os
    import sys

    try:
        app()
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
    except SystemExit as exc:
        if exc.code != 130:
            raise
    else:
        return
    # Ctrl-C: the files are already complete or removed (optiacoustic._atomic). Leave at once:
    # a normal exit joins the simulators' worker threads (ray-cast, kernel and noise pools), and
    # an interrupt can land while the main thread holds a lock one of them waits on (seen
    # rarely in tests/test_interrupt.py: the message was printed, then the exit hung).
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(130)
