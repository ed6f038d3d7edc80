"""Bad input gets a clear error naming what was wrong: never silently wrong, never a hang.

Each class of mistake has several cases; every case checks the error type AND that the
message names the offending file, field or value.
"""

import json
import warnings

import numpy as np
import pytest

from optiacoustic import PinholeCamera, Pose, Rig, Scene, SonarSpec, scenes
from optiacoustic._config import MAX_DEPTH, ConfigError, load_config, parse_config
from optiacoustic._validate import as_array, as_azimuths, as_rng, check_memory
from optiacoustic.scene import SceneError

CAM = PinholeCamera.from_sensor(600, 400, (36, 24), 50)


def _rig():
    return Rig.toed_in(CAM, baseline=0.25, vergence=float(np.arctan(0.25 / 3.0)),
                       sonar=SonarSpec.preset("blueview-p900-90"))


# ----------------------------------------------------------------------------- YAML / JSON files
@pytest.mark.parametrize("text, key", [
    ("bodies:\n  - {name: b, shape: sphere, radius: 5, radius: 0.1}\n", "radius"),
    ("name: a\nname: b\nbodies: []\n", "name"),
    ("bodies:\n  - name: b\n    shape: sphere\n    radius: 1\n    pose: {position: [0, 0, 0], position: [1, 1, 1]}\n",
     "position"),
])
def test_duplicate_yaml_keys_are_refused_with_file_and_key(tmp_path, text, key):
    f = tmp_path / "dup.yaml"
    f.write_text(text)
    with pytest.raises(SceneError) as e:
        Scene.load(f)
    assert str(f) in str(e.value) and repr(key) in str(e.value) and "twice" in str(e.value)


def test_duplicate_keys_in_json_and_rig_files(tmp_path):
    f = tmp_path / "dup.json"
    f.write_text('{"bodies": [{"name": "b", "shape": "sphere", "radius": 1, "radius": 2}]}')
    with pytest.raises(SceneError, match="'radius' given twice") as e:
        Scene.load(f)
    assert str(f) in str(e.value)
    r = tmp_path / "rig.yaml"
    r.write_text("sonar: blueview-p900-90\nsonar: oculus-m1200d-hf\ncamera: {width_px: 600}\n")
    with pytest.raises(ValueError, match="'sonar' given twice") as e:
        Rig.load(r)
    assert str(r) in str(e.value)


def test_merge_keys_may_be_overridden():
    """YAML merge keys (<<) are not duplicates: explicit keys win, as in PyYAML."""
    d = parse_config("base: &b {r: 1, q: 3}\nx: {<<: *b, r: 2}\n")
    assert d["x"] == {"r": 2, "q": 3}


def _bomb(levels=9, width=9):
    lines = ['a0: &a0 [' + ",".join(['"lol"'] * width) + "]"]
    for i in range(1, levels + 1):
        lines.append(f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("text, words", [
    (_bomb(), "expands to more than"),
    ("a: &a [1, *a]\n", "refers to itself"),
    ("a: *nowhere\n", "no anchor"),
    ("x: " + "[" * (MAX_DEPTH + 5) + "]" * (MAX_DEPTH + 5) + "\n", "nesting deeper"),
    ("[" * 200_000 + "]" * 200_000, "nesting deeper"),  # crashes PyYAML's recursive composer
    ("a: !!python/object/apply:os.system [ls]\n", "not supported"),
])
def test_hostile_yaml_is_refused_quickly(tmp_path, text, words):
    f = tmp_path / "evil.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError) as e:
        load_config(f, what="scene file")
    assert words in str(e.value) and str(f) in str(e.value)


def test_deep_json_and_size_limit(tmp_path, monkeypatch):
    f = tmp_path / "deep.json"
    f.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ConfigError, match="nesting deeper") as e:
        load_config(f)
    assert str(f) in str(e.value)
    import optiacoustic._config as cfg

    monkeypatch.setattr(cfg, "MAX_BYTES", 1000)
    big = tmp_path / "big.yaml"
    big.write_text("bodies: []\n" + "# padding\n" * 200)
    with pytest.raises(ValueError) as e:
        Scene.load(big)
    assert str(big) in str(e.value) and "over the limit of 1,000 bytes" in str(e.value)


def test_config_reader_agrees_with_pyyaml_on_valid_files():
    import yaml

    from optiacoustic.scene.io import scene_to_dict

    text = yaml.safe_dump(scene_to_dict(scenes.get("thesis_scene1")), sort_keys=False)
    text += "extra: {a: yes, b: ~, c: 0x10, d: '1', e: 1.5e+3, f: [1, 2.5, -3], g: 2001-01-02}\n"
    assert parse_config(text) == yaml.safe_load(text)


