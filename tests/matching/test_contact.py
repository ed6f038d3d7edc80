"""Vertical-face geometry of the matcher (:mod:`optiacoustic.matching.contact`): analytic cases."""

import numpy as np

from optiacoustic.frames import sonar_from_spherical, spherical_from_sonar
from optiacoustic.matching.acoustic import SeabedPlane
from optiacoustic.matching.contact import (crease_points, echo_end_ranges, echo_start_ranges, foot_edges,
                                          foot_points, search_contacts)


def _rig():
    from optiacoustic.experiments.matching import _rig_for

    rig, sonar_pose = _rig_for((0.0, -6.0, 2.0), (0.0, 0.0, 0.0))
    return rig, sonar_pose


def _seabed(sonar_pose):
    """The world's z = 0 plane in the sonar frame (normal up), from the pose alone."""
    R, t = sonar_pose.R, sonar_pose.t  # P_world = R P_sonar + t
    n = R.T @ np.array([0.0, 0.0, 1.0])
    return SeabedPlane(normal=n, offset=float(-t[2]), rms=0.0, n_beams=100)


def test_crease_points_recover_a_point_below_a_known_crease():
    rig, sp = _rig()
    bed = _seabed(sp)
    # A vertical face at y = 0.3 m (world) whose top edge is 0.8 m above the seabed.
    rng = np.random.default_rng(3)
    x = rng.uniform(-1.0, 1.0, 20)
    crease_w = np.column_stack([x, np.full(20, 0.3), np.full(20, 0.8)])
    drop = rng.uniform(0.0, 0.6, 20)  # the feature's point lies this far below the crease
    X_w = crease_w - drop[:, None] * [0.0, 0.0, 1.0]
    to_sonar = lambda P: (P - sp.t) @ sp.R  # noqa: E731  (world -> sonar frame)
    C_s, X_s = to_sonar(crease_w), to_sonar(X_w)
    r_on = np.linalg.norm(C_s, axis=1)
    r, th, ph = spherical_from_sonar(X_s)
    top = rig.camera.project(rig.camera_from_sonar(C_s))
    c = crease_points(rig, bed, r, th, r_on, top, ph - 0.01, ph + 0.01)
    assert c.found.all()
    expected = rig.camera.project(rig.camera_from_sonar(X_s))
    np.testing.assert_allclose(c.pixels, expected, atol=0.02)
    np.testing.assert_allclose(c.drop, drop, atol=1e-3)
    np.testing.assert_allclose(c.elevations, ph, atol=1e-5)
    # Outside the run it is refused; without a seabed nothing is found.
    assert not crease_points(rig, bed, r, th, r_on, top, ph + 0.01, ph + 0.02).found.any()
    assert not crease_points(rig, SeabedPlane(np.full(3, np.nan), np.nan, np.nan, 0), r, th, r_on, top,
                             ph - 0.01, ph + 0.01).found.any()


def test_echo_start_ranges_find_the_leading_edge_of_a_block_echo():
    rng = np.random.default_rng(0)
    n_bins, n_beams = 300, 60
    ranges = 1.0 + 0.0254 * np.arange(n_bins)
    img = rng.exponential(1.0, (n_bins, n_beams))
    img[120:128, 20:40] += 200.0  # an object's echo from bin 120 to 127 in beams 20-39
    start = echo_start_ranges(img, ranges, np.array([121, 124, 127]), np.array([25, 30, 35]))
    # The echo's first bin (the 3 x 3 mean one bin before it, a third of the echo, stays under 3x
    # its background, which the echo itself raises).
    np.testing.assert_allclose(start, ranges[120], atol=1e-9)
    # A cell outside any echo starts where it is.
    np.testing.assert_allclose(echo_start_ranges(img, ranges, np.array([200]), np.array([5])), ranges[200])


