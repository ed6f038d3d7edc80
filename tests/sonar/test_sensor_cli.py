"""``oas sensor-fit`` and ``oas sonar --profile`` on the shared samples (comparisons without refitting: fast)."""

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from optiacoustic.cli import app

runner = CliRunner()
ARIS = Path(__file__).resolve().parents[1] / "data" / "aris" / "sample.aris"


def test_sensor_fit_report_with_a_shipped_profile(tmp_path):
    r = runner.invoke(app, ["sensor-fit", str(ARIS), "--profile", "aris-1200-telephoto", "--report", str(tmp_path),
                            "--max-report", "1"])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "frame_000.png").stat().st_size > 10_000
    table = json.loads((tmp_path / "comparison.json").read_text())
    assert [row["frame"] for row in table["frames"]] == [0]
    c = table["frames"][0]["speckle_contrast"]
    assert c["real"] > 1.0 and c["sim"] > 1.0


def test_sensor_fit_refuses_bad_input(tmp_path):
    r = runner.invoke(app, ["sensor-fit", str(ARIS), "--frames", "99"])
    assert r.exit_code == 2 and "--frames" in r.output
    r = runner.invoke(app, ["sensor-fit", str(ARIS), "--profile", str(tmp_path / "none.yaml")])
    assert r.exit_code == 2 and "none.yaml" in r.output
    r = runner.invoke(app, ["sensor-fit", str(tmp_path / "missing.aris")])
    assert r.exit_code == 2


def test_sonar_command_renders_with_a_profile(tmp_path):
    r = runner.invoke(app, ["sonar", "flat_seabed", "--profile", "aris-1200-telephoto", "--no-figures",
                            "--elevation-samples", "48", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    data = np.load(tmp_path / "frame.npz")
    assert np.all(np.isfinite(data["image"])) and data["image"].max() > 0
    assert json.loads((tmp_path / "frame.json").read_text())["profile"] == "aris-1200-telephoto"
    r = runner.invoke(app, ["sonar", "flat_seabed", "--profile", "no-such-device", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "unknown sensor profile" in r.output


def test_sensor_fit_region_outside_the_window_or_reversed_is_named_before_the_fit(tmp_path):
    # was: '0 speckle cells ... (nan, read before the seabed's onset at nan m)' after the work
    for region, words in ((("30", "40"), "outside the frames' range window 3.298-23.39 m"),
                          (("10", "5"), "r_min < r_max"), (("nan", "nan"), "expected finite ranges")):
        r = runner.invoke(app, ["sensor-fit", str(ARIS), "--region", *region, "--out", str(tmp_path / "p.yaml")])
        assert r.exit_code == 2 and words in r.output and "Traceback" not in r.output, r.output
        assert not (tmp_path / "p.yaml").exists()
