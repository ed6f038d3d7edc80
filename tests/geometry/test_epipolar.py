"""Opti-acoustic epipolar geometry: true matches on their curves, brute-force references, degenerate rigs."""

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from optiacoustic import PinholeCamera, Rig
from optiacoustic.frames import R_SONAR_FROM_CAMERA_FORWARD, rot_z, spherical_from_sonar
from optiacoustic.geometry import epipolar as ep
from optiacoustic.geometry import projection as pr
from optiacoustic.sonar import SonarSpec

THESIS_CAMERA = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
P900 = SonarSpec.preset("blueview-p900-90")


def random_rig(seed, sonar=None):
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3)
    t *= rng.uniform(0.1, 1.0) / np.linalg.norm(t)
    cam = PinholeCamera(rng.uniform(400, 1200), rng.uniform(400, 1200), rng.uniform(250, 350),
                        rng.uniform(150, 250), 640, 400)
    return Rig(R, t, cam, sonar)


def random_points(seed, n=200):
    rng = np.random.default_rng(seed + 1000)
    z = rng.uniform(1.0, 10.0, n)
    return np.stack([rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.4, 0.4, n) * z, z], -1)


def thesis_rig(sonar=P900):
    """The thesis's rig (sec. 4.3): 0.25 m baseline, vergence aiming at ~6 m (2.39 deg)."""
    return Rig.toed_in(THESIS_CAMERA, baseline=0.25, vergence=np.deg2rad(2.39), sonar=sonar)


