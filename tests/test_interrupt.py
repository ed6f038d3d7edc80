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


def _run_code(code: str, timeout=30):
    env = dict(os.environ, PYTHONPATH=str(SRC))
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout)


_LOST_IN_FINALIZER = """
import os, signal, time
# Python's own SIGINT handler even where the parent ignores SIGINT (a job started in the background by a
# non-interactive shell inherits SIG_IGN, and Python then installs no handler: the signal would do nothing)
signal.signal(signal.SIGINT, signal.default_int_handler)
class Finalized:
    def __del__(self):
        os.kill(os.getpid(), signal.SIGINT)  # Python raises KeyboardInterrupt here, inside __del__: "ignored"
        time.sleep(0.01)
"""


def test_ctrl_c_swallowed_by_a_finalizer_is_delivered_again():
    """SIGINT that lands in a ``__del__`` (as in llvmlite while numba compiles) is not lost."""
    code = "from optiacoustic.cli import _interrupt\n_interrupt.install()\n" + _LOST_IN_FINALIZER + """
f = Finalized(); del f
t0 = time.monotonic()
try:
    while time.monotonic() - t0 < 10:
        time.sleep(0.01)
    print("lost")
except KeyboardInterrupt:
    print(f"delivered after {time.monotonic() - t0:.3f}")
"""
    res = _run_code(code)
    assert res.stdout.startswith("delivered after"), (res.stdout, res.stderr)
    assert float(res.stdout.split()[-1]) < 2.0
    assert "Traceback" not in res.stderr and "ignored" not in res.stderr, res.stderr


def test_without_the_hook_python_loses_it():
    """The control: plain Python prints 'Exception ignored' and goes on (what CI saw)."""
    code = _LOST_IN_FINALIZER + """
f = Finalized(); del f
time.sleep(0.5)
print("lost")
"""
    res = _run_code(code)
    assert res.stdout.strip() == "lost" and "Exception ignored" in res.stderr, (res.stdout, res.stderr)


def test_an_error_that_follows_a_lost_ctrl_c_ends_as_the_interrupt():
    """numba, interrupted mid-compile, then fails with its own RuntimeError: still one line and 130."""
    code = _LOST_IN_FINALIZER + """
import sys
from optiacoustic import cli
app = cli.app

@app.command("boom")
def boom():
    f = Finalized(); del f
    raise RuntimeError("no compiled object yet for <Library 'edge_pairs'>")

sys.argv = ["oas", "boom"]
cli.main()
"""
    res = _run_code(code)
    assert res.returncode == 130, (res.returncode, res.stderr)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert lines == ["interrupted"], res.stderr


def test_an_error_without_ctrl_c_is_not_taken_for_one():
    code = """
import sys
from optiacoustic import cli
app = cli.app

@app.command("boom")
def boom():
    raise RuntimeError("a real bug")

sys.argv = ["oas", "boom"]
cli.main()
"""
    res = _run_code(code)
    assert res.returncode == 1 and "RuntimeError: a real bug" in res.stderr, (res.returncode, res.stderr)
