"""Bad or extreme sonar inputs: refused with the field named, or imaged as the physics says.

Scatterer counts of a tiny density (empty cells, Poisson), a sonar under a floor plane, a frame
without echo and the noise floor, option and field types, levels that would overflow, elevation
sampling too coarse for the image model, and sensor profile files.
"""

from __future__ import annotations

import dataclasses
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from optiacoustic import Body, Material, Pose, Scene, SonarOptions, SonarSpec, simulate_sonar
from optiacoustic.scene.shapes import Plane
from optiacoustic.sonar.gain import DeviceGain
from optiacoustic.sonar.noise import NoEchoWarning, NoiseModel, ScattererNoise
from optiacoustic.sonar.profile import SensorProfile
from optiacoustic.sonar.propagation import Seawater

SMALL = SonarSpec(n_beams=32, n_bins=100, fov_azimuth=np.deg2rad(30), range_min=1, range_max=21, elevation_samples=32)


def _floor(z=0.0, flip=False, bottom="mud"):
    R = np.diag([1.0, -1.0, -1.0]) if flip else np.eye(3)  # flipped: the front faces down
    return Body("floor", Plane(size=(200, 200)), Pose(R, np.array([0.0, 0.0, z])),
                Material(reflectivity=0.5, bottom_type=bottom))


# --------------------------------------------------------------------------- 1. tiny densities
def _zero_fraction(noise, area, seed=0):
    """Fraction of exactly-zero cells of ``noise`` on a uniform echo of cell ``area`` (no background),
    away from the borders, and the number of taps of its 2-D point-spread function."""
    spec = dataclasses.replace(SMALL, n_bins=1200, n_beams=256)
    I = np.ones((spec.n_bins, spec.n_beams), np.float32)
    img = noise.apply(I, spec=spec, seabed_share={}, options=SonarOptions(), rng=seed,
                      cell_area=np.full(I.shape, area, np.float32))
    h_r, h_b = noise.kernels(spec)
    dr, db = len(h_r) // 2, len(h_b) // 2
    inner = img[dr: img.shape[0] - dr, db: img.shape[1] - db]
    return float(np.mean(inner == 0)), len(h_r) * len(h_b), inner.size


@pytest.mark.parametrize("density", [30.0, 10.0, 3.0, 1.0, 1e-2, 1e-4, 1e-6, 1e-8, 1e-10, 1e-12])
def test_empty_cells_follow_the_poisson_law_down_to_tiny_densities(density):
    """A cell of the image is 0 when no scatterer lies under its point-spread function: probability
    ``exp(-density A K)`` (``K`` taps of area ``A``). Densities of 1e-8 and below used to read as no
    seabed (the expected count under 1e-9) and gave fully developed speckle instead of empty cells."""
    A = 1e-3
    noise = ScattererNoise(density=density, gain=DeviceGain(noise_db=None))
    frac, K, n = _zero_fraction(noise, A)
    p = np.exp(-density * A * K)
    # a cell's indicator is correlated with those of the ~4K cells whose point-spread functions overlap its own
    assert abs(frac - p) <= 4 * np.sqrt(p * (1 - p) * 4 * K / n) + 1e-9, (frac, p)


def test_rounding_areas_are_no_seabed_at_any_density():
    """Areas at the rounding of a difference of cumulative sums (1e-17 m^2) hold no seabed: the echo
    is kept (ratio 1), not zeroed by a count of 0, at densities from 1 to 1e12 per m^2."""
    for density in (1.0, 300.0, 1e6, 1e12):
        frac, _, _ = _zero_fraction(ScattererNoise(density=density, gain=DeviceGain(noise_db=None)), 1e-17)
        assert frac == 0.0, density


def test_tiny_cluster_density_empties_the_seabed():
    """``clusters_per_m2`` of 1e-300: (almost) no cell holds a cluster; it used to give the image of inf."""
    frac, _, _ = _zero_fraction(ScattererNoise(density=1e3, clusters_per_m2=1e-300, gain=DeviceGain(noise_db=None)), 1e-3)
    assert frac > 0.999