def test_search_contacts_needs_an_edge_at_the_foot():
    rig, sp = _rig()
    bed = _seabed(sp)
    r = np.array([6.0, 6.3])
    th = np.array([0.0, 0.05])
    half = rig.fov_elevation / 2
    flat = np.zeros((rig.camera.height, rig.camera.width), np.float32)
    c = search_contacts(rig, bed, r, th, np.full(2, -half), np.full(2, half), flat)
    assert not c.found.any()  # no edge anywhere: no foot
    # A step edge along the image of the foot line under the arc point at 5 deg, all the rest flat.
    phi = np.deg2rad(5.0)
    X = sonar_from_spherical(r[0], th[0], phi)
    F = X - bed.height(X) * bed.normal
    q = rig.camera.project(rig.camera_from_sonar(F))
    g = flat.copy()
    g[int(round(q[1])) - 1:int(round(q[1])) + 2, :] = 20.0
    c = search_contacts(rig, bed, r[:1], th[:1], np.full(1, -half), np.full(1, half), g)
    assert c.found[0]
    assert abs(np.rad2deg(c.elevations[0]) - 5.0) < 1.0
    assert c.heights[0] > 0.05


def test_foot_points_recover_a_point_above_a_known_foot():
    """A vertical face whose foot lies on the seabed at the feature's azimuth and the echo's end range."""
    rig, sp = _rig()
    bed = _seabed(sp)
    rng = np.random.default_rng(5)
    th = np.deg2rad(rng.uniform(-20.0, 20.0, 30))
    r_end = rng.uniform(6.0, 7.5, 30)
    # The seabed point at (r_end, theta): bisect the elevation where the height crosses zero.
    lo, hi = np.full(30, -0.6), np.full(30, 0.3)
    for _ in range(60):
        mid = (lo + hi) / 2
        above = bed.height(sonar_from_spherical(r_end, th, mid)) > 0
        hi, lo = np.where(above, mid, hi), np.where(above, lo, mid)
    F = sonar_from_spherical(r_end, th, lo)
    h = rng.uniform(0.05, 0.8, 30)  # the feature's point lies this far above the foot
    X = F + h[:, None] * bed.normal
    r, _, ph = spherical_from_sonar(X)
    c = foot_points(rig, bed, r, th, r_end)
    assert c.found.all()
    np.testing.assert_allclose(c.height, h, atol=1e-6)
    np.testing.assert_allclose(c.elevations, ph, atol=1e-6)
    # The pixel is the feature's own arc point at that elevation.
    expected = rig.camera.project(rig.camera_from_sonar(sonar_from_spherical(r, th, ph)))
    np.testing.assert_allclose(c.pixels, expected, atol=1e-6)
    # A foot nearer than the feature (no such face) and no seabed give nothing.
    assert not foot_points(rig, SeabedPlane(np.full(3, np.nan), np.nan, np.nan, 0), r, th, r_end).found.any()


def test_echo_end_ranges_find_the_trailing_edge_of_a_block_echo():
    rng = np.random.default_rng(0)
    n_bins, n_beams = 300, 60
    ranges = 1.0 + 0.0254 * np.arange(n_bins)
    img = rng.exponential(1.0, (n_bins, n_beams))
    img[120:128, 20:40] += 200.0  # an object's echo from bin 120 to 127 in beams 20-39
    end = echo_end_ranges(img, ranges, np.array([120, 124, 127]), np.array([25, 30, 35]))
    # One bin past the echo's last bin: the 3 x 3 mean there holds a third of the echo, above 1.5x its
    # background (the end's looser threshold), so the end is found one bin late, the blur's width.
    np.testing.assert_allclose(end, ranges[128], atol=1e-9)
    # At the detection's threshold (3x) it is the echo's last bin.
    np.testing.assert_allclose(echo_end_ranges(img, ranges, np.array([124]), np.array([30]), factor=3.0),
                               ranges[127], atol=1e-9)
    # A cell outside any echo ends where it is.
    np.testing.assert_allclose(echo_end_ranges(img, ranges, np.array([200]), np.array([5])), ranges[200])