def polyline_distance(point, line):
    """Distance from a 2D point to a polyline (M, 2)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    s = np.clip(np.einsum("ij,ij->i", point - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
    return np.min(np.linalg.norm(a + s[:, None] * ab - point, axis=-1))


# --------------------------------------------------------------------------- sonar -> optical
@pytest.mark.parametrize("seed", range(6))
def test_true_matches_on_conic(seed):
    rig, P = random_rig(seed), random_points(seed)
    p = pr.project(rig, P)
    C = ep.conic(rig, p.ranges, p.azimuths)
    assert C.shape == (len(P), 3, 3)
    np.testing.assert_allclose(C, np.swapaxes(C, -1, -2), rtol=1e-12, atol=1e-18)
    d = ep.sampson_distance(C, p.pixels)
    assert np.nanmax(d) < 1e-6


def test_sampson_distance_measures_pixels():
    """A step off a true match along the conic's normal has a Sampson distance equal to the step
    to first order (the thesis rig's conics are thin hyperbolas, so the second-order term shows)."""
    rig = thesis_rig()
    rng = np.random.default_rng(8)
    P = np.stack([rng.uniform(-0.5, 0.5, 300), rng.uniform(-0.3, 0.3, 300), rng.uniform(2.5, 10, 300)], -1)
    p = pr.project(rig, P)
    P, p = P[p.visible], pr.project(rig, P[p.visible])
    C = ep.conic(rig, p.ranges, p.azimuths)
    m = np.concatenate([p.pixels, np.ones((len(P), 1))], -1)
    normal = np.einsum("nij,nj->ni", C, m)[:, :2]
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    rel = {}
    for step in (0.1, 1.0):
        off = ep.sampson_distance(C, p.pixels + step * normal)
        rel[step] = np.max(np.abs(off / step - 1))
    # First order: exact as the step shrinks, the relative error linear in the step.
    assert rel[0.1] < 0.01 and 5 < rel[1.0] / rel[0.1] < 20


@pytest.mark.parametrize("offset", [[0.0, 0.0, 0.2], [0.0, 0.0, -0.35], [0.0, 0.0, 0.0]])
def test_sampson_distance_of_a_double_line_is_the_distance_to_the_line(offset):
    """A camera in every azimuth plane (straight above or below the sonar, or at its centre) makes every
    conic the double line (a.q)^2 = 0: true matches are at 0 px and a pixel 5 px off is 5 px off (first-order
    Sampson halves it and, on the line, divides round-off by round-off). The line is from the rig, not the conic."""
    cam = PinholeCamera.from_sensor()
    rig = Rig(R_SONAR_FROM_CAMERA_FORWARD, offset, cam)
    rng = np.random.default_rng(18)
    P = np.c_[rng.uniform(-0.5, 0.5, (40, 2)), rng.uniform(2, 8, 40)]
    p = pr.project(rig, P)
    C = ep.conic(rig, p.ranges, p.azimuths)
    assert set(ep.conic_type(C)) == {"double line"}
    assert np.max(ep.sampson_distance(C, p.pixels)) < 1e-6
    # the azimuth plane's image: the plane's normal (cos th, -sin th, 0) in sonar axes, through the camera centre
    n_cam = np.stack([np.cos(p.azimuths), -np.sin(p.azimuths), np.zeros(len(P))], -1) @ rig.R  # R^T n, (N, 3)
    line = n_cam @ np.linalg.inv(cam.K)  # pixels m with line . m = 0
    step = rng.uniform(0.5, 20.0, len(P))[:, None] * rng.normal(size=(len(P), 2))
    off = p.pixels + step
    m = np.c_[off, np.ones(len(P))]
    truth = np.abs(np.einsum("ij,ij->i", line, m)) / np.linalg.norm(line[:, :2], axis=1)
    np.testing.assert_allclose(ep.sampson_distance(C, off), truth, rtol=1e-9, atol=1e-9)


def test_sampson_distance_unchanged_for_conics_that_are_not_double_lines():
    """Near a double line (camera 1 mm off the sonar's vertical) the conics are thin line pairs of rank 2:
    the first-order formula stands, as for every other rig."""
    for seed, t in ((0, [1e-3, 0.0, 0.2]), (1, None), (2, None)):
        rig = random_rig(seed) if t is None else Rig(R_SONAR_FROM_CAMERA_FORWARD, t, PinholeCamera.from_sensor())
        p = pr.project(rig, random_points(seed))
        C = ep.conic(rig, p.ranges, p.azimuths)
        off = p.pixels + np.random.default_rng(seed).normal(size=p.pixels.shape) * 3
        m = np.c_[off, np.ones(len(off))]
        Cm = np.einsum("nij,nj->ni", C, m)
        first_order = np.abs(np.einsum("ni,ni->n", m, Cm)) / (2 * np.linalg.norm(Cm[:, :2], axis=1))
        # the same to round-off (m^T C m cancels terms ~1e6 times larger; C enters through its symmetric part)
        np.testing.assert_allclose(ep.sampson_distance(C, off), first_order, rtol=1e-7)


def test_conic_reduces_to_thesis_U():
    """With K = I our C is the thesis's U (4.13) divided by cos^2(theta) (it uses tan theta)."""
    rng = np.random.default_rng(1)
    for seed in range(4):
        rig = random_rig(seed)
        rig = Rig(rig.R, rig.t, PinholeCamera(1.0, 1.0, 0.0, 0.0, 10, 10))
        r, th = rng.uniform(1, 10), rng.uniform(-1.2, 1.2)
        R, t = rig.R, rig.t
        tt = np.tan(th)
        a = R[0] - tt * R[1]  # rows r1 - tan(theta) r2
        c = tt * t[1] - t[0]
        U = c ** 2 * np.eye(3) + (t @ t - r ** 2) * np.outer(a, a) + c * (np.outer(a, t @ R) + np.outer(R.T @ t, a))
        np.testing.assert_allclose(ep.conic(rig, r, th) / np.cos(th) ** 2 * 1.0, U, rtol=1e-10, atol=1e-12)


def brute_force_type(rig, r, th):
    """Ellipse iff the whole circle (sphere x azimuth plane, both half-planes) is on one side of
    the camera's principal plane; hyperbola iff it crosses it."""
    psi = np.linspace(0, 2 * np.pi, 20001)
    e = np.array([np.sin(th), np.cos(th), 0.0])
    pts = r * (np.cos(psi)[:, None] * e + np.sin(psi)[:, None] * np.array([0.0, 0.0, 1.0]))
    z = (pts - rig.t) @ rig.R[:, 2]  # camera-frame depth around the circle
    if min(abs(z.min()), abs(z.max())) < 1e-3 * r:
        return None  # nearly tangent to the principal plane: a parabola to within sampling; skip
    return "ellipse" if (z.min() > 0 or z.max() < 0) else "hyperbola"


def test_conic_type_matches_brute_force():
    rng = np.random.default_rng(5)
    checked = {"ellipse": 0, "hyperbola": 0}
    for seed in range(60):
        rig = random_rig(seed)
        for _ in range(5):
            r, th = rng.uniform(0.2, 6.0), rng.uniform(-1.4, 1.4)
            want = brute_force_type(rig, r, th)
            if want is None:
                continue
            assert ep.conic_type(ep.conic(rig, r, th)) == want, (seed, r, th)
            checked[want] += 1
    assert checked["ellipse"] > 10 and checked["hyperbola"] > 10


def test_toed_in_ellipse_criterion():
    """For Rig.toed_in(baseline B, vergence g) the conic of (r, theta) is an ellipse iff
    r |cos(theta - g)| < B sin(g) (docs: the circle stays on one side of the principal plane)."""
    rng = np.random.default_rng(21)
    seen = set()
    for _ in range(300):
        B, g = rng.uniform(0.1, 8.0), rng.uniform(0.0, 1.5)
        r, th = rng.uniform(0.5, 10.0), rng.uniform(-1.4, 1.4)
        margin = B * np.sin(g) - r * abs(np.cos(th - g))
        if abs(margin) < 1e-3 * r:
            continue
        want = "ellipse" if margin > 0 else "hyperbola"
        assert ep.conic_type(ep.conic(Rig.toed_in(THESIS_CAMERA, baseline=B, vergence=g), r, th)) == want
        seen.add(want)
    assert seen == {"ellipse", "hyperbola"}


def test_conic_types_of_rigs():
    # Nearly parallel (the thesis's rig): hyperbolas (sec. 4.3).
    rig = thesis_rig()
    r, th = np.array([3.0, 6.0, 10.0]), np.array([-0.3, 0.0, 0.4])
    assert set(ep.conic_type(ep.conic(rig, r, th))) == {"hyperbola"}
    # Large vergence: a camera 8 m to the side looking across the sonar's beam: ellipses.
    side = Rig(rot_z(-np.pi / 2) @ R_SONAR_FROM_CAMERA_FORWARD, [-8.0, 6.0, 0.0], THESIS_CAMERA, P900)
    assert set(ep.conic_type(ep.conic(side, r, th))) == {"ellipse"}
    # Camera centre in the azimuth plane (t_x = 0, theta = 0): the conic is the plane's image line.
    above = Rig(R_SONAR_FROM_CAMERA_FORWARD, [0.0, 0.0, 0.3], THESIS_CAMERA, P900)
    C = ep.conic(above, 4.0, 0.0)
    assert ep.conic_type(C) == "double line"
    P = np.array([0.0, 0.5, 3.5])  # camera frame, straight ahead: theta = 0
    p = pr.project(above, P)
    assert abs(p.azimuths) < 1e-12
    m = np.array([*p.pixels, 1.0])
    assert abs(m @ ep.conic(above, p.ranges, p.azimuths) @ m) < 1e-12


def test_conic_type_canonical():
    cases = {
        "ellipse": np.diag([1.0, 2.0, -1.0]),
        "imaginary": np.diag([1.0, 1.0, 1.0]),
        "hyperbola": np.diag([1.0, -1.0, -1.0]),
        "parabola": np.array([[0, 0, -0.5], [0, 1.0, 0], [-0.5, 0, 0]]),
        "point": np.diag([1.0, 1.0, 0.0]),
        "line pair": np.diag([1.0, -1.0, 0.0]),
        "parallel lines": np.diag([1.0, 0.0, -1.0]),
        "double line": np.diag([1.0, 0.0, 0.0]),
    }
    got = ep.conic_type(np.stack(list(cases.values())))
    assert got.tolist() == list(cases)
    # Invariant under an affine change of coordinates (pixels = K normalised): C -> K^-T C K^-1.
    Ki = np.linalg.inv(THESIS_CAMERA.K)
    assert ep.conic_type(Ki.T @ np.stack(list(cases.values())) @ Ki).tolist() == list(cases)


def test_sampled_curves_are_true_candidates():
    rig = thesis_rig()
    rng = np.random.default_rng(2)
    n = 40
    P = np.stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.3, 0.3, n), rng.uniform(2.5, 8, n)], -1)
    p = pr.project(rig, P)
    keep = p.visible
    curves = ep.sonar_to_optical_curves(rig, p.ranges, p.azimuths)
    assert len(curves) == n
    half = P900.fov_elevation / 2
    for i in range(n):
        pieces = curves[i]
        if not keep[i]:
            continue
        assert len(pieces) >= 1
        pts = np.concatenate(pieces)
        assert rig.camera.in_image(pts).all()
        C = ep.conic(rig, p.ranges[i], p.azimuths[i])
        assert np.max(ep.sampson_distance(C, pts)) < 1e-6
        # Every sample is a point of the half-plane theta, in front, inside the aperture.
        rays = pr.pixel_rays_in_sonar(rig, pts)
        ps = rays.at_depth(depth_on_sphere(rays, p.ranges[i]))
        r, th, ph = spherical_from_sonar(ps)
        np.testing.assert_allclose(th, p.azimuths[i], atol=1e-9)
        assert np.all(np.abs(ph) <= half + 1e-9)
        # The true match lies on the polyline.
        assert min(polyline_distance(p.pixels[i], c) for c in pieces) < 0.01
    # The mirror point at theta + pi is on the conic but not on the sampled curve.
    i = int(np.nonzero(keep)[0][0])
    ps = rig.sonar_from_camera(P[i])
    mirror = rig.camera_from_sonar(ps * [-1, -1, 1])  # same range, azimuth + pi, same elevation
    if mirror[2] > 0:
        m_pix = rig.camera.project(mirror)
        assert ep.sampson_distance(ep.conic(rig, p.ranges[i], p.azimuths[i]), m_pix) < 1e-6
        assert min((polyline_distance(m_pix, c) for c in curves[i]), default=np.inf) > 5


