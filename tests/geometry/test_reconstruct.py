"""Opti-acoustic reconstruction: exact closed forms, Jacobians, Monte Carlo against first order and the CRLB."""

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from optiacoustic import PinholeCamera, Rig
from optiacoustic.frames import R_SONAR_FROM_CAMERA_FORWARD
from optiacoustic.geometry import projection as pr
from optiacoustic.geometry import reconstruct as rc
from optiacoustic.sonar import SonarSpec

CAM = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
SIG = dict(sigma_pixel=2.0, sigma_range=0.02, sigma_azimuth=0.03)  # the thesis's noise (sec. 5.3)
SIG_VEC = np.array([2.0, 2.0, 0.02, 0.03])


def random_rig(seed):
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3)
    t *= rng.uniform(0.1, 1.0) / np.linalg.norm(t)
    cam = PinholeCamera(rng.uniform(400, 1200), rng.uniform(400, 1200), rng.uniform(250, 350),
                        rng.uniform(150, 250), 640, 400)
    return Rig(R, t, cam)


def random_points(seed, n=200):
    rng = np.random.default_rng(seed + 1000)
    z = rng.uniform(1.0, 10.0, n)
    return np.stack([rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.4, 0.4, n) * z, z], -1)


def thesis_setting(baseline, distance, n, seed=0):
    """Toed-in rig aimed at a 0.6 x 0.4 x 0.6 m cloud of points ``distance`` metres ahead."""
    rig = Rig.toed_in(CAM, baseline=baseline, vergence=np.arctan(baseline / distance))
    rng = np.random.default_rng(seed)
    target = np.array([baseline / 2, 0.0, np.hypot(baseline / 2, distance)])  # camera frame, roughly
    P = target + rng.uniform(-1, 1, (n, 3)) * [0.3, 0.2, 0.3]
    return rig, P


def noisy(rig, P, seed, sig=SIG_VEC):
    p = pr.project(rig, P)
    e = np.random.default_rng(seed).standard_normal(P.shape[:-1] + (4,)) * sig
    return p.pixels + e[..., :2], p.ranges + e[..., 2], p.azimuths + e[..., 3]


# --------------------------------------------------------------------------- closed forms
@pytest.mark.parametrize("seed", range(6))
def test_closed_forms_exact_on_noise_free_data(seed):
    rig, P = random_rig(seed), random_points(seed)
    p = pr.project(rig, P)
    rs = rc.range_solution(rig, p.pixels, p.ranges)
    az = rc.azimuth_solution(rig, p.pixels, p.azimuths)
    cb = rc.combined_solution(rig, p.pixels, p.ranges, p.azimuths, **SIG)
    # Where the camera centre is inside the range sphere the root is unique and exact.
    unique = ~rs.ambiguous
    np.testing.assert_allclose(rs.points[unique], P[unique], atol=1e-9)
    ok = az.valid
    assert ok.mean() > 0.95
    np.testing.assert_allclose(az.points[ok], P[ok], atol=1e-8)
    np.testing.assert_allclose(cb.points[unique], P[unique], atol=1e-8)
    assert bool(rs) and bool(az)


def test_range_solution_against_roots_and_thesis_5_4():
    """Ours is the positive root of the exact quadratic (numpy.roots per point); the thesis's
    eq. 5.4, Z = (r |q| - t^T R q) / |q|^2, drops terms and misses by millimetres."""
    rig = Rig.toed_in(CAM, baseline=0.25, vergence=np.arctan(0.25 / 3))
    P = random_points(3, 20)
    p = pr.project(rig, P)
    z = rc.range_solution(rig, p.pixels, p.ranges).depths
    q = np.concatenate([np.stack(pr.normalized_coordinates(rig, p.pixels), -1), np.ones((20, 1))], -1)
    c = q @ rig.R.T @ rig.t
    for k in range(20):
        roots = np.roots([q[k] @ q[k], 2 * c[k], rig.t @ rig.t - p.ranges[k] ** 2])
        assert z[k] == pytest.approx(roots.real.max(), rel=1e-12)
    z_thesis = (p.ranges * np.linalg.norm(q, axis=-1) - c) / np.sum(q * q, -1)
    err = np.abs(z_thesis - P[:, 2])
    assert np.all(err > 1e-4) and np.all(err < 0.05)