def test_tiny_density_frame_is_an_empty_seabed():
    """Through simulate_sonar: a seabed of 1e-8 scatterers per m^2 is (almost) all empty cells,
    unlike the fully developed speckle of density inf."""
    scene = Scene([_floor()])
    pose = Pose.look_at([0, 0, 2], [0, 10, 0])
    opt = SonarOptions(propagation="spreading")
    g = DeviceGain(noise_db=None)
    I = simulate_sonar(scene, SMALL, pose, noise=False, options=opt).intensity
    m = I > 0.2 * np.median(I[I > 0])
    for density, lo, hi in ((np.inf, 0.0, 0.01), (1e-8, 0.9, 1.0)):  # (cells the pulse blurs past the seabed: no seabed area)
        im = simulate_sonar(scene, SMALL, pose, noise=ScattererNoise(density=density, gain=g), seed=1, options=opt).image
        assert lo <= np.mean(im[m] == 0) <= hi, density


# --------------------------------------------------------------------------- 2. under a floor plane
def test_sonar_under_a_floor_plane_is_refused():
    """The underside would image exactly like the top while the shadow passes back faces: refused,
    naming the body and the sonar's position, as a sonar inside a body."""
    with pytest.raises(ValueError, match=re.escape("pose: the sonar at [0.0, 0.0, -2.0] is below floor plane body "
                                                   "'floor' (z = 0 m), on its back side")):
        simulate_sonar(Scene([_floor()]), SMALL, Pose.look_at([0, 0, -2], [0, 10, 0], up=(0, 0, 1)), noise=False)
    # a floor whose front faces down, seen from above: its back side too
    with pytest.raises(ValueError, match="above floor plane body 'floor'"):
        simulate_sonar(Scene([_floor(flip=True)]), SMALL, Pose.look_at([0, 0, 2], [0, 10, 0]), noise=False)
    f = simulate_sonar(Scene([_floor()]), SMALL, Pose.look_at([0, 0, 2], [0, 10, 0]), noise=False)
    assert f.intensity.max() > 0


# --------------------------------------------------------------------------- 3. a frame without echo
def test_frame_without_echo_has_no_relative_noise_floor():
    """No positive echo and no reference_level: the floor (relative to the frame's echo) has no
    reference; none, with a NoEchoWarning (it used to take 1.0, an arbitrary absolute level)."""
    scene = Scene([_floor()])
    up = Pose.look_at([0, 0, 2], [0, 10, 4])  # sees nothing
    with pytest.warns(NoEchoWarning, match=r"reference_level"):
        f = simulate_sonar(scene, SMALL, up, seed=1)
    assert f.intensity.max() == 0 and f.image.max() == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error", NoEchoWarning)
        g = simulate_sonar(scene, SMALL, up, seed=1, noise=NoiseModel(reference_level=1e-3, noise_floor_db=-10.0))
    assert 0 < g.image.mean() and np.isfinite(g.image).all()
    assert issubclass(NoEchoWarning, UserWarning)


# --------------------------------------------------------------------------- 6. option types
@pytest.mark.parametrize("make, words", [
    (lambda: SonarOptions(azimuth_pattern="no"), "SonarOptions.azimuth_pattern: expected True or False, got 'no'"),
    (lambda: SonarOptions(azimuth_pattern=None), "SonarOptions.azimuth_pattern"),
    (lambda: SonarOptions(azimuth_pattern=2), "SonarOptions.azimuth_pattern"),
    (lambda: SonarOptions(range_oversample=True), "SonarOptions.range_oversample"),
    (lambda: NoiseModel(target_speckle="no"), "NoiseModel.target_speckle: expected True or False"),
    (lambda: NoiseModel(tvg_noise="no"), "NoiseModel.tvg_noise"),
    (lambda: NoiseModel(noise_floor_db=True), "NoiseModel.noise_floor_db: expected a number or None, got True"),
    (lambda: NoiseModel(noise_floor_db="x"), "NoiseModel.noise_floor_db: expected a number or None, got 'x'"),
    (lambda: NoiseModel(reference_level=True), "NoiseModel.reference_level"),
    (lambda: NoiseModel(reference_level="1"), "NoiseModel.reference_level"),
    (lambda: NoiseModel(bottom_type=["mud"]), "NoiseModel.bottom_type: unknown ['mud']"),
    (lambda: DeviceGain(gain_db=True), "DeviceGain.gain_db: expected a number, got True"),
    (lambda: DeviceGain(gain_db="3"), "DeviceGain.gain_db: expected a number, got '3'"),
    (lambda: DeviceGain(reference_range=True), "DeviceGain.reference_range"),
    (lambda: DeviceGain(noise_db="x"), "DeviceGain.noise_db"),
    (lambda: ScattererNoise(density=True), "ScattererNoise.density: expected a number, got True"),
    (lambda: ScattererNoise(density="x"), "ScattererNoise.density"),
    (lambda: ScattererNoise(looks=True), "ScattererNoise.looks"),
    (lambda: ScattererNoise(clusters_per_m2=True), "ScattererNoise.clusters_per_m2"),
    (lambda: ScattererNoise(bottom_type=["mud"]), "ScattererNoise.bottom_type: unknown ['mud']"),
    (lambda: Seawater(temperature=True), "Seawater.temperature: expected a number, got True"),
    (lambda: Seawater(temperature="5"), "Seawater.temperature"),
    (lambda: Seawater(depth=None), "Seawater.depth"),
])
def test_option_types_are_checked(make, words):
    with pytest.raises(ValueError) as e:
        make()
    assert words in str(e.value), str(e.value)


