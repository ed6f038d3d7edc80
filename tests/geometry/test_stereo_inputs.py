"""Stereo baseline on degenerate geometry and caller mistakes: analytic truths, not the code's own numbers."""

import numpy as np
import pytest

from optiacoustic import PinholeCamera, Rig
from optiacoustic.geometry import stereo as st

CAM = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
DIST = PinholeCamera(fx=800.0, fy=800.0, cx=299.5, cy=199.5, width=600, height=400,
                     dist=(-0.25, 0.08, 0.001, -0.0005, 0.0))


def toed_in():
    return st.StereoRig.from_rig(Rig.toed_in(CAM, baseline=0.25, vergence=np.deg2rad(2.3)))


def rectified(b, cam=CAM):
    """Camera 2 a distance b to the right of camera 1, same orientation: P_2 = P_1 - (b, 0, 0)."""
    return st.StereoRig(np.eye(3), np.array([-b, 0.0, 0.0]), cam, cam)


def test_point_at_infinity_is_invalid_in_the_optimal_triangulation_too():
    stereo = toed_in()
    d = np.array([0.1, 0.05, 1.0])  # one direction seen by both cameras: parallel rays
    u1, u2 = CAM.project(d), CAM.project(stereo.R @ d)
    lin = st.triangulate_linear(stereo, u1, u2)
    opt = st.triangulate_optimal(stereo, u1, u2)
    assert lin.status == 3 and opt.status == 3
    assert not opt and not opt.valid and np.isnan(opt.points).all() and np.isnan(opt.covariance).all()
    assert np.isnan(opt.cost)
    # stereo's own words, not the opti-acoustic azimuth plane
    for res in (lin, opt):
        assert "parallel" in res.message and "azimuth" not in res.message
    # a batch: the finite point next to it is untouched
    P = np.array([0.1, 0.05, 3.0])
    p = st.project(stereo, P)
    both = st.triangulate_optimal(stereo, np.stack([u1, p.pixels1]), np.stack([u2, p.pixels2]))
    assert both.status.tolist() == [3, 0]
    np.testing.assert_allclose(both.points[1], P, atol=1e-9)


def test_far_points_stay_valid_with_the_analytic_depth_bound():
    # rectified pair, point on camera 1's axis: var Z = 2 Z^4 sigma^2 / (f b)^2, var X = Z^2 sigma^2 / f^2,
    # cov XZ = -Z^3 sigma^2 / (f^2 b), var Y = Z^2 sigma^2 / (2 f^2)
    b, s, f = 0.25, 1.5, CAM.fx
    stereo = rectified(b)
    for Z in (3.0, 1e3, 1e5):
        c = st.crlb(stereo, [0.0, 0.0, Z], sigma_pixel=s)
        k = s**2 / f**2
        want = np.array([[Z**2 * k, 0, -Z**3 * k / b], [0, Z**2 * k / 2, 0], [-Z**3 * k / b, 0, 2 * Z**4 * k / b**2]])
        np.testing.assert_allclose(c, want, rtol=1e-6, atol=1e-9 * Z**2 * k)
        p = st.project(stereo, [0.0, 0.0, Z])
        opt = st.triangulate_optimal(stereo, p.pixels1, p.pixels2, sigma_pixel=s)
        assert opt.status == 0
        np.testing.assert_allclose(opt.covariance, want, rtol=1e-5, atol=1e-9 * Z**2 * k)


def test_zero_baseline_leaves_depth_undetermined():
    stereo = st.StereoRig(np.eye(3), np.zeros(3), CAM, CAM)
    rng = np.random.default_rng(8)
    P = np.c_[rng.uniform(-1, 1, (200, 2)), rng.uniform(2, 8, 200)]
    c = st.crlb(stereo, P)
    assert np.isnan(c).all()  # singular Fisher matrix: no negative or huge "variances"
    assert np.isnan(st.first_order_mse(stereo, P, method="optimal").mse).all()
    assert np.isnan(st.first_order_mse(stereo, P, method="linear").mse).all()
    p = st.project(stereo, P)
    lin = st.triangulate_linear(stereo, p.pixels1, p.pixels2)
    assert (lin.status == 3).all() and np.isnan(lin.points).all()  # not a depth picked by the SVD
    opt = st.triangulate_optimal(stereo, p.pixels1, p.pixels2)
    assert not opt.valid.any() and np.isnan(opt.points).all()
    opt = st.triangulate_optimal(stereo, p.pixels1, p.pixels2, initial=P)
    assert not opt.valid.any() and np.isnan(opt.covariance).all()


