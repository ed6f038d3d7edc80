"""Run every benchmarks/bench_*.py and write the table to docs/benchmarks.md.

Each bench module defines ``run() -> list[dict]`` whose dicts have at least ``name``,
``value``, ``unit``, ``reference`` (what the ratio is measured against), ``ratio`` and
``note``; both numbers of a ratio are measured in the same run. Speed is never asserted
by a test: it is measured here.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the bench modules share benchmarks/_timing.py

HEADER = """# Benchmarks

Measured by `make bench` (`benchmarks/run_all.py`) on {machine}, {date}. Every ratio is
taken against a reference measured in the same run, so it travels across machines better
than the absolute numbers. Medians of repeated runs after a warm-up.

"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(HERE.parent / "docs" / "benchmarks.md"))
    ap.add_argument("--only", default=None, help="run only bench modules whose name contains this")
    args = ap.parse_args(argv)
    rows_by_module = {}
    for path in sorted(HERE.glob("bench_*.py")):
        if args.only and args.only not in path.stem:
            continue
        spec = importlib.util.spec_from_file_location(path.stem, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        print(f"== {path.stem}", flush=True)
        t0 = time.perf_counter()
        rows = mod.run()
        for r in rows:
            ratio = r.get("ratio")
            ratio_s = "" if ratio is None else f"  ratio {ratio:.3g} vs {r.get('reference', '')}"
            print(f"   {r['name']}: {r['value']:.4g} {r['unit']}{ratio_s}")
        rows_by_module[path.stem] = (getattr(mod, "TITLE", path.stem), getattr(mod, "DESCRIPTION", ""), rows,
                                     time.perf_counter() - t0)
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in Path("/proc/cpuinfo").read_text().splitlines()
                   if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    machine = f"{cpu}, {len(os.sched_getaffinity(0))} cores, Python {sys.version.split()[0]}"
    text = HEADER.format(machine=machine, date=time.strftime("%Y-%m-%d"))
    for stem, (title, desc, rows, dt) in rows_by_module.items():
        text += f"## {title}\n\n{desc}\n\n| measurement | value | unit | reference | ratio | note |\n|---|---|---|---|---|---|\n"
        for r in rows:
            ratio = r.get("ratio")
            text += (f"| {r['name']} | {r['value']:.4g} | {r['unit']} | {r.get('reference', '')} | "
                     f"{'' if ratio is None else f'{ratio:.3g}'} | {r.get('note', '')} |\n")
        text += f"\n(`benchmarks/{stem}.py`, {dt:.0f} s)\n\n"
    notes = HERE / "notes.md"  # hand-written sections kept across regenerations
    if notes.exists() and not args.only:
        text += notes.read_text()
    from optiacoustic._atomic import write_text

    write_text(args.out, text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
