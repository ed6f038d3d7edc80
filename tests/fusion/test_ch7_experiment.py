"""The chapter 7 experiment (quick mode): files written, and the thesis's claims hold."""

import json

import pytest

from optiacoustic import experiments


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("ch7")
    return experiments.run("enhancement", out, quick=True, seed=0), out


def test_files_and_registration(result):
    res, out = result
    assert "enhancement" in experiments.names()
    mod = experiments.get("enhancement")
    assert mod.CHAPTER == 7 and mod.TITLE and mod.SUMMARY
    data = json.loads((out / "results.json").read_text())
    assert data["name"] == "enhancement" and len(data["tables"]) == 3
    assert len(res.figures) >= 10
    for path, caption in res.figures:
        assert path.exists() and path.stat().st_size > 10_000 and caption


def test_thesis_claims(result):
    res, _ = result
    grid, cub, deg = (res.numbers[k]["errors"] for k in ("grid", "cuboids", "degraded_grid"))
    # 7.3.1: a perfect fit on the planar grid
    assert grid["RBF exact, sigma=200 px"]["test_max_px"] < 1.0
    assert grid["geometric, fitted plane"]["test_max_px"] < 1e-6
    # 7.3.2: exact interpolation fails on the top faces, smoothing improves it at every width
    for s in (1000, 500, 200):
        exact, smooth = cub[f"RBF exact, sigma={s} px"], cub[f"RBF smoothed, sigma={s} px"]
        assert exact["test_mean_px"] > 50
        assert smooth["test_mean_px"] < exact["test_mean_px"]
    # 7.4.1: the plane through the rig extrapolates exactly over the whole grid
    assert deg["geometric, fitted plane"]["test_max_px"] < 1e-6
    d = res.numbers["degraded_grid"]
    assert d["contrast_range_train"][0] >= d["contrast_threshold"] > d["contrast_range_test"][1]
