"""Beam patterns of a line aperture against their closed forms (docs/physics.md, "Beam patterns from the aperture")."""

import numpy as np
import pytest

from optiacoustic.scene import Body, Material, Plane, Scene
from optiacoustic.sonar import SonarOptions, SonarSpec, simulate_sonar
from optiacoustic.sonar.beampattern import BeamPattern
from optiacoustic.sonar.formation import azimuth_kernel
from optiacoustic.sonar.seabed_echo import flat_seabed_echo, seabed_pose

V = np.linspace(-3000, 3000, 3_000_001)  # v = L sin(theta) / lambda; dv = 2e-3


def _pattern(p):
    return BeamPattern(length=1.0, wavelength=1.0, pedestal=p)  # v == u here


@pytest.mark.parametrize("p", [1.0, 0.6, 0.0])
def test_one_way_power_integrates_to_the_parseval_value(p):
    bp = _pattern(p)
    from optiacoustic.sonar.beampattern import _pedestal_f

    num = np.trapezoid(_pedestal_f(V, p) ** 2, V)
    # the tail beyond |v| = 3000 holds about 2 / (pi^2 3000) of a uniform aperture's power
    assert num == pytest.approx(bp.integral_one_way_u(), rel=2e-4)


@pytest.mark.parametrize("p", [1.0, 0.6, 0.0])
def test_two_way_power_integrates_to_the_weighting_autocorrelation(p):
    """integral F^4 dv = integral (a * a)^2 dx / mean(a)^4 (L = lambda = 1), with a * a from np.convolve."""
    from optiacoustic.sonar.beampattern import _pedestal_f

    n = 4001
    x = np.linspace(-0.5, 0.5, n)
    dx = x[1] - x[0]
    a = p + (1 - p) * np.cos(np.pi * x)
    auto = np.convolve(a, a) * dx
    expected = np.trapezoid(auto**2, dx=dx) / np.mean(a) ** 4
    vv = V[np.abs(V) < 200]
    num = np.trapezoid(_pedestal_f(vv, p) ** 4, vv)
    assert num == pytest.approx(expected, rel=2e-3)
    if p == 1.0:
        assert expected == pytest.approx(2 / 3, rel=1e-3)


@pytest.mark.parametrize("p, sidelobe_db", [(1.0, -13.26), (0.0, -23.0)])
def test_sidelobe_levels(p, sidelobe_db):
    assert _pattern(p).sidelobe_db() == pytest.approx(sidelobe_db, abs=0.05)


@pytest.mark.parametrize("width_deg, freq, p", [(1.0, 900e3, 1.0), (20.0, 900e3, 1.0), (12.0, 2.1e6, 0.3)])
def test_from_beamwidth_is_minus_3_db_at_the_edges(width_deg, freq, p):
    w = np.deg2rad(width_deg)
    bp = BeamPattern.from_beamwidth(w, freq, 1500.0, pedestal=p)
    assert bp.one_way(w / 2) == pytest.approx(0.5, rel=1e-6)
    assert bp.one_way(-w / 2) == pytest.approx(0.5, rel=1e-6)
    assert bp.two_way(w / 3) == pytest.approx(bp.one_way(w / 3) ** 2)
    assert bp.beamwidth() == pytest.approx(w, rel=1e-9)
    assert bp.amplitude(bp.null_angle(1)) == pytest.approx(0.0, abs=1e-9)
    if p == 1.0:  # uniform aperture: L = 0.4429 lambda / sin(w / 2)
        assert bp.length == pytest.approx(0.442946 * 1500 / freq / np.sin(w / 2), rel=1e-5)


def test_tabulated_pattern_matches_the_aperture_it_samples():
    ap = BeamPattern.from_beamwidth(np.deg2rad(10), 1e6)
    ang = np.linspace(-0.5, 0.5, 2001)
    tab = BeamPattern.table(ang, 10 * np.log10(np.maximum(ap.one_way(ang), 1e-12)))
    assert tab.beamwidth() == pytest.approx(ap.beamwidth(), rel=3e-3)  # dB interpolated between samples
    assert tab.sidelobe_db() == pytest.approx(ap.sidelobe_db(), abs=0.05)
    th = np.deg2rad([0.0, 2.0, 4.9, 7.0])
    np.testing.assert_allclose(tab.one_way(th), ap.one_way(th), rtol=2e-3, atol=1e-6)
    with pytest.raises(ValueError, match="increasing"):
        BeamPattern.table([0.0, -1.0, 1.0], [0.0, -3.0, -3.0])


def test_bad_patterns_are_refused():
    with pytest.raises(ValueError, match="length"):
        BeamPattern(length=0.0, wavelength=1e-3)
    with pytest.raises(ValueError, match="pedestal"):
        BeamPattern(length=0.1, wavelength=1e-3, pedestal=1.5)
    with pytest.raises(ValueError, match="beam_model"):
        SonarOptions(beam_model="fancy")


def test_azimuth_kernel_sums_to_the_equivalent_beam_width():
    """sum of the cell-averaged F^4 = integral F^4 dtheta / dtheta = (2/3) lambda / (L dtheta) (small angles)."""
    spec = SonarSpec(n_beams=256, fov_azimuth=np.deg2rad(45), beamwidth_azimuth=np.deg2rad(1.0), frequency=900e3)
    k = azimuth_kernel(spec)
    pat = spec.azimuth_pattern()
    # the kernel reaches the second null only: the tail beyond holds ~0.1 % of the two-way power
    assert k.sum() == pytest.approx((2 / 3) * pat.wavelength / pat.length / spec.beam_spacing, rel=3e-3)
    assert 0.97 < k[len(k) // 2] < 1.0  # the peak, averaged over one beam cell


def test_flat_seabed_echo_matches_the_analytic_integral():
    """The aperture model's image of a flat seabed equals the analytic elevation integral, times the azimuth kernel."""
    scene = Scene([Body("seabed", Plane(size=(200, 200)), material=Material(reflectivity=1.0))])
    spec = SonarSpec(n_beams=64, n_bins=400, fov_azimuth=np.deg2rad(60), fov_elevation=np.deg2rad(12), range_min=0.3,
                     range_max=3.0, frequency=2.1e6, beamwidth_azimuth=np.deg2rad(0.4), range_resolution=0.0025,
                     elevation_samples=256)
    h, pitch, roll = 0.4, np.deg2rad(20), np.deg2rad(5)
    f = simulate_sonar(scene, spec, seabed_pose(h, pitch, roll), noise=False, options=SonarOptions(beam_model="aperture"))
    E = flat_seabed_echo(spec.ranges, spec.azimuths, h, pitch, roll, spec.elevation_pattern()) * azimuth_kernel(spec).sum()
    inner = slice(10, 54)  # away from the fan's edges, where the azimuth kernel runs out of beams
    a, b = f.intensity[:, inner], E[:, inner]
    assert np.abs(a - b).sum() / b.sum() < 0.01
    assert a.sum() / b.sum() == pytest.approx(1.0, abs=0.005)