def test_foot_edges_see_the_foot_on_an_edge_and_an_edge_on_the_way_down():
    """Candidates on an arc; the foot of one of them (dropped by hand onto the world's seabed) drawn as an edge."""
    rig, sp = _rig()
    bed = _seabed(sp)
    r, th = np.full(3, 6.2), np.full(3, 0.03)
    phi = np.deg2rad([4.0, 1.0, np.nan])  # the second candidate 3 deg lower; the third: no candidate
    X_s = sonar_from_spherical(r[:1], th[:1], phi[:1])
    X_w = X_s @ sp.R.T + sp.t  # sonar -> world
    F_w = X_w * [1.0, 1.0, 0.0]  # straight down onto z = 0
    q = rig.camera.project(rig.camera_from_sonar((F_w - sp.t) @ sp.R))[0]
    p = rig.camera.project(rig.camera_from_sonar(X_s))[0]
    H, W = rig.camera.height, rig.camera.width
    g = np.zeros((H, W), np.float32)
    row = int(round(q[1]))
    g[row, :] = 20.0  # the foot line's edge, one pixel thick
    fe, ce = foot_edges(rig, bed, r, th, phi, g)
    assert fe[0] == 20.0 and ce[0] == 0.0  # on the edge (within 2 px), nothing on the way down
    assert np.isnan(fe[2]) and np.isnan(ce[2])
    # The lower candidate (0.3 m lower on the arc) stands in front of the first one's foot: its own
    # foot is nearer the camera, lower in the image, off the edge, and its way down crosses the edge.
    X1 = sonar_from_spherical(r[1:2], th[1:2], phi[1:2])
    p1 = rig.camera.project(rig.camera_from_sonar(X1))[0]
    q1 = rig.camera.project(rig.camera_from_sonar(((X1 @ sp.R.T + sp.t) * [1.0, 1.0, 0.0] - sp.t) @ sp.R))[0]
    assert p1[1] < row - 1 and q1[1] > row + 3  # by hand: the point above the edge, its foot below it
    assert fe[1] == 0.0 and ce[1] == 20.0
    # An edge across the face, halfway between the point and its foot, is seen on the way down (a
    # band as wide as the 16 samples' spacing, as a blurred image's edges are).
    mid, step = int(round((p[1] + q[1]) / 2)), int(np.ceil(0.85 * abs(q[1] - p[1]) / 15))
    g[mid - step // 2:mid + step // 2 + 1, :] = 7.0
    fe, ce = foot_edges(rig, bed, r, th, phi, g)
    assert fe[0] == 20.0 and ce[0] == 7.0
    # No seabed: nothing; mismatched lengths: a clear error.
    no_bed = SeabedPlane(np.full(3, np.nan), np.nan, np.nan, 0)
    assert np.isnan(foot_edges(rig, no_bed, r, th, phi, g)[0]).all()
    import pytest

    with pytest.raises(ValueError, match="one length"):
        foot_edges(rig, bed, r, th[:2], phi, g)


def test_seabed_points_lie_on_the_seabed_plane_and_project_to_their_pixels():
    """The seabed point (round i15k): world points of the z = 0 seabed, seen from the rig, are recovered."""
    import pytest

    from optiacoustic.matching.acoustic import seabed_points

    rig, sp = _rig()
    bed = _seabed(sp)
    rng = np.random.default_rng(11)
    X_w = np.column_stack([rng.uniform(-1.5, 1.5, 30), rng.uniform(-1.0, 1.5, 30), np.zeros(30)])
    X_s = (X_w - sp.t) @ sp.R  # world -> sonar frame
    r, th, ph = spherical_from_sonar(X_s)
    el, px, found = seabed_points(rig, bed, r, th, rig.fov_elevation)
    inside = np.abs(ph) <= rig.fov_elevation / 2
    expected_px = rig.camera.project(rig.camera_from_sonar(X_s))
    seen = inside & rig.camera.in_image(expected_px)
    assert seen.sum() >= 10
    np.testing.assert_array_equal(found, seen)
    np.testing.assert_allclose(el[found], ph[found], atol=1e-9)
    np.testing.assert_allclose(px[found], expected_px[found], atol=1e-6)
    np.testing.assert_allclose(bed.height(sonar_from_spherical(r[found], th[found], el[found])), 0.0, atol=1e-9)
    # Nothing without a seabed; a range shorter than the sonar's height never meets it.
    assert not seabed_points(rig, SeabedPlane(np.full(3, np.nan), np.nan, np.nan, 0), r, th,
                             rig.fov_elevation)[2].any()
    assert not seabed_points(rig, bed, np.full(3, 1.0), np.zeros(3), rig.fov_elevation)[2].any()
    with pytest.raises(ValueError, match="one length"):  # mismatched features: named, not broadcast
        seabed_points(rig, bed, r, th[:1], rig.fov_elevation)