def test_range_solution_invalid_and_ambiguous():
    rig = Rig(R_SONAR_FROM_CAMERA_FORWARD, [0.0, -2.0, 0.0], CAM)  # camera 2 m behind the sonar
    pix = np.array([[CAM.cx, CAM.cy]] * 3)  # the central ray, through the sonar's centre
    s = rc.range_solution(rig, pix, [3.0, 1.0, 0.5])
    # r = 3 > |t|: one root, 5 m; r = 1 < |t|: the ray crosses the sphere at 1 m and 3 m.
    assert s.depths[0] == pytest.approx(5.0) and not s.ambiguous[0]
    assert s.depths[1] == pytest.approx(3.0) and s.ambiguous[1]
    assert s.valid[:2].all() and s.status[1] == 0
    # An off-axis ray that misses a small sphere.
    miss = rc.range_solution(rig, [[CAM.cx + 300, CAM.cy]], [0.5])
    assert not miss.valid[0] and miss.status[0] == 1 and np.isnan(miss.points).all()
    assert not miss and "misses the range sphere" in miss.message
    # The only crossing behind the camera.
    front = Rig(R_SONAR_FROM_CAMERA_FORWARD, [0.0, 2.0, 0.0], CAM)  # camera 2 m ahead of the sonar
    s = rc.range_solution(front, [[CAM.cx, CAM.cy]], [1.0])
    assert s.status[0] == 2 and np.isnan(s.points).all()


def test_azimuth_solution_degenerate_rigs():
    # t_x = 0: the camera centre lies in the azimuth plane theta = 0.
    behind = Rig(R_SONAR_FROM_CAMERA_FORWARD, [0.0, -0.3, 0.2], CAM)
    P = np.array([[0.0, 0.4, 3.0], [0.5, 0.4, 3.0]])
    p = pr.project(behind, P)
    assert abs(p.azimuths[0]) < 1e-15
    s = rc.azimuth_solution(behind, p.pixels, p.azimuths)
    assert s.status.tolist() == [3, 0] and np.isnan(s.points[0]).all()
    np.testing.assert_allclose(s.points[1], P[1], atol=1e-9)
    assert "azimuth plane" in s.message and bool(s)
    # Camera straight above the sonar: on the axis shared by every azimuth plane. No solution at all.
    above = Rig(R_SONAR_FROM_CAMERA_FORWARD, [0.0, 0.0, 0.3], CAM)
    p = pr.project(above, P)
    s = rc.azimuth_solution(above, p.pixels, p.azimuths)
    assert s.status.tolist() == [3, 3] and not s
    # Baseline along x: the azimuth planes at +-90 deg contain the baseline.
    side = Rig.toed_in(CAM, baseline=0.25)
    s = rc.azimuth_solution(side, [[300.0, 200.0]] * 2, [np.pi / 2, -np.pi / 2])
    assert s.status.tolist() == [3, 3] and not s
    # Near +-90 deg: valid but ill-conditioned (first-order error grows without bound).
    P = np.array([[3.0, 0.0, 0.3]])  # far to the right of the camera: theta close to 90 deg
    p = pr.project(side, P)
    s = rc.azimuth_solution(side, p.pixels, p.azimuths)
    np.testing.assert_allclose(s.points, P, atol=1e-6)
    fo = rc.first_order_mse(side, [[0.0, 0.0, 3.0], P[0]], **SIG, method="azimuth")
    assert fo.mse[1] > 10 * fo.mse[0]


