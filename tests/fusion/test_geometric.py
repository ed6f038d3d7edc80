"""Plane-induced sonar-to-optical mappings against exact 3D geometry."""

import numpy as np
import pytest

from optiacoustic.frames import Pose, fan_from_polar, rot_x, sonar_from_spherical
from optiacoustic.fusion import (
    PiecewisePlanarMapping,
    SonarPlane,
    PlaneMapping,
    plane_elevation,
    reconstruct_matches,
)

BAR_TOP = 0.03  # the bar tops of conftest.grid_points

HALF = np.deg2rad(10.0)


def _seabed_points(rng, n):
    """A random sonar pose above z = 0 and seabed points inside its elevation aperture."""
    height = rng.uniform(1.0, 3.0)
    tilt = np.deg2rad(rng.uniform(20.0, 40.0))
    pose = Pose.look_at((rng.uniform(-1, 1), -4.0, height), (0.0, -4.0 + height / np.tan(tilt), 0.0))
    th = rng.uniform(-0.6, 0.6, n)
    ph = rng.uniform(-0.9 * HALF, 0.9 * HALF, n)
    d_world = sonar_from_spherical(1.0, th, ph) @ pose.R.T
    r = -pose.t[2] / d_world[:, 2]  # the ray meets z = 0
    return pose, r, th, ph


def test_plane_elevation_recovers_the_true_elevation():
    rng = np.random.default_rng(10)
    for _ in range(5):
        pose, r, th, ph = _seabed_points(rng, 50)
        plane = SonarPlane.from_world((0, 0, 1), 0.0, pose)
        sol = plane_elevation(plane, r, th, fov_elevation=2 * HALF)
        assert sol.valid.all() and not sol.ambiguous.any()
        np.testing.assert_allclose(sol.elevations, ph, atol=1e-9)
        np.testing.assert_allclose(plane.signed_distance(sonar_from_spherical(r, th, sol.elevations)), 0, atol=1e-9)


def test_two_roots_in_the_aperture_keep_the_one_nearer_the_boresight():
    # a wall Y cos(a) + Z sin(a) = d: roots phi = a +- arccos(d / r) = 2 +- 5 deg, both inside +-10 deg
    a = np.deg2rad(2.0)
    plane = SonarPlane((0.0, np.cos(a), np.sin(a)), 3.0)
    r = 3.0 / np.cos(np.deg2rad(5.0))
    sol = plane_elevation(plane, r, 0.0, fov_elevation=2 * HALF)
    assert sol.valid and sol.ambiguous
    assert sol.elevations == pytest.approx(np.deg2rad(-3.0), abs=1e-12)
    # with a 8-degree aperture only the -3 degree root is inside: not ambiguous
    sol = plane_elevation(plane, r, 0.0, fov_elevation=np.deg2rad(8.0))
    assert sol.valid and not sol.ambiguous and sol.elevations == pytest.approx(np.deg2rad(-3.0))


@pytest.mark.parametrize("fov", [-1.0, 0.0, np.nan, "wide"])
def test_an_aperture_that_is_not_a_positive_angle_is_refused(fov):
    # was: every point silently invalid
    with pytest.raises(ValueError, match="fov_elevation"):
        plane_elevation(SonarPlane((0.0, 1.0, 0.0), 5.0), [6.0], [0.0], fov_elevation=fov)


def test_no_root_gives_nan_and_invalid():
    plane = SonarPlane((0.0, 1.0, 0.0), 5.0)  # a wall 5 m ahead
    sol = plane_elevation(plane, [4.0, 6.0, 6.0], [0.0, 0.0, np.nan], fov_elevation=2 * HALF)
    assert sol.valid.tolist() == [False, False, False]  # too short; root at 33.6 deg outside; NaN
    assert np.all(np.isnan(sol.elevations))


def test_plane_from_world_and_from_points():
    rng = np.random.default_rng(11)
    pose = Pose(rot_x(-0.4), np.array([0.3, -3.0, 1.5]))
    pw = np.column_stack([rng.uniform(-1, 1, (20, 2)), np.full(20, 0.25)])
    ps = pose.to_body(pw)
    plane = SonarPlane.from_world((0, 0, 2.0), 0.5, pose)  # z = 0.25, unnormalised on purpose
    np.testing.assert_allclose(plane.signed_distance(ps), 0.0, atol=1e-12)
    fitted = SonarPlane.from_points(ps)
    np.testing.assert_allclose(fitted.normal, plane.normal, atol=1e-12)
    assert fitted.offset == pytest.approx(plane.offset) and fitted.offset > 0
    with pytest.raises(ValueError, match="collinear"):
        SonarPlane.from_points(np.outer(np.linspace(0, 1, 5), [1.0, 2.0, 3.0]))
    with pytest.raises(ValueError, match="at least 3"):
        SonarPlane.from_points(ps[:2])
    with pytest.raises(ValueError, match="non-zero"):
        SonarPlane((0, 0, 0), 1.0)


def test_plane_mapping_is_exact_on_the_grid(setup, grid):
    xy_tr, px_tr, xy_te, px_te = grid
    known = PlaneMapping(setup.rig, SonarPlane.from_world((0, 0, 1), BAR_TOP, setup.sonar_pose))
    res = known.solve(xy_te)
    assert res.valid.all() and bool(res)
    np.testing.assert_allclose(res.pixels, px_te, atol=1e-6)
    fitted = PlaneMapping.fit(setup.rig, xy_tr, px_tr)
    np.testing.assert_allclose(fitted.plane.normal, known.plane.normal, atol=1e-9)
    np.testing.assert_allclose(fitted(xy_te), px_te, atol=1e-6)


