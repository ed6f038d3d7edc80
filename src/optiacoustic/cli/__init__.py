"""The ``oas`` command line: thin wrappers over the library.

Each command group lives in its own module and registers itself on :data:`app`.
"""

from __future__ import annotations

from .common import app

# command modules register their commands on `app` when imported
from . import sonar_cmds  # noqa: E402,F401
from . import demo_cmd  # noqa: E402,F401

__all__ = ["app", "main"]


def main() -> None:
    app()