# --------------------------------------------------------------------------- 7. extremes
@pytest.mark.parametrize("make, field", [
    (lambda: NoiseModel(noise_floor_db=1e6), "NoiseModel.noise_floor_db"),
    (lambda: NoiseModel(noise_floor_db=400), "NoiseModel.noise_floor_db"),
    (lambda: NoiseModel(reference_level=1e300), "NoiseModel.reference_level"),
    (lambda: NoiseModel(reference_level=1e30, noise_floor_db=10.0), "NoiseModel.reference_level"),
    (lambda: DeviceGain(gain_db=1e6), "DeviceGain.gain_db"),
    (lambda: DeviceGain(gain_db=400), "DeviceGain.gain_db"),
    (lambda: DeviceGain(absorption_db_per_m=1e5), "DeviceGain.absorption_db_per_m"),
    (lambda: DeviceGain(spreading_db=1e4), "DeviceGain.spreading_db"),
    (lambda: DeviceGain(noise_db=1e6), "DeviceGain.noise_db"),
    (lambda: ScattererNoise(density=1e300), "ScattererNoise.density"),
    (lambda: ScattererNoise(looks=1e300), "ScattererNoise.looks"),
    (lambda: ScattererNoise(clusters_per_m2=1e300), "ScattererNoise.clusters_per_m2"),
])
def test_levels_and_counts_that_would_overflow_are_refused(make, field):
    with pytest.raises(ValueError, match=re.escape(field)):
        make()


def test_levels_at_the_bounds_give_finite_images_or_a_named_refusal():
    scene = Scene([_floor()])
    pose = Pose.look_at([0, 0, 2], [0, 10, 0])
    opt = SonarOptions(propagation="spreading")
    for noise, o in ((NoiseModel(noise_floor_db=300.0), None), (NoiseModel(noise_floor_db=-300.0), None),
                     (ScattererNoise(gain=DeviceGain(gain_db=300.0)), opt),
                     (ScattererNoise(gain=DeviceGain(noise_db=300.0)), opt),
                     (ScattererNoise(gain=DeviceGain(spreading_db=100.0)), opt),
                     (ScattererNoise(density=1e12), opt), (ScattererNoise(density=5e-324), opt)):
        im = simulate_sonar(scene, SMALL, pose, noise=noise, seed=3, options=o).image
        assert np.isfinite(im).all(), noise
    # a TVG whose factor overflows over the frame's ranges: refused when formed, naming the fields
    with pytest.raises(ValueError, match="absorption_db_per_m"):
        simulate_sonar(scene, SMALL, pose, noise=ScattererNoise(gain=DeviceGain(absorption_db_per_m=10.0)), seed=3,
                       options=opt)


# --------------------------------------------------------------------------- 8. elevation sampling
def _aperture_minimum(spec):
    from optiacoustic.sonar.formation import MIN_SAMPLES_PER_LOBE, elevation_samples_for

    return elevation_samples_for(spec, "aperture", MIN_SAMPLES_PER_LOBE)


