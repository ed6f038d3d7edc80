"""Speckle from scatterer counts against its exact moments (docs/physics.md, "Speckle from scatterers")."""

import numpy as np
import pytest

from optiacoustic.scene import Body, Material, Plane, Scene
from optiacoustic.sonar import SonarOptions, SonarSpec, simulate_sonar
from optiacoustic.sonar.beampattern import BeamPattern
from optiacoustic.sonar.formation import cell_area
from optiacoustic.sonar.gain import DeviceGain, decode, encode
from optiacoustic.sonar.noise import ScattererNoise
from optiacoustic.sonar.seabed_echo import seabed_pose
from optiacoustic.sonar.speckle import (
    analytic_autocorrelation,
    analytic_contrast,
    autocorrelation,
    beam_kernel,
    effective_shape,
    gaussian_pulse_kernel,
    speckle_field,
)

H_R = gaussian_pulse_kernel(2.5)
H_B = beam_kernel(BeamPattern.from_beamwidth(np.deg2rad(1.0), 900e3), np.deg2rad(0.25))


def _blocks(z, n=16):
    """Contrast of each of ``n`` row blocks: their spread gives a Monte Carlo standard error."""
    return np.array([b.std() / b.mean() for b in np.array_split(z, n, axis=0)])


@pytest.mark.parametrize("mu", [0.2, 2.0, np.inf])
def test_contrast_matches_the_scatterer_count_law(mu):
    rng = np.random.default_rng(7)
    f = speckle_field(mu, H_R, H_B, rng, shape=(1600, 400))[20:-20, 20:-20]
    c = _blocks(f)
    se = c.std(ddof=1) / np.sqrt(len(c))
    expected = analytic_contrast(mu, H_R, H_B)
    assert abs(c.mean() - expected) < 4 * se + 0.002
    assert se > 0
    assert f.mean() == pytest.approx(1.0, abs=0.03)
    if np.isfinite(mu):  # K shape nu = mu N_eff: contrast^2 = 1 + 2 / nu
        assert expected**2 == pytest.approx(1 + 2 / effective_shape(mu, H_R, H_B))


@pytest.mark.parametrize("mu", [0.5, np.inf])
@pytest.mark.parametrize("axis", [0, 1])
def test_autocorrelation_matches_the_filter(mu, axis):
    rng = np.random.default_rng(11 + axis)
    f = speckle_field(mu, H_R, H_B, rng, shape=(1200, 300))[20:-20, 20:-20]
    lags = np.arange(6)
    est = autocorrelation(f, 5, axis)
    expected = analytic_autocorrelation(mu, H_R, H_B, lags, axis)
    # Monte Carlo: about 1e5 pairs; sd of a correlation estimate of correlated cells ~ 0.01
    np.testing.assert_allclose(est, expected, atol=0.03)
    assert expected[1] > 0.2  # the grain spans more than one cell: not i.i.d. pixels


def test_encodings_round_trip():
    x = np.array([1e-3, 0.5, 1.0, 300.0])
    for enc in ("linear", "amplitude", "root-amplitude", "db"):
        np.testing.assert_allclose(decode(encode(x, enc, 2.0), enc, 2.0), x, rtol=1e-12)
    with pytest.raises(ValueError, match="encoding"):
        encode(x, "gamma")


def test_device_gain_background_profile():
    g = DeviceGain(noise_db=-30, volume_db=-10, spreading_db=20, absorption_db_per_m=0.0)
    r = np.array([1.0, 2.0, 4.0])
    # receiver noise rises with the 20 log r TVG; volume reverberation (r^-2) is flat after it
    np.testing.assert_allclose(g.background(r), 1e-3 * r**2 + 1e-1)
    with pytest.raises(ValueError, match="noise_db"):
        DeviceGain(noise_db=float("nan"))


