"""``oas workbench`` end to end: a subprocess serving the default pair on a free loopback port."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import httpx
import pytest

from .conftest import REPO


@pytest.mark.parametrize("quiet", [[], ["-q"]], ids=["plain", "quiet"])
def test_oas_workbench_serves_the_default_pair_on_loopback(quiet):
    # under --quiet the progress line goes, the address (the command's output, with its token) stays
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"), PYTHONUNBUFFERED="1")
    cmd = [sys.executable, "-c", "from optiacoustic.cli import main; main()", *quiet, "workbench", "--no-browser",
           "--port", "0"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        url, lines, t0 = None, [], time.monotonic()
        while url is None and time.monotonic() - t0 < 120:
            line = p.stdout.readline()
            if not line:
                break
            lines.append(line)
            m = re.search(r"(http://127\.0\.0\.1:\d+/)", line)
            url = m.group(1) if m else None
        assert url, "".join(lines)
        assert ("preparing the pair" in "".join(lines)) == (not quiet), "".join(lines)
        st = httpx.get(url + "api/state", timeout=30).json()
        assert st["source"]["name"] == "thesis_scene1" and "noise-free" not in st["source"]["description"]
        assert "thesis" in st["source"]["description"]  # thesis water
        assert httpx.get(url, timeout=30).text.startswith("<!doctype html>")
    finally:
        p.terminate()
        p.wait(20)


def test_oas_workbench_bad_sources_fail_with_one_line():
    from typer.testing import CliRunner

    from optiacoustic.cli import app

    r = CliRunner().invoke(app, ["workbench", "no_such_scene", "--no-browser"])
    assert r.exit_code == 2 and "no_such_scene" in r.output and "Traceback" not in r.output
    r = CliRunner().invoke(app, ["workbench", "--sonar-log", "x.aris", "--no-browser"])
    assert r.exit_code == 2 and "--camera-log" in r.output
    r = CliRunner().invoke(app, ["workbench", "--port", "70000", "--no-browser"])
    assert r.exit_code == 2 and "--port" in r.output