def test_point_on_the_baseline_is_undetermined():
    # camera 2 straight behind camera 1 on its optical axis: both see an axis point at the principal
    # point, the two rays coincide along the baseline and any depth fits
    stereo = st.StereoRig(np.eye(3), np.array([0.0, 0.0, 0.5]), CAM, CAM)
    c = np.array([CAM.cx, CAM.cy])
    lin = st.triangulate_linear(stereo, c, c)
    assert lin.status == 3
    assert np.isnan(st.crlb(stereo, [0.0, 0.0, 4.0])).all()


def test_points_behind_a_camera_are_masked():
    stereo = toed_in()
    P = np.array([[0.1, 0.1, -3.0], [0.1, 0.1, 3.0]])
    c = st.crlb(stereo, P)
    assert np.isnan(c[0]).all() and np.isfinite(c[1]).all()
    for method in ("linear", "optimal"):
        fo = st.first_order_mse(stereo, P, method=method)
        assert np.isnan(fo.mse[0]) and np.isfinite(fo.mse[1]) and fo.mse[1] > 0
    # in front of camera 1, behind camera 2 (camera 2 one metre ahead on the axis, looking back)
    back = st.StereoRig(np.diag([-1.0, 1.0, -1.0]), np.array([0.0, 0.0, 1.0]), CAM, CAM)
    assert np.isnan(st.crlb(back, [0.0, 0.1, 2.0])).all()
    assert np.isnan(st.first_order_mse(back, [0.0, 0.1, 2.0]).mse)


def test_first_order_linear_error_does_not_depend_on_distortion():
    # the noise is on ideal pixels: a distorted camera with the same pinhole gives the same error
    rng = np.random.default_rng(3)
    P = np.c_[rng.uniform(-0.4, 0.4, (50, 2)), rng.uniform(2, 6, 50)]
    ideal = PinholeCamera(fx=800.0, fy=800.0, cx=299.5, cy=199.5, width=600, height=400)
    a = st.first_order_mse(rectified(0.3, ideal), P, sigma_pixel=1.0).covariance
    b = st.first_order_mse(rectified(0.3, DIST), P, sigma_pixel=1.0).covariance
    np.testing.assert_allclose(b, a, rtol=1e-5)


def test_optimal_measurements_are_ideal_pixels():
    stereo = rectified(0.3, DIST)
    rng = np.random.default_rng(12)
    P = np.c_[rng.uniform(-0.5, 0.5, (100, 2)), rng.uniform(2, 8, 100)]
    p = st.project(stereo, P)
    v = p.visible
    opt = st.triangulate_optimal(stereo, p.pixels1[v], p.pixels2[v])
    np.testing.assert_allclose(opt.points, P[v], atol=1e-8)
    f, c = np.array([DIST.fx, DIST.fy]), np.array([DIST.cx, DIST.cy])
    P2 = P[v] + np.array([-0.3, 0.0, 0.0])  # P_2 = R P_1 + t
    want = np.concatenate([f * P[v][:, :2] / P[v][:, 2:] + c, f * P2[:, :2] / P2[:, 2:] + c], -1)
    np.testing.assert_allclose(opt.measurements, want, atol=1e-6)
    assert np.max(np.abs(p.pixels1[v] - want[:, :2])) > 1.0  # the distortion is not negligible here


@pytest.mark.parametrize("bad", [True, np.True_, 0, -3, 2.5, "10"])
def test_max_iter_must_be_a_positive_integer(bad):
    stereo = toed_in()
    p = st.project(stereo, [0.1, 0.0, 3.0])
    with pytest.raises(ValueError, match=r"max_iter: .*" + str(bad)[:2]):
        st.triangulate_optimal(stereo, p.pixels1, p.pixels2, max_iter=bad)