def test_exponent_numbers_are_numbers_as_in_yaml_1_2_and_quoted_ones_stay_text():
    # YAML 1.1 (PyYAML) reads 1e9 as the text '1e9', and a rig's range_max: 1e9 then failed as "got '1e9'"
    d = parse_config("a: 1e9\nb: '1e9'\nc: 2E-3\nd: 1.0e+3\ne: -.5e2\nf: 1e\ng: [3e1, 5]\n")
    assert d == {"a": 1e9, "b": "1e9", "c": 2e-3, "d": 1e3, "e": -50.0, "f": "1e", "g": [30.0, 5]}
    assert isinstance(d["a"], float) and isinstance(d["g"][1], int)


@pytest.mark.parametrize("text, words", [
    ("R: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nt: [0, 0, 0]\ncamera_in_sonar: {position: [0, 0, 0]}\n",
     "'R'/'t' and 'camera_in_sonar' both place the camera"),
    ("R: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n", "field 't' missing"),
    ("camera: {width_px: 0, height_px: 400, sensor_mm: [36, 24], focal_mm: 50}\n", "width_px: must be a positive integer"),
    ("camera: {width_px: '600', height_px: 400, sensor_mm: [36, 24], focal_mm: 50}\n", "width_px: must be a positive"),
    ("camera: {width_px: 600, height_px: 400, sensor_mm: [36, 24], focal_mm: fifty}\n", "focal_mm: expected a number"),
])
def test_rig_file_mistakes_name_the_field(tmp_path, text, words):
    f = tmp_path / "rig.yaml"
    f.write_text(text)
    with pytest.raises(ValueError) as e:
        Rig.load(f)
    assert str(f) in str(e.value) and words in str(e.value)


def test_rig_file_numbers_in_exponent_notation_load(tmp_path):
    f = tmp_path / "rig.yaml"
    f.write_text("sonar: {preset: blueview-p900-90, range_max: 4e1}\n")
    assert Rig.load(f).sonar.range_max == 40.0


# ----------------------------------------------------------------------------- scenes and ray caster
@pytest.mark.parametrize("size", ["[1.0e+39, 4]", "[4, 2.0e+7]", "[3.0e+4, 4]"])  # 1.5e4 m: float32 resolves 2 mm
def test_bodies_too_big_for_float32_are_refused(tmp_path, size):
    from optiacoustic.raycast import RayCaster

    f = tmp_path / "huge.yaml"
    f.write_text(f"bodies:\n  - {{name: seabed, shape: plane, size: {size}}}\n  - {{name: rock, shape: sphere, radius: 1}}\n")
    with pytest.raises(SceneError) as e:
        RayCaster(Scene.load(f))
    assert "'seabed'" in str(e.value) and "float32" in str(e.value)


@pytest.mark.parametrize("radius", [1e-12, 3.3e-10, 1.234567890123e-5])
def test_export_keeps_small_values_and_reloads(tmp_path, radius):
    f = tmp_path / "small.yaml"
    f.write_text(f"bodies:\n  - {{name: ball, shape: sphere, radius: {radius!r}}}\n")
    out = tmp_path / "exported.yaml"
    Scene.load(f).save(out)
    again = Scene.load(out)
    assert again.bodies[0].shape.radius == pytest.approx(radius, rel=1e-11)


# ----------------------------------------------------------------------------- calibration CSVs
def _csv(tmp_path, text, name="view.csv"):
    f = tmp_path / name
    f.write_text(text)
    return f


@pytest.mark.parametrize("text, words", [
    ("u,v,range,azimuth_deg\n300,200,2.0,1.0\n310,200,2.0\n", "data row 2 has 3 values"),
    ("u,v,range,azimuth_deg\n300,200,2.0,1.0,5\n", "data row 1 has 5 values"),
    ("u,v,range,azimuth,azimuth_deg\n300,200,2.0,0.01,0.6\n", "both azimuth (rad) and azimuth_deg"),
    ("u,v,range,azimuth\n300,200,2.0,12.5\n", "degrees given as radians"),
    ("u,u,range,azimuth\n300,200,2.0,0.1\n", "column 'u' appears twice"),
    ("u,v,range,azimuth\n300,200,2.0,abc\n", "data row 1"),
    ("\ufeffu,v,range,azimuth\n300,200,2.0,abc\n", "data row 1"),  # a spreadsheet's BOM is not part of 'u'
])
def test_calibration_csv_mistakes(tmp_path, text, words):
    from optiacoustic.geometry.calibrate import load_view

    f = _csv(tmp_path, text)
    with pytest.raises(ValueError) as e:
        load_view(f)
    assert words in str(e.value) and (str(f) in str(e.value) or "azimuths" in str(e.value))