def depth_on_sphere(rays, r):
    d, t = rays.directions, rays.origin
    dd = np.sum(d * d, -1)
    td = d @ t
    return (-td + np.sqrt(td * td - dd * (t @ t - r * r))) / dd


def test_curve_clipping_ends_are_exact():
    rig = thesis_rig()
    P = np.array([0.1, 0.05, 4.0])
    p = pr.project(rig, P)
    (piece,) = ep.sonar_to_optical_curves(rig, p.ranges, p.azimuths)[0]
    rays = pr.pixel_rays_in_sonar(rig, piece[[0, -1]])
    _, _, ph = spherical_from_sonar(rays.at_depth(depth_on_sphere(rays, p.ranges)))
    cam = rig.camera
    for k, end in enumerate(piece[[0, -1]]):
        on_aperture = abs(abs(ph[k]) - P900.fov_elevation / 2) < 1e-9
        on_border = min(abs(end[0] + 0.5), abs(end[0] - cam.width + 0.5), abs(end[1] + 0.5), abs(end[1] - cam.height + 0.5)) < 1e-6
        assert on_aperture or on_border
    # Without the aperture the curve is longer (the elevation constraint of sec. 4.3 shortens it).
    (longer,) = ep.sonar_to_optical_curves(rig, p.ranges, p.azimuths, clip_elevation=False)[0]
    length = lambda c: np.sum(np.linalg.norm(np.diff(c, axis=0), axis=-1))  # noqa: E731
    assert length(longer) > length(piece) * 1.2