def test_plane_mapping_marks_unmappable_points(setup):
    m = PlaneMapping(setup.rig, SonarPlane.from_world((0, 0, 1), 0.0, setup.sonar_pose))
    # a point far beyond where the seabed leaves the aperture, a point too close, NaN
    q = np.array([[0.0, 15.0], [0.0, 1.0], [np.nan, 3.0], [0.0, 3.9]])
    res = m.solve(q)
    assert res.valid.tolist() == [False, False, False, True]
    assert np.all(np.isnan(res.pixels[:3])) and np.all(np.isfinite(res.pixels[3]))
    assert "1 of 4 points mapped" in res.message


def test_reconstruct_matches_returns_the_true_points(setup):
    rng = np.random.default_rng(12)
    pw = np.column_stack([rng.uniform(-1, 1, (15, 2)), rng.uniform(0, 0.5, 15)])
    xy, px, _ = setup.observe(pw)
    np.testing.assert_allclose(reconstruct_matches(setup.rig, xy, px), setup.sonar_pose.to_body(pw), atol=1e-9)
    with pytest.raises(ValueError, match="cannot be reconstructed"):
        reconstruct_matches(setup.rig, xy[:3] * 0.01, px[:3])  # ranges of 4 cm: rays miss the spheres


def test_piecewise_planar_is_exact_on_a_plane_and_on_its_training_points(setup, grid):
    xy_tr, px_tr, xy_te, px_te = grid
    m = PiecewisePlanarMapping.fit(setup.rig, xy_tr, px_tr)
    np.testing.assert_allclose(m(xy_tr), px_tr, atol=1e-6)
    np.testing.assert_allclose(m(xy_te), px_te, atol=1e-6)
    # outside the features' hull: the nearest triangle's plane, still the seabed here
    outside = setup.observe(np.array([[0.0, 1.3, BAR_TOP], [-1.2, -1.2, BAR_TOP]]))
    np.testing.assert_allclose(m(outside[0]), outside[1], atol=1e-6)
    assert m.triangles.shape[1] == 3 and len(m.normals) == len(m.triangles)


def test_piecewise_planar_follows_two_planes(setup):
    # seabed (z = 0) for y < 0, a plateau (z = 0.4) for y > 0.3: points inside triangles whose
    # three features lie on one plane must map exactly
    g = np.linspace(-1, 1, 9)
    low = np.array([(x, y, 0.0) for x in g for y in g if y < -0.05])
    high = np.array([(x, y, 0.4) for x in g for y in g if y > 0.3])
    feats = np.vstack([low, high])
    xy, px, _ = setup.observe(feats)
    m = PiecewisePlanarMapping.fit(setup.rig, xy, px)
    rng = np.random.default_rng(13)
    test_low = np.column_stack([rng.uniform(-0.9, 0.9, 30), rng.uniform(-0.9, -0.3, 30), np.zeros(30)])
    test_high = np.column_stack([rng.uniform(-0.9, 0.9, 30), rng.uniform(0.45, 0.9, 30), np.full(30, 0.4)])
    on_plane = np.r_[np.zeros(len(low)), np.ones(len(high))]
    checked = 0
    for pts, which in ((test_low, 0), (test_high, 1)):
        q, truth, _ = setup.observe(pts)
        k = m.triangle_of(q)
        pure = np.all(on_plane[m.triangles[k]] == which, axis=1)
        checked += pure.sum()
        np.testing.assert_allclose(m(q)[pure], truth[pure], atol=1e-6)
    assert checked > 40


def test_bad_inputs(setup, grid):
    xy_tr, px_tr, _, _ = grid
    with pytest.raises(ValueError, match="rig"):
        PlaneMapping("not a rig", SonarPlane((0, 0, 1), 1.0))
    with pytest.raises(ValueError, match="plane"):
        PlaneMapping(setup.rig, "not a plane")
    with pytest.raises(ValueError, match="rig"):
        PiecewisePlanarMapping.fit(None, xy_tr, px_tr)
    with pytest.raises(ValueError, match="at least 3"):
        PiecewisePlanarMapping.fit(setup.rig, xy_tr[:2], px_tr[:2])
    with pytest.raises(ValueError, match="collinear"):
        x = np.linspace(-0.5, 0.5, 6)
        PiecewisePlanarMapping.fit(setup.rig, np.column_stack([x, 4 + x]), px_tr[:6])
    with pytest.raises(ValueError, match="duplicated"):
        PlaneMapping.fit(setup.rig, np.vstack([xy_tr, xy_tr[:1]]), np.vstack([px_tr, px_tr[:1]]))
    with pytest.raises(ValueError, match="finite"):
        bad = xy_tr.copy()
        bad[3, 1] = np.nan
        PiecewisePlanarMapping.fit(setup.rig, bad, px_tr)
    with pytest.raises(ValueError, match="sonar_xy"):
        PlaneMapping(setup.rig, SonarPlane((0, 0, 1), 1.0))(np.zeros((4, 3)))


def test_batched_equals_loop(setup, grid):
    xy_tr, px_tr, xy_te, _ = grid
    m = PiecewisePlanarMapping.fit(setup.rig, xy_tr, px_tr)
    q = xy_te[:12].reshape(2, 6, 2)
    loop = np.array([m(p) for p in q.reshape(-1, 2)]).reshape(2, 6, 2)
    np.testing.assert_allclose(m(q), loop, atol=1e-9)
    r, th = np.hypot(q[..., 0], q[..., 1]), np.arctan2(q[..., 0], q[..., 1])
    np.testing.assert_allclose(np.stack(fan_from_polar(r, th), -1), q)
