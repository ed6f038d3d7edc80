"""Sensor profiles: recovery of known parameters from simulated frames, files, simulate_sonar(profile=)."""

import dataclasses

import numpy as np
import pytest

from optiacoustic.scene import Body, Material, Plane, Scene
from optiacoustic.sonar import SonarOptions, SonarSpec, simulate_sonar
from optiacoustic.sonar.gain import DeviceGain
from optiacoustic.sonar.noise import ScattererNoise
from optiacoustic.sonar.profile import SensorProfile, fit_profile
from optiacoustic.sonar.seabed_echo import seabed_pose

TRUE = dict(height=0.5, pitch=np.deg2rad(22.0), roll=np.deg2rad(4.0), el_bw=np.deg2rad(12.0))
SPEC = SonarSpec(n_beams=96, n_bins=500, fov_azimuth=np.deg2rad(50), fov_elevation=TRUE["el_bw"], range_min=0.2,
                 range_max=3.0, frequency=2.1e6, beamwidth_azimuth=np.deg2rad(0.8), range_resolution=0.0112,
                 elevation_samples=128, name="test-device")
GAIN = DeviceGain(gain_db=20.0, noise_db=-55.0, volume_db=None, spreading_db=30.0, absorption_db_per_m=0.0)


NOISE = dict(clusters_per_m2=3000.0, looks=1.5)  # the speckle model the fit assumes (density inf)
SEEDS = (5, 6, 7)


def _simulate(seed):
    scene = Scene([Body("seabed", Plane(size=(60, 60)), material=Material(reflectivity=1.0))])
    pose = seabed_pose(TRUE["height"], TRUE["pitch"], TRUE["roll"])
    opts = SonarOptions(beam_model="aperture", propagation="spreading")
    from optiacoustic.sonar.propagation import absorption_db_per_m

    gain = dataclasses.replace(GAIN, absorption_db_per_m=float(absorption_db_per_m(SPEC.frequency)))
    return simulate_sonar(scene, SPEC, pose, noise=ScattererNoise(gain=gain, **NOISE), seed=seed, options=opts)


@pytest.fixture(scope="module")
def fits():
    """Profiles fitted (without the simulation refinement) to frames of independent seeds."""
    out = []
    for seed in SEEDS:
        frame = _simulate(seed)
        out.append((frame, fit_profile(frame, refine_density=False)))
    return out


@pytest.fixture(scope="module")
def simulated(fits):
    return fits[0]


def _monte_carlo(fits, value, true, sd_key, scale=1.0):
    """Two-sided Monte Carlo check of an estimate and its stated one-sigma uncertainty over
    independent seeds: every estimate within 3 stated sigma of the truth, the mean error
    within 3 sigma / sqrt(n), and the stated sigma not grossly larger than the spread seen
    (the ratio of the rms error to the mean stated sigma at least 1/5)."""
    est = np.array([value(p) for _, p in fits])
    sd = np.array([p.uncertainty[sd_key] * scale for _, p in fits])
    err = est - true
    assert np.all(sd > 0) and np.all(np.isfinite(sd)), sd
    assert np.all(np.abs(err) <= 3 * sd), (est, true, sd)
    assert abs(err.mean()) <= 3 * sd.mean() / np.sqrt(len(err)), (est, true, sd)
    assert np.sqrt(np.mean(err**2)) >= sd.mean() / 5, ("stated uncertainty far larger than the errors", est, true, sd)


def test_fit_recovers_the_seabed_pose_and_elevation_width(fits):
    """No systematic term: the model is measured like the data (pulse blur, beams of a group)."""
    _monte_carlo(fits, lambda p: p.height, TRUE["height"], "height")
    _monte_carlo(fits, lambda p: np.rad2deg(p.pitch), np.rad2deg(TRUE["pitch"]), "pitch_deg")
    _monte_carlo(fits, lambda p: np.rad2deg(p.roll), np.rad2deg(TRUE["roll"]), "roll_deg")
    _monte_carlo(fits, lambda p: np.rad2deg(p.spec.fov_elevation), np.rad2deg(TRUE["el_bw"]), "elevation_beamwidth_deg")
    for _, p in fits:
        assert p.encoding == "linear"
        assert p.uncertainty["height"] < 0.05 * TRUE["height"]


def test_fit_recovers_the_gain_chain(fits):
    """The TVG exponent (true 30 dB) and the receiver noise (true -55 dB) over independent seeds."""
    _monte_carlo(fits, lambda p: p.gain.spreading_db, GAIN.spreading_db, "spreading_db")
    _monte_carlo(fits, lambda p: p.gain.noise_db, GAIN.noise_db, "noise_db")


def test_fit_recovers_the_speckle_grain(simulated):
    frame, prof = simulated
    # range resolution and azimuth beam width come back from the correlation lengths
    assert prof.spec.range_resolution == pytest.approx(SPEC.range_resolution, rel=0.25)
    assert prof.spec.beamwidth_azimuth == pytest.approx(SPEC.beamwidth_azimuth, rel=0.25)
    assert prof.density == np.inf and np.isfinite(prof.clusters_per_m2) and prof.clusters_per_m2 > 0
    assert 1.0 <= prof.looks <= 8.0


