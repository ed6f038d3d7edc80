"""Noise fits on frames in device units: dithering, detrending, regions, flags (seeded Monte Carlo)."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import optiacoustic as oa
from optiacoustic.io import units
from optiacoustic.sonar.frame import MeasuredSonarFrame
from optiacoustic.sonar.realfit import fit_frames, region_amplitudes

SPEC = oa.SonarSpec(n_beams=64, n_bins=400, range_min=1.0, range_max=9.0)


def _frames(intensity_stack, encoding, **params):
    out = []
    for k, I in enumerate(intensity_stack):
        raw = units.encode(I, encoding, **params)
        out.append(MeasuredSonarFrame(raw=raw, image=units.decode(raw, encoding, **params), spec=SPEC,
                                      encoding=encoding, index=k, meta={"encoding_params": params}))
    return out


def _weibull_intensity(beta, n_frames, rng, scale=1.0):
    a = rng.weibull(beta, (n_frames, SPEC.n_bins, SPEC.n_beams))
    return (scale * a) ** 2


@pytest.mark.parametrize("beta", [1.3, 1.8])
def test_dithered_aris_bytes_recover_weibull_shape(beta):
    rng = np.random.default_rng(int(beta * 10))
    # amplitudes spanning ~ 40 dB of ARIS bytes (3 frames pooled)
    frames = _frames(_weibull_intensity(beta, 2, rng, scale=300.0), "aris_db")
    res = fit_frames(frames, seed=1, ranges=(1.0, 5.0), models=("weibull",))
    assert res.n_frames == 2 and res.dithered and "aris_db" in res.linearisation
    assert abs(res.weibull_beta - beta) < 0.03 and res.weibull_beta != beta
    plain = fit_frames(frames, dither=False, ranges=(1.0, 5.0), models=("weibull",))
    ks = {f.model: f.ks_statistic for f in res.fits}
    ks_plain = {f.model: f.ks_statistic for f in plain.fits}
    assert ks["weibull"] < ks_plain["weibull"]  # the staircase of 0.31 dB steps is what KS saw


def test_sub_rayleigh_flagged_and_k_at_bound():
    rng = np.random.default_rng(5)
    frames = _frames(_weibull_intensity(3.0, 1, rng), "linear")
    res = fit_frames(frames)
    assert res.sub_rayleigh and res.weibull_beta == pytest.approx(3.0, abs=0.05)
    assert any("sub-Rayleigh" in n for n in res.notes)
    assert any("upper bound" in f for f in res.flags["k"])
    assert res.flags["weibull"]


def test_rayleigh_mixture_collapse_flagged_on_pure_rayleigh():
    rng = np.random.default_rng(2)
    frames = _frames(_weibull_intensity(2.0, 1, rng), "linear")
    res = fit_frames(frames, ranges=(1.0, 3.0), models=("mixture",))
    assert any("collapsed" in f or "empty" in f for f in res.flags["mixture"])


def test_detrending_removes_a_range_trend():
    rng = np.random.default_rng(3)
    I = _weibull_intensity(2.0, 2, rng)
    trend = (1.0 + 30.0 * np.linspace(0, 1, SPEC.n_bins) ** 2)[None, :, None]
    frames = _frames(I * trend, "linear")
    raw_fit = fit_frames(frames, models=("weibull",))
    det_fit = fit_frames(frames, detrend=True, detrend_window=9, models=("weibull",))
    assert abs(det_fit.weibull_beta - 2.0) < 0.05
    assert abs(raw_fit.weibull_beta - 2.0) > 0.3


def test_region_selection_counts_cells():
    rng = np.random.default_rng(4)
    frames = _frames(_weibull_intensity(2.0, 2, rng) + 1e-3, "linear")
    r_sel = (SPEC.ranges >= 3.0) & (SPEC.ranges <= 5.0)
    a_sel = (SPEC.azimuths >= -0.2) & (SPEC.azimuths <= 0.3)
    amp, info = region_amplitudes(frames, ranges=(3.0, 5.0), azimuths=(-0.2, 0.3), dither=False)
    assert amp.size == 2 * r_sel.sum() * a_sel.sum() and np.mean(amp ** 2) == pytest.approx(1.0)
    mask = np.zeros((SPEC.n_bins, SPEC.n_beams), bool)
    mask[10:20, 5:7] = True
    amp, _ = region_amplitudes(frames, mask=mask, dither=False)
    assert amp.size == 2 * 20
    with pytest.raises(ValueError, match="selects no cell"):
        region_amplitudes(frames, ranges=(50, 60))


def test_cli_noise_fit_on_real_oculus(tmp_path):
    from optiacoustic.cli import app
    from pathlib import Path

    sample = Path(__file__).resolve().parents[1] / "data" / "oculus" / "one_ping_8bit.raw"
    out = tmp_path / "fit.json"
    r = CliRunner().invoke(app, ["noise-fit", "--input", str(sample), "--range-min", "0.8", "--range-max", "0.95",
                                 "--reading", "amplitude", "--detrend", "--out", str(out)])
    assert r.exit_code == 0, r.output
    d = json.loads(out.read_text())
    assert d["source"]["dithered"] and d["source"]["reading"] == "amplitude"
    assert "oculus_gamma8" in d["source"]["linearisation"]
    assert {f["model"] for f in d["fits"]} == {"rayleigh", "weibull", "mixture", "k"}
    assert isinstance(d["sub_rayleigh"], bool)
    r = CliRunner().invoke(app, ["noise-fit", "--input", str(sample), "--roi", "0", "0", "5", "5"])
    assert r.exit_code == 2 and "--roi is a pixel box" in r.output