def test_flat_seabed_speckle_through_the_simulator():
    """Image over its exact mean: E[z^2] = 2 (1 + S4 / (mu S2^2)) with mu = density x cell area."""
    scene = Scene([Body("seabed", Plane(size=(100, 100)), material=Material(reflectivity=1.0))])
    spec = SonarSpec(n_beams=160, n_bins=600, fov_azimuth=np.deg2rad(40), fov_elevation=np.deg2rad(14), range_min=1.0,
                     range_max=6.0, frequency=900e3, beamwidth_azimuth=np.deg2rad(0.6), range_resolution=0.02,
                     elevation_samples=96)
    density = 2000.0
    noise = ScattererNoise(density=density, gain=DeviceGain(noise_db=None, spreading_db=20.0, absorption_db_per_m=0.0))
    options = SonarOptions(beam_model="aperture", propagation="spreading")
    pose = seabed_pose(1.5, np.deg2rad(25), 0.0)
    f = simulate_sonar(scene, spec, pose, noise=noise, seed=3, options=options)
    mean = f.intensity * noise.gain.tvg(spec.ranges)[:, None]
    mu = density * cell_area(spec, _img_rays(scene, spec, pose, options), {})
    h_r, h_b = noise.kernels(spec)
    s2 = (h_r**2).sum() * (h_b**2).sum()
    s4 = (h_r**4).sum() * (h_b**4).sum()
    ok = (mean > 0.2 * mean.max()) & (mu > 0)
    ok[:, :12] = ok[:, -12:] = False
    z = f.image[ok] / mean[ok]
    pred = 2 * (1 + s4 / (mu[ok] * s2**2))
    blocks = np.array_split(np.arange(z.size), 20)
    m = np.array([np.mean(z[b] ** 2) / np.mean(pred[b]) for b in blocks])
    se = m.std(ddof=1) / np.sqrt(len(m))
    assert ok.sum() > 5000
    assert z.mean() == pytest.approx(1.0, abs=0.05)
    assert abs(m.mean() - 1.0) < 4 * se + 0.02
    assert pred.mean() > 2.2  # the counts matter here (not fully developed speckle)


def _img_rays(scene, spec, pose, options):
    from optiacoustic.sonar.formation import _aperture_elevation_weights, _scan, caster_for, scan_spec

    _, img = _scan(scene, caster_for(scene), scan_spec(spec, "aperture"), pose, options,
                   _aperture_elevation_weights(spec), spec.elevation_pattern())
    return img


# --------------------------------------------------------------------------- clusters and looks
def test_look_weights_give_the_effective_number_of_looks():
    from optiacoustic.sonar.speckle import look_weights

    rng = np.random.default_rng(4)
    for L in (1.0, 1.3, 2.0, 2.7, 4.5):
        w = look_weights(L)
        assert w.sum() == pytest.approx(1.0) and np.all(w > 0)
        assert w.sum() ** 2 / (w**2).sum() == pytest.approx(L)
        x = rng.exponential(size=(len(w), 200_000)).T @ w  # weighted average of independent looks
        c = _blocks(x.reshape(-1, 1000).T, 20)
        assert abs(c.mean() - 1 / np.sqrt(L)) < 4 * c.std(ddof=1) / np.sqrt(len(c)) + 0.002
    with pytest.raises(ValueError, match="looks"):
        look_weights(0.5)


@pytest.mark.parametrize("mu,nu", [(np.inf, 0.7), (3.0, 2.0), (np.inf, np.inf)])
def test_cluster_ratio_is_gamma_mixed_poisson(mu, nu):
    """E[n / mu] = 1 and Var(n / mu) = 1 / mu + 1 / nu (negative binomial counts)."""
    from optiacoustic.sonar.speckle import cluster_ratio

    x = cluster_ratio(np.full(400_000, mu), np.full(400_000, nu), np.random.default_rng(2), dtype=np.float64)
    var = (0 if not np.isfinite(mu) else 1 / mu) + (0 if not np.isfinite(nu) else 1 / nu)
    b = x.reshape(40, -1)
    means, vars_ = b.mean(1), b.var(1)
    assert abs(means.mean() - 1) < 4 * means.std(ddof=1) / np.sqrt(40) + 1e-12
    assert abs(vars_.mean() - var) < 4 * vars_.std(ddof=1) / np.sqrt(40) + 1e-12


