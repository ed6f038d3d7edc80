"""The bundle's numba kernels (:mod:`optiacoustic.geometry._kernels`) against the numpy reference.

``OAS_KERNELS=numpy`` selects ``Problem._residual_numpy`` / ``_lm_numpy`` / ``_converged`` and
the numpy projection; the kernels do the same arithmetic one point at a time, so both paths
must agree to rounding on seeded problems (one plane, two planes, free points; camera and
sonar channels; both elevation branches), and ``motion.estimate`` must give the same motion.
"""

from __future__ import annotations

import numpy as np
import pytest

from optiacoustic.geometry import _bundle as B
from optiacoustic.geometry import motion

from .test_motion import PLANE_C, PLANE_N, RIG, SA, SIG, SP, SR, plane_points, plane_truth, views


def _problems(rng):
    """Seeded variable-projection problems: one plane, two planes, free points."""
    D = views(rng, plane_points(rng, 4000, PLANE_C, PLANE_N, 3.0), n_opt=40, n_son=15, noise=1.0)
    d = motion._data(RIG, D["p1"], D["p2"], D["s1"], D["s2"], SP, SR, SA)
    n, dist = plane_truth(D["c1"], PLANE_C, PLANE_N)
    m1 = (n / dist)[None]
    m2 = np.stack([n / dist, n / dist + [0.1, -0.05, 0.08]])
    lo, ls = rng.integers(0, 2, 40), rng.integers(0, 2, 15)
    out = []
    for model, m, lo_, ls_ in (("plane", m1, lo * 0, ls * 0), ("plane", m2, lo, ls), ("free", np.zeros((0, 3)), lo * 0,
                                                                                        ls * 0)):
        prob = motion._problem(d, lo_, ls_, model, D["R_o"], m)[0]
        th = motion._theta(D["t_o"], m) + rng.normal(0, 0.01, 6 + 3 * len(m) * (model == "plane"))
        out.append((prob, th))
    return out


def _starts(prob, blk, th, rng):
    Rv, cv, pl = prob.unpack(th)
    p0 = np.asarray(blk.init(Rv, cv, pl, blk.plane), float)
    p0 = p0[:, 0] if p0.ndim == 3 else p0
    return np.where(np.isfinite(p0), p0, 0.1) + rng.normal(0, 1e-3, p0.shape)


def test_kernel_residuals_jacobians_and_point_solve_equal_numpy():
    rng = np.random.default_rng(21)
    for prob, th in _problems(rng):
        Rv, cv, pl = prob.unpack(th)
        for blk in prob.blocks:
            m = pl[blk.plane] if blk.model == "plane" else None
            p = _starts(prob, blk, th, rng)
            prob.kernels = True
            e1, Jp1, Jt1 = prob._residual(blk, p, m, Rv, cv, th[:3], want_theta=True)
            q1, c1 = prob._lm(blk, p, m, Rv, cv, th[:3], blk.meas)
            conv1 = prob._converged(e1, Jp1, 1e-8)
            Y1, Jr1 = prob._project(Jp1, Jt1)
            prob.kernels = False
            e0, Jp0, Jt0 = prob._residual(blk, p, m, Rv, cv, th[:3], want_theta=True)
            q0, c0 = prob._lm(blk, p, m, Rv, cv, th[:3], blk.meas)
            conv0 = prob._converged(e0, Jp0, 1e-8)
            Y0, Jr0 = prob._project(Jp0, Jt0)
            for a, b in ((e1, e0), (Jp1, Jp0), (Jt1, Jt0), (Y1, Y0), (Jr1, Jr0)):
                assert a.shape == b.shape
                assert np.allclose(a, b, rtol=1e-11, atol=1e-11 * np.abs(b).max())
            assert np.allclose(q1, q0, rtol=1e-9, atol=1e-12)
            assert np.allclose(c1, c0, rtol=1e-9, atol=1e-12)
            assert np.array_equal(conv1, conv0)
            assert np.all(c1 <= np.einsum("nr,nr->n", e0, e0) * (1 + 1e-12))  # the solve descended
            assert not conv1.all()  # (the starts are off the optimum: the test has points to solve)


def test_fused_evaluation_equals_the_stepwise_one():
    # Problem._evaluate: one kernel call per block (warm path) against solve_points + the
    # numpy projection, along a few outer steps from the same start
    rng = np.random.default_rng(22)
    for prob, th in _problems(rng):
        ref = B.Problem(prob.K, prob.blocks, prob.k, prob.R_ref)
        ref.inner_rtol, ref.kernels = prob.inner_rtol, False
        prob.kernels = True
        for P in (prob, ref):
            P._branches_fixed = False
            for b in P.blocks:
                P.solve_points(b, th)
            P._branches_fixed = True
        for step in range(4):
            t = th + step * rng.normal(0, 2e-3, th.size)
            e1, J1 = prob._evaluate(t)
            e0, J0 = ref._evaluate(t)
            assert np.allclose(e1, e0, rtol=1e-9, atol=1e-9)
            assert np.allclose(J1, J0, rtol=1e-7, atol=1e-9 * np.abs(J0).max())


