"""``oas noise-fit``: fit the reverberation amplitude models of thesis sec. 2.7 (Table 2.3 style)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import app, out, reports_errors


def _jsonable(params: dict) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in params.items()}


@app.command("noise-fit")
@reports_errors
def noise_fit(
    bottom: Optional[str] = typer.Option(
        None, "--bottom", help="Draw samples from a Table 2.2 seabed: sand/shell, coarse sand, posidonia, mud, medium sand, shells."
    ),
    model: Optional[str] = typer.Option(
        None, "--model", help="Model to draw the --bottom samples from: rayleigh, weibull, k or mixture (default mixture)."
    ),
    n: int = typer.Option(100_000, "--n", min=1, help="Number of samples drawn with --bottom."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed of the draw."),
    input_file: Optional[Path] = typer.Option(
        None, "--input", help="Real sonar image: .npy amplitude array or a grayscale image (PNG, ...)."
    ),
    roi: Optional[tuple[int, int, int, int]] = typer.Option(
        None, "--roi", help="Pixel box X0 Y0 X1 Y1 of --input (columns X0:X1, rows Y0:Y1)."
    ),
    out_json: Optional[Path] = typer.Option(None, "--out", help="Write the numbers to this JSON file."),
):
    """Fit Rayleigh, Weibull, Rayleigh-mixture and K amplitude models and compare them (Table 2.3)."""
    from rich.markup import escape
    from rich.table import Table

    from .._atomic import write_json
    from ..sonar import distributions as D

    if (bottom is None) == (input_file is None):
        raise ValueError("give exactly one of --bottom TYPE or --input FILE")
    if input_file is not None and (model is not None):
        raise ValueError("--model only applies to --bottom (it picks the model the samples are drawn from)")
    if bottom is not None and roi is not None:
        raise ValueError("--roi only applies to --input")

    ref = None
    if bottom is not None:
        model = model or "mixture"
        if n < 3:
            raise ValueError(f"--n: need at least 3 samples, got {n}")
        ref = D.lookup_bottom(bottom)
        source_dist = D.bottom_model(ref, model)
        samples = source_dist.sample(n, rng=seed)
        title = (
            f"{n} amplitudes drawn from the {model} model of '{ref.name}' (Table 2.2, rescaled to "
            f"E[x^2] = 1: {source_dist.describe()}), seed {seed}"
        )
    else:
        samples = D.amplitudes_from_image(input_file, roi)
        title = f"{samples.size} non-zero amplitudes of {input_file}" + (f", roi {tuple(roi)}" if roi else "")

    fits = D.compare_models(samples)
    best = min(fits, key=lambda f: f.aic).model

    out.print(escape(title), highlight=False)
    scores = Table(title="Goodness of fit (thesis Table 2.3 style)", title_justify="left")
    scores.add_column("model")
    for col in ("KS D", "p-value", "log-likelihood", "AIC"):
        scores.add_column(col, justify="right")
    if ref is not None:
        scores.add_column("Table 2.3", justify="right")
    params = Table(title="Parameters (Table 2.1 parametrisation)", title_justify="left")
    params.add_column("model")
    params.add_column("fitted", overflow="fold")
    if ref is not None:
        params.add_column("thesis Table 2.2", overflow="fold")
    for f in fits:
        name = f.model + (" *" if f.model == best else "")
        row = [name, f"{f.ks_statistic:.4f}", f"{f.p_value:.3g}", f"{f.log_likelihood:.1f}", f"{f.aic:.1f}"]
        prow = [name, f.dist.describe()]
        if ref is not None:
            row.append(f"{ref.table_2_3.get(f.model):.3g}")
            prow.append("-" if f.model == "rayleigh" else ref.model(f.model).describe())
        scores.add_row(*row)
        params.add_row(*prow)
    out.print(scores)
    out.print(params)
    out.print(
        "* lowest AIC. KS p-values with parameters fitted to the same samples are optimistic (Lilliefors).",
        highlight=False,
    )

    if out_json is not None:
        result = {
            "source": {"bottom": ref.name, "model": model, "n": n, "seed": seed}
            if ref is not None
            else {"input": str(input_file), "roi": list(roi) if roi else None, "n": int(samples.size)},
            "fits": [
                {
                    "model": f.model,
                    "params": _jsonable(f.dist.params),
                    "n_params": f.dist.n_params,
                    "log_likelihood": f.log_likelihood,
                    "aic": f.aic,
                    "ks_statistic": f.ks_statistic,
                    "p_value": f.p_value,
                }
                for f in fits
            ],
            "best_aic": best,
        }
        if ref is not None:
            result["thesis"] = {
                "table_2_2": {m: _jsonable(ref.model(m).params) for m in ("weibull", "mixture", "k")},
                "table_2_3": {m: ref.table_2_3.get(m) for m in ("rayleigh", "weibull", "mixture", "k")},
            }
        write_json(out_json, result)
        out.print(f"  {out_json}")
