"""Two-view sonar triangulation (appendix B): identities, noise-free recovery, Monte Carlo, degeneracies."""

import numpy as np
import pytest
from scipy.stats import chi2

from optiacoustic.frames import rot_x, rot_y, rot_z, sonar_from_spherical, spherical_from_sonar
from optiacoustic.geometry import sonar_stereo as ss
from optiacoustic.geometry.sonar_stereo import _linear_system, _whitened

FOV = np.deg2rad(20.0)
SR, SA = 0.01, np.deg2rad(0.2)


def points(rng, n, r=(1.0, 3.0), half_el=np.deg2rad(9.0)):
    return sonar_from_spherical(rng.uniform(*r, n), rng.uniform(-0.7, 0.7, n), rng.uniform(-half_el, half_el, n))


# a motion with heave and pitch: elevation parallax
R_GOOD, T_GOOD = rot_x(0.15) @ rot_z(0.1), np.array([0.2, 0.1, 0.4])


def test_measure_is_the_spherical_projection_in_both_views():
    rng = np.random.default_rng(0)
    P = points(rng, 50)
    m = ss.measure(P, R_GOOD, T_GOOD)
    r2, th2, ph2 = spherical_from_sonar(P @ R_GOOD.T + T_GOOD)
    assert np.allclose(m.ranges_2, r2) and np.allclose(m.azimuths_2, th2) and np.allclose(m.elevations_2, ph2)
    assert np.allclose(m.ranges_1, np.linalg.norm(P, axis=1))


def test_linear_rows_B1_B2_hold_for_true_points_and_b3_needs_the_correction():
    rng = np.random.default_rng(1)
    for _ in range(5):
        R = rot_z(rng.normal(0, 0.2)) @ rot_y(rng.normal(0, 0.2)) @ rot_x(rng.normal(0, 0.2))
        t = rng.normal(0, 0.3, 3)
        P = points(rng, 40)
        m = ss.measure(P, R, t)
        A, b = _linear_system(m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, R, t)
        assert np.allclose(np.einsum("nij,nj->ni", A, P), b, atol=1e-10)
        # the thesis's (b3) = r'^2 - r^2 - |t|^2 / 2 does not hold
        b3_thesis = m.ranges_2**2 - m.ranges_1**2 - t @ t / 2
        assert np.max(np.abs(np.einsum("ni,ni->n", A[:, 2], P) - b3_thesis)) > 1e-3


def test_closed_forms_and_ml_recover_noise_free_points():
    rng = np.random.default_rng(2)
    P = points(rng, 100)
    m = ss.measure(P, R_GOOD, T_GOOD)
    cf = ss.closed_forms(m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, R_GOOD, T_GOOD)
    for name in ("b3", "b5", "b7"):
        assert np.max(np.abs(getattr(cf, name) - P)) < 1e-9, name
    # one of the two roots of the azimuth planes and the range sphere is the point
    err = np.min(np.linalg.norm(cf.planes - P[:, None], axis=2), axis=1)
    assert err.max() < 1e-8
    for method in ("ml", "b3", "b5", "b7", "planes"):
        # at 1 mm / 0.02 deg noise no second root fits (at 1 cm a few points are truly ambiguous)
        res = ss.triangulate(m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, R_GOOD, T_GOOD,
                             fov_elevation=FOV, method=method, sigma_range=1e-3, sigma_azimuth=SA / 10)
        assert res and np.max(np.abs(res.points - P)) < 1e-6, method
        assert not res.degenerate.any() and not res.ambiguous.any()


