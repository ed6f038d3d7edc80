"""The chapter-6 motion and appendix-A calibration experiments run quickly and write what they promise."""

import json

import numpy as np

from optiacoustic import experiments


def test_motion_and_calibration_are_discovered_in_report_order():
    names = experiments.names()
    assert "motion" in names and "calibration" in names
    assert experiments.get("motion").CHAPTER == 6 and experiments.get("calibration").CHAPTER == 9
    assert names.index("motion") < names.index("calibration")


def test_motion_experiment_quick(tmp_path):
    res = experiments.run("motion", tmp_path, quick=True, seed=0)
    names = {p.name for p, _ in res.figures}
    assert {"fig6_2_geometry.png", "fig6_3_views.png", "fig6_4_initial.png", "fig6_5_planar.png",
            "errors.png"} <= names
    for p, cap in res.figures:
        assert p.is_file() and p.stat().st_size > 10_000 and cap
    data = json.loads((tmp_path / "results.json").read_text())
    main = data["numbers"]["main"]
    for stage in ("initial", "planar"):
        assert np.isfinite(main[stage]["rotation_deg"]) and main[stage]["runs"] >= 3
    assert data["tables"] and len(data["tables"][0]["header"]) == 7
    assert res.summary


def test_calibration_experiment_quick(tmp_path):
    res = experiments.run("calibration", tmp_path, quick=True, seed=0)
    for p, cap in res.figures:
        assert p.is_file() and p.stat().st_size > 10_000 and cap
    data = json.loads((tmp_path / "results.json").read_text())
    six = data["numbers"]["by_views"]["6"]
    assert six["failures"] == 0
    # yaw is well determined, t_z is not (the sonar's elevation ambiguity)
    assert six["rms_deg"][2] < 0.5 and six["rms_mm"][2] > six["rms_mm"][0]
    assert res.summary
