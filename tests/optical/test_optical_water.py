"""Water types and the volume scattering function, against independent quadratures and sources."""

import numpy as np
import pytest
from scipy.integrate import quad

from optiacoustic.optical import JERLOV_KD, PhaseFunction, Water
from optiacoustic.optical.water import A_WATER_POPE_FRY, KOPELEVICH_B_LARGE, KOPELEVICH_B_SMALL, molecular_scattering

# break points for quadrature of peaked phase functions (rad)
_BRK = np.deg2rad([0, 0.001, 0.01, 0.1, 0.5, 1, 2, 4, 6, 10, 15, 30, 45, 60, 90, 120, 150, 180])


def sphere_integral(fn) -> float:
    """2 pi int_0^pi fn(psi) sin(psi) dpsi by adaptive quadrature between break points."""
    return sum(quad(lambda x: 2 * np.pi * fn(x) * np.sin(x), a, b, limit=200, epsrel=1e-10)[0]
               for a, b in zip(_BRK[:-1], _BRK[1:]))


@pytest.mark.parametrize("name", ["thesis", "pure-water", "jerlov-I", "jerlov-II", "jerlov-3C", "jerlov-9C"])
def test_vsf_integrates_to_b(name):
    """Eq. (3.2): 2 pi int beta(psi) sin(psi) dpsi = b in every channel."""
    w = Water.preset(name)
    for ch in range(3):
        got = sphere_integral(lambda x: float(w.vsf(np.cos(x))[ch]))
        assert got == pytest.approx(w.b[ch], rel=2e-3)


def test_henyey_greenstein_against_its_formula():
    g = 0.8
    p = PhaseFunction.henyey_greenstein(g)
    mu = np.linspace(-1, 1, 41)
    ref = (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * mu) ** 1.5)
    np.testing.assert_allclose(p(mu)[:, 1], ref, rtol=1e-12)
    assert sphere_integral(lambda x: float(p(np.cos(x))[0])) == pytest.approx(1.0, rel=1e-6)
    mean_cos = sphere_integral(lambda x: float(p(np.cos(x))[0]) * np.cos(x))
    assert mean_cos == pytest.approx(g, rel=1e-4)


def test_molecular_shape():
    """Einstein-Smoluchowski: beta(0) / beta(90) = 1.835 and b = 16.06 beta(90)."""
    w = Water((0, 0, 0), (0.01, 0.02, 0.03), PhaseFunction.molecular())
    b90 = w.vsf(0.0)
    np.testing.assert_allclose(w.vsf(1.0) / b90, 1.835, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(w.b) / b90, 16.0640, rtol=1e-4)
    # wavelength law of eq. (3.5): (lambda0 / lambda)^4.32
    assert molecular_scattering(450) / molecular_scattering(550) == pytest.approx((550 / 450) ** 4.32)


def test_kopelevich_tables_match_kopelevich_coefficients():
    """The tabulated shapes integrate to Kopelevich's b_s* = 1.34 and b_l* = 0.312 (to 1 % and 5 %)."""
    from optiacoustic.optical.water import _KOP_DEG, _KOP_LARGE, _KOP_SMALL

    nodes = np.deg2rad(_KOP_DEG)
    for tab, ref, tol in ((_KOP_SMALL, KOPELEVICH_B_SMALL, 0.015), (_KOP_LARGE, KOPELEVICH_B_LARGE, 0.05)):
        f = lambda x, t=tab: float(np.exp(np.interp(x, nodes, np.log(t))))  # noqa: E731
        assert sphere_integral(f) == pytest.approx(ref, rel=tol)


def test_kopelevich_constructor_eq_3_6():
    w = Water.kopelevich(0.01, 0.02, (0.1, 0.05, 0.02), wavelengths_nm=(650, 550, 450))
    lam = np.array([650.0, 550.0, 450.0])
    ref = 0.0017 * (550 / lam) ** 4.32 + 1.34 * 0.01 * (550 / lam) ** 1.7 + 0.312 * 0.02 * (550 / lam) ** 0.3
    np.testing.assert_allclose(w.b, ref, rtol=1e-12)
    np.testing.assert_allclose(w.c, np.asarray(w.a) + ref)