def test_batched_equals_a_loop_of_singles():
    rng = np.random.default_rng(3)
    P = points(rng, 12)
    m = ss.measure(P, R_GOOD, T_GOOD)
    noisy = [x + rng.normal(0, s, x.shape) for x, s in
             ((m.ranges_1, SR), (m.azimuths_1, SA), (m.ranges_2, SR), (m.azimuths_2, SA))]
    batch = ss.triangulate(*noisy, R_GOOD, T_GOOD, fov_elevation=FOV)
    for i in range(len(P)):
        one = ss.triangulate(*(x[i:i + 1] for x in noisy), R_GOOD, T_GOOD, fov_elevation=FOV)
        assert np.allclose(one.points[0], batch.points[i], atol=1e-7)
        assert np.allclose(one.covariance[0], batch.covariance[i], rtol=1e-5)


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(4)
    n = 20
    x = np.stack([rng.uniform(1, 3, n), rng.uniform(-0.6, 0.6, n), rng.uniform(-0.15, 0.15, n)], -1)
    meas = [rng.uniform(1, 3, n), rng.uniform(-0.6, 0.6, n), rng.uniform(1, 3, n), rng.uniform(-0.6, 0.6, n)]
    e, J, _ = _whitened(x, *meas, R_GOOD, T_GOOD, SR, SA)
    h = 1e-7
    for k in range(3):
        dx = np.zeros(3)
        dx[k] = h
        ep = _whitened(x + dx, *meas, R_GOOD, T_GOOD, SR, SA)[0]
        em = _whitened(x - dx, *meas, R_GOOD, T_GOOD, SR, SA)[0]
        assert np.allclose((ep - em) / (2 * h), J[:, :, k], rtol=1e-5, atol=1e-3)


def test_monte_carlo_ml_is_consistent_and_beats_the_linear_closed_form():
    # 5 mm / 0.1 deg: the elevation's standard deviation is about 1 deg, where first order holds
    # (at 1 cm it is 2 deg and the average NEES creeps a few percent above 3)
    sr, sa = 0.005, np.deg2rad(0.1)
    rng = np.random.default_rng(5)
    P = points(rng, 60)
    m = ss.measure(P, R_GOOD, T_GOOD)
    nees, e_ml, e_b3 = [], [], []
    for _ in range(20):
        noisy = [x + rng.normal(0, s, x.shape) for x, s in
                 ((m.ranges_1, sr), (m.azimuths_1, sa), (m.ranges_2, sr), (m.azimuths_2, sa))]
        res = ss.triangulate(*noisy, R_GOOD, T_GOOD, sigma_range=sr, sigma_azimuth=sa, fov_elevation=FOV)
        b3 = ss.closed_forms(*noisy, R_GOOD, T_GOOD).b3
        v = res.valid
        d = res.points - P
        nees.append(np.einsum("ni,nij,nj->n", d[v], np.linalg.inv(res.covariance[v]), d[v]))
        e_ml.append(np.linalg.norm(d, axis=1))
        e_b3.append(np.linalg.norm(b3 - P, axis=1))
    nees = np.concatenate(nees)
    k = nees.size
    lo, hi = chi2.ppf([0.025, 0.975], 3 * k) / k
    assert lo < nees.mean() < hi
    rms_ml = np.sqrt(np.mean(np.concatenate(e_ml) ** 2))
    rms_b3 = np.sqrt(np.nanmean(np.concatenate(e_b3) ** 2))
    assert 1e-3 < rms_ml < 0.05  # errors are there, and they are cm-level (the elevation's ~1 deg)
    assert rms_ml < rms_b3


def test_pure_rotation_is_flagged_b3_is_singular_and_the_planes_form_still_triangulates():
    rng = np.random.default_rng(6)
    P = points(rng, 50)
    R = rot_x(0.1) @ rot_z(0.1)
    m = ss.measure(P, R, np.zeros(3))
    res = ss.triangulate(m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, R, np.zeros(3), fov_elevation=FOV)
    assert res.flags == ("pure_rotation",) and "pure_rotation" in res.message
    assert np.all(np.isnan(res.closed.b3)) and np.all(~np.isfinite(res.condition) | (res.condition > 1e8))
    ok = res.valid
    assert ok.any()
    assert np.max(np.abs(res.points[ok] - P[ok])) < 1e-6
    # a yaw about the sonar centre tells nothing about elevation: every point degenerate, falsy
    m2 = ss.measure(P, rot_z(0.1), np.zeros(3))
    res2 = ss.triangulate(m2.ranges_1, m2.azimuths_1, m2.ranges_2, m2.azimuths_2, rot_z(0.1), np.zeros(3),
                          fov_elevation=FOV)
    assert not res2 and res2.degenerate.all()
    assert "pure rotation" in res2.message and "planar_motion" in res2.flags