@pytest.mark.parametrize("planes", [1, "auto"])
def test_motion_estimate_is_the_same_with_either_path(monkeypatch, planes):
    rng = np.random.default_rng(23)
    D = views(rng, plane_points(rng, 4000, PLANE_C, PLANE_N, 3.0), noise=1.0, outliers=0.2)
    res = {}
    for k in ("numpy", "numba"):
        monkeypatch.setenv("OAS_KERNELS", k)
        res[k] = motion.estimate(RIG, D["p1"], D["p2"], D["s1"], D["s2"], planes=planes, **SIG)
    a, b = res["numpy"], res["numba"]
    assert a and b
    assert np.array_equal(a.inliers_optical, b.inliers_optical)
    assert np.array_equal(a.inliers_sonar, b.inliers_sonar)
    sd = np.sqrt(np.diag(a.covariance_motion))
    dw = B.log_so3(b.R_o @ a.R_o.T)
    assert np.all(np.abs(np.r_[dw, b.t_o - a.t_o]) < 1e-6 * sd)
    assert np.allclose(b.covariance_motion, a.covariance_motion, rtol=1e-6, atol=0)


def test_the_switch_selects_the_numpy_reference(monkeypatch):
    rng = np.random.default_rng(24)
    prob, _ = _problems(rng)[0]
    assert prob.kernels  # default: numba
    monkeypatch.setenv("OAS_KERNELS", "numpy")
    prob, _ = _problems(rng)[0]
    assert not prob.kernels


def test_scale_searches_in_the_kernel_equal_numpy(monkeypatch):
    # the per-match golden-section searches of the elevation (plane and five-point paths):
    # the same steps one match at a time; they may part only where two chi-squares tie to
    # rounding near the minimum, so the elevations agree far below the aperture's resolution
    from .test_motion import S1, S2

    rng = np.random.default_rng(25)
    D = views(rng, plane_points(rng, 4000, PLANE_C, PLANE_N, 3.0), noise=1.0, s1=S1, s2=S2)
    d = motion._data(RIG, D["p1"], D["p2"], D["s1"], D["s2"], SP, SR, SA)
    n, dist = plane_truth(D["c1"], PLANE_C, PLANE_N)
    sol = motion.MonocularSolution(D["R_o"], D["t_o"] / dist, n)
    t_dir = D["t_o"] / np.linalg.norm(D["t_o"])
    out = {}
    for k in ("numpy", "numba"):
        monkeypatch.setenv("OAS_KERNELS", k)
        out[k] = motion._plane_scale(d, sol), motion._essential_scale(d, D["R_o"], t_dir)
    (do0, phi0, c0), (s0, cs0) = out["numpy"]
    (do1, phi1, c1), (s1, cs1) = out["numba"]
    assert np.isfinite(c0).sum() > 40 and np.isfinite(cs0).sum() > 40
    assert np.array_equal(np.isfinite(c0), np.isfinite(c1)) and np.array_equal(np.isfinite(cs0), np.isfinite(cs1))
    ok, oks = np.isfinite(c0), np.isfinite(cs0)
    assert np.allclose(phi1[ok], phi0[ok], rtol=0, atol=1e-6)  # rad (seen: 1.2e-7 over 10 seeds)
    assert np.allclose(do1[ok], do0[ok], rtol=1e-6)
    assert np.allclose(c1[ok], c0[ok], rtol=1e-6, atol=1e-9)
    assert np.allclose(s1[oks], s0[oks], rtol=1e-6)
    assert np.allclose(cs1[oks], cs0[oks], rtol=1e-6, atol=1e-9)
    # the plane's distance from most single matches is the true one within their noise
    assert np.median(np.abs(do1[ok] - dist)) < 0.05 * dist


def test_the_outer_solve_through_leastsq_is_least_squares_lm():
    # Problem._least_squares calls MINPACK's lmder through scipy's leastsq (a thinner wrapper):
    # the same call as least_squares(method="lm", x_scale="jac"), so the same iterates
    rng = np.random.default_rng(26)
    for prob, th in _problems(rng):
        out = []
        for fast in (True, False):
            P = B.Problem(prob.K, prob.blocks, prob.k, prob.R_ref)
            P.inner_rtol, P.ftol, P.fast_outer = prob.inner_rtol, prob.ftol, fast
            sol = P.solve(th, max_nfev=50)
            out.append((sol, P.residuals(sol.x)))
        (a, ea), (b, eb) = out
        assert np.array_equal(a.x, b.x) and a.nfev == b.nfev
        assert a.cost == b.cost and np.array_equal(ea, eb)
        assert a.cost < 0.5 * float(prob.residuals(th) @ prob.residuals(th))  # (it did descend)
