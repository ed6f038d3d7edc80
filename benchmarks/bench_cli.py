"""Start-up time of the command line: ``oas --help`` against ``python -c "import numpy"``.

Both are fresh interpreter processes started the same way, so the ratio says how much the CLI
adds on top of the least a numpy program pays. ``oas --help`` must not import scipy,
matplotlib, OpenCV or Embree (they load inside the commands that need them); the row
``modules`` lists which of those the help path imported (it should be none).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

TITLE = "Command-line start-up"
DESCRIPTION = ("Wall time of `oas --help` and `oas experiment --help` in a fresh interpreter, as ratios to "
               "`python -c \"import numpy\"` measured in the same run (median of repeated runs).")

SRC = str(Path(__file__).resolve().parents[1] / "src")
HEAVY = ("scipy", "matplotlib", "cv2", "embreex", "trimesh")


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = SRC + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["COLUMNS"] = "100"
    return env


def _median_s(args, repeat=7):
    import time

    env = _env()
    subprocess.run(args, env=env, capture_output=True, check=True)  # warm the file cache
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(args, env=env, capture_output=True, check=True)
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def heavy_modules_on_help() -> list[str]:
    """Which heavy libraries ``oas --help`` imports (should be none)."""
    code = ("import sys, contextlib, io\nfrom optiacoustic.cli import app\n"
            "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):\n"
            "    app(['--help'])\n"
            f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, check=True)
    return [m for m in r.stdout.strip().split(",") if m]


def run() -> list[dict]:
    ref = _median_s([sys.executable, "-c", "import numpy"])
    rows = [dict(name="python -c 'import numpy'", value=ref * 1e3, unit="ms", reference="", ratio=None, note="")]
    for name, args in (("oas --help", ["--help"]), ("oas experiment --help", ["experiment", "--help"])):
        t = _median_s([sys.executable, "-m", "optiacoustic.cli", *args])
        rows.append(dict(name=name, value=t * 1e3, unit="ms", reference="python -c 'import numpy'", ratio=t / ref,
                         note="fresh process"))
    heavy = heavy_modules_on_help()
    rows.append(dict(name="heavy modules imported by oas --help", value=len(heavy), unit="modules", reference="",
                     ratio=None, note=", ".join(heavy) or "none of " + ", ".join(HEAVY)))
    return rows


if __name__ == "__main__":
    for r in run():
        print(r)
