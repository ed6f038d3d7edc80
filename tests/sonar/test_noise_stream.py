"""The thesis noise model's counter stream (issue 14): each cell's variates are Philox4x32-10 words of
(seed's key, cell index), so the compiled kernel computes them row by row on any thread.

Truths that do not come from the code under test: the words against the numpy reference generator
(itself checked against Random123's known answers in test_kernels.py), and the variates' laws
against their analytic distributions (Exp(1), the Rayleigh mixture's exponential mixture, the
Rician intensity, i.e. a scaled noncentral chi-square with 2 degrees of freedom) by two-sided KS
tests and moment bounds on seeded frames; neighbouring cells and a cell's own words uncorrelated.
"""

import dataclasses

import numpy as np
import pytest
from scipy import stats

from optiacoustic.sonar import SonarOptions, SonarSpec
from optiacoustic.sonar import noise as N
from optiacoustic.sonar.noise import NoiseKey, NoiseModel

from .conftest import both_kernel_paths

SPEC = dataclasses.replace(SonarSpec.preset("blueview-p900-90"), n_bins=400, n_beams=250)
SHAPE = (SPEC.n_bins, SPEC.n_beams)
OPT = SonarOptions()


def _image(model, I, shares, seed=3, threads=1):
    d = model.draw(I.shape, list(shares), np.random.default_rng(seed))
    return model.apply(I, spec=SPEC, seabed_share=shares, options=OPT, draws=d, threads=threads)


def _noise(model, I):
    return model.noise_power(I, SPEC.ranges, SPEC.frequency, OPT.propagation, OPT.water)[:, None].astype(float)


def _moments_ok(z, mean, second, n_sigma=5.0):
    """Two-sided bounds on the sample mean and second moment of i.i.d. ``z`` (CLT, with the fourth
    moment estimated from the sample)."""
    n = z.size
    se1 = np.sqrt(np.var(z) / n)
    se2 = np.sqrt(np.var(z * z) / n)
    assert abs(z.mean() - mean) < n_sigma * se1, (z.mean(), mean)
    assert abs(np.mean(z * z) - second) < n_sigma * se2, (np.mean(z * z), second)


@pytest.mark.parametrize("n_types", [1, 2, 3, 6])
def test_kernel_words_are_the_reference_generators(n_types):
    """The kernel's words are ``_philox_numpy``'s, block by block (two blocks from 3 bottom types
    on), the scatterer noise's stream is another, and rows drawn alone equal rows drawn together."""
    from optiacoustic.sonar import _numba_kernels as kn

    key = NoiseKey(np.array([2024, 77], np.uint32), (30, 41))
    ref = N.counter_words(key, n_types)
    assert ref.shape == (4 * N._n_blocks(n_types), 30, 41) and ref.dtype == np.uint32
    out = np.zeros_like(ref)
    kn.counter_words(np.uint32(2024), np.uint32(77), N._STREAM, 0, 30, out)
    assert np.array_equal(out, ref)
    part = np.zeros_like(ref)
    kn.counter_words(np.uint32(2024), np.uint32(77), N._STREAM, 11, 17, part)
    assert np.array_equal(part[:, 11:17], ref[:, 11:17]) and not part[:, :11].any()
    # another stream than the scatterer noise's words under the same key
    scat = N.cell_words(key.key, np.arange(30 * 41)).reshape(3, 30, 41)
    assert not np.any(scat == ref[:3])


def test_words_are_uniform_and_independent():
    """Each word's uniform passes KS; the words of a cell, and of neighbouring cells (along the beam,
    across beams, and across a row's end, where the counters are consecutive) are uncorrelated."""
    key = NoiseKey(np.array([9, 10], np.uint32), (300, 200))
    u = N._uniforms(N.counter_words(key, 3))  # two blocks: 8 words, 5 used
    n = u[0].size
    bound = 5 / np.sqrt(n)
    for k in range(u.shape[0]):
        assert stats.kstest(u[k].ravel(), "uniform").pvalue > 1e-3, k
        assert abs(u[k].mean() - 0.5) < 5 * np.sqrt(1 / 12 / n)
    c = np.corrcoef(u.reshape(u.shape[0], -1))
    assert np.all(np.abs(c[np.triu_indices(u.shape[0], 1)]) < bound)
    for k in (0, 2):
        w = u[k]
        assert abs(np.corrcoef(w[:, :-1].ravel(), w[:, 1:].ravel())[0, 1]) < bound  # next beam
        assert abs(np.corrcoef(w[:-1].ravel(), w[1:].ravel())[0, 1]) < bound  # next range bin
        flat = w.ravel()
        assert abs(np.corrcoef(flat[:-1], flat[1:])[0, 1]) < bound  # next counter (row ends included)
        assert abs(np.corrcoef(w[:-1, -1], w[1:, 0])[0, 1]) < 5 / np.sqrt(w.shape[0])
    # a different key gives different words
    other = N.counter_words(NoiseKey(np.array([9, 11], np.uint32), (300, 200)), 3)
    assert np.mean(other == N.counter_words(key, 3)) < 1e-3


