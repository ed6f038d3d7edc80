"""The noise and reverberation model applied to sonar images."""

import numpy as np
import pytest
from scipy import stats

from optiacoustic import Pose, scenes
from optiacoustic.sonar import Seawater, SonarSpec, simulate_sonar
from optiacoustic.sonar.distributions import bottom_model
from optiacoustic.sonar.noise import NoiseModel

SPEC = SonarSpec(n_beams=64, n_bins=300, fov_azimuth=np.deg2rad(40), range_min=3.0, range_max=12.0)


@pytest.fixture(scope="module")
def seabed():
    scene = scenes.get("flat_seabed")  # bottom_type sand/shell
    return scene, Pose.look_at((0, -6, 2), (0, 0, 0))


def test_noise_off_and_seeds(seabed):
    scene, pose = seabed
    a = simulate_sonar(scene, SPEC, pose, noise=False)
    assert np.array_equal(a.image, a.intensity)
    b = simulate_sonar(scene, SPEC, pose, noise=NoiseModel.off(), seed=3)
    assert np.array_equal(b.image, b.intensity)
    c1 = simulate_sonar(scene, SPEC, pose, seed=7)
    c2 = simulate_sonar(scene, SPEC, pose, seed=7)
    c3 = simulate_sonar(scene, SPEC, pose, seed=8)
    assert np.array_equal(c1.image, c2.image) and not np.array_equal(c1.image, c3.image)
    assert c1.image.dtype == np.float32 and np.all(c1.image >= 0)


def test_mean_image_is_echo_plus_noise(seabed):
    """E[image] = I + N: reverberation and speckle redistribute power, noise adds it (D2.6)."""
    scene, pose = seabed
    model = NoiseModel(noise_floor_db=-10.0)
    frames = [simulate_sonar(scene, SPEC, pose, noise=model, seed=s) for s in range(40)]
    I = frames[0].intensity.astype(float)
    N = model.noise_power(I, SPEC.ranges, SPEC.frequency, "tvg", Seawater())[:, None].astype(float)
    mean = np.mean([f.image for f in frames], axis=0)
    lit = I > 0.2 * I.max()
    # average over many cells and frames: the relative error of the mean shrinks as 1/sqrt(n)
    ratio = mean[lit].sum() / (I + N)[lit].sum()
    n = lit.sum() * len(frames)
    assert abs(ratio - 1) < 6 / np.sqrt(n) + 2e-3, ratio
    # noise alone where nothing echoes: mean N, exponential statistics
    dark = (I == 0) & (np.arange(SPEC.n_bins)[:, None] > 10)
    if dark.any():
        rows = np.broadcast_to(np.arange(SPEC.n_bins)[:, None], I.shape)[dark]
        z = np.concatenate([f.image[dark] / N[rows, 0] for f in frames])
        assert abs(z.mean() - 1) < 0.05
    # with noise, the image is not the echo: the test can fail
    assert np.abs(frames[0].image - I).mean() > 0.1 * I[lit].mean()


def test_seabed_amplitude_follows_the_bottom_model(seabed):
    scene, pose = seabed
    for model in ("mixture", "weibull", "k", "rayleigh"):
        nm = NoiseModel(reverberation=model, noise_floor_db=None, target_speckle=False)
        f = simulate_sonar(scene, SPEC, pose, noise=nm, seed=11)
        lit = f.intensity > 0.05 * f.intensity.max()
        x = np.sqrt(f.image[lit] / f.intensity[lit])
        dist = bottom_model("sand/shell", model)
        p = stats.kstest(x, dist.cdf).pvalue
        assert p > 1e-3, (model, p)
        # and a model it does not follow is rejected (the check has teeth)
        wrong = bottom_model("posidonia", "k")
        assert stats.kstest(x, wrong.cdf).pvalue < 1e-6


def test_bottom_type_override_and_validation(seabed):
    scene, pose = seabed
    nm = NoiseModel(bottom_type="posidonia", reverberation="k", noise_floor_db=None, target_speckle=False)
    f = simulate_sonar(scene, SPEC, pose, noise=nm, seed=2)
    lit = f.intensity > 0.05 * f.intensity.max()
    x = np.sqrt(f.image[lit] / f.intensity[lit])
    assert stats.kstest(x, bottom_model("posidonia", "k").cdf).pvalue > 1e-3
    with pytest.raises(ValueError, match="bottom_type"):
        NoiseModel(bottom_type="gravel")
    with pytest.raises(ValueError, match="reverberation"):
        NoiseModel(reverberation="gaussian")
    with pytest.raises(TypeError, match="noise"):
        simulate_sonar(scene, SPEC, pose, noise="loud")


def test_target_speckle_is_rayleigh():
    scene = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    pose = Pose.look_at(scene.view.eye, scene.view.target)
    nm = NoiseModel(reverberation=None, noise_floor_db=None, target_speckle=True)
    f = simulate_sonar(scene, spec, pose, noise=nm, seed=5)
    share = f.seabed_share["sand/shell"]
    target = (share == 0) & (f.intensity > 1e-3 * f.intensity.max())
    assert target.sum() > 500
    # exponential intensity <=> Rayleigh amplitude with E[x^2] = 1
    z = f.image[target] / f.intensity[target]
    assert stats.kstest(z, "expon").pvalue > 1e-3