def test_azimuth_solution_wrong_half_plane_and_behind():
    rig = Rig.toed_in(CAM, baseline=0.25)
    P = np.array([0.1, 0.0, 3.0])
    p = pr.project(rig, P)
    # The ray sweeps azimuths from the camera centre's (-90 deg) to its direction's (about +2 deg):
    # +0.3 rad is crossed behind the camera; azimuth + pi on the opposite half-plane.
    s = rc.azimuth_solution(rig, [p.pixels] * 2, [p.azimuths + np.pi, 0.3])
    assert s.status.tolist() == [4, 2]
    assert np.isnan(s.points).all()


def test_clip_elevation():
    spec = SonarSpec.preset("blueview-p900-90")
    rig = Rig.toed_in(CAM, baseline=0.25, sonar=spec)
    P = np.array([[0.0, 0.0, 3.0], [0.0, -0.8, 3.0]])  # the second is 15 deg up: outside +-10 deg
    p = pr.project(rig, P)
    s = rc.range_solution(rig, p.pixels, p.ranges, clip_elevation=True)
    assert s.status.tolist() == [0, 5]
    assert rc.range_solution(rig, p.pixels, p.ranges).valid.all()


def test_validation_errors():
    rig = random_rig(0)
    with pytest.raises(ValueError, match="ranges"):
        rc.range_solution(rig, np.zeros((4, 2)), np.ones(3))
    with pytest.raises(ValueError, match="azimuths"):
        rc.azimuth_solution(rig, np.zeros((4, 2)), [np.nan] * 4)
    with pytest.raises(ValueError, match="pixels"):
        rc.range_solution(rig, np.zeros((4, 3)), 1.0)
    with pytest.raises(ValueError, match="sigma_range"):
        rc.refine(rig, np.zeros((4, 2)), 1.0, 0.0, sigma_pixel=1.0, sigma_range=0.0, sigma_azimuth=0.01)
    with pytest.raises(ValueError, match="sigma_pixel"):
        rc.crlb(rig, [0, 0, 1.0], sigma_pixel=[1.0, 2.0, 3.0], sigma_range=0.01, sigma_azimuth=0.01)
    with pytest.raises(ValueError, match="method"):
        rc.refine(rig, np.zeros((4, 2)), 1.0, 0.0, **SIG, method="penalty")
    with pytest.raises(ValueError, match="method"):
        rc.first_order_mse(rig, [0, 0, 1.0], **SIG, method="stereo")
    with pytest.raises(ValueError, match="initial"):
        rc.refine(rig, np.zeros((4, 2)), 1.0, 0.0, **SIG, initial=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="rig"):
        rc.range_solution(None, np.zeros((4, 2)), 1.0)


# --------------------------------------------------------------------------- Jacobians
def _measurements(rig, P):
    p = pr.project(rig, P)
    return np.concatenate([p.pixels, p.ranges[:, None], p.azimuths[:, None]], -1)


@pytest.mark.parametrize("seed", range(4))
def test_closed_form_jacobians_equal_finite_differences(seed):
    rig, P = random_rig(seed), random_points(seed, 30)
    m = _measurements(rig, P)
    az_ok = rc.azimuth_solution(rig, m[:, :2], m[:, 3]).valid & ~rc.range_solution(rig, m[:, :2], m[:, 2]).ambiguous
    m = m[az_ok]
    steps = [1e-3, 1e-3, 1e-6, 1e-7]
    for method in ("range", "azimuth"):
        J = rc.closed_form_jacobian(rig, m[:, :2], m[:, 2], m[:, 3], method=method)
        f = (lambda mm: rc.range_solution(rig, mm[:, :2], mm[:, 2]).points) if method == "range" else \
            (lambda mm: rc.azimuth_solution(rig, mm[:, :2], mm[:, 3]).points)
        for k, h in enumerate(steps):
            e = np.zeros(4)
            e[k] = h
            fd = (8 * (f(m + e) - f(m - e)) - (f(m + 2 * e) - f(m - 2 * e))) / (12 * h)  # 4th order
            np.testing.assert_allclose(J[:, :, k], fd, rtol=1e-5, atol=1e-7 * np.abs(J).max())