def test_onset_refinement_is_consistent_with_the_truth(simulated):
    """On a frame simulated with the model the fit assumes, the elevation width set by the
    seabed onset (simulated frames matched to the measured onset width) lies within 3 stated
    sigma of the true width, and the lower edge of the pattern stays where the fit put it."""
    from optiacoustic.sonar import profile as P
    from optiacoustic.sonar.realism import frame_statistics

    frame, prof = simulated
    stats = frame_statistics(frame.image, frame.ranges, frame.azimuths)
    out = P._refine_onset(prof, stats, frame)
    w_true, w_out = np.rad2deg(TRUE["el_bw"]), np.rad2deg(out.spec.fov_elevation)
    sd = out.uncertainty["elevation_beamwidth_deg"]
    assert np.isfinite(sd) and sd > 0
    assert abs(w_out - w_true) <= 3 * sd, (w_out, w_true, sd)
    assert np.isclose(out.pitch + 0.5 * out.spec.fov_elevation, prof.pitch + 0.5 * prof.spec.fov_elevation)
    assert any("seabed onset on simulated frames" in n for n in out.notes)


@pytest.fixture(scope="module")
def refined(fits):
    """The fits of ``fits`` taken through the simulation refinements of the geometry that
    ``fit_profile(refine_density=True)`` runs (height, onset width, height again)."""
    from optiacoustic.sonar import profile as P
    from optiacoustic.sonar.realism import frame_statistics

    out = []
    for frame, prof in fits:
        stats = frame_statistics(frame.image, frame.ranges, frame.azimuths)
        out.append((frame, P._refine_geometry(prof, stats, frame)))
    return out


def test_position_refinement_recovers_height_and_pitch(refined):
    """Round trip through the whole geometry fit (least squares, onset width, position): on
    frames simulated with a known pose and profile, height and pitch are within their
    stated uncertainties (two-sided Monte Carlo over seeds); the height scale the position
    step applies is 1 within its stated sigma, and the step says what it did."""
    _monte_carlo(refined, lambda p: p.height, TRUE["height"], "height")
    _monte_carlo(refined, lambda p: np.rad2deg(p.pitch), np.rad2deg(TRUE["pitch"]), "pitch_deg")
    for _, p in refined:
        note = next(n for n in p.notes if n.startswith("height set by the seabed's onset"))
        scale = float(note.split("(scale ")[1].split(";")[0])
        assert abs(np.log(scale)) <= 3 * p.uncertainty["height_scale_sd"], (scale, p.uncertainty["height_scale_sd"])
        assert p.uncertainty["height"] < 0.05 * TRUE["height"]


def test_profile_file_round_trip(simulated, tmp_path):
    _, prof = simulated
    p = prof.save(tmp_path / "p.yaml")
    back = SensorProfile.load(p)
    assert back.encoding == prof.encoding
    assert back.density == pytest.approx(prof.density)
    assert back.clusters_per_m2 == pytest.approx(prof.clusters_per_m2) and back.looks == pytest.approx(prof.looks)
    assert back.height == pytest.approx(prof.height)
    assert back.spec.elevation_pattern().beamwidth() == pytest.approx(prof.spec.elevation_pattern().beamwidth())
    np.testing.assert_allclose(back.seabed_pose.R, prof.seabed_pose.R, atol=1e-12)
    assert back.gain == prof.gain
    (tmp_path / "bad.yaml").write_text("a: 1\n")
    with pytest.raises(ValueError, match="not a sensor profile"):
        SensorProfile.load(tmp_path / "bad.yaml")
    with pytest.raises(FileNotFoundError):
        SensorProfile.load(tmp_path / "missing.yaml")


def test_simulate_with_a_profile_and_the_shipped_presets():
    names = SensorProfile.preset_names()
    assert {"oculus-m1200d-2mhz", "aris-1200-telephoto"} <= set(names)
    prof = SensorProfile.preset("aris-1200-telephoto")
    assert prof.encoding == "db"
    scene = Scene([Body("seabed", Plane(size=(80, 80)), material=Material(reflectivity=1.0))])
    spec = dataclasses.replace(prof.simulation_spec(), n_bins=400)
    f = simulate_sonar(scene, spec, prof.seabed_pose, seed=1, profile=prof)
    assert f.image.shape == (400, 48) and np.all(np.isfinite(f.image)) and f.image.max() > 0
    with pytest.raises(TypeError, match="SensorProfile"):
        simulate_sonar(scene, spec, prof.seabed_pose, profile="aris")
    with pytest.raises(KeyError, match="unknown sensor profile"):
        SensorProfile.preset("nope")


def test_a_frame_without_speckle_cells_is_refused_with_the_reason():
    """The window starts just before the seabed's onset: the 'background' read there is seabed,
    no cell is 10 dB over it, and the texture cannot be fitted; a clear error, not numpy's."""
    spec = dataclasses.replace(SPEC, n_bins=400, range_min=1.0, fov_elevation=np.deg2rad(20.0))
    scene = Scene([Body("seabed", Plane(size=(60, 60)), material=Material(reflectivity=1.0))])
    frame = simulate_sonar(scene, spec, seabed_pose(0.3, np.deg2rad(10.0), 0.0), seed=3,
                           noise=ScattererNoise(gain=GAIN, **NOISE), options=SonarOptions(beam_model="aperture", propagation="spreading"))
    with pytest.raises(ValueError, match=r"fit_profile: 0 speckle cells .* background"):
        fit_profile(frame, refine_density=False)
