"""Numeric proofs of the formulas of docs/derivations.md (ch. 7) (no fusion code involved)."""

import numpy as np

from optiacoustic.frames import sonar_from_spherical


def test_corrected_7_4_sonar_coordinates_of_a_pixel_and_depth(setup):
    # x_s = |R q Z + t| sin(atan2(r1.qZ + t_x, r2.qZ + t_y)), y_s likewise with cos (eq. 7.4 corrected)
    rng = np.random.default_rng(20)
    pw = np.column_stack([rng.uniform(-1, 1, (50, 2)), rng.uniform(0, 0.7, 50)])
    xy, px, _ = setup.observe(pw)
    cam, R, t = setup.rig.camera, setup.rig.R, setup.rig.t
    Z = setup.camera_pose.to_body(pw)[:, 2]
    q = np.column_stack([(px[:, 0] - cam.cx) / cam.fx, (px[:, 1] - cam.cy) / cam.fy, np.ones(len(px))])
    Ps = (q * Z[:, None]) @ R.T + t
    r = np.linalg.norm(Ps, axis=1)
    th = np.arctan2(Ps[:, 0], Ps[:, 1])
    np.testing.assert_allclose(np.column_stack([r * np.sin(th), r * np.cos(th)]), xy, atol=1e-12)
    # and (x_s, y_s) = (X_s, Y_s) / cos(phi): the fan is the horizontal projection stretched by 1/cos(phi)
    ph = np.arctan2(Ps[:, 2], np.hypot(Ps[:, 0], Ps[:, 1]))
    np.testing.assert_allclose(xy * np.cos(ph)[:, None], Ps[:, :2], atol=1e-12)


def test_a_plane_induces_a_homography_at_zero_elevation(setup):
    # plane n.P_s = d; with X_s = x_s, Y_s = y_s, Z_s = (d - n_x x_s - n_y y_s) / n_z the pixel is
    # H (x_s, y_s, 1) with H = K R^T (M - t e3^T): exact at phi = 0, off by O(phi^2) elsewhere
    rig = setup.rig
    n_w = np.array([0.0, 0.0, 1.0])  # the seabed z = 0, in the sonar frame: (R^T n_w) . P_s = 0 - n_w . t
    n = setup.sonar_pose.R.T @ n_w
    d = 0.0 - n_w @ setup.sonar_pose.t
    M = np.array([[1, 0, 0], [0, 1, 0], [-n[0] / n[2], -n[1] / n[2], d / n[2]]])
    H = rig.camera.K @ rig.R.T @ (M - np.outer(rig.t, [0, 0, 1]))

    def through_h(xs, ys):
        h = np.column_stack([xs, ys, np.ones_like(xs)]) @ H.T
        return h[:, :2] / h[:, 2:]

    def on_plane(th, ph):
        u = sonar_from_spherical(1.0, th, ph)
        r = d / (u @ n)
        return sonar_from_spherical(r, th, ph), r

    th = np.linspace(-0.3, 0.3, 21)

    def error(ph_deg):
        P, r = on_plane(th, np.deg2rad(ph_deg))
        pix = rig.camera.project(rig.camera_from_sonar(P))
        return np.linalg.norm(through_h(r * np.sin(th), r * np.cos(th)) - pix, axis=1)

    assert error(0.0).max() < 1e-8
    e5, e10 = error(5.0), error(10.0)
    assert e5.min() > 0.1  # not exact off the zero-elevation line
    assert 3.0 < np.median(e10 / e5) < 5.0  # quadratic in phi: (10 / 5)^2 = 4