@pytest.mark.parametrize("pixels, ranges, az_deg, words", [
    ([[300, 200], [900, 200]], [2.0, 2.0], [1.0, 1.0], "outside the 600 x 400 image"),
    ([[300, 200], [310, -40]], [2.0, 2.0], [1.0, 1.0], "outside the 600 x 400 image"),
    ([[300, 200], [310, 200]], [2.0, 2.0], [1.0, 60.0], "outside the sonar's fan"),
    ([[300, 200], [310, 200]], [2.0, 200.0], [1.0, 1.0], "outside the sonar's"),
])
def test_calibration_corners_outside_what_the_sensors_see(pixels, ranges, az_deg, words):
    from optiacoustic.geometry.calibrate import CalibrationView, check_view

    rig = _rig()
    view = CalibrationView(np.array(pixels, float), np.array(ranges), np.deg2rad(az_deg))
    with pytest.raises(ValueError) as e:
        check_view(view, rig.camera, rig.sonar, name="view_07.csv")
    assert "view_07.csv" in str(e.value) and words in str(e.value) and "corner 1" in str(e.value)


def test_calibrate_cli_names_the_bad_file(tmp_path):
    from typer.testing import CliRunner

    from optiacoustic.cli import app

    rig = tmp_path / "rig.yaml"
    rig.write_text("sonar: blueview-p900-90\ncamera: {width_px: 600, height_px: 400, sensor_mm: [36, 24], focal_mm: 50}\n")
    good = _csv(tmp_path, "u,v,range,azimuth_deg\n" + "".join(f"{300 + i},{200 + i % 3},2.0,{i * 0.5}\n" for i in range(6)),
                "a.csv")
    bad = _csv(tmp_path, "u,v,range,azimuth\n" + "".join(f"{300 + i},{200 + i % 3},2.0,{0.9 + i * 0.05}\n" for i in range(6)),
               "b.csv")
    r = CliRunner().invoke(app, ["calibrate", str(good), str(bad), "--rig", str(rig)])
    assert r.exit_code == 2 and "b.csv" in r.output and "fan" in r.output and "Traceback" not in r.output


# ----------------------------------------------------------------------------- geometry and fusion
def test_negative_ranges_and_degree_azimuths_are_refused():
    from optiacoustic.geometry import epipolar, reconstruct

    rig = _rig()
    with pytest.raises(ValueError, match=r"ranges: .* got -2.0 at index 1"):
        reconstruct.range_solution(rig, [[300, 200], [310, 205]], [3.0, -2.0])
    with pytest.raises(ValueError, match="deg2rad") as e:
        epipolar.sonar_to_optical_curves(rig, [3.0], [20.0])  # 20 degrees given as radians
    assert "20" in str(e.value)
    with pytest.raises(ValueError, match="deg2rad"):
        epipolar.conic(rig, [3.0], [45.0])
    # within the fan, radians work
    assert len(epipolar.sonar_to_optical_curves(rig, [3.0], [0.05])) == 1


def test_crlb_behind_the_camera_is_nan_with_a_mask():
    from optiacoustic.geometry import reconstruct

    rig = _rig()
    P = np.array([[0.0, 0.0, 3.0], [0.1, 0.0, -3.0], [0.0, 0.1, 0.0]])
    cov = reconstruct.crlb(rig, P, sigma_pixel=1.0, sigma_range=0.01, sigma_azimuth=0.005)
    mask = np.isfinite(cov[..., 0, 0])
    assert mask.tolist() == [True, False, False]
    assert np.all(np.isnan(cov[~mask])) and np.all(np.linalg.eigvalsh(cov[mask]) > 0)


def test_ill_conditioned_rbf_fit_warns_with_the_condition_number():
    from optiacoustic.fusion import IllConditionedWarning, RBFMapping

    rng = np.random.default_rng(3)
    xy = rng.uniform(-1, 1, (30, 2))
    px = xy * 100 + 300
    with pytest.warns(IllConditionedWarning, match=r"condition number \d\.\de\+\d\d"):
        m = RBFMapping.fit(xy, px, sigma=3.0)
    assert m.condition_number > 1e12
    with warnings.catch_warnings():
        warnings.simplefilter("error", IllConditionedWarning)
        RBFMapping.fit(xy, px, sigma=0.2)  # well conditioned: silent
        RBFMapping.fit(xy, px, sigma=3.0, smoothing=1e-3)  # regularised: silent


