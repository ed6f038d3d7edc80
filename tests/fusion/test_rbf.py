"""RBF sonar-to-optical mapping: thesis claims on exact geometry, identities, bad input."""

import numpy as np
import pytest

from optiacoustic.fusion import RBFMapping, cross_validate, epsilon_from_sigma

THESIS_PIXEL = 19.0 / 750  # one range bin of the thesis's 750-bin image over 1-20 m


def test_planar_grid_held_out_within_one_pixel(grid):
    # thesis 7.3.1: "perfect fit" on the planar grid (sigma = 200 sonar pixels)
    xy_tr, px_tr, xy_te, px_te = grid
    m = RBFMapping.fit(xy_tr, px_tr, sigma=200 * THESIS_PIXEL)
    err = np.linalg.norm(m(xy_te) - px_te, axis=-1)
    assert len(err) == 80
    assert err.max() < 1.0
    assert m.training_error < 0.1


def test_gaussian_width_is_the_thesis_sigma():
    # (7.6)-(7.7) solved by hand with exp(-d^2 / (2 sigma^2)) must equal scipy's with epsilon
    rng = np.random.default_rng(1)
    xy = rng.uniform(-1, 1, (12, 2))
    px = rng.uniform(0, 600, (12, 2))
    sigma = 0.4
    phi = lambda a, b: np.exp(-np.sum((a[:, None] - b[None]) ** 2, -1) / (2 * sigma ** 2))  # noqa: E731
    w = np.linalg.solve(phi(xy, xy), px)
    q = rng.uniform(-1.2, 1.2, (30, 2))
    m = RBFMapping.fit(xy, px, sigma=sigma)
    np.testing.assert_allclose(m(q), phi(q, xy) @ w, atol=1e-6)
    assert m.epsilon == pytest.approx(1 / (np.sqrt(2) * sigma))
    assert epsilon_from_sigma(2.0) == pytest.approx(0.5 / np.sqrt(2))


def test_exact_interpolation_reproduces_training():
    rng = np.random.default_rng(2)
    xy = rng.uniform([-1, 3], [1, 5], (25, 2))
    px = rng.uniform(0, 600, (25, 2))
    for base in ("none", "affine", "homography"):
        m = RBFMapping.fit(xy, px, sigma=0.3, base=base)
        np.testing.assert_allclose(m(xy), px, atol=1e-6)
        assert m.training_error < 1e-6


def test_bases_reproduce_their_own_maps_away_from_the_data():
    rng = np.random.default_rng(3)
    xy = rng.uniform([-1, 3], [1, 5], (20, 2))
    q = rng.uniform([-1.5, 2.5], [1.5, 5.5], (40, 2))
    A, b = np.array([[200.0, 30.0], [-20.0, -150.0]]), np.array([300.0, 900.0])
    H = np.array([[250.0, 10.0, 300.0], [5.0, -120.0, 800.0], [0.02, 0.15, 1.0]])

    def hom(p):
        h = np.column_stack([p, np.ones(len(p))]) @ H.T
        return h[:, :2] / h[:, 2:]

    m = RBFMapping.fit(xy, xy @ A.T + b, sigma=0.5, base="affine")
    np.testing.assert_allclose(m(q), q @ A.T + b, atol=1e-6)
    m = RBFMapping.fit(xy, hom(xy), sigma=0.5, base="homography", smoothing=1.0)
    np.testing.assert_allclose(m(q), hom(q), atol=1e-4)
    np.testing.assert_allclose(m.homography / m.homography[2, 2], H, rtol=1e-4)  # cv2 stops at ~1e-5


def test_large_smoothing_tends_to_the_least_squares_base():
    rng = np.random.default_rng(4)
    xy = rng.uniform([-1, 3], [1, 5], (30, 2))
    px = rng.uniform(0, 600, (30, 2))
    design = np.column_stack([xy, np.ones(len(xy))])
    coef = np.linalg.lstsq(design, px, rcond=None)[0]
    q = rng.uniform([-1, 3], [1, 5], (10, 2))
    errs = []
    for lam in (0.0, 1e-2, 1.0, 1e8):
        m = RBFMapping.fit(xy, px, sigma=0.3, smoothing=lam, base="affine")
        errs.append(m.training_error)
    np.testing.assert_allclose(m(q), np.column_stack([q, np.ones(len(q))]) @ coef, atol=1e-3)
    assert errs[0] < 1e-6 < errs[1] < errs[2] < errs[3]


def test_batched_equals_loop_and_nan_passes_through(grid):
    xy_tr, px_tr, xy_te, _ = grid
    m = RBFMapping.fit(xy_tr, px_tr, sigma=1.0, base="homography")
    q = xy_te[:12].reshape(3, 4, 2)
    out = m(q)
    assert out.shape == (3, 4, 2)
    loop = np.array([m(p) for p in q.reshape(-1, 2)]).reshape(3, 4, 2)
    np.testing.assert_allclose(out, loop, atol=1e-9)
    q2 = xy_te[:3].copy()
    q2[1] = np.nan
    r = m(q2)
    assert np.all(np.isnan(r[1])) and np.all(np.isfinite(r[[0, 2]]))


