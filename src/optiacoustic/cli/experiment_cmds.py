"""``oas experiment``: run one experiment of the thesis."""

from __future__ import annotations

from pathlib import Path

import typer

from rich.markup import escape

from .common import _Command, app, out, progress, reports_errors


class _ExperimentCommand(_Command):
    """Lists the experiments in its help (read only when help is asked for, so ``oas --help`` stays fast)."""

    def format_help(self, ctx, formatter):
        from .. import experiments

        rows = "\n".join(f"  {n:15s} ch. {getattr(experiments.get(n), 'CHAPTER', '?')}: "
                         f"{getattr(experiments.get(n), 'TITLE', '')}" for n in experiments.names())
        self.epilog = "\b\nExperiments:\n" + rows
        return super().format_help(ctx, formatter)


@app.command("experiment", cls=_ExperimentCommand)
@reports_errors
def experiment(
    name: str = typer.Argument(..., metavar="NAME", help="Experiment name (listed below); 'list' prints them."),
    out_dir: Path = typer.Option(Path("out/experiments"), "--out", help="Output folder (NAME is appended)."),
    quick: bool = typer.Option(False, "--quick", help="Fewer Monte Carlo trials (for smoke runs)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed."),
):
    """Run a thesis experiment: writes PNG figures and results.json into --out/NAME."""
    from .. import experiments

    if name == "list":
        for n in experiments.names():
            mod = experiments.get(n)
            out.print(f"{n:16s} ch. {getattr(mod, 'CHAPTER', '?')}: {getattr(mod, 'TITLE', '')}")
        return
    experiments.get(name)  # an unknown name fails here, before any folder is made
    target = out_dir / name if out_dir.name != name else out_dir
    with progress(f"experiment {name}"):
        res = experiments.run(name, target, quick=quick, seed=seed)
    out.print(f"[bold]{escape(name)}[/]: {escape(str(res.summary))}", markup=True)
    for f, cap in res.figures:
        out.print(f"  {f}  - {cap}")
    out.print(f"  {target / 'results.json'}")