def test_measurement_jacobian_equals_finite_differences():
    rig, P = random_rig(9), random_points(9, 30)
    J = rc.measurement_jacobian(rig, P)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1e-6
        fd = (_measurements(rig, P + e) - _measurements(rig, P - e)) / 2e-6
        np.testing.assert_allclose(J[:, :, k], fd, rtol=1e-6, atol=1e-6)


# --------------------------------------------------------------------------- Monte Carlo
def _mc_mse(est, P):
    e = np.sum((est - P) ** 2, -1)
    return np.nanmean(e), np.mean(np.isfinite(e))


def test_first_order_mse_matches_monte_carlo():
    """Eq. 5.10 within 15% of Monte Carlo where the linearisation holds: range solution at the
    thesis's 3 m / 0.25 m, azimuth and combined at 1.25 m / 0.5 m (parallax 0.38 rad >> 0.03 rad)."""
    cases = [("range", 0.25, 3.0), ("azimuth", 0.5, 1.25), ("combined", 0.5, 1.25), ("range", 0.5, 1.25)]
    for method, b, dist in cases:
        rig, P = thesis_setting(b, dist, 4000, seed=1)
        px, r, th = noisy(rig, P, seed=2)
        if method == "range":
            est = rc.range_solution(rig, px, r).points
        elif method == "azimuth":
            est = rc.azimuth_solution(rig, px, th).points
        else:
            est = rc.combined_solution(rig, px, r, th, **SIG).points
        mc, frac = _mc_mse(est, P)
        fo = rc.first_order_mse(rig, P, **SIG, method=method).mse.mean()
        assert frac == 1.0
        assert 0.85 < mc / fo < 1.15, (method, b, dist, mc / fo)


def test_azimuth_first_order_fails_at_3m():
    """At 3 m / 0.25 m the azimuth noise (0.03 rad) is a third of the parallax (0.08 rad): the
    depth Z = b / (a . q) is far from linear and its Monte Carlo MSE exceeds first order."""
    rig, P = thesis_setting(0.25, 3.0, 3000, seed=4)
    px, r, th = noisy(rig, P, seed=5)
    mc, _ = _mc_mse(rc.azimuth_solution(rig, px, th).points, P)
    fo = rc.first_order_mse(rig, P, **SIG, method="azimuth").mse.mean()
    assert mc / fo > 2


def test_direct_ml_reaches_the_crlb():
    """The thesis setting (0.25 m, 3 m), 3000 points: MSE / CRLB in [0.85, 1.15]; the cost is
    chi-square with 1 degree of freedom; the covariance at the optimum is the CRLB."""
    rig, P = thesis_setting(0.25, 3.0, 3000, seed=6)
    px, r, th = noisy(rig, P, seed=7)
    res = rc.refine(rig, px, r, th, **SIG)
    assert res.valid.all() and res.converged.all() and bool(res)
    crlb = rc.crlb(rig, P, **SIG)
    mse = np.mean(np.sum((res.points - P) ** 2, -1))
    ratio = mse / np.mean(np.trace(crlb, axis1=-2, axis2=-1))
    assert 0.85 < ratio < 1.15
    assert 0.9 < np.mean(res.cost) < 1.1
    tr_est = np.trace(res.covariance, axis1=-2, axis2=-1)
    np.testing.assert_allclose(np.median(tr_est / np.trace(crlb, axis1=-2, axis2=-1)), 1.0, atol=0.02)
    np.testing.assert_allclose(rc.first_order_mse(rig, P, **SIG, method="ml").covariance, crlb)
    # ML measurements are consistent: the conic / closed forms reproduce the estimate.
    m = res.measurements
    np.testing.assert_allclose(rc.range_solution(rig, m[:, :2], m[:, 2]).points, res.points, atol=1e-8)
    np.testing.assert_allclose(rc.azimuth_solution(rig, m[:, :2], m[:, 3]).points, res.points, atol=1e-6)
    # Direct beats both closed forms and their combination.
    for est in (rc.range_solution(rig, px, r).points, rc.combined_solution(rig, px, r, th, **SIG).points):
        assert mse < np.mean(np.sum((est - P) ** 2, -1))