def test_complex_data_is_refused_not_truncated(tmp_path):
    from optiacoustic.sonar import distributions as D

    with pytest.raises(ValueError, match="samples: .*complex"):
        D.Rayleigh.fit(np.array([1 + 1j, 2 + 0.5j, 0.3 + 2j]))
    f = tmp_path / "iq.npy"
    np.save(f, (np.ones((8, 8)) + 1j).astype(np.complex64))
    with pytest.raises(ValueError) as e:
        D.amplitudes_from_image(f)
    assert "iq.npy" in str(e.value) and "complex" in str(e.value)
    with pytest.raises(ValueError, match="pixels: expected real"):
        as_array([1j, 2.0], "pixels")


@pytest.mark.parametrize("seed", [1.5, -1, "3", True, np.float64(2.0)])
def test_bad_seeds_are_refused(seed):
    with pytest.raises(ValueError) as e:
        as_rng(seed)
    assert "seed" in str(e.value)


def test_bad_seed_in_the_simulators():
    from optiacoustic import simulate_sonar

    spec = SonarSpec.preset("didson-300-hf")
    with pytest.raises(ValueError, match=r"seed: .* got 1\.5"):
        simulate_sonar(scenes.get("flat_seabed"), spec, Pose.look_at((0, -4, 1.5), (0, 0, 0)), seed=1.5)


def test_sonar_axes_pose_given_to_the_camera_warns():
    from optiacoustic import simulate_optical
    from optiacoustic.optical._sanity import BlindCameraWarning

    cam = PinholeCamera.from_sensor(48, 32, (36, 24), 50)
    sc = scenes.get("flat_seabed")
    with pytest.warns(BlindCameraWarning, match="sonar-axes pose"):
        simulate_optical(sc, cam, Pose.look_at((0, -4, 2), (0, 0, 0), body="sonar"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", BlindCameraWarning)
        simulate_optical(sc, cam, Pose.look_at((0, -4, 2), (0, 0, 0), body="camera"))


# ----------------------------------------------------------------------------- sizes and failures
def test_sizes_have_upper_bounds_and_a_memory_estimate(monkeypatch):
    import dataclasses

    with pytest.raises(ValueError, match=r"PinholeCamera.width: at most 32767 px, got 100000"):
        PinholeCamera(1000, 1000, 50, 50, 100000, 10)
    spec = SonarSpec.preset("didson-300-hf")
    with pytest.raises(ValueError, match="SonarSpec.n_bins: must be at most"):
        dataclasses.replace(spec, n_bins=10**7)
    import optiacoustic._validate as V

    monkeypatch.setattr(V, "available_memory", lambda: 2**30)
    with pytest.raises(ValueError, match=r"a 20000 x 20000 camera image .* needs about .* GiB"):
        check_memory(160.0 * 20000 * 20000, "a 20000 x 20000 camera image (PinholeCamera.width x height)")
    from optiacoustic import simulate_optical

    with pytest.raises(ValueError, match=r"20000 x 20000 camera image \(PinholeCamera.width x height\)"):
        simulate_optical(scenes.get("flat_seabed"), PinholeCamera(1e4, 1e4, 1e4, 1e4, 20000, 20000),
                         Pose.look_at((0, -4, 2), (0, 0, 0), body="camera"))


def test_failed_results_say_they_failed():
    from optiacoustic.geometry import calibrate

    res = calibrate.extrinsics(CAM, [])
    assert not res and res.message
    with pytest.raises(ValueError, match=r"calibration failed \(no views\)"):
        res.rig(CAM)
    json.dumps(res.to_dict())  # the summary of a failure is still writable


def test_azimuth_helper_limits():
    assert as_azimuths([0.1, -3.0], "a").shape == (2,)
    with pytest.raises(ValueError, match=r"a: .* got 4 at index \(1,\)"):
        as_azimuths([0.1, 4.0], "a")


def test_a_long_lens_renders_instead_of_allocating_petabytes():
    # focal 1e9 mm: the forward-scatter kernels' reduction grew past the image and cv2.resize asked for 1e16 bytes
    from optiacoustic import PinholeCamera, simulate_optical

    cam = PinholeCamera.from_sensor(50, 30, (36, 24), 1e9)
    out = simulate_optical(scenes.get("thesis_scene1"), cam, Pose.look_at((-0.25, -6, 2), (0, 0, 0), body="camera"))
    assert out.image.shape == (30, 50, 3) and np.isfinite(out.image).all()
