"""The command line: commands run, write their files, and report caller mistakes in one line."""

import json

import numpy as np
from typer.testing import CliRunner

from optiacoustic.cli import app
from optiacoustic.scene import Scene

runner = CliRunner()


def test_listing_commands():
    r = runner.invoke(app, ["scenes"])
    assert r.exit_code == 0 and "thesis_scene1" in r.output and "planar_grid" in r.output
    r = runner.invoke(app, ["presets"])
    assert r.exit_code == 0
    for name in ("blueview-p900-90", "oculus-m1200d-hf", "didson-300-hf", "aris-3000-128", "gemini-720is"):
        assert name in r.output
    r = runner.invoke(app, ["--help"])
    assert r.exit_code == 0 and "sonar" in r.output


def test_scene_export_roundtrip(tmp_path):
    f = tmp_path / "s.yaml"
    r = runner.invoke(app, ["scene", "thesis_scene1", "--export", str(f)])
    assert r.exit_code == 0, r.output
    assert Scene.load(f).body_names()[0] == "seabed"


def test_sonar_command_writes_npz_and_pngs(tmp_path):
    r = runner.invoke(app, ["sonar", "flat_seabed", "--preset", "didson-300-hf", "--eye", "0", "-4", "1.5",
                            "--target", "0", "0", "0", "--out", str(tmp_path), "--no-noise", "--no-figures"])
    assert r.exit_code == 0, r.output
    data = np.load(tmp_path / "frame.npz")
    assert data["intensity"].shape == (512, 96)
    assert np.array_equal(data["intensity"], data["image"])
    assert data["ranges"].shape == (512,) and data["azimuths"].shape == (96,)
    assert data["gt_body"].shape == (512, 96) and data["gt_shadow"].dtype == bool
    meta = json.loads((tmp_path / "frame.json").read_text())
    assert meta["preset"] == "didson-300-hf"
    assert (tmp_path / "frame_fan.png").stat().st_size > 1000


def test_caller_mistakes_are_one_line_errors(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("bodies:\n  - {name: a, shape: sphere, radius: -1}\n")
    r = runner.invoke(app, ["sonar", str(bad), "--eye", "0", "-4", "1", "--out", str(tmp_path)])
    assert r.exit_code == 2
    assert "body 'a'" in r.output and "radius" in r.output and "Traceback" not in r.output
    r = runner.invoke(app, ["sonar", "flat_seabed", "--eye", "0", "0", "3", "--target", "0", "0", "0", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "parallel to up" in r.output
    r = runner.invoke(app, ["sonar", "no_such_scene", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "built-in" in r.output
    r = runner.invoke(app, ["sonar", "flat_seabed", "--preset", "nope", "--out", str(tmp_path)])
    assert r.exit_code == 2 and "unknown sonar preset" in r.output
