"""``oas experiment``: run one experiment of the thesis."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import app, out, reports_errors


@app.command("experiment")
@reports_errors
def experiment(
    name: str = typer.Argument(..., help="Experiment name; 'list' shows them."),
    out_dir: Path = typer.Option(Path("out/experiments"), "--out", help="Output folder (NAME is appended)."),
    quick: bool = typer.Option(False, "--quick", help="Fewer Monte Carlo trials (for smoke runs)."),
    seed: int = typer.Option(0, "--seed", help="Random seed."),
):
    """Run a thesis experiment: writes PNG figures and results.json into --out/NAME."""
    from .. import experiments

    if name == "list":
        for n in experiments.names():
            mod = experiments.get(n)
            out.print(f"{n:16s} ch. {getattr(mod, 'CHAPTER', '?')}: {getattr(mod, 'TITLE', '')}")
        return
    target = out_dir / name if out_dir.name != name else out_dir
    res = experiments.run(name, target, quick=quick, seed=seed)
    out.print(f"[bold]{name}[/]: {res.summary}")
    for f, cap in res.figures:
        out.print(f"  {f}  - {cap}")
    out.print(f"  {target / 'results.json'}")
