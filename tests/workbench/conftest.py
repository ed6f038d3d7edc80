"""Fixtures of the workbench tests: the default pair (simulated once), sessions, a live server, a browser."""

from __future__ import annotations

import functools
import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


@functools.lru_cache(maxsize=1)
def _default_pair():
    from optiacoustic.workbench import default_pair

    return default_pair()


@pytest.fixture
def session():
    from optiacoustic.workbench import Session

    return Session(_default_pair())


@pytest.fixture
def client(session):
    from fastapi.testclient import TestClient

    from optiacoustic.workbench import create_app

    with TestClient(create_app(session), base_url="http://127.0.0.1") as c:
        yield c


def truth_points():
    """Six camera-frame points (m) on and above the seabed that both sensors of the thesis rig see."""
    return np.array([[0.1, 0.05, 6.0], [-0.3, 0.2, 6.3], [0.4, -0.1, 5.5], [0.0, 0.3, 7.0], [0.5, 0.25, 6.5],
                     [-0.5, -0.2, 5.8]])


def truth_matches(session, P=None):
    """Exact measurements of ``P``: camera pixels, fan-image pixels, ranges, azimuths."""
    from optiacoustic.geometry import projection as pr
    from optiacoustic.workbench import compute

    P = truth_points() if P is None else P
    p = pr.project(session.rig, P)
    assert p.visible.all()
    return p.pixels, compute.fan_pixels(session.fan, p.ranges, p.azimuths), p.ranges, p.azimuths


def chromium_path():
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture
def live_server(session):
    """The app on uvicorn on a free loopback port, in a thread."""
    import uvicorn

    from optiacoustic.workbench import create_app
    from optiacoustic.workbench.server import allowed_hosts, free_port

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(session, allowed_hosts=allowed_hosts("127.0.0.1", port)),
                                           host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    t0 = time.monotonic()
    while not server.started:
        if time.monotonic() - t0 > 30 or not th.is_alive():
            pytest.fail("the workbench server did not start")
        time.sleep(0.05)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    th.join(10)


@pytest.fixture(scope="module")
def browser():
    exe = chromium_path()
    if exe is None:
        pytest.skip("browser tests skipped: no chromium found (apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("browser tests skipped: playwright is not installed")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=["--no-sandbox"])
        yield b
        b.close()


@pytest.fixture
def shots(tmp_path):
    """Where screenshots go: $OAS_WORKBENCH_SCREENSHOTS if set, else the test's tmp folder."""
    d = Path(os.environ.get("OAS_WORKBENCH_SCREENSHOTS", tmp_path))
    d.mkdir(parents=True, exist_ok=True)
    return d