@pytest.mark.parametrize("model", [
    NoiseModel(),
    NoiseModel(reverberation="rayleigh"),
    NoiseModel(reverberation="rayleigh", noise_floor_db=None),
    NoiseModel(target_speckle=False),
    NoiseModel(reverberation=None),
    NoiseModel(reverberation=None, target_speckle=False),
    NoiseModel(reverberation=None, noise_floor_db=None),
    NoiseModel(bottom_type="mud"),
])
@pytest.mark.parametrize("n_types", [0, 1, 2, 3])
def test_kernel_and_reference_agree_on_the_same_words(model, n_types, monkeypatch):
    """The compiled pass and the numpy reference (``_counter_draws`` + ``_apply_numpy``) give the same
    image from the same key (within float32 rounding: the kernel's ``ln`` and ``cos`` are
    polynomials), for 0 to 3 bottom types (the one-type fast path and the general loop)."""
    rng = np.random.default_rng(5 + n_types)
    I = (rng.exponential(1.0, SHAPE) * (rng.random(SHAPE) < 0.8)).astype(np.float32)
    names = ["sand/shell", "mud", "posidonia"][:n_types]
    left = np.ones(SHAPE, np.float32)
    shares = {}
    for t in names:
        shares[t] = (left * rng.random(SHAPE)).astype(np.float32)
        left = left - shares[t]
    a, b = both_kernel_paths(monkeypatch, lambda: _image(model, I, shares, threads=2))
    assert a.dtype == np.float32 and np.all(a >= 0)
    np.testing.assert_allclose(a, b, rtol=2e-5, atol=2e-6 * float(b.max()))
    assert not np.array_equal(a, I)


def test_same_image_at_any_number_of_threads_and_for_a_seed():
    """A cell's variates depend on its index alone: 1, 2 and 3 threads (chunks taken in any order)
    give the image to the bit; the same seed the same image, another seed another."""
    rng = np.random.default_rng(2)
    I = rng.exponential(1.0, SHAPE).astype(np.float32)
    shares = {"sand/shell": rng.random(SHAPE).astype(np.float32)}
    for model in (NoiseModel(), NoiseModel(target_speckle=False), NoiseModel(reverberation=None)):
        one = _image(model, I, shares, seed=4, threads=1)
        for threads in (2, 3):
            assert np.array_equal(_image(model, I, shares, seed=4, threads=threads), one)
        assert np.array_equal(_image(model, I, shares, seed=4), one)
        assert np.mean(_image(model, I, shares, seed=5) == one) < 0.01


def test_noise_floor_alone_is_exponential():
    """No echo: every cell is the noise floor's power times ``E``; ``E / 1`` is Exp(1) (KS, mean and
    second moment 2), and independent of its neighbours. (Without echo the floor needs an absolute
    ``reference_level``: relative to no echo there is none, NoEchoWarning.)"""
    model = NoiseModel(reference_level=1.0)
    I = np.zeros(SHAPE, np.float32)
    z = _image(model, I, {"sand/shell": np.zeros(SHAPE, np.float32)}, seed=6) / _noise(model, I)
    assert stats.kstest(z.ravel(), "expon").pvalue > 1e-3
    _moments_ok(z.ravel(), 1.0, 2.0)
    assert stats.kstest(z.ravel(), stats.expon(scale=1.02).cdf).pvalue < 1e-6  # the check has teeth
    assert abs(np.corrcoef(z[:, :-1].ravel(), z[:, 1:].ravel())[0, 1]) < 5 / np.sqrt(z.size)
    assert abs(np.corrcoef(z[:-1].ravel(), z[1:].ravel())[0, 1]) < 5 / np.sqrt(z.size)


@pytest.mark.parametrize("bottom", ["sand/shell", "posidonia"])
def test_mixture_reverberation_follows_its_exponential_mixture(bottom):
    """All seabed, no noise floor: ``image / I = lam_c E`` with component ``c`` of probability
    ``eps_c``, the law ``sum_c eps_c Exp(mean lam_c)`` (KS; mean ``sum eps lam``, second moment
    ``2 sum eps lam^2``); its square root follows the bottom model's amplitude cdf."""
    from optiacoustic.sonar.distributions import bottom_model

    model = NoiseModel(noise_floor_db=None)
    I = np.full(SHAPE, 2.5, np.float32)
    z = (_image(model, I, {bottom: np.ones(SHAPE, np.float32)}, seed=7) / I).ravel().astype(float)
    w, lam = N._mixture_table(bottom_model(bottom, "mixture"))
    assert len(w) > 1

    def cdf(x):
        return np.sum(w[:, None] * (1 - np.exp(-np.asarray(x)[None] / lam[:, None])), axis=0)

    assert stats.kstest(z, cdf).pvalue > 1e-3
    _moments_ok(z, float(w @ lam), float(2 * w @ lam**2))
    assert stats.kstest(np.sqrt(z), bottom_model(bottom, "mixture").cdf).pvalue > 1e-3
    assert stats.kstest(z, "expon", args=(0, float(w @ lam))).pvalue < 1e-6  # a single exponential fails


