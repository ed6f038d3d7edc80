"""Run the benchmarks/bench_*.py modules and write their tables to docs/benchmarks.md.

Each bench module defines ``run() -> list[dict]`` whose dicts have at least ``name``,
``value``, ``unit``, ``reference`` (what the ratio is measured against), ``ratio`` and
``note``; both numbers of a ratio are measured in the same run. Speed is never asserted
by a test: it is measured here.

The file is rebuilt as: the header, one generated table per bench module (in the modules'
name order), then the hand-written sections of ``benchmarks/notes.md``. Each table ends with
a line naming its module, how long it ran, the date and the machine. ``--only NAME`` runs
only the modules whose name contains NAME and keeps the other modules' tables as they are
in the existing file (a table is recognised by that last line), so re-measuring one module
never drops the others or the notes.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import re
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the bench modules share benchmarks/_timing.py

HEADER = """# Benchmarks

Measured by `make bench` (`benchmarks/run_all.py`). Every ratio is taken against a reference
measured in the same run, so it travels across machines better than the absolute numbers.
Medians of repeated runs after a warm-up. Each table's last line names its benchmark module,
how long it ran, the date and the machine (`run_all.py --only NAME` re-measures the modules
whose name contains NAME and keeps the other tables).

"""

# The last line of a generated table: (`benchmarks/bench_x.py`, 9 s[, date, machine])
_TRAILER = re.compile(r"\(`benchmarks/(bench_\w+)\.py`, [^\n]*\)")


def machine_name() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in Path("/proc/cpuinfo").read_text().splitlines()
                   if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{cpu}, {len(os.sched_getaffinity(0))} cores, Python {sys.version.split()[0]}"


def render_table(stem: str, title: str, desc: str, rows: list[dict], seconds: float, date: str,
                 machine: str) -> str:
    """One module's section, ending with its trailer line and a blank line."""
    text = f"## {title}\n\n{desc}\n\n| measurement | value | unit | reference | ratio | note |\n|---|---|---|---|---|---|\n"
    for r in rows:
        ratio = r.get("ratio")
        text += (f"| {r['name']} | {r['value']:.4g} | {r['unit']} | {r.get('reference', '')} | "
                 f"{'' if ratio is None else f'{ratio:.3g}'} | {r.get('note', '')} |\n")
    return text + f"\n(`benchmarks/{stem}.py`, {seconds:.0f} s, {date}, {machine})\n\n"


def generated_tables(text: str) -> dict[str, str]:
    """The generated tables of an existing benchmarks.md, by module name.

    The text is cut before every line that starts with ``## ``; a piece is a module's table
    when it is such a section and its last non-blank line is that module's trailer. The
    hand-written sections (no trailer as their last line) are not returned.
    """
    tables = {}
    for piece in re.split(r"(?m)^(?=## )", text):
        if not piece.startswith("## "):
            continue
        body = piece.rstrip()
        last = body.rsplit("\n", 1)[-1]
        m = _TRAILER.fullmatch(last)
        if m:
            tables[m.group(1)] = body + "\n\n"
    return tables


def compose(stems: list[str], new_tables: dict[str, str], old_tables: dict[str, str], notes: str) -> str:
    """The whole file: header, a table per module of ``stems`` (this run's, else the old file's), notes.

    ``old_tables`` is :func:`generated_tables` of the existing file. A module with neither a new
    nor an old table is left out; an old table whose module is no longer in ``stems`` is dropped.
    """
    text = HEADER
    for stem in stems:
        table = new_tables.get(stem, old_tables.get(stem))
        if table:
            text += table
    return text + notes


def run_modules(bench_dir: Path, stems: list[str]) -> dict[str, str]:
    """Run each module's ``run()``, print its rows, and return its rendered table by module name."""
    machine, date = machine_name(), time.strftime("%Y-%m-%d")
    tables = {}
    for stem in stems:
        spec = importlib.util.spec_from_file_location(stem, bench_dir / f"{stem}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        print(f"== {stem}", flush=True)
        t0 = time.perf_counter()
        rows = mod.run()
        for r in rows:
            ratio = r.get("ratio")
            ratio_s = "" if ratio is None else f"  ratio {ratio:.3g} vs {r.get('reference', '')}"
            print(f"   {r['name']}: {r['value']:.4g} {r['unit']}{ratio_s}")
        tables[stem] = render_table(stem, getattr(mod, "TITLE", stem), getattr(mod, "DESCRIPTION", ""), rows,
                                    time.perf_counter() - t0, date, machine)
    return tables


def main(argv=None, bench_dir: Path = HERE) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(HERE.parent / "docs" / "benchmarks.md"))
    ap.add_argument("--only", default=None, help="run only bench modules whose name contains this; "
                    "the other modules' tables are kept from the existing file")
    args = ap.parse_args(argv)
    out = Path(args.out)
    stems = [p.stem for p in sorted(bench_dir.glob("bench_*.py"))]
    chosen = [s for s in stems if not args.only or args.only in s]
    if not chosen:
        print(f"run_all.py: no benchmark module in {bench_dir} has a name containing {args.only!r}; "
              f"the modules are: {', '.join(stems) or 'none'}", file=sys.stderr)
        return 2
    old_tables = {}
    if args.only and out.exists():  # read before running, so a bad file fails in seconds, not minutes
        try:
            old_tables = generated_tables(out.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as e:
            print(f"run_all.py: cannot read {out} to keep its other tables: {e}", file=sys.stderr)
            return 2
    notes_path = bench_dir / "notes.md"  # hand-written sections kept across regenerations
    notes = notes_path.read_text(encoding="utf-8") if notes_path.exists() else ""
    from optiacoustic._atomic import OutputError, _check_destination, write_text

    try:
        _check_destination(out)  # before the modules run: a bad --out fails in seconds, not minutes
        new_tables = run_modules(bench_dir, chosen)
        write_text(out, compose(stems, new_tables, old_tables, notes))  # whole, or not at all
    except OutputError as e:
        print(f"run_all.py: {e}", file=sys.stderr)
        return 2
    kept = [s for s in stems if s not in new_tables and s in old_tables]
    print(f"wrote {out}" + (f" (kept the tables of {', '.join(kept)})" if kept else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
