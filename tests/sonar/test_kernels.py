"""The numba kernels of sonar formation against the numpy reference path, on seeded inputs.

``OAS_KERNELS=numpy`` selects the reference; both must give the same numbers (within
float rounding: the kernels sum in another order) and the same draws. Independent truths
too: energy conservation of the echo, scipy's Poisson quantiles, normal statistics.
"""

import dataclasses
import subprocess
import sys

import numba
import numpy as np
import pytest
from scipy import stats

from optiacoustic import Pose, scenes
from optiacoustic.sonar import SonarOptions, SonarSpec, simulate_sonar
from optiacoustic.sonar import formation as F
from optiacoustic.sonar import noise as N
from optiacoustic.sonar._numba_kernels import _invert_poisson
from optiacoustic.sonar.gain import DeviceGain
from optiacoustic.sonar.noise import NoiseModel, ScattererNoise

from .conftest import both_kernel_paths

SPEC = dataclasses.replace(SonarSpec.preset("blueview-p900-90"), n_beams=96, n_bins=240, elevation_samples=48)


def _close(a, b, rtol=1e-5):
    scale = float(np.max(np.abs(b))) if np.size(b) else 1.0
    np.testing.assert_allclose(a, b, rtol=rtol, atol=1e-6 * scale)


@pytest.fixture(scope="module")
def thesis():
    sc = scenes.get("thesis_scene1")
    return sc, Pose.look_at(sc.view.eye, sc.view.target)


def test_switch_is_validated(monkeypatch):
    from optiacoustic.sonar._kernels import use_numba

    monkeypatch.setenv("OAS_KERNELS", "fortran")
    with pytest.raises(ValueError, match="OAS_KERNELS"):
        use_numba()


@pytest.mark.parametrize("options", [SonarOptions(), SonarOptions(elevation_pattern="gaussian", propagation="spreading")])
def test_thesis_frame_rays_echo_shares_and_truth_agree(thesis, options, monkeypatch):
    sc, pose = thesis
    a, b = both_kernel_paths(monkeypatch, lambda: simulate_sonar(sc, SPEC, pose, seed=4, options=options))
    for name in ("range", "energy", "footprint_lo", "footprint_hi", "cos_incidence", "elevation_lo", "elevation_hi"):
        x, y = getattr(a.rays, name), getattr(b.rays, name)
        assert np.array_equal(np.isfinite(x), np.isfinite(y)), name
        _close(np.nan_to_num(x), np.nan_to_num(y), rtol=1e-9)
    assert np.array_equal(a.rays.body, b.rays.body)
    _close(a.intensity, b.intensity)
    lit = b.intensity > 1e-6 * b.intensity.max()  # the numpy path zeroes its class images' residue
    for k in b.seabed_share:
        np.testing.assert_allclose(a.seabed_share[k][lit], b.seabed_share[k][lit], atol=1e-3)
    _close(a.image, b.image, rtol=1e-4)  # the same draws
    ga, gb = a.ground_truth, b.ground_truth
    assert np.array_equal(ga.body, gb.body)
    np.testing.assert_array_equal(ga.elevation_min, gb.elevation_min)
    np.testing.assert_array_equal(ga.elevation_max, gb.elevation_max)
    assert np.array_equal(ga.shadow, gb.shadow) and ga.shadow.any()


def test_aperture_model_subcells_area_and_image_agree(thesis, monkeypatch):
    sc, pose = thesis
    opts = SonarOptions(beam_model="aperture", propagation="spreading")
    a, b = both_kernel_paths(monkeypatch, lambda: simulate_sonar(sc, SPEC, pose, noise=False, options=opts))
    _close(a.intensity, b.intensity)
    sspec = F.scan_spec(SPEC, "aperture")
    caster = F.caster_for(sc)

    def area():
        _, img = F._scan(sc, caster, sspec, pose, opts, F._aperture_elevation_weights(SPEC), SPEC.elevation_pattern())
        return img, F.cell_area(SPEC, img, F._bottom_types(sc))

    (ia, aa), (ib, ab) = both_kernel_paths(monkeypatch, area)
    assert ia.energy.size == ib.energy.size
    _close(ia.energy, ib.energy, rtol=1e-7)
    _close(aa, ab)
    noise = ScattererNoise(density=300.0, gain=DeviceGain(noise_db=-60.0, volume_db=-50.0, spreading_db=30.0))
    area_big = ab.copy()
    area_big[::17, ::13] = 0.2  # some cells of mean count >= 30: drawn by the generator in both paths

    def image():
        d = noise.draw(b.intensity.shape, (), np.random.default_rng(9))
        return noise.apply(b.intensity, spec=SPEC, seabed_share=b.seabed_share, options=opts, draws=d,
                           cell_area=area_big, threads=2)

    x, y = both_kernel_paths(monkeypatch, image)
    _close(x, y, rtol=1e-4)


def _boxes(spec, lo, hi, e, rng):
    n = lo.size
    return F.SonarRays(range=lo, energy=e, body=np.zeros(n, np.int32), cos_incidence=np.ones(n), footprint_lo=lo,
                       footprint_hi=hi, beam_index=rng.integers(0, spec.n_beams, n), elevation=np.zeros(n),
                       elevation_lo=np.zeros(n), elevation_hi=np.zeros(n), elevation_step=0.01)


def _echo(spec, rays):
    opts = SonarOptions()
    if F.use_numba():
        return F._form_with_shares_numba(spec, rays, opts, {}, 2)[0]
    return F._form_image(spec, rays, opts)