def test_thesis_and_pure_water_presets():
    t = Water.preset("thesis")
    np.testing.assert_allclose(t.c, (0.41, 0.066, 0.018), rtol=1e-12)
    assert np.all(np.asarray(t.a) > 0) and np.all(np.asarray(t.b) > 0)
    # the split never asks for less absorption than pure water at 450 nm (Pope & Fry)
    assert t.a[2] >= A_WATER_POPE_FRY[2]
    p = Water.preset("pure-water")  # thesis Table 3.2 at 670, 530, 470 nm
    np.testing.assert_allclose(p.a, (0.4346, 0.0505, 0.0130))
    np.testing.assert_allclose(p.b, (0.0006, 0.0017, 0.0027))
    assert p.wavelengths_nm == (670.0, 530.0, 470.0)
    assert Water.preset("clear").c.tolist() == [0.0, 0.0, 0.0]


def test_jerlov_presets_reproduce_jerlov_kd():
    """K_d = 1.0395 (a + b_b) with b_b integrated from each preset's own VSF equals Jerlov's K_d."""
    for jt, kd in JERLOV_KD.items():
        w = Water.preset(f"jerlov-{jt}")
        bb = np.array([2 * np.pi * quad(lambda x: float(w.vsf(np.cos(x))[ch]) * np.sin(x), np.pi / 2, np.pi,
                                        epsrel=1e-10)[0] for ch in range(3)])
        np.testing.assert_allclose(1.0395 * (np.asarray(w.a) + bb), kd, rtol=0.01, err_msg=jt)
        # physical: never less absorbing than pure water (not imposed by the derivation)
        assert np.all(np.asarray(w.a) >= np.asarray(A_WATER_POPE_FRY) * 0.999), jt
        assert w.doubtful


def test_jerlov_series_get_more_turbid():
    for series in (["I", "IA", "IB", "II", "III"], ["1C", "3C", "5C", "7C", "9C"]):
        c = np.array([Water.preset(f"jerlov-{s}").c for s in series])
        assert np.all(np.diff(c, axis=0) > 0), series


def test_preset_names_all_build_and_case_insensitive():
    for n in Water.preset_names():
        w = Water.preset(n)
        assert w.name and w.source
    assert Water.preset("JERLOV-ii").name == "jerlov-II"
    assert Water.preset("Jerlov_3c").name == "jerlov-3C"


@pytest.mark.parametrize("bad, field", [
    (dict(a=(-0.1, 0.1, 0.1)), "Water.a"),
    (dict(b=(0.1, float("nan"), 0.1)), "Water.b"),
    (dict(a=(0.1, 0.1)), "Water.a"),
    (dict(b=(0.1, 0.1, float("inf"))), "Water.b"),
    (dict(phase="hg"), "Water.phase"),
])
def test_bad_water_raises_naming_the_field(bad, field):
    with pytest.raises(ValueError, match=field):
        Water(**{"a": (0.1, 0.1, 0.1), "b": (0.1, 0.1, 0.1), **bad})


def test_unknown_water_type():
    with pytest.raises(ValueError, match="unknown water type 'jerlov-XI'"):
        Water.preset("jerlov-XI")
    with pytest.raises(ValueError, match="unknown water type"):
        Water.preset("muddy")


def test_bad_phase_weights():
    with pytest.raises(ValueError, match="PhaseFunction.weights"):
        PhaseFunction(((0.5, 1, 1), (0, 0, 0), (0, 0, 0), (0, 0, 0)))
    with pytest.raises(ValueError, match="PhaseFunction.g"):
        PhaseFunction.henyey_greenstein(1.0)


def test_with_henyey_greenstein_keeps_b():
    w = Water.preset("jerlov-II").with_henyey_greenstein(0.9)
    np.testing.assert_allclose(w.b, Water.preset("jerlov-II").b)
    for ch in range(3):
        assert sphere_integral(lambda x: float(w.vsf(np.cos(x))[ch])) == pytest.approx(w.b[ch], rel=1e-4)
