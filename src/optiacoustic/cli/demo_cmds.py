"""``oas demo``: run every experiment and write the report page."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import app, fail, out, progress, reports_errors


@app.command("demo")
@reports_errors
def demo(
    out_dir: Path = typer.Option(Path("out/demo"), "--out", help="Output folder for figures and index.html."),
    quick: bool = typer.Option(False, "--quick", help="Fewer Monte Carlo trials."),
    only: Optional[str] = typer.Option(None, "--only", metavar="NAME[,NAME...]",
                                       help="Comma-separated experiment names (oas experiment list)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed."),
):
    """Reproduce the thesis: run every experiment and write OUT/index.html."""
    from ..report import build_report

    names = None if only is None else [s.strip() for s in only.split(",") if s.strip()]
    with progress("starting") as step:
        try:
            index = build_report(out_dir, only=names, quick=quick, seed=seed,
                                 progress=lambda n: step(f"experiment {n}"))
        except RuntimeError as exc:  # an experiment failed: the report shows its error; exit 1, not a traceback
            fail(str(exc), code=1)
    out.print(f"report: {index}")