def test_echo_kernel_matches_box_integration_and_conserves_energy(monkeypatch):
    """Random boxes, some past either end of the range window, some of zero energy: both paths
    agree. Boxes well inside the window: the image holds their energy (the box integral and
    the normalised anti-aliasing weights conserve it)."""
    spec = dataclasses.replace(SPEC, n_bins=120, n_beams=16)
    rng = np.random.default_rng(2)
    n = 3000
    lo = rng.uniform(spec.range_min - 0.3, spec.range_max, n)
    hi = lo + rng.exponential(0.05, n) + 1e-6
    e = rng.uniform(0.0, 1.0, n)
    e[::7] = 0.0
    rays = _boxes(spec, lo, hi, e, rng)
    a, b = both_kernel_paths(monkeypatch, lambda: _echo(spec, rays))
    _close(a, b)
    lo = rng.uniform(spec.range_min + 0.3, spec.range_max - 0.6, n)
    hi = lo + np.minimum(rng.exponential(0.05, n), 0.3) + 1e-6
    inner = _boxes(spec, lo, hi, e, rng)
    a, b = both_kernel_paths(monkeypatch, lambda: _echo(spec, inner))
    _close(a, b)
    assert float(a.astype(float).sum()) * spec.bin_width == pytest.approx(float(e.sum()), rel=1e-5)


@pytest.mark.parametrize("model", [
    NoiseModel(),
    NoiseModel(reverberation="rayleigh", noise_floor_db=None),
    NoiseModel(target_speckle=False),
    NoiseModel(reverberation="k", target_speckle=False),
    NoiseModel(reverberation=None),
])
def test_noise_model_paths_agree(model, monkeypatch):
    rng = np.random.default_rng(5)
    shape = (SPEC.n_bins, SPEC.n_beams)
    I = (rng.exponential(1.0, shape) * (rng.random(shape) < 0.7)).astype(np.float32)
    s1 = rng.random(shape).astype(np.float32) * 0.6
    shares = {"sand/shell": s1, "mud": (1 - s1) * rng.random(shape).astype(np.float32)}

    def image():
        d = model.draw(shape, list(shares), np.random.default_rng(11))
        return model.apply(I, spec=SPEC, seabed_share=shares, options=SonarOptions(), draws=d, threads=2)

    a, b = both_kernel_paths(monkeypatch, image)
    _close(a, b, rtol=1e-5)
    assert a.dtype == np.float32 and np.all(a >= 0)


def test_poisson_inversion_is_scipys_quantile_and_poisson(monkeypatch):
    rng = np.random.default_rng(3)
    mu = np.concatenate([rng.uniform(0, 29.9, 4000), [0.0, 31.0, 80.0]])
    u = rng.random(mu.size)
    a, b = both_kernel_paths(monkeypatch, lambda: N._poisson_counts(mu, u, np.random.default_rng(1)))
    assert np.array_equal(a, b)
    assert np.array_equal(a[:4000], stats.poisson.ppf(u[:4000], mu[:4000]).astype(np.int64))
    # and it is Poisson: mean and variance of many counts of one mean
    m = np.full(200_000, 0.7)
    n = N._poisson_counts(m, np.random.default_rng(4).random(m.size), np.random.default_rng(1))
    assert abs(n.mean() - 0.7) < 5 * np.sqrt(0.7 / m.size)
    assert abs(n.var() - 0.7) < 0.02