def test_motion_within_the_azimuth_plane_is_ambiguous_and_falsy():
    rng = np.random.default_rng(7)
    P = points(rng, 50, half_el=np.deg2rad(9))
    R, t = rot_z(0.1), np.array([0.6, 0.3, 0.0])
    m = ss.measure(P, R, t)
    res = ss.triangulate(m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, R, t, fov_elevation=FOV)
    assert res.flags == ("planar_motion",)
    assert not res
    assert (res.ambiguous | res.degenerate).all()
    assert "azimuth plane" in res.message
    # (B.3) is singular for every point
    assert np.all(np.isnan(res.closed.b3))
    # the mirror image fits exactly as well: both roots of the planes form reproduce the measurements
    mirror = P * np.array([1, 1, -1])
    mm = ss.measure(mirror, R, t)
    assert np.allclose(mm.ranges_2, m.ranges_2) and np.allclose(mm.azimuths_2, m.azimuths_2)


def test_radical_form_is_exact_for_general_motion_and_for_heave_where_the_azimuth_planes_coincide():
    rng = np.random.default_rng(8)
    P = points(rng, 80)
    m = ss.measure(P, R_GOOD, T_GOOD)
    cf = ss.closed_forms(m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, R_GOOD, T_GOOD)
    assert np.min(np.linalg.norm(cf.radical - P[:, None], axis=2), axis=1).max() < 1e-8
    # pure heave: azimuth preserved, so both azimuth planes are the same plane; Z = (r'^2 - r^2 - h^2) / 2h
    t = np.array([0.0, 0.0, 0.5])
    m = ss.measure(P, np.eye(3), t)
    assert np.allclose(m.azimuths_2, m.azimuths_1)
    z = (m.ranges_2**2 - m.ranges_1**2 - 0.25) / (2 * 0.5)
    assert np.allclose(z, P[:, 2], atol=1e-12)
    cf = ss.closed_forms(m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, np.eye(3), t)
    assert np.all(np.isnan(cf.b3)) and np.all(np.isnan(cf.planes))
    # one root ahead of the sonar (the point), the other behind it
    err = np.linalg.norm(cf.radical - P[:, None], axis=2)
    near = np.argmin(err, axis=1)
    assert np.max(err[np.arange(len(P)), near]) < 1e-9
    assert np.all(cf.radical[np.arange(len(P)), 1 - near, 1] < 0)


@pytest.mark.parametrize("sway", [0.0, 1e-9, 1e-6, 1e-2])
def test_heave_triangulates_every_point_and_a_little_sway_changes_nothing(sway):
    rng = np.random.default_rng(9)
    P = points(rng, 100)
    R, t = np.eye(3), np.array([sway, 0.0, 0.5])
    m = ss.measure(P, R, t)
    res = ss.triangulate(m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, R, t, fov_elevation=FOV)
    assert res.flags == () and res.valid.all(), res.message
    assert np.max(np.abs(res.points - P)) < 1e-9
    # the elevation's first-order std, by hand: only r and r'^2 = r^2 + 2 h r sin(phi) + h^2 carry it;
    # with a = dr'/dr, b = dr'/dphi the (r, phi) information is [[1 + a^2, a b], [a b, b^2]] / s^2,
    # so var(phi) = s^2 (1 + a^2) / b^2
    r, _, ph = spherical_from_sonar(P)
    a = (r + 0.5 * np.sin(ph)) / m.ranges_2
    b = 0.5 * r * np.cos(ph) / m.ranges_2
    expect = SR * np.sqrt(1 + a**2) / b
    if sway <= 1e-6:
        assert np.allclose(res.elevation_std, expect, rtol=1e-4)
    else:  # 1 cm of sway beside 50 cm of heave moves it by < 0.3 % (measured: the formula omits the sway)
        assert np.allclose(res.elevation_std, expect, rtol=0.01)