@pytest.mark.parametrize("nu_c,looks", [(0.8, 1.0), (2.0, 2.5)])
def test_texture_and_looks_through_the_noise_model(nu_c, looks):
    """A uniform seabed through ScattererNoise: mean kept (the image's own mean, blurred once)
    and contrast^2 = (1 + S4 / (S2^2 nu_c))(1 + 1 / L) - 1, the generalised K law of the
    filtered texture (docs/physics.md 4.3)."""
    from optiacoustic.sonar.speckle import gk_moments

    spec = SonarSpec(n_beams=200, n_bins=1200, fov_azimuth=np.deg2rad(50), fov_elevation=np.deg2rad(14), range_min=1.0,
                     range_max=6.0, frequency=900e3, beamwidth_azimuth=np.deg2rad(0.5), range_resolution=0.01)
    area = 1e-3
    noise = ScattererNoise(clusters_per_m2=nu_c / area, looks=looks,
                           gain=DeviceGain(noise_db=None, spreading_db=0.0, absorption_db_per_m=0.0))
    I = np.ones((spec.n_bins, spec.n_beams), np.float32)
    out = noise.apply(I, spec=spec, seabed_share={}, options=SonarOptions(beam_model="aperture"), rng=11,
                      cell_area=np.full(I.shape, area))[40:-40, 20:-20]
    h_r, h_b = noise.kernels(spec)
    s2 = (h_r**2).sum() * (h_b**2).sum()
    s4 = (h_r**4).sum() * (h_b**4).sum()
    expected, _ = gk_moments(nu_c * s2**2 / s4, looks)
    c = _blocks(out, 20)
    m = np.array([b.mean() for b in np.array_split(out, 20, axis=0)])
    assert abs(m.mean() - 1) < 4 * m.std(ddof=1) / np.sqrt(20)
    assert abs(c.mean() - expected) < 4 * c.std(ddof=1) / np.sqrt(len(c)) + 0.01


@pytest.mark.parametrize("kernels", ["numba", "numpy"])
@pytest.mark.parametrize("model", [dict(density=500.0), dict(density=500.0, clusters_per_m2=3000.0)])
def test_rounding_sized_areas_are_no_seabed(monkeypatch, kernels, model):
    """A cell's seabed area is a difference of cumulative sums: a cell without seabed holds
    about +-1e-18 m^2 of rounding. Read as a real area, a positive one drew a count of 0 and
    zeroed the cell's whole echo. The image must be the same for areas 0, +1e-18 and -1e-18
    (same draws), and a seabed echo of real area must still be scaled by its counts."""
    monkeypatch.setenv("OAS_KERNELS", kernels)
    spec = SonarSpec(n_beams=64, n_bins=300, fov_azimuth=np.deg2rad(40), fov_elevation=np.deg2rad(14), range_min=1.0,
                     range_max=4.0, frequency=900e3, beamwidth_azimuth=np.deg2rad(0.6), range_resolution=0.02)
    noise = ScattererNoise(gain=DeviceGain(noise_db=-60.0, spreading_db=0.0, absorption_db_per_m=0.0), **model)
    I = np.random.default_rng(5).uniform(0.5, 2.0, (spec.n_bins, spec.n_beams)).astype(np.float32)
    area = np.full(I.shape, 1e-3)
    area[100:200, 20:40] = 0.0  # a target's cells: no seabed there

    def image(a):
        d = noise.draw(I.shape, (), np.random.default_rng(9))
        return noise.apply(I, spec=spec, seabed_share={}, options=SonarOptions(beam_model="aperture"), draws=d,
                           cell_area=a, threads=2)

    ref = image(area)
    for eps in (1e-18, -1e-18):
        a = area.copy()
        a[100:200, 20:40] = eps
        np.testing.assert_array_equal(image(a), ref)
    # a real area is not taken for rounding: a tiny but physical sliver of seabed (1e-6 m^2,
    # 5e-4 scatterers expected) changes the image there (its count is almost surely 0)
    a = area.copy()
    a[100:200, 20:40] = 1e-6
    assert not np.array_equal(image(a)[100:200, 20:40], ref[100:200, 20:40])