def test_aperture_model_refuses_too_few_elevation_samples():
    """One ray stands for a huge elevation cell: 1 sample put a wall at 10 m at 16 m with 0.70 of
    its energy, 5 samples gave 1.45x. Refused below the minimum, with the field and the minimum."""
    wall = Body("wall", Plane(size=(60, 30)), Pose(np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float),
                                                    np.array([0, 10.0, 0])), Material(reflectivity=0.5))
    base = SonarSpec(n_beams=31, n_bins=400, fov_azimuth=np.deg2rad(30), range_min=1, range_max=21)
    need = _aperture_minimum(base)
    look = Pose(np.eye(3), np.zeros(3))
    opt = SonarOptions(beam_model="aperture")
    for es in (1, 3, 5, 7, need - 1):
        with pytest.raises(ValueError, match=rf"SonarSpec.elevation_samples: {es} is too coarse for "
                                             rf"beam_model='aperture': it needs at least {need} "):
            simulate_sonar(Scene([wall]), dataclasses.replace(base, elevation_samples=es), look, noise=False, options=opt)

    def energy(es):
        s = dataclasses.replace(base, elevation_samples=es)
        return float(simulate_sonar(Scene([wall]), s, look, noise=False, options=opt).intensity[:, 15].sum() * s.bin_width)

    assert energy(need + 1) == pytest.approx(energy(256), rel=0.02)


def test_aperture_model_just_above_the_minimum_matches_the_analytic_seabed_echo():
    """At one sample above the minimum the aperture model's flat seabed has the analytic echo's energy."""
    from optiacoustic.sonar.formation import azimuth_kernel
    from optiacoustic.sonar.seabed_echo import flat_seabed_echo, seabed_pose

    scene = Scene([Body("seabed", Plane(size=(200, 200)), material=Material(reflectivity=1.0))])
    spec = SonarSpec(n_beams=64, n_bins=400, fov_azimuth=np.deg2rad(60), fov_elevation=np.deg2rad(12), range_min=0.3,
                     range_max=3.0, frequency=2.1e6, beamwidth_azimuth=np.deg2rad(0.4), range_resolution=0.0025)
    spec = dataclasses.replace(spec, elevation_samples=_aperture_minimum(spec) + 1)
    h, pitch, roll = 0.4, np.deg2rad(20), np.deg2rad(5)
    f = simulate_sonar(scene, spec, seabed_pose(h, pitch, roll), noise=False, options=SonarOptions(beam_model="aperture"))
    E = flat_seabed_echo(spec.ranges, spec.azimuths, h, pitch, roll, spec.elevation_pattern()) * azimuth_kernel(spec).sum()
    a, b = f.intensity[:, 10:54], E[:, 10:54]
    assert a.sum() / b.sum() == pytest.approx(1.0, abs=0.01)
    assert np.abs(a - b).sum() / b.sum() < 0.02


def test_thesis_model_refuses_fewer_than_four_elevation_samples():
    """1 sample put a seabed's onset at 1.3 m instead of 5.5 m, 2 at 3.9 m: refused below 4."""
    scene = Scene([_floor()])
    pose = Pose.look_at([0, 0, 2], [0, 10, 0])
    for es in (1, 2, 3):
        with pytest.raises(ValueError, match=rf"SonarSpec.elevation_samples: {es} is too coarse for "
                                             r"beam_model='thesis': it needs at least 4"):
            simulate_sonar(scene, dataclasses.replace(SMALL, elevation_samples=es), pose, noise=False)
    assert simulate_sonar(scene, dataclasses.replace(SMALL, elevation_samples=4), pose, noise=False).intensity.max() > 0


def test_simulation_spec_keeps_its_rule():
    """SensorProfile.simulation_spec shares the rule (24 samples per main lobe, 64 to 512)."""
    p = SensorProfile.preset("aris-1200-telephoto")
    el = p.spec.elevation_pattern()
    span = 2 * min(el.null_angle(2), np.deg2rad(75.0))
    assert p.simulation_spec().elevation_samples == int(np.clip(np.ceil(24 * span / el.beamwidth()), 64, 512))