def test_monte_carlo_under_heave_is_consistent():
    sr, sa = 0.005, np.deg2rad(0.1)
    rng = np.random.default_rng(10)
    P = points(rng, 60, half_el=np.deg2rad(7))
    R, t = np.eye(3), np.array([0.0, 0.0, 0.4])
    m = ss.measure(P, R, t)
    nees = []
    for _ in range(20):
        noisy = [x + rng.normal(0, s, x.shape) for x, s in
                 ((m.ranges_1, sr), (m.azimuths_1, sa), (m.ranges_2, sr), (m.azimuths_2, sa))]
        res = ss.triangulate(*noisy, R, t, sigma_range=sr, sigma_azimuth=sa, fov_elevation=FOV)
        v = res.valid
        assert v.mean() > 0.9 and not res.ambiguous.any()
        d = res.points - P
        nees.append(np.einsum("ni,nij,nj->n", d[v], np.linalg.inv(res.covariance[v]), d[v]))
    nees = np.concatenate(nees)
    k = nees.size
    lo, hi = chi2.ppf([0.025, 0.975], 3 * k) / k
    assert lo < nees.mean() < hi


def test_empty_input_is_falsy():
    res = ss.triangulate([], [], [], [], np.eye(3), np.array([0.1, 0, 0.1]))
    assert not res and res.message == "no points"


@pytest.mark.parametrize("bad, match", [
    (dict(azimuths_1=[0.1, 0.2, 0.3]), "azimuths_1"),
    (dict(R_s=np.ones((3, 3))), "R_s"),
    (dict(t_s=[0, 1]), "t_s"),
    (dict(ranges_1=[-1.0, 1.0]), "ranges"),
    (dict(method="x"), "method"),
    (dict(sigma_range=0.0), "sigma_range"),
    (dict(fov_elevation=20.0), "fov_elevation.*degrees"),  # degrees for radians
    (dict(azimuths_1=[20.0, 21.0]), "azimuths_1.*radians"),
    (dict(azimuths_2=[0.1, 21.0]), "azimuths_2.*radians"),
])
def test_caller_mistakes_raise_value_error_naming_the_argument(bad, match):
    kw = dict(ranges_1=[1.0, 2.0], azimuths_1=[0.1, 0.2], ranges_2=[1.1, 2.1], azimuths_2=[0.1, 0.2],
              R_s=np.eye(3), t_s=[0.1, 0.0, 0.1])
    kw.update(bad)
    with pytest.raises(ValueError, match=match):
        ss.triangulate(**kw)


def test_closed_forms_refuse_azimuths_in_degrees():
    with pytest.raises(ValueError, match="azimuths_1.*radians"):
        ss.closed_forms([5.0], [20.0], [5.0], [0.1], np.eye(3), [0.1, 0.0, 0.1])


def _outside_case():
    """A point 3.1 deg up in a 20 deg aperture whose four noisy measurements are fitted best at
    40 deg: its only in-aperture start (the planes form's -8.8 deg root) used to be refined to
    40.4 deg and reported valid."""
    rng = np.random.default_rng(12)
    n = 40
    P = sonar_from_spherical(rng.uniform(3, 10, n), rng.uniform(-0.6, 0.6, n), rng.uniform(-0.8, 0.8, n) * FOV / 2)
    ang = np.deg2rad([4.0, -3.0, 6.0])
    th = np.linalg.norm(ang)
    k = ang / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R_s, t_s = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K, np.array([0.4, 0.3, 0.25])
    m = ss.measure(P, R_s, t_s)
    for _ in range(27):
        z = [m.ranges_1 + SR * rng.standard_normal(n), m.azimuths_1 + SA * rng.standard_normal(n),
             m.ranges_2 + SR * rng.standard_normal(n), m.azimuths_2 + SA * rng.standard_normal(n)]
    return P, m, z, R_s, t_s