def test_batched_conic_equals_singles():
    rig, P = random_rig(3), random_points(3, 12).reshape(3, 4, 3)
    p = pr.project(rig, P)
    C = ep.conic(rig, p.ranges, p.azimuths)
    assert C.shape == (3, 4, 3, 3)
    for idx in np.ndindex(3, 4):
        np.testing.assert_array_equal(C[idx], ep.conic(rig, p.ranges[idx], p.azimuths[idx]))
    np.testing.assert_allclose(ep.conic(rig, 5.0, np.array([0.1, 0.2]))[1], ep.conic(rig, 5.0, 0.2))


# --------------------------------------------------------------------------- optical -> sonar
@pytest.mark.parametrize("seed", range(6))
def test_true_matches_on_sonar_curve(seed):
    rig, P = random_rig(seed), random_points(seed)
    p = pr.project(rig, P)
    r = ep.sonar_range(rig, p.pixels, p.azimuths)
    np.testing.assert_allclose(r, p.ranges, atol=1e-6, rtol=0)
    assert np.max(np.abs(r - p.ranges)) < 1e-9


def brute_force_range(rig, pixel, theta):
    """Range where the pixel's ray has azimuth theta: dense scan in depth + Brent, NaN if none."""
    rays = pr.pixel_rays_in_sonar(rig, pixel)
    z = np.concatenate([[0.0], np.logspace(-6, 6, 4001)])
    ps = rays.at_depth(z)
    az = np.arctan2(ps[:, 0], ps[:, 1])
    f = np.angle(np.exp(1j * (az - theta)))  # wrapped difference
    sign = np.nonzero((f[:-1] * f[1:] <= 0) & (np.abs(f[:-1] - f[1:]) < np.pi))[0]
    if sign.size == 0:
        return np.nan
    k = sign[0]

    def g(zz):
        q = rays.at_depth(zz)
        return np.angle(np.exp(1j * (np.arctan2(q[0], q[1]) - theta)))

    zz = brentq(g, z[k], z[k + 1], xtol=1e-14, rtol=1e-14) if f[k] != 0 else z[k]
    return float(np.linalg.norm(rays.at_depth(zz)))