def test_indirect_equals_direct():
    rig, P = thesis_setting(0.25, 3.0, 2000, seed=8)
    px, r, th = noisy(rig, P, seed=9)
    d = rc.refine(rig, px, r, th, **SIG, method="direct")
    i = rc.refine(rig, px, r, th, **SIG, method="indirect")
    assert i.valid.all() and d.valid.all()
    np.testing.assert_allclose(i.points, d.points, atol=1e-6)
    np.testing.assert_allclose(i.cost, d.cost, rtol=1e-6, atol=1e-9)
    mse_d, _ = _mc_mse(d.points, P)
    mse_i, _ = _mc_mse(i.points, P)
    assert mse_d <= mse_i * (1 + 1e-6)


def test_refine_batched_equals_singles_and_scipy():
    rig, P = thesis_setting(0.5, 1.25, 25, seed=10)
    px, r, th = noisy(rig, P, seed=11)
    batch = rc.refine(rig, px, r, th, **SIG)
    cam = rig.camera
    for k in range(25):
        one = rc.refine(rig, px[k], r[k], th[k], **SIG)
        assert one.points.shape == (3,)
        np.testing.assert_array_equal(one.points, batch.points[k])
        # An independent reference: scipy's LM with numeric derivatives, from the noisy range solution.

        def residual(Pk, k=k):
            pp = pr.project(rig, Pk)
            dth = np.angle(np.exp(1j * (pp.azimuths - th[k])))
            return np.concatenate([(pp.pixels - px[k]) / 2.0, [(pp.ranges - r[k]) / 0.02, dth / 0.03]])

        x0 = rc.range_solution(rig, px[k], r[k]).points
        ref = least_squares(residual, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        np.testing.assert_allclose(batch.points[k], ref.x, atol=1e-9)
        assert batch.cost[k] == pytest.approx(2 * ref.cost, rel=1e-6)
    assert cam.fx > 0


def test_refine_scipy_solver_agrees():
    """The same problem through one scipy least_squares call (block-sparse Jacobian), outliers included."""
    rig, P = thesis_setting(0.25, 3.0, 400, seed=12)
    px, r, th = noisy(rig, P, seed=13)
    r[::50] += 0.8  # gross outliers
    lm = rc.refine(rig, px, r, th, **SIG)
    sp = rc.refine(rig, px, r, th, **SIG, solver="scipy")
    assert lm.converged.all() and sp.converged.all()
    np.testing.assert_allclose(sp.points, lm.points, atol=1e-6)
    np.testing.assert_allclose(sp.cost, lm.cost, rtol=1e-6)
    with pytest.raises(ValueError, match="solver"):
        rc.refine(rig, px, r, th, **SIG, solver="ceres")


def test_refine_degenerate_inputs():
    rig = Rig.toed_in(CAM, baseline=0.25)
    # Rays that miss their range sphere and cross no azimuth half-plane ahead: no initial guess.
    res = rc.refine(rig, [[300.0, 200.0]] * 2, [0.1, 0.1], [np.pi / 2, np.pi / 2], **SIG)
    assert not res and res.status.tolist() == [7, 7] and np.isnan(res.points).all()
    assert "initial guess" in res.message
    # A user-supplied initial guess behind the camera is no guess.
    P = np.array([0.0, 0.0, 3.0])
    p = pr.project(rig, P)
    res = rc.refine(rig, p.pixels, p.ranges, p.azimuths, **SIG, initial=[0.0, 0.0, -1.0])
    assert res.status == 7
    res = rc.refine(rig, p.pixels, p.ranges, p.azimuths, **SIG, initial=[0.1, 0.1, 2.5])
    np.testing.assert_allclose(res.points, P, atol=1e-9)


def test_refine_with_distortion():
    cam = PinholeCamera(833.0, 833.0, 300.0, 200.0, 600, 400, (-0.1, 0.02, 0.0, 0.0, 0.0))
    rig = Rig.toed_in(cam, baseline=0.25, vergence=0.05)
    P = random_points(12, 50) * 0.5
    P = P[cam.visible(P)]
    p = pr.project(rig, P)
    res = rc.refine(rig, p.pixels, p.ranges, p.azimuths, **SIG)
    np.testing.assert_allclose(res.points, P, atol=1e-7)
    np.testing.assert_allclose(res.cost, 0.0, atol=1e-10)


def _degree_and_negative_cases():
    rig = random_rig(3)
    P = np.array([[1.3, 0.1, 5.0], [-0.4, 0.3, 3.0]])
    p = pr.project(rig, P)
    sig = dict(sigma_pixel=1.0, sigma_range=0.01, sigma_azimuth=0.005)
    forms = {
        "azimuth_solution": lambda r, th: rc.azimuth_solution(rig, p.pixels, th),
        "combined_solution": lambda r, th: rc.combined_solution(rig, p.pixels, r, th, **sig),
        "closed_form_jacobian": lambda r, th: rc.closed_form_jacobian(rig, p.pixels, r, th),
        "refine direct": lambda r, th: rc.refine(rig, p.pixels, r, th, **sig),
        "refine indirect": lambda r, th: rc.refine(rig, p.pixels, r, th, method="indirect", **sig),
    }
    return p, forms


@pytest.mark.parametrize("form", ["azimuth_solution", "combined_solution", "closed_form_jacobian", "refine direct",
                                  "refine indirect"])
def test_azimuths_in_degrees_and_negative_ranges_are_refused(form):
    """Degrees gave 'valid' points 0.8 m off (refine) or NaN without a word (azimuth solution); a negative range
    was used as |r| by every form that squares it. Each is refused, naming the argument and the value."""
    p, forms = _degree_and_negative_cases()
    f = forms[form]
    f(p.ranges, p.azimuths)  # the true measurements are accepted
    with pytest.raises(ValueError, match=r"azimuths: azimuths are in radians.*degrees\? use np.deg2rad"):
        f(p.ranges, np.rad2deg(p.azimuths))
    if form != "azimuth_solution":
        with pytest.raises(ValueError, match=r"ranges: must be >= 0 m .*got -[0-9.]+ at index 1"):
            f(p.ranges * np.array([1, -1]), p.azimuths)


def test_conic_refuses_a_negative_range():
    from optiacoustic.geometry import epipolar as ep

    rig = random_rig(3)
    with pytest.raises(ValueError, match=r"ranges: must be >= 0 m .*got -5"):
        ep.conic(rig, [5.0, -5.0], [0.1, 0.1])


def test_covariance_of_a_singular_fisher_matrix_is_nan_not_rounding():
    """The adjugate inverse of a rank-2 Fisher matrix is rounding noise (even negative variances): NaN instead;
    a well-conditioned one is the plain inverse."""
    rng = np.random.default_rng(4)
    J = rng.normal(size=(50, 4, 3))
    A = np.einsum("nki,nkj->nij", J, J)
    np.testing.assert_allclose(rc._cov3(A), np.linalg.inv(A), rtol=1e-9, atol=1e-12)
    Js = J.copy()
    Js[:, :, 2] = Js[:, :, 0] + 2 * Js[:, :, 1]  # rank 2: one direction unmeasured
    As = np.einsum("nki,nkj->nij", Js, Js)
    assert np.isnan(rc._cov3(As)).all()
    A_bad = A.copy()
    A_bad[3, 1, 1] = np.inf
    out = rc._cov3(A_bad)
    assert np.isnan(out[3]).all() and np.isfinite(np.delete(out, 3, axis=0)).all()