def test_steady_echo_plus_noise_is_rician():
    """No reverberation, no speckle, a noise floor: ``|sqrt(S) + g|^2`` with ``g ~ CN(0, P)``, the
    uniform phase ``psi`` from the words: ``2 image / P`` is noncentral chi-square, 2 degrees of
    freedom, noncentrality ``2 S / P`` (KS; mean ``S + P``, second moment ``S^2 + 4 S P + 2 P^2``)."""
    model = NoiseModel(reverberation=None, target_speckle=False, noise_floor_db=0.0, reference_level=1.0,
                       tvg_noise=False)
    S = 1.5
    I = np.full(SHAPE, S, np.float32)
    img = _image(model, I, {}, seed=8).ravel().astype(float)
    P = float(_noise(model, I)[0, 0])
    assert P == pytest.approx(1.0)
    law = stats.ncx2(2, 2 * S / P, scale=P / 2)
    assert stats.kstest(img, law.cdf).pvalue > 1e-3
    _moments_ok(img, S + P, S * S + 4 * S * P + 2 * P * P)
    assert stats.kstest(img, stats.ncx2(2, 2 * 1.3 * S / P, scale=P / 2).cdf).pvalue < 1e-6  # teeth


def test_draws_are_a_key_for_the_thesis_models_and_arrays_for_weibull_and_k():
    rng = np.random.default_rng(1)
    assert isinstance(NoiseModel().draw(SHAPE, ["mud"], rng), NoiseKey)
    assert isinstance(NoiseModel(reverberation=None).draw(SHAPE, ["mud"], rng), NoiseKey)
    for rev in ("weibull", "k"):
        d = NoiseModel(reverberation=rev).draw(SHAPE, ["mud"], rng)
        assert isinstance(d, N.NoiseDraws) and d.x["mud"].shape == SHAPE
    I = np.ones(SHAPE, np.float32)
    key = NoiseModel().draw((10, 10), ["mud"], rng)
    with pytest.raises(ValueError, match="shape"):
        NoiseModel().apply(I, spec=SPEC, seabed_share={}, options=OPT, draws=key)
    with pytest.raises(ValueError, match="draws"):
        NoiseModel(reverberation="k").apply(I, spec=SPEC, seabed_share={}, options=OPT,
                                            draws=NoiseModel().draw(SHAPE, [], rng))


def test_numpy_philox_known_answer_and_chunks():
    """The numpy reference generator (in chunks of 32 768 counters) on Random123's first known-answer
    vector, and across chunk boundaries against the kernel's words for counters with ``c1``, ``c2``."""
    from optiacoustic.sonar import _numba_kernels as kn

    assert [int(w[0]) for w in N._philox_numpy(np.array([0]), (0, 0))] == [0x6627E8D5, 0xE169C58D, 0xBC57AC4C,
                                                                          0x9B00DBD8]
    cells = np.arange(70_001)
    ref = np.stack(N._philox_numpy(cells, (31, 4), 2, 1))
    for k in (0, 32_767, 32_768, 65_536, 70_000):
        out = np.zeros(4, np.uint32)
        kn.philox_block(k, 2, 1, 0, 31, 4, out)
        assert np.array_equal(ref[:, k], out), k


@pytest.mark.parametrize("model", [NoiseModel(), NoiseModel(target_speckle=False), NoiseModel(reverberation=None)])
def test_variates_formed_beside_the_scan_give_the_same_frame(model):
    """``simulate_sonar`` with two threads forms the variates beside the scan
    (``draw(_field=True)``, ``noise_variates`` then ``noise_apply``); with one thread ``apply`` forms
    them in its own pass (``noise_counter``): the same image to the bit, and the same as ``apply``
    on the frame's intensity with a fresh key from the same seed."""
    from optiacoustic import Pose, scenes, simulate_sonar
    from optiacoustic.raycast import caster_for

    sc = scenes.get("flat_seabed")
    pose = Pose.look_at((0, -6, 2), (0, 0, 0))
    spec = dataclasses.replace(SPEC, n_bins=300, n_beams=64, elevation_samples=32)
    caster = caster_for(sc)
    old = caster.threads
    try:
        caster.threads = 2
        two = simulate_sonar(sc, spec, pose, noise=model, seed=21)
        two_b = simulate_sonar(sc, spec, pose, noise=model, seed=21)  # pooled buffers reused
        caster.threads = 1
        one = simulate_sonar(sc, spec, pose, noise=model, seed=21)
    finally:
        caster.threads = old
    assert np.array_equal(two.image, one.image) and np.array_equal(two_b.image, one.image)
    d = model.draw(one.intensity.shape, list(one.seabed_share), np.random.default_rng(21))
    direct = model.apply(one.intensity, spec=spec, seabed_share=dict(one.seabed_share), options=OPT, draws=d)
    assert np.array_equal(direct, one.image)
    d2 = model.draw(one.intensity.shape, list(one.seabed_share), np.random.default_rng(21), _reuse=True, _field=True)
    assert d2.variates is not None
    beside = model.apply(one.intensity, spec=spec, seabed_share=dict(one.seabed_share), options=OPT, draws=d2,
                         threads=2)
    N.release_noise_draws(d2)
    assert np.array_equal(beside, one.image)
