"""``oas noise-fit``: fit the reverberation amplitude models of thesis sec. 2.7 (Table 2.3 style)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .._atomic import write_json
from .common import app, check_output, out, reports_errors


def _jsonable(params: dict) -> dict:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in params.items()}


def _is_sonar_log(path: Path) -> bool:
    from ..io.errors import ReadError
    from ..io.sonar import sniff

    if path.suffix.lower() in (".npy", ".png", ".tif", ".tiff", ".pgm", ".jpg", ".jpeg", ".bmp"):
        return False
    try:
        sniff(path)
    except ReadError:
        return False
    return True


def _fit_log(path, *, topic, frames, range_min, range_max, azimuth_min_deg, azimuth_max_deg, mask, reading,
             detrend, dither, seed, out_json):
    import numpy as np
    from rich.table import Table

    from ..io import open_sonar
    from ..io.sonar import sniff
    from ..sonar.realfit import fit_frames
    from .view_cmds import parse_frames

    opts = {"reading": reading} if sniff(path) == "oculus" else {}
    with open_sonar(path, topic=topic, **opts) as seq:
        idx = parse_frames(frames, len(seq)) if frames is not None else range(len(seq))
        chosen = [seq[i] for i in idx]
    rng_win = None if range_min is None and range_max is None else (
        -np.inf if range_min is None else range_min, np.inf if range_max is None else range_max)
    az_win = None if azimuth_min_deg is None and azimuth_max_deg is None else (
        -np.inf if azimuth_min_deg is None else np.deg2rad(azimuth_min_deg),
        np.inf if azimuth_max_deg is None else np.deg2rad(azimuth_max_deg))
    m = None
    if mask is not None:
        try:
            m = np.load(mask, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise ValueError(f"--mask: cannot read {mask} as a .npy array ({exc})") from None
    res = fit_frames(chosen, ranges=rng_win, azimuths=az_win, mask=m, detrend=detrend, dither=dither, seed=seed)
    region = (f"ranges {rng_win[0]:g}-{rng_win[1]:g} m" if rng_win else "all ranges") + ", " + (
        f"azimuths {np.rad2deg(az_win[0]):g} to {np.rad2deg(az_win[1]):g} deg" if az_win else "all beams") + (
        f", mask {mask}" if mask is not None else "")
    out.print(f"{res.n_samples} amplitudes from {res.n_frames} frame(s) of {path} ({region})", highlight=False)
    out.print(f"linearised: {res.linearisation}; dithered: {res.dithered}; range-detrended: {res.detrended}",
              highlight=False)
    table = Table(title="Goodness of fit", title_justify="left")
    for col in ("model", "KS D", "p-value", "log-likelihood", "AIC", "fitted", "flags"):
        table.add_column(col, overflow="fold")
    for f in res.fits:
        table.add_row(f.model + (" *" if f.model == res.best else ""), f"{f.ks_statistic:.4f}", f"{f.p_value:.3g}",
                      f"{f.log_likelihood:.1f}", f"{f.aic:.1f}", f.dist.describe(), "; ".join(res.flags[f.model]) or "-")
    out.print(table)
    for note in res.notes:
        out.print(f"note: {note}", highlight=False)
    out.print("* lowest AIC. KS p-values with parameters fitted to the same samples are optimistic (Lilliefors).",
              highlight=False)
    if out_json is not None:
        write_json(out_json, {
            "source": {"input": str(path), "topic": topic, "frames": list(idx), "region": region,
                       "linearisation": res.linearisation, "dithered": res.dithered, "detrended": res.detrended,
                       "n": res.n_samples, "reading": reading if opts else None},
            "fits": [{"model": f.model, "params": _jsonable(f.dist.params), "n_params": f.dist.n_params,
                      "log_likelihood": f.log_likelihood, "aic": f.aic, "ks_statistic": f.ks_statistic,
                      "p_value": f.p_value, "flags": res.flags[f.model]} for f in res.fits],
            "best_aic": res.best, "weibull_beta": res.weibull_beta, "sub_rayleigh": res.sub_rayleigh,
            "notes": res.notes})
        out.print(f"  {out_json}")


@app.command("noise-fit")
@reports_errors
def noise_fit(
    bottom: Optional[str] = typer.Option(
        None, "--bottom", help="Draw samples from a Table 2.2 seabed: sand/shell, coarse sand, posidonia, mud, medium sand, shells."
    ),
    model: Optional[str] = typer.Option(
        None, "--model", help="Model to draw the --bottom samples from: rayleigh, weibull, k or mixture (default mixture)."
    ),
    n: int = typer.Option(100_000, "--n", min=3, max=10_000_000, help="Number of samples drawn with --bottom (3 to 10 million)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Random seed of the draw."),
    input_file: Optional[Path] = typer.Option(
        None, "--input", help="Real sonar data: a sonar log (.aris, Oculus pings, bag, .mcap; polar, linearised "
        "from the device encoding), or a .npy amplitude array / grayscale image."
    ),
    roi: Optional[tuple[int, int, int, int]] = typer.Option(
        None, "--roi", help="Pixel box X0 Y0 X1 Y1 of an --input image (columns X0:X1, rows Y0:Y1)."
    ),
    topic: Optional[str] = typer.Option(None, "--topic", help="Bag topic of a sonar log."),
    frames: Optional[str] = typer.Option(None, "--frames", help="Frames i:j of a sonar log to pool (default all)."),
    range_min: Optional[float] = typer.Option(None, "--range-min", help="Region of a sonar log: nearest range (m)."),
    range_max: Optional[float] = typer.Option(None, "--range-max", help="Region: farthest range (m)."),
    azimuth_min_deg: Optional[float] = typer.Option(None, "--azimuth-min-deg", help="Region: leftmost azimuth (deg)."),
    azimuth_max_deg: Optional[float] = typer.Option(None, "--azimuth-max-deg", help="Region: rightmost azimuth (deg)."),
    mask: Optional[Path] = typer.Option(None, "--mask", help="Region: .npy boolean polar mask (n_bins, n_beams)."),
    detrend: bool = typer.Option(False, "--detrend/--no-detrend", help="Divide each range bin by its mean intensity."),
    dither: bool = typer.Option(True, "--dither/--no-dither", help="Dither quantised device counts before fitting."),
    reading: str = typer.Option("gamma", "--reading", help="Oculus 8-bit samples: 'gamma' (apply the gamma byte) or 'amplitude'."),
    out_json: Optional[Path] = typer.Option(None, "--out", help="Write the numbers to this JSON file."),
):
    """Fit Rayleigh, Weibull, Rayleigh-mixture and K amplitude models and compare them (Table 2.3)."""
    from rich.table import Table

    from .._atomic import write_json
    from ..sonar import distributions as D

    if (bottom is None) == (input_file is None):
        raise ValueError("give exactly one of --bottom TYPE or --input FILE")
    check_output(out_json, "--out", input_file)
    if input_file is not None and (model is not None):
        raise ValueError("--model only applies to --bottom (it picks the model the samples are drawn from)")
    if bottom is not None and roi is not None:
        raise ValueError("--roi only applies to --input")

    log_opts = dict(topic=topic, frames=frames, range_min=range_min, range_max=range_max,
                    azimuth_min_deg=azimuth_min_deg, azimuth_max_deg=azimuth_max_deg, mask=mask)
    if input_file is not None and _is_sonar_log(input_file):
        if roi is not None:
            raise ValueError("--roi is a pixel box for images; a sonar log takes --range-min/--range-max, "
                             "--azimuth-min-deg/--azimuth-max-deg or --mask")
        return _fit_log(input_file, reading=reading, detrend=detrend, dither=dither, seed=seed, out_json=out_json,
                        **log_opts)
    given = [k for k, v in log_opts.items() if v is not None]
    if given:
        raise ValueError(f"--{given[0].replace('_', '-')} applies to a sonar log --input only")

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

    out.print(title, highlight=False)
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

