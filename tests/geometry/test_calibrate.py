"""Rig calibration from a planar grid (appendix A): noise-free recovery, Monte Carlo, degenerate input, CLI."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2
from typer.testing import CliRunner

from optiacoustic import PinholeCamera, Rig, SonarSpec
from optiacoustic.frames import R_SONAR_FROM_CAMERA_FORWARD, rot_x, rot_z
from optiacoustic.geometry import calibrate as C
from optiacoustic.geometry._bundle import log_so3

CAM = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
SPEC = SonarSpec.preset("blueview-p900-90")
RIG = Rig(rot_z(np.deg2rad(-2.3)) @ rot_x(np.deg2rad(3)) @ R_SONAR_FROM_CAMERA_FORWARD,
          np.array([-0.25, 0.02, 0.05]), CAM, SPEC)
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "calibration"


def errors(res, rig=RIG):
    return np.concatenate([log_so3(rig.R @ res.R.T), rig.t - res.t])


def test_simulated_views_are_consistent_with_the_rig():
    views, truth = C.simulate_views(RIG, 3, seed=0)
    for v, P_o in zip(views, truth):
        assert np.allclose(CAM.project(P_o), v.pixels)
        P_s = RIG.sonar_from_camera(P_o)
        assert np.allclose(np.linalg.norm(P_s, axis=1), v.ranges)
        assert np.allclose(np.arctan2(P_s[:, 0], P_s[:, 1]), v.azimuths)
        # the corners are coplanar
        c = P_o - P_o.mean(0)
        assert np.linalg.svd(c, compute_uv=False)[2] < 1e-12


def test_noise_free_views_are_recovered_exactly():
    views, truth = C.simulate_views(RIG, 6, seed=1)
    res = C.extrinsics(CAM, views, sonar=SPEC)
    assert res, res.message
    assert np.max(np.abs(errors(res))) < 1e-6
    for pl, P_o in zip(res.planes, truth):
        assert np.allclose(P_o @ pl[:3], pl[3], atol=1e-6)
    # the closed-form start is already within a few degrees and centimetres (x, y)
    assert np.linalg.norm(log_so3(RIG.R @ res.initial_R.T)) < np.deg2rad(3)
    assert np.max(np.abs(res.initial_t[:2] - RIG.t[:2])) < 0.1
    rig = res.rig(CAM, SPEC)
    assert np.allclose(rig.R, RIG.R, atol=1e-6)


def test_start_from_a_nominal_mounting_converges_to_the_same_answer():
    views, _ = C.simulate_views(RIG, 4, seed=2)
    res = C.extrinsics(CAM, views, sonar=SPEC, initial=(R_SONAR_FROM_CAMERA_FORWARD, [-0.25, 0, 0]))
    assert res and np.max(np.abs(errors(res))) < 1e-6
    # one view is enough from a start
    res1 = C.extrinsics(CAM, views[:1], sonar=SPEC, initial=(RIG.R, RIG.t))
    assert res1 and np.max(np.abs(errors(res1))) < 1e-6


def test_monte_carlo_is_consistent_and_reports_pitch_and_tz_as_weak():
    sp, sr, sa = 0.5, 0.002, np.deg2rad(0.1)
    runs, nees, err = 20, [], []
    for k in range(runs):
        views, _ = C.simulate_views(RIG, 6, sigma_pixel=sp, sigma_range=sr, sigma_azimuth=sa, seed=100 + k)
        res = C.extrinsics(CAM, views, sigma_pixel=sp, sigma_range=sr, sigma_azimuth=sa, sonar=SPEC)
        assert res, res.message
        e = errors(res)
        nees.append(e @ np.linalg.solve(res.covariance, e))
        err.append(e)
        assert "t_z" in res.weak and "pitch" in res.weak
        # the weakest direction is mostly pitch and t_z
        v = res.eigenvectors[:, 0]
        assert v[0] ** 2 + v[5] ** 2 > 0.8
    lo, hi = chi2.ppf([0.025, 0.975], 6 * runs) / runs
    assert lo < np.mean(nees) < hi
    rms = np.sqrt(np.mean(np.square(err), 0))
    assert np.all(rms > 0)
    assert rms[2] < np.deg2rad(0.3) and rms[3] < 0.01 and rms[4] < 0.01  # yaw, t_x, t_y are well observed
    assert rms[5] > 3 * max(rms[3], rms[4])  # t_z is not


def test_degenerate_input_gives_a_falsy_result_with_a_message():
    views, _ = C.simulate_views(RIG, 3, seed=3)
    one = C.extrinsics(CAM, views[:1])
    assert not one and "two views" in one.message
    few = C.extrinsics(CAM, [C.CalibrationView(v.pixels[:3], v.ranges[:3], v.azimuths[:3]) for v in views])
    assert not few and "at least 4" in few.message
    line = [C.CalibrationView(np.c_[np.linspace(100, 500, 10), np.full(10, 200.0)], np.full(10, 2.0),
                              np.linspace(-0.2, 0.2, 10))] * 2
    col = C.extrinsics(CAM, line)
    assert not col and "collinear" in col.message
    empty = C.extrinsics(CAM, [])
    assert not empty and np.all(np.isnan(empty.R))


@pytest.mark.parametrize("kw, match", [
    (dict(camera="cam"), "camera"),
    (dict(views=[(np.zeros((5, 2)), np.ones(4), np.zeros(5))]), "views\\[0\\]"),
    (dict(views=[(np.zeros((5, 2)), -np.ones(5), np.zeros(5))]), "ranges"),
    (dict(sigma_range=-1.0), "sigma_range"),
    (dict(initial=np.eye(3)), "initial"),
])
def test_caller_mistakes_raise_value_error(kw, match):
    views, _ = C.simulate_views(RIG, 2, seed=4)
    args = dict(camera=CAM, views=views)
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        C.extrinsics(**args)


def test_view_files_roundtrip(tmp_path):
    views, _ = C.simulate_views(RIG, 1, seed=5)
    C.save_view(tmp_path / "v.csv", views[0], header="a test")
    back = C.load_view(tmp_path / "v.csv")
    assert np.allclose(back.pixels, views[0].pixels, atol=1e-6)
    assert np.allclose(back.azimuths, views[0].azimuths, atol=1e-7)
    np.savez(tmp_path / "v.npz", u=views[0].pixels[:, 0], v=views[0].pixels[:, 1], range=views[0].ranges,
             azimuth=views[0].azimuths)
    assert np.allclose(C.load_view(tmp_path / "v.npz").ranges, views[0].ranges)
    (tmp_path / "bad.csv").write_text("u,v,range\n1,2,3\n")
    with pytest.raises(ValueError, match="azimuth"):
        C.load_view(tmp_path / "bad.csv")


def test_oas_calibrate_on_the_shipped_example(tmp_path):
    from optiacoustic.cli import app

    files = sorted(str(p) for p in EXAMPLE.glob("view_*.csv"))
    assert len(files) == 8
    out = tmp_path / "rig.yaml"
    js = tmp_path / "cal.json"
    r = CliRunner().invoke(app, ["calibrate", *files, "--rig", str(EXAMPLE / "rig.yaml"), "--sigma-pixel", "0.5",
                                 "--sigma-range", "0.005", "--sigma-azimuth-deg", "0.1", "--out", str(out),
                                 "--json", str(js)])
    assert r.exit_code == 0, r.output
    assert "weakly observed" in r.output
    rig = Rig.load(out)
    truth = Rig.load(EXAMPLE / "truth.yaml")
    d = json.loads(js.read_text())
    std = np.array([d["std"][n] for n in C.CalibrationResult.DOF_NAMES])
    e = np.concatenate([log_so3(truth.R @ rig.R.T), truth.t - rig.t])
    assert np.all(np.abs(e) < 4 * std)  # within the reported uncertainty
    assert yaml.safe_load(out.read_text())["sonar"] == "blueview-p900-90"
    r = CliRunner().invoke(app, ["calibrate", files[0], "--rig", str(EXAMPLE / "rig.yaml")])
    assert r.exit_code == 2 and "two views" in r.output


@pytest.mark.parametrize("kw, match", [
    (dict(n_views=0), r"n_views: .*got 0"),
    (dict(n_views=-1), r"n_views: .*got -1"),
    (dict(n_views=1.5), r"n_views: .*got 1\.5"),
    (dict(n_views=True), r"n_views: .*got True"),
    (dict(grid_shape=(0, 5)), r"grid_shape: .*\(0, 5\)"),
    (dict(grid_shape=(7,)), r"grid_shape: .*\(7,\)"),
    (dict(grid_shape=(7.5, 5)), r"grid_shape: .*7\.5"),
    (dict(spacing=0.0), r"spacing: .*0\.0"),
    (dict(spacing=float("nan")), r"spacing: .*nan"),
    (dict(distance=(3.0, 1.5)), r"distance: .*\[3\.0, 1\.5\]"),
    (dict(distance=(-1.0, 2.0)), r"distance: .*-1\.0"),
    (dict(distance=2.0), r"distance: expected shape \(2,\)"),
    (dict(tilt_deg=-5.0), r"tilt_deg: .*-5\.0"),
    (dict(tilt_deg=120.0), r"tilt_deg: .*120"),
    (dict(sigma_pixel=-1.0), r"sigma_pixel: .*-1\.0"),
    (dict(sigma_range=-0.01), r"sigma_range: .*-0\.01"),
    (dict(sigma_azimuth=float("inf")), r"sigma_azimuth: .*inf"),
    (dict(rig="rig"), r"rig: .*str"),
])
def test_simulate_views_rejects_bad_arguments_by_name(kw, match):
    args = dict(rig=RIG, n_views=1)
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        C.simulate_views(**args)


def test_simulate_views_edge_values_are_honoured():
    # one distance (near == far): every grid centre lies at that range from the sonar; noise 0 is exact
    views, truth = C.simulate_views(RIG, 2, distance=(2.0, 2.0), tilt_deg=0.0, grid_shape=(3, 2), seed=6)
    for v, P_o in zip(views, truth):
        assert v.n == 6
        P_s = RIG.sonar_from_camera(P_o)
        assert np.linalg.norm(P_s.mean(0)) == pytest.approx(2.0, rel=1e-12)
        # no tilt: the grid faces the sonar, its corners 0.1 m apart
        assert np.linalg.norm(P_o[1] - P_o[0]) == pytest.approx(0.1, rel=1e-12)


@pytest.mark.parametrize("R0, what", [
    (np.zeros((3, 3)), "det = 0"),
    (np.ones((3, 3)), "det = 0"),
    (np.diag([1.0, 1.0, -1.0]) @ RIG.R, "det = -1"),
    (2 * RIG.R, "det = 8"),
])
def test_initial_rotation_must_be_close_to_a_rotation(R0, what):
    views, _ = C.simulate_views(RIG, 2, seed=4)
    with pytest.raises(ValueError, match=r"initial R: not close to a rotation .*" + what):
        C.extrinsics(CAM, views, initial=(R0, RIG.t), sonar=SPEC)


def test_a_rounded_initial_rotation_is_accepted():
    # a mounting drawing's rotation, rounded to 3 decimals: close to a rotation, orthonormalised
    views, _ = C.simulate_views(RIG, 3, seed=4)
    res = C.extrinsics(CAM, views, initial=(np.round(RIG.R, 3), RIG.t + 0.01), sonar=SPEC)
    assert res
    np.testing.assert_allclose(errors(res), 0.0, atol=1e-6)
