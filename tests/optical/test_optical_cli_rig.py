"""The rig file, the `oas optical` / `oas render` / `oas waters` commands and the chapter-3 experiment."""

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from optiacoustic import Pose, Rig
from optiacoustic.cli import app

runner = CliRunner()
RIG = Path(__file__).resolve().parents[2] / "examples" / "rig_thesis.yaml"


def test_thesis_rig_file_aims_both_sensors_at_the_origin():
    rig = Rig.load(RIG)
    assert rig.sonar.name == "blueview-p900-90"
    assert (rig.camera.width, rig.camera.height) == (600, 400)
    np.testing.assert_allclose(rig.camera.fx, 50 * 600 / 36)
    sonar_pose = Pose.look_at((0.0, -6.0, 2.0), (0.0, 0.0, 0.0), body="sonar")
    cam = rig.camera_pose(sonar_pose)
    np.testing.assert_allclose(cam.t, (-0.25, -6.0, 2.0), atol=1e-12)
    origin_cam = cam.to_body(np.zeros(3))  # the origin in the camera frame lies on the optical axis
    assert np.hypot(origin_cam[0], origin_cam[1]) < 1e-4 and origin_cam[2] > 6
    # and it is the thesis's camera: level, as Pose.look_at builds it
    ref = Pose.look_at((-0.25, -6.0, 2.0), (0.0, 0.0, 0.0), body="camera")
    np.testing.assert_allclose(cam.R, ref.R, atol=1e-7)


def test_oas_render_writes_a_synchronised_pair(tmp_path):
    r = runner.invoke(app, ["render", "thesis_scene1", "--rig", str(RIG), "--eye", "0", "-6", "2",
                            "--target", "0", "0", "0", "--out", str(tmp_path)])
    assert r.exit_code == 0, r.output
    for name in ("sonar.npz", "sonar_fan.png", "sonar_polar.png", "optical.npz", "optical_image.png",
                 "optical_clear.png", "pair.png", "pair.json"):
        assert (tmp_path / name).is_file(), name
    o = np.load(tmp_path / "optical.npz")
    assert o["image"].shape == (400, 600, 3) and o["depth"].shape == (400, 600) and o["body"].shape == (400, 600)
    assert np.all(o["clear"] >= 0)
    s = np.load(tmp_path / "sonar.npz")
    assert s["intensity"].shape == (750, 512)
    meta = json.loads((tmp_path / "pair.json").read_text())
    np.testing.assert_allclose(meta["sonar_pose"]["t"], (0, -6, 2))
    np.testing.assert_allclose(meta["camera_pose"]["t"], (-0.25, -6, 2), atol=1e-9)
    np.testing.assert_allclose(meta["rig"]["t"], (-0.25, 0, 0))
    # the two poses and the rig agree: camera pose = sonar pose o (R, t)
    S = np.eye(4)
    S[:3, :3], S[:3, 3] = meta["sonar_pose"]["R"], meta["sonar_pose"]["t"]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = meta["rig"]["R"], meta["rig"]["t"]
    C = S @ T
    np.testing.assert_allclose(C[:3, :3], meta["camera_pose"]["R"], atol=1e-12)
    assert meta["water"]["name"] == "thesis" and meta["camera"]["width"] == 600


def test_oas_optical_uses_the_scene_view_and_options(tmp_path):
    r = runner.invoke(app, ["optical", "planar_grid", "--out", str(tmp_path), "--water", "jerlov-IB",
                            "--width", "120", "--height", "80", "--no-figures"])
    assert r.exit_code == 0, r.output
    o = np.load(tmp_path / "optical.npz")
    assert o["image"].shape == (80, 120, 3)
    assert str(o["water_name"]) == "jerlov-IB"
    assert (tmp_path / "optical_image.png").is_file()


def test_oas_optical_reports_bad_water(tmp_path):
    r = runner.invoke(app, ["optical", "flat_seabed", "--water", "swamp", "--out", str(tmp_path)])
    assert r.exit_code == 2
    assert "unknown water type 'swamp'" in r.output


def test_oas_waters_lists_presets():
    r = runner.invoke(app, ["waters"])
    assert r.exit_code == 0
    for name in ("thesis", "pure-water", "jerlov-I", "jerlov-9C"):
        assert name in r.output


def test_experiment_quick(tmp_path):
    from optiacoustic import experiments

    res = experiments.run("optical", tmp_path, quick=True)
    assert experiments.get("optical").CHAPTER == 3
    for p, caption in res.figures:
        assert Path(p).is_file() and caption
    n = res.numbers
    assert n["render_ms"] > 0 and n["bare_cast_ms"] > 0
    tr = n["mean_transmittance_rgb"]
    assert tr[0] < tr[1] < tr[2]  # red fades first
    # contrast falls with range in every water, and with turbidity at every range
    c = np.array([n["contrast_vs_range"][w] for w in ("thesis", "jerlov-IB", "jerlov-II", "jerlov-1C")])
    assert np.all(np.diff(c, axis=1) <= 1e-6)
    assert np.all(np.diff(c, axis=0)[:, 1:] < 0)
    assert (tmp_path / "results.json").is_file()