def test_sonar_range_against_brute_force():
    rng = np.random.default_rng(11)
    n_nan = n_val = 0
    for seed in range(8):
        rig = random_rig(seed)
        pix = rng.uniform([0, 0], [640, 400], (6, 2))
        th = rng.uniform(-np.pi / 2, np.pi / 2, 6)
        got = ep.sonar_range(rig, pix, th)
        for k in range(6):
            want = brute_force_range(rig, pix[k], th[k])
            if np.isnan(want):
                assert np.isnan(got[k])
                n_nan += 1
            else:
                assert abs(got[k] - want) < 1e-6 * max(1.0, want)
                n_val += 1
    assert n_nan > 3 and n_val > 3


def test_sonar_curves_sampled_on_r_theta():
    rig = thesis_rig()
    rng = np.random.default_rng(4)
    pix = rng.uniform([50, 50], [550, 350], (8, 2))
    for coords in ("polar", "fan"):
        curves = ep.optical_to_sonar_curves(rig, pix, coords=coords)
        for k, pieces in enumerate(curves):
            assert pieces, "a pixel of the thesis rig has a curve in the fan"
            pts = np.concatenate(pieces)
            if coords == "fan":
                r, th = np.hypot(pts[:, 0], pts[:, 1]), np.arctan2(pts[:, 0], pts[:, 1])
            else:
                r, th = pts[:, 0], pts[:, 1]
            np.testing.assert_allclose(ep.sonar_range(rig, pix[k], th), r, rtol=1e-9)
            # Clipped to the aperture and the fan.
            assert np.all(np.isfinite(ep.sonar_range(rig, pix[k], th[1:-1], clip_elevation=True)))
            assert np.all((r >= P900.range_min - 1e-9) & (r <= P900.range_max + 1e-9))
            assert np.all(np.abs(th) <= P900.fov_azimuth / 2 + 1e-12)


def test_sonar_curves_start_at_epipole():
    rig = thesis_rig(sonar=None)
    e = ep.epipole(rig)
    assert e.range == pytest.approx(0.25) and e.azimuth == pytest.approx(-np.pi / 2)
    assert (e.x_s, e.y_s) == pytest.approx((-0.25, 0.0), abs=1e-12)
    curves = ep.optical_to_sonar_curves(rig, [[300.0, 200.0], [100.0, 250.0]], clip_elevation=False, coords="fan")
    for pieces in curves:
        np.testing.assert_allclose(pieces[0][0], [e.x_s, e.y_s], atol=1e-12)
    assert not ep.epipole(thesis_rig()).in_fan  # beside the sonar, inside its range_min