def test_callers_arrays_stay_writable(grid):
    xy_tr, px_tr, _, _ = grid
    a, b = xy_tr.copy(), px_tr.copy()
    RBFMapping.fit(a, b, sigma=1.0)
    a[0, 0] += 1.0  # must not raise "assignment destination is read-only"
    b[0, 0] += 1.0
    assert a.flags.writeable and b.flags.writeable


def test_cross_validation_prefers_smoothing_on_noisy_data():
    # a smooth truth plus seeded pixel noise: leave-one-out must prefer some smoothing, and a
    # noise-free truth must give a smaller LOO error than the noisy one
    rng = np.random.default_rng(5)
    xy = rng.uniform([-1, 3], [1, 5], (40, 2))
    truth = np.column_stack([300 + 200 * xy[:, 0] + 20 * xy[:, 1] ** 2, 900 - 150 * xy[:, 1]])
    noisy = truth + rng.normal(0, 3.0, truth.shape)
    lams = [0.0, 1e-3, 1e-2, 1e-1, 1.0]
    cv = cross_validate(xy, noisy, sigmas=[0.5], smoothings=lams, base="affine")
    assert cv.errors.shape == (1, 5)
    assert cv.best_smoothing > 0
    assert cv.errors[0].min() < cv.errors[0, 0]
    clean = cross_validate(xy, truth, sigmas=[0.5], smoothings=lams, base="affine")
    assert clean.errors.min() < cv.errors.min()
    assert cv.errors.min() > 1.0  # the injected 3 px noise cannot be predicted away


def test_cross_validation_scores_singular_widths_as_infinite():
    rng = np.random.default_rng(6)
    xy = rng.uniform(-1, 1, (30, 2))
    px = rng.uniform(0, 600, (30, 2))
    cv = cross_validate(xy, px, sigmas=[0.3, 1e7], base="none")
    assert np.isfinite(cv.errors[0, 0])
    assert cv.best_sigma == 0.3


# --------------------------------------------------------------------------- bad input
GOOD_XY = np.array([[0.0, 3.0], [1.0, 3.5], [-1.0, 4.0], [0.3, 4.5]])
GOOD_PX = np.array([[100.0, 300.0], [400.0, 250.0], [50.0, 200.0], [320.0, 120.0]])


@pytest.mark.parametrize(
    "xy, px, kw, match",
    [
        (GOOD_XY[:2], GOOD_PX[:2], {}, "at least 3"),
        (GOOD_XY[:3], GOOD_PX[:3], {"base": "homography"}, "at least 4"),
        (np.vstack([GOOD_XY, GOOD_XY[1]]), np.vstack([GOOD_PX, GOOD_PX[0]]), {}, "duplicated"),
        (np.column_stack([np.linspace(0, 1, 5), 3 + 2 * np.linspace(0, 1, 5)]), np.ones((5, 2)), {}, "collinear"),
        (np.where(np.arange(8).reshape(4, 2) == 3, np.nan, GOOD_XY), GOOD_PX, {}, "finite"),
        (GOOD_XY, np.where(np.arange(8).reshape(4, 2) == 5, np.nan, GOOD_PX), {}, "finite"),
        (GOOD_XY, GOOD_PX[:3], {}, "one pixel per sonar feature"),
        (GOOD_XY[:, :1], GOOD_PX, {}, "expected shape"),
        (GOOD_XY, GOOD_PX, {"sigma": 0.0}, "sigma"),
        (GOOD_XY, GOOD_PX, {"smoothing": -1.0}, "smoothing"),
        (GOOD_XY, GOOD_PX, {"base": "cubic"}, "base"),
        (np.repeat(GOOD_XY[:1], 4, axis=0), GOOD_PX, {}, "same place"),
    ],
)
def test_bad_layouts_raise_clear_value_errors(xy, px, kw, match):
    kw = {"sigma": 1.0, **kw}
    with pytest.raises(ValueError, match=match) as info:
        RBFMapping.fit(xy, px, **kw)
    assert not isinstance(info.value, np.linalg.LinAlgError)


def test_numerically_singular_system_is_a_value_error_not_linalgerror(grid):
    # so wide a Gaussian that every kernel entry is 1 in double precision: the matrix is singular
    xy_tr, px_tr, _, _ = grid
    with pytest.raises(ValueError, match="singular") as info:
        RBFMapping.fit(xy_tr, px_tr, sigma=1e9)
    assert not isinstance(info.value, np.linalg.LinAlgError)


def test_cross_validate_bad_candidates():
    with pytest.raises(ValueError, match="sigmas"):
        cross_validate(GOOD_XY, GOOD_PX, sigmas=[-1.0])
    with pytest.raises(ValueError, match="smoothings"):
        cross_validate(GOOD_XY, GOOD_PX, sigmas=[1.0], smoothings=[-1.0])
    with pytest.raises(ValueError, match="at least 4"):
        cross_validate(GOOD_XY[:3], GOOD_PX[:3], sigmas=[1.0])