def test_ml_refinement_keeps_every_point_inside_the_elevation_aperture():
    P, m, z, R_s, t_s = _outside_case()
    i = 36
    one = [a[i:i + 1] for a in z]
    free = ss._refine(np.array([[one[0][0], one[1][0], np.deg2rad(-8.8)]]), *one, R_s, t_s, SR, SA)
    assert abs(free[0, 2]) > FOV / 2  # the unconstrained optimum is outside the aperture
    res = ss.triangulate(*one, R_s, t_s, sigma_range=SR, sigma_azimuth=SA, fov_elevation=FOV)
    assert abs(res.elevations[0]) <= FOV / 2 + 1e-9, np.rad2deg(res.elevations)
    # the constrained optimum: on the aperture's edge, its chi-square no worse than the truth's,
    # and within its standard deviation of the true elevation
    truth, _ = ss._chi2_of(P[i:i + 1], *one, R_s, t_s, SR, SA)
    assert res.chi2[0] <= truth[0] + 1e-9
    if res.valid[0]:
        assert abs(res.elevations[0] - m.elevations_1[i]) < 3 * res.elevation_std[0]
    # every point of the draw: no valid one outside the aperture
    res = ss.triangulate(*z, R_s, t_s, sigma_range=SR, sigma_azimuth=SA, fov_elevation=FOV)
    assert np.all(np.abs(res.elevations[res.valid]) <= FOV / 2 + 1e-9)
    assert np.all(np.isfinite(res.chi2[res.valid]))


def test_bounded_refinement_is_the_constrained_optimum():
    # the bounded block problem (all points at once) against scipy's bounded trust region point by point
    from scipy.optimize import least_squares

    _, _, z, R_s, t_s = _outside_case()
    cf = ss.closed_forms(*z, R_s, t_s)
    x0 = np.stack(spherical_from_sonar(cf.planes[:, 0]), -1)
    ok = np.flatnonzero(np.all(np.isfinite(x0), 1))[:15]
    half = np.deg2rad(5.0)  # a narrow aperture: many points end on its edges
    zz = [a[ok] for a in z]
    x = ss._refine(x0[ok], *zz, R_s, t_s, SR, SA, half=half)
    assert np.all(np.abs(x[:, 2]) <= half)
    for k in range(ok.size):
        one = [a[k:k + 1] for a in zz]
        start = x0[ok[k]].copy()
        start[2] = np.clip(start[2], -half, half)
        ref = least_squares(lambda v: _whitened(v[None], *one, R_s, t_s, SR, SA)[0].ravel(), start,
                            bounds=([-np.inf, -np.inf, -half], [np.inf, np.inf, half]), xtol=1e-14, ftol=1e-14,
                            gtol=1e-14)
        c_ref = 2 * ref.cost
        e, _, _ = _whitened(x[k:k + 1], *one, R_s, t_s, SR, SA)
        assert np.sum(e * e) <= c_ref + 1e-6 * (1 + c_ref)


def test_chi2_of_with_the_aperture_is_inf_outside_it():
    P = sonar_from_spherical(np.array([2.0, 2.0, 2.0]), np.zeros(3), np.deg2rad([5.0, 15.0, -12.0]))
    m = ss.measure(P, R_GOOD, T_GOOD)
    args = (m.ranges_1, m.azimuths_1, m.ranges_2, m.azimuths_2, R_GOOD, T_GOOD, SR, SA)
    c, _ = ss._chi2_of(P, *args)
    assert np.all(c < 1e-12)
    c, _ = ss._chi2_of(P, *args, FOV)
    assert c[0] < 1e-12 and np.all(np.isinf(c[1:]))