def test_ray_in_an_azimuth_plane():
    """A ray whose horizontal trace passes through the sonar's axis lies in one azimuth plane:
    r(theta) is undefined (NaN) and the sampled curve is a radial segment."""
    rig = Rig(R_SONAR_FROM_CAMERA_FORWARD, [0.0, -0.5, 0.2], THESIS_CAMERA)  # camera behind the sonar
    pix = np.array([THESIS_CAMERA.cx, 150.0])  # the central column: a ray in the plane x_s = 0
    assert np.all(np.isnan(ep.sonar_range(rig, pix, np.linspace(-0.5, 0.5, 7))))
    (pieces,) = ep.optical_to_sonar_curves(rig, pix)
    pts = np.concatenate(pieces)
    assert np.ptp(pts[:, 1]) < 1e-12 and np.ptp(pts[:, 0]) > 1.0


def test_sonar_range_invalid_cases():
    rig = thesis_rig(sonar=None)
    pix = np.array([300.0, 200.0])
    d = pr.pixel_rays_in_sonar(rig, pix).directions
    th_inf = np.arctan2(d[0], d[1])  # the ray's azimuth at infinite depth
    th_cam = -np.pi / 2  # the camera centre's azimuth
    r = ep.sonar_range(rig, pix, np.array([th_inf + 0.05, th_inf - 0.05, th_cam - 0.1, th_inf]))
    assert np.isnan(r[0])  # beyond the asymptote: the crossing is behind the camera
    assert np.isfinite(r[1])  # between the epipole's and the asymptote's azimuths
    assert np.isnan(r[2])  # the plane is crossed on the opposite half-plane
    assert np.isnan(r[3]) or r[3] > 1e6  # parallel to the plane


def test_validation():
    rig = thesis_rig()
    with pytest.raises(ValueError, match="ranges.*azimuths|azimuths.*ranges"):
        ep.conic(rig, np.ones(3), np.zeros(4))
    with pytest.raises(ValueError, match="pixels"):
        ep.sonar_range(rig, np.zeros((3, 3)), 0.0)
    with pytest.raises(ValueError, match="azimuths"):
        ep.sonar_range(rig, np.zeros((3, 2)), np.zeros(4))
    with pytest.raises(ValueError, match="symmetric"):
        ep.conic_type(np.arange(9.0).reshape(3, 3))
    with pytest.raises(ValueError, match="coords"):
        ep.optical_to_sonar_curves(rig, [300.0, 200.0], coords="cartesian")
    with pytest.raises(ValueError, match="ranges"):
        ep.sonar_to_optical_curves(rig, -1.0, 0.0)
    with pytest.raises(ValueError, match="ranges"):
        ep.conic(rig, np.nan, 0.0)
    with pytest.raises(ValueError, match="n_samples"):
        ep.sonar_to_optical_curves(rig, 5.0, 0.0, n_samples=1)
    with pytest.raises(ValueError, match="max_range"):
        ep.optical_to_sonar_curves(rig, [300.0, 200.0], max_range=-3.0)


def test_bad_tolerances_and_sample_counts_are_refused_by_name():
    C = np.diag([1.0, 2.0, -1.0])  # an ellipse
    assert ep.conic_type(C) == "ellipse"
    for bad in (-1, np.nan, 1.5, True, "1e-9"):
        with pytest.raises(ValueError, match="rtol: expected a relative tolerance in"):
            ep.conic_type(C, rtol=bad)
    rig = thesis_rig()
    for bad in (1, 10**12, 2.5):
        with pytest.raises(ValueError, match=r"n_samples: expected an integer in \[2, 100000\]"):
            ep.sonar_to_optical_curves(rig, [5.0], [0.1], n_samples=bad)
        with pytest.raises(ValueError, match=r"n_samples: expected an integer in \[2, 100000\]"):
            ep.optical_to_sonar_curves(rig, [[300.0, 200.0]], n_samples=bad)


def test_a_point_with_a_nan_coordinate_has_no_pixel():
    p = pr.to_pixels(thesis_rig(), [[np.nan, 0.0, 1.0], [0.1, 0.0, 2.0], [0.0, 0.0, np.nan]])
    assert np.isnan(p.pixels[[0, 2]]).all() and np.isfinite(p.pixels[1]).all()
    assert not p.in_image[[0, 2]].any() and p.in_image[1]
