"""The opti-acoustic workbench: a local web page to match, reconstruct, calibrate and fuse.

``oas workbench`` serves it; in Python::

    from optiacoustic.workbench import Session, create_app, default_pair, serve
    serve(Session(default_pair()), port=8765)

Modules: :mod:`.sources` (what is shown), :mod:`.session` (the state, with undo),
:mod:`.compute` (the library calls behind every answer), :mod:`.images` and :mod:`.exports`
(PNG, CSV, PLY), :mod:`.app` (the ASGI app and its guard), :mod:`.server` (uvicorn).
The page is plain HTML, CSS and ES modules in ``static/``, shipped in the wheel.
"""

from .app import create_app
from .server import serve, url_for
from .session import Match, Session
from .sources import Pair, SourceUnavailable, default_pair, simulated_pair, source_kinds

__all__ = ["Match", "Pair", "Session", "SourceUnavailable", "create_app", "default_pair", "serve", "simulated_pair",
           "source_kinds", "url_for"]
