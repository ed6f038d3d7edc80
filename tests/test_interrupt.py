"""A run killed at any moment leaves only complete files; Ctrl-C ends with one line and exit 130.

The CLI writes a sequence of sonar frames (NPZ + PNGs + JSON); it is killed (SIGKILL, and
SIGINT as Ctrl-C sends) at several moments, and every file left under its final name must
load completely. With SIGINT the temporary files are removed too.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
CMD = [sys.executable, "-m", "optiacoustic.cli", "sonar", "flat_seabed", "--preset", "didson-300-hf", "--eye", "0", "-4",
       "1.5", "--target", "0", "0", "0", "--frames", "400", "--no-figures"]


def _start(out: Path):
    env = dict(os.environ, PYTHONPATH=str(SRC))
    return subprocess.Popen(CMD + ["--out", str(out)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _wait_for_files(out: Path, n: int, proc, timeout=60.0):
    """Wait until ``n`` complete frames exist (so the kill lands while files are being written)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if proc.poll() is not None:
            return
        if out.exists() and len(list(out.glob("frame_*_fan.png"))) >= n:
            return
        time.sleep(0.02)


def _check_complete(out: Path, allow_tmp: bool):
    import cv2

    finals = [p for p in out.iterdir() if ".tmp-" not in p.name]
    tmps = [p for p in out.iterdir() if ".tmp-" in p.name]
    assert allow_tmp or not tmps, tmps
    for p in finals:
        if p.suffix == ".npz":
            with np.load(p) as z:
                for k in z.files:
                    z[k]  # reads (and CRC-checks) every member
        elif p.suffix == ".png":
            assert cv2.imread(str(p), cv2.IMREAD_UNCHANGED) is not None, p
        elif p.suffix == ".json":
            json.loads(p.read_text())
    return finals


@pytest.mark.parametrize("frames_before", [0, 3])
def test_sigkill_leaves_only_complete_files(tmp_path, frames_before):
    out = tmp_path / "run"
    proc = _start(out)
    _wait_for_files(out, frames_before, proc)
    time.sleep(0.05 * frames_before)  # land at different points of a frame's writes
    proc.kill()
    proc.wait(timeout=30)
    if out.exists():
        _check_complete(out, allow_tmp=True)


@pytest.mark.parametrize("frames_before", [0, 2])
def test_sigint_exits_130_with_one_line_and_complete_files(tmp_path, frames_before):
    out = tmp_path / "run"
    proc = _start(out)
    _wait_for_files(out, frames_before, proc)
    if frames_before == 0:
        time.sleep(0.5)  # during imports or the first frame
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines and "interrupted" in lines[-1] and len(lines) <= 2, err
    if out.exists():
        finals = _check_complete(out, allow_tmp=False)
        assert len(finals) >= 3 * frames_before  # npz, polar png, fan png per frame