# --------------------------------------------------------------------------- 5. sensor profile files
PRESET = Path(__file__).resolve().parents[2] / "src" / "optiacoustic" / "data" / "sonar_profiles" / "oculus-m1200d-2mhz.yaml"


def _variant(tmp_path, name, edit):
    text = PRESET.read_text()
    new = edit(text)
    assert new != text, name
    p = tmp_path / f"{name}.yaml"
    p.write_text(new)
    return p


@pytest.mark.parametrize("name, edit, words", [
    ("dup_key", lambda s: re.sub(r"(\nlooks: [^\n]*)", r"\1\nlooks: 50.0", s, count=1), "key 'looks' given twice"),
    ("gain_list", lambda s: re.sub(r"gain: \{[^}]*\}", "gain: [1, 2]", s), "field 'gain': expected a mapping"),
    ("seabed_list", lambda s: re.sub(r"seabed: \{[^}]*\}", "seabed: [1, 2]", s), "field 'seabed': expected a mapping"),
    ("gain_bool", lambda s: re.sub(r"gain_db: [0-9.]+,", "gain_db: true,", s, count=1), "DeviceGain.gain_db"),
    ("gain_key", lambda s: re.sub(r"gain_db: [0-9.]+,", "gain_dbb: 3,", s, count=1), "field 'gain.gain_dbb': unknown"),
    ("looks_str", lambda s: re.sub(r"\nlooks: [^\n]*", "\nlooks: abc", s, count=1), "field 'looks': expected a number"),
    ("looks_bool", lambda s: re.sub(r"\nlooks: [^\n]*", "\nlooks: true", s, count=1), "field 'looks': expected a number"),
    ("db_range_0", lambda s: s.replace("db_range: 80.0", "db_range: 0"), "field 'db_range'"),
    ("db_range_nan", lambda s: s.replace("db_range: 80.0", "db_range: .nan"), "field 'db_range'"),
    ("full_scale_neg", lambda s: s.replace("full_scale: 255.0", "full_scale: -255"), "field 'full_scale'"),
    ("height_neg", lambda s: re.sub(r"height: [0-9.]+", "height: -5.0", s, count=1), "field 'seabed.height'"),
    ("pitch_big", lambda s: re.sub(r"pitch_deg: [0-9.]+", "pitch_deg: 4817", s, count=1), "field 'seabed.pitch_deg'"),
    ("version_99", lambda s: s.replace("optiacoustic_sensor_profile: 1", "optiacoustic_sensor_profile: 99"),
     "field 'optiacoustic_sensor_profile': version 99 is not supported"),
    ("unknown", lambda s: s.replace("\nlooks:", "\nlookz: 1\nlooks:", 1), "field 'lookz': unknown"),
])
def test_bad_profile_files_name_the_file_and_the_field(tmp_path, name, edit, words):
    p = _variant(tmp_path, name, edit)
    with pytest.raises(ValueError) as e:
        SensorProfile.load(p)
    msg = str(e.value)
    assert msg.startswith(str(p)) and words in msg, msg


def test_unreadable_profile_files_are_value_errors_naming_the_file(tmp_path):
    b = tmp_path / "binary.yaml"
    b.write_bytes(b"optiacoustic_sensor_profile: 1\n\xff\xfe\x00bad")
    with pytest.raises(ValueError, match=re.escape(f"{b}: sensor profile is not UTF-8")):
        SensorProfile.load(b)
    with pytest.raises(ValueError, match=re.escape(f"{tmp_path}: sensor profile is not a file")):
        SensorProfile.load(tmp_path)
    assert SensorProfile.load(PRESET).looks > 0  # the shipped file reads


def test_sonar_command_with_a_bad_profile_exits_2_with_one_error_line(tmp_path):
    from optiacoustic.cli import app

    p = _variant(tmp_path, "gain_list", lambda s: re.sub(r"gain: \{[^}]*\}", "gain: [1, 2]", s))
    r = CliRunner().invoke(app, ["sonar", "flat_seabed", "--profile", str(p), "--no-figures", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert lines[0].startswith("error:") and "gain_list.yaml" in r.output and "Traceback" not in r.output, r.output
