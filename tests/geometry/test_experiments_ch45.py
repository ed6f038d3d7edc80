"""The chapter 4 and 5 experiments run (quick mode), write their figures and report sound numbers."""

import json

import numpy as np
import pytest

from optiacoustic import experiments


def test_epipolar_experiment(tmp_path):
    res = experiments.run("epipolar", tmp_path, quick=True)
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["name"] == "epipolar" and len(res.figures) == 3
    for path, caption in res.figures:
        assert path.is_file() and path.stat().st_size > 10_000 and caption
    n = res.numbers
    assert n["n_sonar_features"] >= 4 and n["n_optical_features"] >= 4
    # The thesis's nearly parallel rig gives hyperbolas (sec. 4.3), the side camera ellipses.
    assert set(n["conic_types_thesis_rig"]) == {"hyperbola"}
    assert set(n["conic_types_side_rig"]) == {"ellipse"}
    # True matches on their curves: exactly for exact measurements, within a pixel for bin-quantised ones.
    assert n["max_sampson_exact_px"] < 1e-6
    assert 0 < n["max_curve_distance_marked_px"] < 1.0
    assert n["max_range_error_optical_m"] < 1e-6
    assert n["epipole"]["range_m"] == pytest.approx(0.25, abs=1e-9)


def test_reconstruction_experiment(tmp_path):
    res = experiments.run("reconstruction", tmp_path, quick=True)
    assert (tmp_path / "results.json").is_file() and len(res.figures) == 5
    assert all(p.is_file() for p, _ in res.figures)
    cfg = {(c["baseline_m"], c["distance_m"]): c for c in res.numbers["configs"]}
    c = cfg[(0.25, 3.0)]
    # Direct ML near the CRLB (600 points x 2 trials: a loose two-sided bound).
    assert 0.8 < c["direct_mse_over_crlb"] < 1.2
    # The thesis's conclusion: opti-acoustic far better than stereo optical at 3 m with 0.25 m...
    assert c["opti_acoustic_over_stereo_rmse"] < 0.5
    # ...and comparable at 1.25 m with 0.25 m.
    assert 0.7 < cfg[(0.25, 1.25)]["opti_acoustic_over_stereo_rmse"] < 1.3
    # Direct no worse than indirect; both no worse than the closed forms.
    for c in cfg.values():
        r = c["rmse_mm"]
        assert r["direct"] <= r["indirect"] * (1 + 1e-6)
        assert r["direct"] < r["range"] * 1.01 and r["direct"] < r["azimuth"]
        assert np.isfinite(c["crlb_rmse_mm"]) and c["crlb_rmse_mm"] > 0