# Random123's published known-answer vectors of Philox4x32-10 (counter, key, output)
PHILOX_KAT = [
    ((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
     (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1)),
]


@pytest.mark.parametrize("ctr,key,want", PHILOX_KAT)
def test_philox_known_answers(ctr, key, want):
    from optiacoustic.sonar._numba_kernels import philox_block

    out = np.zeros(4, np.uint32)
    philox_block(*ctr, *key, out)
    assert out.tolist() == list(want)


def test_noise_words_agree_and_are_uniform(monkeypatch):
    """The words of the scatterer noise (Philox of the cell index): numba and numpy give the same
    words; each word's uniform passes KS, and the three words of a cell are uncorrelated."""
    key = np.array([12345, 678910], np.uint32)
    cells = np.arange(200_000)
    a, b = both_kernel_paths(monkeypatch, lambda: N.cell_words(key, cells))
    assert a.dtype == np.uint32 and a.shape == (3, cells.size)
    assert np.array_equal(a, b)
    assert np.array_equal(N.cell_words(key, cells[::7]), a[:, ::7])  # a cell's words depend on it alone
    u = N._uniforms(a)
    for k in range(3):
        assert stats.kstest(u[k], "uniform").pvalue > 1e-3
    c = np.corrcoef(u)
    assert np.all(np.abs(c[np.triu_indices(3, 1)]) < 5 / np.sqrt(cells.size))
    assert not np.array_equal(N.cell_words(key + 1, cells[:100]), a[:, :100])


@pytest.mark.parametrize("n_r,n_b,symmetric", [(1, 1, False), (3, 27, False), (7, 5, False), (9, 1, False),
                                                (7, 27, True), (3, 9, True), (5, 3, True), (11, 19, True),
                                                (1, 1, True), (7, 27, "r"), (7, 27, "b")])
def test_speckle_image_kernel_matches_cv2_filters(n_r, n_b, symmetric):
    """The fused one-look image pass against its reference: the field filtered by cv2.sepFilter2D
    (zero borders), the mean by the squared kernels, |f|^2 x mean / expected x TVG (0 where the
    filtered mean is not positive). Asymmetric kernels (cv2 correlates), symmetric ones (their taps
    folded: 1 to 6 pairs, so every remainder of the sweeps of four; "r" / "b": only that one
    symmetric), images smaller than a kernel's reach on one side, rows of no mean. Tolerance: both
    sum in float32 in different orders, so ``rtol = 2e-5`` with ``atol = 1e-6`` of the peak (where
    ``|f|^2`` nearly cancels the relative difference can be larger, measured up to 2e-4 of a cell
    of 2e-7 of the peak on a realistic frame)."""
    from optiacoustic.sonar._numba_kernels import speckle_image
    from optiacoustic.sonar.speckle import filter_complex, filter_real

    rng = np.random.default_rng(n_r * 100 + n_b + (7 if symmetric else 0))
    B, J = 40, 23
    z = rng.standard_normal((B, J, 2)).astype(np.float32)
    mean = rng.uniform(0.5, 2.0, (B, J)).astype(np.float32)
    mean[10:14] = 0.0  # no echo and no background: expected 0 there when the kernel is short
    h_r = rng.uniform(0.1, 1.0, n_r).astype(np.float32)
    h_b = rng.uniform(0.1, 1.0, n_b).astype(np.float32)
    if symmetric in (True, "r"):
        h_r = (h_r + h_r[::-1]) * np.float32(0.5)
        assert np.array_equal(h_r, h_r[::-1])
    if symmetric in (True, "b"):
        h_b = (h_b + h_b[::-1]) * np.float32(0.5)
        assert np.array_equal(h_b, h_b[::-1])
    tvg = rng.uniform(1.0, 3.0, B).astype(np.float32)
    f = filter_complex(z, h_r, h_b)
    expected = filter_real(mean, h_r**2, h_b**2)
    ref = np.where(expected > 0, (f[..., 0] ** 2 + f[..., 1] ** 2) * mean / np.where(expected > 0, expected, 1)
                   * tvg[:, None], 0.0)
    out = np.full((B, J), np.nan, np.float32)
    speckle_image(z, mean, h_r, h_b, tvg, 0, 17, out)  # two row ranges, as two threads take them
    speckle_image(z, mean, h_r, h_b, tvg, 17, B, out)
    np.testing.assert_allclose(out, ref, rtol=2e-5, atol=1e-6 * float(ref.max()))
    assert np.array_equal(out == 0, ref == 0)


@pytest.mark.parametrize("have_words,n_r", [(False, 7), (True, 7), (True, 81)])
def test_scatterer_speckle_is_the_two_passes_bit_for_bit(have_words, n_r):
    """``scatterer_speckle`` (the field and the speckle image in one pass over row blocks, i14q) against
    the two kernels it fuses, ``scatterer_field`` (or ``field_words`` + ``scatterer_field_words``) and then
    ``speckle_image``, on seeded echo and areas: the same image to the bit for row ranges that split the
    image anywhere (one range, 8 as two threads take them, ranges shorter than the range kernel's reach,
    ranges across the block size; the device's 7-tap range kernel and an asymmetric one of 81 taps, longer
    than a block) and the same count of cells of large mean (0 here; with a few large areas it counts them,
    and ``ScattererNoise.apply`` then takes the two passes)."""
    from optiacoustic.sonar import _numba_kernels as K

    rng = np.random.default_rng(41)
    B, J = 150, 37
    I = rng.exponential(1.0, (B, J)).astype(np.float32)
    I[:, :5] = 0.0  # beams of no echo
    area = rng.uniform(0.0, 4e-3, (B, J)).astype(np.float32)
    area[20:30] = 0.0  # off the seabed
    back = rng.uniform(1e-3, 2e-3, B).astype(np.float32)
    tvg = rng.uniform(1.0, 3.0, B).astype(np.float32)
    h_r = (np.array([0.2, 0.5, 0.8, 1.0, 0.8, 0.5, 0.2], np.float32) if n_r == 7
           else rng.uniform(0.1, 1.0, n_r).astype(np.float32))
    h_b = rng.uniform(0.1, 1.0, 27).astype(np.float32)
    h_b = (h_b + h_b[::-1]) * np.float32(0.5)
    gain, density, mu_max = np.float32(3.0), 500.0, 30.0
    k0, k1 = np.uint32(1234), np.uint32(98765)
    words = (np.empty((B, J), np.uint32), np.empty((B, J), np.float32), np.empty((B, J, 2), np.float32))
    K.field_words(k0, k1, 0, B, *words)
    z = np.empty((B, J, 2), np.float32)
    big = np.empty((B, J), np.bool_)
    mean = np.empty((B, J), np.float32)
    if have_words:
        K.scatterer_field_words(I, gain, back, area, density, mu_max, 0, B, *words, z, big, mean)
    else:
        K.scatterer_field(I, gain, back, area, density, k0, k1, mu_max, 0, B, z, big, mean)
    assert not big.any()
    ref = np.empty((B, J), np.float32)
    K.speckle_image(z, mean, h_r, h_b, tvg, 0, B, ref)
    for cuts in ([0, B], [0, 19, 38, 57, 76, 95, 114, 133, B], [0, 1, 3, 4, 70, 71, 72, B], [0, 32, 33, 65, 97, B]):
        out = np.full((B, J), np.nan, np.float32)
        n_big = sum(K.scatterer_speckle(I, gain, back, area, density, mu_max, k0, k1, have_words, *words,
                                        h_r, h_b, tvg, r0, r1, out) for r0, r1 in zip(cuts[:-1], cuts[1:]))
        assert n_big == 0
        assert np.array_equal(out, ref), cuts
    area[70, 3:6] = 0.1  # mean 50 > mu_max: three cells whose counts the caller must draw
    out = np.empty((B, J), np.float32)
    assert K.scatterer_speckle(I, gain, back, area, density, mu_max, k0, k1, have_words, *words,
                               h_r, h_b, tvg, 0, B, out) == 3


_MU_NO_SEABED = N.MU_NO_SEABED


@numba.njit(cache=False, error_model="numpy")
def _poisson_small_row(m_row, p0, scale, u_row, mu_max, n_row, fix):
    """The float64 inversion of a row's counts (``p0`` ``exp(-mu)`` as ``_exp_neg_row`` left it, times
    ``scale``, on return): the kernels' operations before i14s, kept here as the reference that
    ``_poisson_small_row32`` (the kernels' screened float32 counts) must equal."""
    J = m_row.size
    fours = np.int32(0)
    for j in range(J):  # counts 0..3 by comparisons with the first four cumulative probabilities
        m = min(max(m_row[j], 0.0), 40.0)
        p = p0[j] * scale[j]
        p0[j] = p
        uu = u_row[j]
        t1 = p * m
        c1 = p + t1
        t2 = t1 * (m / 2.0)
        c2 = c1 + t2
        c3 = c2 + t2 * (m / 3.0)
        n = np.int32(uu > p) + np.int32(uu > c1) + np.int32(uu > c2) + np.int32(uu > c3)
        n_row[j] = n
        fours += np.int32(n == 4)
    n_fix = 0
    for j in range(J if fours > 0 else 0):
        m = m_row[j]
        fix[n_fix] = j
        n_fix += (n_row[j] == 4) & (m > _MU_NO_SEABED) & (m < mu_max)
    for t in range(n_fix):  # counts above 3: the inversion from the start
        j = fix[t]
        n_row[j] = _invert_poisson(u_row[j], p0[j], m_row[j])


def _counts_float64(K, m, words, mu_max):
    """``_poisson_small_row``'s counts (the float64 inversion) of one row."""
    J = m.size
    p0, scale, u = np.empty(J), np.empty(J), np.empty(J)
    K._exp_neg_row(m, 40.0, p0, scale)
    K._uniform_bits_row(words, u)
    n = np.empty(J, np.int32)
    _poisson_small_row(m, p0, scale, u, mu_max, n, np.empty(J, np.int64))
    return n


def test_screened_float32_counts_are_the_float64_inversions():
    """``_poisson_small_row32`` (the scatterer field's counts in float32, cells too close to call
    counted again in float64, i14s) gives ``_poisson_small_row``'s counts: on random means over the
    whole range (off the seabed, below and above ``mu_max``, non-float32 densities) with random
    words, and on words placed within a few units of the last place of every float64 boundary
    ``P(N <= n)``, n = 0..4, where a float32 comparison alone would often decide the other way. The
    seabed cells' counts are also scipy's Poisson quantiles. The screen catches few cells (so the
    float32 comparisons decide the rest)."""
    from optiacoustic.sonar import _numba_kernels as K

    rng = np.random.default_rng(77)
    mu_max = 30.0
    J = 4096
    area = np.concatenate([np.zeros(8), np.full(8, 1e-13), rng.uniform(0.0, 2e-3, J - 96),
                           rng.uniform(0.0, 0.09, 80)]).astype(np.float32)
    scr = [np.empty(J, t) for t in (np.int32, np.int64, np.float32, np.float32, np.float64, np.float64, np.float64)]
    screened = 0
    for density in (500.0, 333.3, 1.0e4):
        m = density * area.astype(np.float64)
        # boundaries of the float64 inversion: P(N <= n) for n = 0..4 (the kernel's operations)
        p0, scale = np.empty(J), np.empty(J)
        K._exp_neg_row(m, 40.0, p0, scale)
        c = np.empty((5, J))
        p = p0 * scale
        c[0] = p
        term = p
        for n in range(1, 5):
            term = term * (np.minimum(np.maximum(m, 0.0), 40.0) / n)
            c[n] = c[n - 1] + term
        word_sets = [rng.integers(0, 2**32, J, dtype=np.uint64).astype(np.uint32)]
        for n in range(5):  # (b + 1/2) 2^-32 within a few 2^-32 of c[n]
            for off in (-2, -1, 0, 1, 2):
                b = np.clip(np.floor(c[n] * 2.0**32 - 0.5) + off, 0, 2**32 - 1)
                word_sets.append(b.astype(np.uint64).astype(np.uint32))
        for words in word_sets:
            want = _counts_float64(K, m, words, mu_max)
            n32, fix, p32, s32, pp, sc, fm = scr
            K._poisson_small_row32(area, density, m, words, mu_max, n32, fix, p32, s32, pp, sc, fm)
            sea = (m > N.MU_NO_SEABED) & (m < mu_max)
            assert np.array_equal(n32[sea], want[sea]), density
        u = (words.astype(np.float64) + 0.5) * 2.0**-32
        assert np.array_equal(want[sea], stats.poisson.ppf(u[sea], m[sea]).astype(np.int32))
        # how often the float32 decision is not trusted, on random words
        words = word_sets[0]
        K._poisson_small_row32(area, density, m, words, mu_max, *scr)
        want = _counts_float64(K, m, words, mu_max)
        screened += int(np.sum((scr[0] == 4) & (want < 4) & sea))
    assert screened <= 3 * J * 1e-3


def test_scatterer_noise_with_large_means_takes_the_two_passes(monkeypatch):
    """A frame with cells of large mean (their counts drawn by the generator): ``ScattererNoise.apply``
    gives the image of the two-pass path (``_FUSED`` off), not the fused pass's."""
    from optiacoustic import SonarSpec
    from optiacoustic.sonar import SonarOptions
    from optiacoustic.sonar.gain import DeviceGain
    from optiacoustic.sonar.noise import ScattererNoise

    spec = SonarSpec.preset("blueview-p900-90")
    rng = np.random.default_rng(5)
    I = rng.exponential(1e-3, (spec.n_bins, spec.n_beams)).astype(np.float32)
    area = rng.uniform(0.0, 2e-3, I.shape).astype(np.float32)
    area[300:303, 100:110] = 0.2  # density x area = 100 > 30
    nz = ScattererNoise(density=500.0, gain=DeviceGain(noise_db=-60.0, volume_db=-50.0, spreading_db=30.0))
    opts = SonarOptions(beam_model="aperture", propagation="spreading")

    def image():
        return nz.apply(I, spec=spec, seabed_share={}, options=opts, rng=3, cell_area=area, threads=2)

    fused = image()
    monkeypatch.setattr(N, "_FUSED", False)
    assert np.array_equal(fused, image())
    area[300:303, 100:110] = 0.01
    two = image()
    monkeypatch.setattr(N, "_FUSED", True)
    assert np.array_equal(two, image())


def test_device_kernels_are_symmetric_in_float32():
    """The pulse's and the beam pattern's amplitude kernels of every preset are symmetric to the bit
    in float32 (``speckle_image`` folds their taps only then: otherwise it takes the general path)."""
    from optiacoustic import SonarSpec
    from optiacoustic.sonar.noise import _kernels

    for name in SonarSpec.preset_names():
        for h in _kernels(SonarSpec.preset(name)):
            h32 = np.asarray(h, np.float32)
            assert h32.size % 2 == 1 and np.array_equal(h32, h32[::-1]), name


def test_box_muller_normals(monkeypatch):
    """Normals from random words: both paths agree, each part is N(0, 1) (KS), the parts are
    uncorrelated, and the extreme words give the documented tail (radius sqrt(2 ln 2^33))."""
    rng = np.random.default_rng(8)
    bits = rng.integers(0, 2**32, (3, 300, 200), dtype=np.uint32)
    bits[1, 0, :4] = [0, 1, 2**32 - 1, 2**31]
    bits[2, 0, :4] = [0, 2**30, 2**31, 3 * 2**30]  # phases 0, 1/4, 1/2, 3/4 of a turn
    scale = np.full((300, 200), 2.0, np.float32)
    a, b = both_kernel_paths(monkeypatch, lambda: N._complex_normals(bits, scale))
    _close(a, b, rtol=1e-5)
    for c in (0, 1):
        assert stats.kstest(a[..., c].ravel() / 2.0, "norm").pvalue > 1e-3
    assert abs(np.corrcoef(a[..., 0].ravel(), a[..., 1].ravel())[0, 1]) < 0.02
    r = np.hypot(a[0, :4, 0], a[0, :4, 1]) / 2.0
    np.testing.assert_allclose(r[0], np.sqrt(2 * 33 * np.log(2)), rtol=1e-6)  # the largest radius
    np.testing.assert_allclose(r[2], np.sqrt(-2 * np.log1p(-0.5 * 2.0**-32)), rtol=1e-3)  # the smallest
    np.testing.assert_allclose(r[3], np.sqrt(-2 * np.log((2**31 + 0.5) / 2**32)), rtol=1e-6)
    ang = np.arctan2(a[0, :4, 1], a[0, :4, 0])
    np.testing.assert_allclose(np.cos(ang), [1, 0, -1, 0], atol=1e-6)
    np.testing.assert_allclose(np.sin(ang), [0, 1, 0, -1], atol=1e-6)


def test_import_does_not_load_numba():
    code = "import sys, optiacoustic, optiacoustic.sonar; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


@pytest.mark.parametrize("name", ["thesis_scene1", "cuboids"])
def test_shadow_floor_shortcut_is_exact(name, monkeypatch):
    """Rays going down through a floor plane (nothing below it) cast no continuation ray: same mask."""
    sc = scenes.get(name)
    assert F._floor_planes(sc) == (0,)  # the seabed
    pose = Pose.look_at(sc.view.eye, sc.view.target)
    f = simulate_sonar(sc, SPEC, pose, noise=False)
    fast = f.ground_truth.shadow
    monkeypatch.setattr(F, "_floor_planes", lambda scene: ())
    slow = F._shadow_mask(sc, F.caster_for(sc), SPEC, pose, f.rays, f.ground_truth.elevation_min)
    assert fast.any() and np.array_equal(fast, slow)


def test_kernels_make_no_python_callbacks(thesis, monkeypatch):
    """A kernel that returned an array would call back into Python to box it; a Ctrl-C landing
    there surfaces as SystemError, not KeyboardInterrupt (oas's one-line exit 130). None do."""
    import numba.core.serialize as serialize

    calls = []
    orig = serialize._numba_unpickle
    monkeypatch.setattr(serialize, "_numba_unpickle", lambda *a: calls.append(1) or orig(*a))
    sc, pose = thesis
    f = simulate_sonar(sc, SPEC, pose, seed=1)
    f.ground_truth.body, f.ground_truth.shadow
    simulate_sonar(sc, SPEC, pose, seed=1, options=SonarOptions(beam_model="aperture", propagation="spreading"),
                   noise=ScattererNoise(density=300.0))
    assert calls == []


@pytest.mark.parametrize("table", [False, True])
def test_fan_kernel_matches_cv2_remap(table, monkeypatch):
    """The fan through the cached bilinear taps equals cv2.remap's (float maps, border replicated)."""
    from optiacoustic.sonar.display import polar_to_fan

    spec = SPEC.with_beam_table(SonarSpec.equal_sine_azimuths(SPEC.n_beams, SPEC.fov_azimuth)) if table else SPEC
    img = np.random.default_rng(6).exponential(1.0, (spec.n_bins, spec.n_beams)).astype(np.float32)
    for width in (64, 301):
        a, b = both_kernel_paths(monkeypatch, lambda: polar_to_fan(img, spec, width=width))
        assert np.array_equal(a.mask, b.mask)
        np.testing.assert_allclose(a.data, b.data, rtol=1e-5, atol=1e-6)
        assert np.all(a.data[~a.mask] == 0)


@pytest.mark.parametrize("bottom_types", [{"sand/shell": [0], "mud": [1, 2]}, {"mud": [3]}])
def test_echo_and_shares_of_several_classes_agree(thesis, bottom_types, monkeypatch):
    """The general finishing pass (two bottom types, or a class with most rays that is not a
    bottom type) against the numpy path's class images and shares."""
    sc, pose = thesis
    f = simulate_sonar(sc, SPEC, pose, noise=False)
    opts = SonarOptions()
    monkeypatch.setenv("OAS_KERNELS", "numba")
    inten_a, sh_a = F._form_with_shares_numba(SPEC, f.rays, opts, bottom_types, 2)
    monkeypatch.setenv("OAS_KERNELS", "numpy")
    inten_b = F._form_image(SPEC, f.rays, opts)
    sh_b = F._seabed_shares(bottom_types, *F._class_parts(bottom_types, SPEC, f.rays, opts), inten_b)
    _close(inten_a, inten_b)
    lit = inten_b > 1e-6 * inten_b.max()
    assert set(sh_a) == set(sh_b) == set(bottom_types)
    for k in sh_b:
        np.testing.assert_allclose(sh_a[k][lit], sh_b[k][lit], atol=1e-3)
        assert np.all(sh_a[k][inten_a <= 0] == 0)
    assert any(sh_b[k][lit].max() > 0.5 for k in sh_b)


def test_fused_aperture_pass_matches_materialised_subcells(thesis, monkeypatch):
    """The aperture model's one-pass kernel (sub-cells formed in the kernel, never stored; echo,
    seabed split and cell areas together) against the sub-cells materialised and integrated by
    the numba path (the same formulas: the areas summed in the same order, bit for bit; the
    echo to float32 rounding, which scales before or after mixing beams and whose float64 sums
    run in another order: ``test_aperture_rows_match_deposit_by_deposit`` bounds that) and by
    the numpy reference path (``_subdivide``, ``_form_image``, ``cell_area``).

    The areas: the same deposits summed in the same order, but each sub-cell's ``cos(elevation)``
    by angle addition from the ray's elevation and the cos/sin of the sub-cell's offset that its
    footprint uses (i14j), not libm's ``cos`` of the sum: a few float64 ulp per sub-cell. So the
    float32 areas agree to one float32 step (``2^-23`` relative, each side) where they hold area,
    and to ``1e-12`` of the peak where the cumulative sums leave their float64 residue (``~1e-16``
    of the largest running sum: cells past a box's end, which hold such residue in either path;
    here ``density x 1e-12 x peak`` is ~1e-12 scatterers, below ``MU_NO_SEABED = 1e-9``)."""
    sc, pose = thesis
    monkeypatch.setenv("OAS_KERNELS", "numba")
    bt = F._bottom_types(sc)
    caster = F.caster_for(sc)
    for opts in (SonarOptions(beam_model="aperture", propagation="spreading"), SonarOptions(beam_model="aperture")):
        sspec = F.scan_spec(SPEC, "aperture")
        args = (sc, caster, sspec, pose, opts, F._aperture_elevation_weights(SPEC), SPEC.elevation_pattern())
        _, cells = F._scan(*args, materialise=False)
        assert isinstance(cells, F._ApertureCells)
        inten, shares, area = F._form_aperture_numba(SPEC, cells, opts, bt, 2, True)
        _, img = F._scan(*args)
        inten_m, shares_m = F._form_with_shares_numba(SPEC, img, opts, bt, 2)
        _close(inten, inten_m, rtol=1e-6)
        ref_area = F.cell_area(SPEC, img, bt)
        np.testing.assert_allclose(area, ref_area, rtol=2.0**-22, atol=1e-12 * float(ref_area.max()))
        assert np.count_nonzero(ref_area > 1e-6 * ref_area.max()) > ref_area.size // 4  # the seabed fills the fan
        assert shares.keys() == shares_m.keys()
        for k in shares:
            np.testing.assert_allclose(shares[k], shares_m[k], atol=1e-5)
        assert F._form_aperture_numba(SPEC, cells, opts, bt, 1, False)[2] is None
        monkeypatch.setenv("OAS_KERNELS", "numpy")
        _, img_np = F._scan(*args)
        _close(inten, F._form_image(SPEC, img_np, opts))
        _close(area, F.cell_area(SPEC, img_np, bt))
        monkeypatch.setenv("OAS_KERNELS", "numba")


def test_chunked_run_covers_each_index_once():
    from optiacoustic.sonar import _kernels as K

    seen = []
    K.chunked_run(lambda a, b: seen.append((a, b)), 1000, 2)
    assert sorted(i for a, b in seen for i in range(a, b)) == list(range(1000))
    assert len(seen) == 2 * K._CHUNKS_PER_THREAD
    seen.clear()
    K.chunked_run(lambda a, b: seen.append((a, b)), 100, 2)  # too few for two threads: one call
    assert seen == [(0, 100)]


def test_work_sharing_does_not_wait_for_a_worker_that_never_starts():
    """A stage whose pool job has not started when the caller has taken every chunk cancels it (i14r):
    with every worker of the pool held, ``chunked_run`` still covers each index once and ``split_run``
    runs the other part itself, and both return (they waited for the worker before)."""
    import threading

    from optiacoustic.sonar import _kernels as K

    pool = K._pool(1)
    gate = threading.Event()
    blockers = [pool.submit(gate.wait) for _ in range(pool._max_workers)]  # noqa: SLF001 - our own pool
    seen, parts = [], []

    def run():
        K.chunked_run(lambda a, b: seen.append((a, b)), 1000, 2)
        K.split_run(lambda a, b: parts.append((a, b)), 1000, 2)

    t = threading.Thread(target=run)
    try:
        t.start()
        t.join(timeout=20)
        assert not t.is_alive(), "a stage waited for a worker that had no chance to run"
        assert sorted(i for a, b in seen for i in range(a, b)) == list(range(1000))
        assert sorted(parts) == [(0, 500), (500, 1000)]
    finally:
        gate.set()
        for b in blockers:
            b.result()
        t.join()


def test_aperture_rows_independent_of_threads(thesis, monkeypatch):
    """The kernel's beams in chunks on two threads give the rows, live flags and seabed areas of
    one pass on one thread, bit for bit (each beam's row is its own; the cos memo holds only
    values that libm gives again)."""
    sc, pose = thesis
    monkeypatch.setenv("OAS_KERNELS", "numba")
    spec = dataclasses.replace(SPEC, n_beams=160, elevation_samples=24)
    bt = F._bottom_types(sc)
    opts = SonarOptions(beam_model="aperture", propagation="spreading")
    sspec = F.scan_spec(spec, "aperture")
    _, cells = F._scan(sc, F.caster_for(sc), sspec, pose, opts, F._aperture_elevation_weights(spec),
                       spec.elevation_pattern(), materialise=False)
    got = [tuple(np.copy(x) for x in F._aperture_rows(spec, cells, opts, bt, t, True)[:3]) for t in (1, 2)]
    for a, b in zip(*got):
        np.testing.assert_array_equal(a, b)
    assert np.count_nonzero(got[0][1]) > 0


@pytest.mark.parametrize("bottom_types", [{}, {"sand/shell": [0], "mud": [1, 2]}])
def test_aperture_words_are_the_counts_flags_and_bodies_beam_major(bottom_types):
    """``aperture_words`` against the passes it replaces on the aperture path, on seeded rays of a
    ``(K, J)`` grid: decoded beam-major, each word is ``subcell_counts``' sub-cell count, the body id
    of a hit ray and whether ``a`` or ``b`` is not the half step; its class counts are
    ``class_counts``' with those counts as weights."""
    from optiacoustic.sonar import _aperture_kernels as ak
    from optiacoustic.sonar import _numba_kernels as kn

    rng = np.random.default_rng(7)
    K, J, half, bw = 37, 53, 0.004, 0.05
    n = K * J
    body = rng.integers(-1, 4, n).astype(np.int32)
    lo = rng.uniform(1.0, 20.0, n)
    hi = lo + rng.exponential(0.4, n)
    energy = np.where(rng.random(n) < 0.8, rng.random(n), 0.0)
    a = np.where(rng.random(n) < 0.1, rng.uniform(0, 2 * half, n), half)
    b = np.where(rng.random(n) < 0.1, rng.uniform(0, 2 * half, n), half)
    names, cls = F._class_table(bottom_types, body)
    word, counts = np.empty(n, np.int64), np.zeros(len(names), np.int64)
    top = ak.aperture_words(body, lo, hi, energy, a, b, half, cls, bw, 16, 2.0, K, J, word, counts)
    n_sub = np.empty(n, np.int64)
    kn.subcell_counts(body, lo, hi, bw, 16, 2.0, n_sub)
    want_counts, ray_cls = np.zeros(len(names), np.int64), np.empty(n, np.int64)
    ak.class_counts(body, energy, n_sub, cls, want_counts, ray_cls)
    w = word.reshape(J, K).T.reshape(-1)  # back to the grid's order
    np.testing.assert_array_equal(w & 255, n_sub)
    hit = body >= 0
    np.testing.assert_array_equal(w[hit] >> 16, body[hit])
    np.testing.assert_array_equal((w[hit] >> 8) & 1, ((a != half) | (b != half))[hit])
    assert not np.any(w[~hit])
    np.testing.assert_array_equal(counts, want_counts)
    assert top == max(1, n_sub.max()) and 1 < top <= 16


@pytest.mark.parametrize("q", [2, 3])  # the default two phases, and the general path
def test_aperture_rows_match_deposit_by_deposit(thesis, monkeypatch, q):
    """The aperture kernel's rows (per beam: the boxes' fine-cell deposits, then one pass of the
    taps and steps) against ``echo_rows`` on the materialised sub-cells (each deposit carried to
    the bins by the same tables, one at a time): the same linear map on the same deposits, so
    the float64 rows differ only by the order of their sums: by float64 rounding (``2^-52``) of
    the running sums, which a short footprint's ``+dens``/``-dens`` pair (its width at least
    ``1e-4`` bin) can make up to ``~1e4`` times the echo it leaves (measured here: ~1e-13 of a
    row's peak). Tolerance: one float32 rounding step each side (``2^-23`` relative) plus
    ``1e-9`` of the row's peak, the level below which the image keeps nothing
    (``_finish_numba`` zeroes it as the cumulative sums' residue)."""
    sc, pose = thesis
    monkeypatch.setenv("OAS_KERNELS", "numba")
    bt = F._bottom_types(sc)
    caster = F.caster_for(sc)
    opts = SonarOptions(beam_model="aperture", propagation="spreading", range_oversample=q)
    sspec = F.scan_spec(SPEC, "aperture")
    args = (sc, caster, sspec, pose, opts, F._aperture_elevation_weights(SPEC), SPEC.elevation_pattern())
    _, cells = F._scan(*args, materialise=False)
    rows, _, live, slot_of = F._aperture_rows(SPEC, cells, opts, bt, 2, False)
    rows = rows.copy()  # a scratch that _echo_rows_numba reuses
    _, img = F._scan(*args)
    slot, n_slots, slot_of_m = F._class_slots(bt, img)
    assert slot_of_m == slot_of and n_slots == rows.shape[0]
    sigma_bins = max(SPEC.pulse_width / SPEC.bin_width / 2.3548, 0.5)
    ref = F._echo_rows_numba(SPEC, img, slot, n_slots, 1, opts.range_oversample, sigma_bins).copy()
    assert np.count_nonzero(ref[0]) > ref[0].size // 2  # the seabed fills most of the fan
    for s in range(n_slots):
        peak = float(np.abs(ref[s]).max())
        np.testing.assert_allclose(rows[s], ref[s], rtol=2.0**-23, atol=1e-9 * peak)
        # rows without deposits (left out of the beam mixing) are zeros, in both
        assert not np.any(rows[s][~live[s]]) and not np.any(ref[s][~live[s]])
        assert live[s].any()


def test_scatterer_words_drawn_beside_the_scan_give_the_same_image(thesis, monkeypatch):
    """``ScattererNoise.draw(_field=True)`` (the echo-free part of the field, drawn beside the scan when a
    frame has a second thread) and the one-pass kernel give the same image, bit for bit, and a frame
    on two threads (which draws them so) equals one on one thread (which does not)."""
    monkeypatch.setenv("OAS_KERNELS", "numba")
    sc, pose = thesis
    opts = SonarOptions(beam_model="aperture", propagation="spreading")
    noise = ScattererNoise(density=300.0, gain=DeviceGain(noise_db=-60.0, volume_db=-50.0, spreading_db=30.0))
    f = simulate_sonar(sc, SPEC, pose, noise=False, options=opts)
    area = np.full(f.intensity.shape, 0.01, np.float32)
    area[::17, ::13] = 0.2  # some cells of mean count >= 30: drawn by the generator

    def image(field):
        d = noise.draw(f.intensity.shape, (), np.random.default_rng(9), _reuse=True, _field=field)
        assert len(d) == (3 if field else 2)
        img = noise.apply(f.intensity, spec=SPEC, seabed_share=f.seabed_share, options=opts, draws=d,
                          cell_area=area, threads=2)
        N.release_draws(d)
        return img

    a, b = image(False), image(True)
    assert np.array_equal(a, b) and a.std() > 0
    caster = F.caster_for(sc)
    frames = []
    for threads in (1, 2):
        monkeypatch.setattr(caster, "threads", threads)
        frames.append(simulate_sonar(sc, SPEC, pose, noise=noise, options=opts, seed=4).image)
    assert np.array_equal(frames[0], frames[1])


def test_edge_subray_directions_kernel_is_the_numpy_expression_bit_for_bit():
    # the numpy path's sub-ray directions (formation._refine_edges), against the kernel's from
    # per-spec tables, on random pairs and poses: the same float32 rays
    from optiacoustic.sonar import _numba_kernels as kn

    spec = SonarSpec.preset("blueview-p900-90")
    rng = np.random.default_rng(11)
    S, K, J, step = F._EDGE_SUBRAYS, spec.elevation_samples, spec.n_beams, spec.elevation_step
    frac = (np.arange(S) + 0.5) / S
    for _ in range(20):
        pose = Pose.look_at(rng.normal(size=3) * 5, rng.normal(size=3) * 5 + [0, 20, 0])
        m = 3000
        kk, jj = rng.integers(0, K - 1, m), rng.integers(0, J, m)
        phi = spec.elevations[kk][:, None] + step * frac[None, :]
        th = spec.azimuths[jj][:, None]
        cp = np.cos(phi)
        d = pose.directions_to_world(np.stack(np.broadcast_arrays(cp * np.sin(th), cp * np.cos(th), np.sin(phi)), -1))
        ref = np.ascontiguousarray(d.reshape(-1, 3), np.float32)
        out = np.empty_like(ref)
        kn.edge_directions32(kk, jj, *F._edge_trig(spec), np.ascontiguousarray(pose.R), 0, m, out)
        assert np.array_equal(out, ref)


@pytest.mark.parametrize("n_bins", [97, 300, 750, 1500])
def test_beam_mixing_in_column_pieces_is_the_whole_image_bit_for_bit(n_bins):
    # _form_aperture_numba mixes the beams in pieces of _MIX_COLUMNS bins on several threads: each
    # piece must give exactly what cv2 gives on the whole image (and zeros outside the live span)
    spec = dataclasses.replace(SonarSpec.preset("blueview-p900-90"), n_bins=n_bins)
    rng = np.random.default_rng(n_bins)
    rows = (rng.random((spec.n_beams, n_bins)) ** 6).astype(np.float32)
    rows[:40] = 0.0
    rows[-25:] = 0.0
    span = F._live_span(rows.any(axis=1), spec)
    whole = np.full_like(rows, np.nan)
    F._mix_rows(spec, rows, whole, span)
    pieces = np.full_like(rows, np.nan)
    for c0 in range(0, n_bins, F._MIX_COLUMNS):
        c1 = min(c0 + F._MIX_COLUMNS, n_bins)
        F._mix_rows(spec, rows[:, c0:c1], pieces[:, c0:c1], span)
    assert np.array_equal(whole, pieces)
    assert np.all(whole[:span[0]] == 0) and np.all(whole[span[1]:] == 0) and span[0] > 0


def test_vectorised_exp_is_libm_exp_to_a_few_ulp():
    """``exp_row`` (the aperture kernel's and ``spreading_gain``'s exp, a polynomial so that the loops
    vectorise) against numpy's ``exp`` on seeded arguments over its whole domain and the spreading's
    range: a degree-13 Taylor series on ``|r| <= ln 2 / 2`` truncates at < 5e-18 relative and the
    reduction with ``ln 2`` in two parts loses < 1 ulp, so each value is within a few float64 ulp
    (bound 8; measured 1). Below -708 it returns 0 (libm: < 3.4e-308, at most a subnormal)."""
    pytest.importorskip("numba")
    from optiacoustic.sonar._numba_kernels import exp_row

    rng = np.random.default_rng(4)
    x = np.concatenate([rng.uniform(-708.0, 709.0, 100_000), rng.uniform(-20.0, 1.0, 100_000),
                        rng.uniform(-1e-6, 1e-6, 1000), [-708.0, -0.0, 0.0, 709.0, -1e-300]])
    out, scratch = np.empty_like(x), np.empty_like(x)
    exp_row(x, x.size, out, scratch)
    ref = np.exp(x)
    assert np.all(np.abs(out - ref) <= 8 * np.spacing(ref))
    low = np.array([-708.5, -750.0, -1e5])
    exp_row(low, low.size, out, scratch)
    assert np.all(out[:3] == 0.0)


@pytest.mark.parametrize("K, J", [(1, 1), (7, 5), (48, 96), (3, 300)])
def test_grid_directions_origins_and_extents_are_the_numpy_expressions_bit_for_bit(K, J):
    """The serial pre-cast kernels (i14r): ``ray_grid32`` (one flat loop per elevation row) is
    ``cos(phi_k) a_j + sin(phi_k) R_z`` in float64 rounded to float32, as numpy forms it, to the bit;
    ``fill_rows3`` sets every row of an ``(N, 3)`` array to the origin (N above and below its 256-row
    pattern); ``fill2`` fills the two extents' arrays over ``i0..i1`` only."""
    from optiacoustic.sonar import _numba_kernels as kn

    rng = np.random.default_rng(11)
    ph = rng.uniform(-0.3, 0.3, K)
    cp, sp = np.cos(ph), np.sin(ph)
    a = rng.standard_normal((J, 3))
    rz = rng.standard_normal(3)
    out = np.empty((K * J, 3), np.float32)
    kn.ray_grid32(cp, sp, a, rz, out)
    want = (cp[:, None, None] * a[None, :, :] + sp[:, None, None] * rz[None, None, :]).astype(np.float32)
    np.testing.assert_array_equal(out, want.reshape(-1, 3))
    origin = np.array([1.5, -2.25, 3.0e-3], np.float32)
    for n in (1, 255, 256, 257, 1000):
        o = np.full((n, 3), np.nan, np.float32)
        kn.fill_rows3(o, origin)
        np.testing.assert_array_equal(o, np.broadcast_to(origin, (n, 3)))
    x, y = np.zeros(50), np.zeros(50)
    kn.fill2(x, y, 0.125, 7, 31)
    want = np.zeros(50)
    want[7:31] = 0.125
    np.testing.assert_array_equal(x, want)
    np.testing.assert_array_equal(y, want)
