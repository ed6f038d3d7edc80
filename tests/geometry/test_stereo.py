"""The stereo-optical baseline: DLT against OpenCV, optimal triangulation against the CRLB and scipy."""

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares

from optiacoustic import PinholeCamera, Rig
from optiacoustic.frames import R_SONAR_FROM_CAMERA_FORWARD
from optiacoustic.geometry import stereo as st

CAM = PinholeCamera.from_sensor(600, 400, (36, 24), 50)


def setting(baseline, distance, n, seed=0):
    rig = Rig.toed_in(CAM, baseline=baseline, vergence=np.arctan(baseline / distance))
    rng = np.random.default_rng(seed)
    target = np.array([baseline / 2, 0.0, np.hypot(baseline / 2, distance)])
    P = target + rng.uniform(-1, 1, (n, 3)) * [0.3, 0.2, 0.3]
    return st.StereoRig.from_rig(rig), rig, P


def noisy(stereo, P, seed, sigma=2.0):
    p = st.project(stereo, P)
    e = np.random.default_rng(seed).standard_normal(P.shape[:-1] + (4,)) * sigma
    return p.pixels1 + e[..., :2], p.pixels2 + e[..., 2:]


def test_second_camera_replaces_the_sonar():
    stereo, rig, P = setting(0.25, 3.0, 50)
    # Camera 2 sits at the sonar's centre with the axes of a forward-looking camera.
    P2 = P @ stereo.R.T + stereo.t
    np.testing.assert_allclose(P2, rig.sonar_from_camera(P) @ R_SONAR_FROM_CAMERA_FORWARD, atol=1e-12)
    assert stereo.baseline == pytest.approx(rig.baseline)
    assert st.project(stereo, P).visible.all()


def test_linear_exact_and_equal_to_opencv():
    stereo, _, P = setting(0.25, 3.0, 500)
    p = st.project(stereo, P)
    lin = st.triangulate_linear(stereo, p.pixels1, p.pixels2)
    np.testing.assert_allclose(lin.points, P, atol=1e-10)
    P1, P2 = stereo.projection_matrices()
    X = cv2.triangulatePoints(P1, P2, p.pixels1.T.copy(), p.pixels2.T.copy())
    np.testing.assert_allclose((X[:3] / X[3]).T, P, atol=1e-9)
    # With noise both are DLTs of the same data (their row scaling differs): close, not equal.
    u1, u2 = noisy(stereo, P, seed=1)
    lin = st.triangulate_linear(stereo, u1, u2)
    X = cv2.triangulatePoints(P1, P2, u1.T.copy(), u2.T.copy())
    diff = np.linalg.norm((X[:3] / X[3]).T - lin.points, axis=-1)
    err = np.linalg.norm(lin.points - P, axis=-1)
    assert np.median(diff) < 0.05 * np.median(err)


def test_optimal_reaches_crlb_and_beats_linear():
    stereo, _, P = setting(0.25, 3.0, 3000, seed=2)
    u1, u2 = noisy(stereo, P, seed=3)
    lin = st.triangulate_linear(stereo, u1, u2)
    opt = st.triangulate_optimal(stereo, u1, u2, sigma_pixel=2.0)
    assert opt.valid.all() and opt.converged.all()
    crlb = np.trace(st.crlb(stereo, P, sigma_pixel=2.0), axis1=-2, axis2=-1).mean()
    mse = np.mean(np.sum((opt.points - P) ** 2, -1))
    assert 0.85 < mse / crlb < 1.15
    assert 0.9 < np.mean(opt.cost) < 1.1
    # The optimum's reprojection error is never above the linear estimate's.
    pl = st.project(stereo, lin.points)
    cost_lin = (np.sum((pl.pixels1 - u1) ** 2, -1) + np.sum((pl.pixels2 - u2) ** 2, -1)) / 4.0
    assert np.all(opt.cost <= cost_lin * (1 + 1e-9))
    assert np.mean(opt.cost) < np.mean(cost_lin)
    # First-order prediction of the DLT within 15% of Monte Carlo.
    fo = st.first_order_mse(stereo, P, sigma_pixel=2.0, method="linear").mse.mean()
    mc = np.mean(np.sum((lin.points - P) ** 2, -1))
    assert 0.85 < mc / fo < 1.15


def test_optimal_batched_equals_singles_and_scipy():
    stereo, _, P = setting(0.5, 1.25, 15, seed=4)
    u1, u2 = noisy(stereo, P, seed=5)
    batch = st.triangulate_optimal(stereo, u1, u2, sigma_pixel=2.0)
    for k in range(15):
        one = st.triangulate_optimal(stereo, u1[k], u2[k], sigma_pixel=2.0)
        np.testing.assert_array_equal(one.points, batch.points[k])

        def residual(X, k=k):
            p = st.project(stereo, X)
            return np.concatenate([p.pixels1 - u1[k], p.pixels2 - u2[k]]) / 2.0

        ref = least_squares(residual, P[k] + 0.01, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        np.testing.assert_allclose(batch.points[k], ref.x, atol=1e-9)


def test_degenerate_and_invalid():
    stereo, _, P = setting(0.25, 3.0, 3)
    # Parallel rays: the same direction seen from both centres (a point at infinity).
    d = np.array([0.05, 0.02, 1.0])
    u1 = CAM.project(d)
    u2 = stereo.camera2.project(stereo.R @ d)
    lin = st.triangulate_linear(stereo, u1, u2)
    assert not lin and lin.status == 3 and np.isnan(lin.points).all()
    # Rays that meet behind the cameras.
    p = st.project(stereo, P[0])
    behind = st.triangulate_linear(stereo, p.pixels1 - [40.0, 0.0], p.pixels2 + [40.0, 0.0])
    assert behind.status == 2
    opt = st.triangulate_optimal(stereo, p.pixels1 - [40.0, 0.0], p.pixels2 + [40.0, 0.0])
    assert opt.status == 7 and not opt
    with pytest.raises(ValueError, match="pixels2"):
        st.triangulate_linear(stereo, np.zeros((4, 2)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="sigma_pixel"):
        st.triangulate_optimal(stereo, np.zeros((4, 2)), np.zeros((4, 2)), sigma_pixel=-1)
    with pytest.raises(ValueError, match="stereo"):
        st.triangulate_linear("rig", np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="StereoRig.R"):
        st.StereoRig(np.eye(3) * 2, np.zeros(3), CAM, CAM)
