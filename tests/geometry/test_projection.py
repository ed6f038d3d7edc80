"""Projections through the rig: identities on seeded random rigs, masks, validation."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from optiacoustic import PinholeCamera, Rig
from optiacoustic.frames import R_SONAR_FROM_CAMERA_FORWARD, spherical_from_sonar
from optiacoustic.geometry import projection as pr
from optiacoustic.sonar import SonarSpec


def random_rig(seed, sonar=None, dist=(0.0, 0.0, 0.0, 0.0, 0.0)):
    """Any rotation, a baseline of 0.1-1 m, a random pinhole camera."""
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3)
    t *= rng.uniform(0.1, 1.0) / np.linalg.norm(t)
    cam = PinholeCamera(rng.uniform(400, 1200), rng.uniform(400, 1200), rng.uniform(250, 350),
                        rng.uniform(150, 250), 640, 400, dist)
    return Rig(R, t, cam, sonar)


def random_points(seed, n=200):
    """Camera-frame points in front of the camera, 1-10 m deep."""
    rng = np.random.default_rng(seed + 1000)
    z = rng.uniform(1.0, 10.0, n)
    return np.stack([rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.4, 0.4, n) * z, z], -1)


@pytest.mark.parametrize("seed", range(5))
def test_pixel_depth_round_trip(seed):
    rig, P = random_rig(seed), random_points(seed)
    pix = pr.to_pixels(rig, P)
    assert pix.in_front.all()
    back = pr.camera_from_pixels(rig, pix.pixels, P[:, 2])
    np.testing.assert_allclose(back, P, atol=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_sonar_round_trip(seed):
    rig, P = random_rig(seed), random_points(seed)
    son = pr.to_sonar(rig, P)
    back = pr.camera_from_sonar(rig, son.ranges, son.azimuths, son.elevations)
    np.testing.assert_allclose(back, P, atol=1e-9)
    # The measurements are those of the sonar-frame point R P + t.
    r, th, ph = spherical_from_sonar(P @ rig.R.T + rig.t)
    np.testing.assert_allclose(son.ranges, r, rtol=1e-12)
    np.testing.assert_allclose(son.azimuths, th, atol=1e-12)
    np.testing.assert_allclose(son.elevations, ph, atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_pixel_rays_in_sonar(seed):
    rig, P = random_rig(seed), random_points(seed)
    rays = pr.pixel_rays_in_sonar(rig, pr.to_pixels(rig, P).pixels)
    np.testing.assert_allclose(rays.origin, rig.t)
    np.testing.assert_allclose(rays.at_depth(P[:, 2]), rig.sonar_from_camera(P), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(rays.unit_directions, axis=-1), 1.0, rtol=1e-12)


def test_project_masks():
    cam = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
    spec = SonarSpec.preset("blueview-p900-90")
    rig = Rig.toed_in(cam, baseline=0.25, sonar=spec)
    P = np.array([
        [0.0, 0.0, 3.0],    # ahead: seen by both
        [0.0, 0.0, -3.0],   # behind the camera (and the sonar)
        [0.0, -1.5, 3.0],   # 26 deg up: in the image? no (vertical half-fov 13.5 deg); outside +-10 deg elevation
        [0.0, -0.6, 3.0],   # 11 deg up: in the image, outside the sonar's elevation aperture
        [0.0, 0.0, 30.0],   # beyond range_max
    ])
    p = pr.project(rig, P)
    assert p.in_front.tolist() == [True, False, True, True, True]
    assert np.isnan(p.pixels[1]).all() and np.isfinite(p.pixels[[0, 2, 3, 4]]).all()
    assert p.in_image.tolist() == [True, False, False, True, True]
    assert p.in_fan.tolist() == [True, False, False, False, False]
    assert p.visible.tolist() == [True, False, False, False, False]
    # Without a sonar the fan is the half-space ahead, no range window.
    p0 = pr.project(Rig(R_SONAR_FROM_CAMERA_FORWARD, [-0.25, 0, 0], cam), P)
    assert p0.in_fan.tolist() == [True, False, True, True, True]


def test_broadcast_and_single_point():
    rig, P = random_rig(7), random_points(7, 12).reshape(3, 4, 3)
    p = pr.project(rig, P)
    assert p.pixels.shape == (3, 4, 2) and p.ranges.shape == (3, 4)
    single = pr.project(rig, P[1, 2])
    assert single.pixels.shape == (2,) and single.ranges.shape == ()
    np.testing.assert_array_equal(single.pixels, p.pixels[1, 2])
    np.testing.assert_array_equal(single.ranges, p.ranges[1, 2])
    # A scalar depth broadcasts over many pixels.
    back = pr.camera_from_pixels(rig, p.pixels, 2.0)
    np.testing.assert_allclose(back[..., 2], 2.0)


def test_distortion_round_trip():
    rig = random_rig(3, dist=(-0.12, 0.05, 0.001, -0.0005, 0.0))
    P = random_points(3)
    P = P[rig.camera.visible(P)]
    pix = pr.to_pixels(rig, P).pixels
    np.testing.assert_allclose(pr.camera_from_pixels(rig, pix, P[:, 2]), P, atol=1e-7 * P[:, 2:].max())
    ideal = pr.ideal_pixels(rig, pix)
    cam = rig.camera
    np.testing.assert_allclose(ideal, np.stack([cam.fx * P[:, 0] / P[:, 2] + cam.cx,
                                                cam.fy * P[:, 1] / P[:, 2] + cam.cy], -1), atol=1e-6)


def test_validation_errors():
    rig = random_rig(0)
    with pytest.raises(ValueError, match="points_camera"):
        pr.project(rig, np.zeros((4, 2)))
    with pytest.raises(ValueError, match="pixels"):
        pr.camera_from_pixels(rig, np.zeros((4, 3)), 1.0)
    with pytest.raises(ValueError, match="pixels"):
        pr.camera_from_pixels(rig, [[np.nan, 1.0]], 1.0)
    with pytest.raises(ValueError, match="depths"):
        pr.camera_from_pixels(rig, np.zeros((4, 2)), np.ones(3))
    with pytest.raises(ValueError, match="elevations"):
        pr.camera_from_sonar(rig, np.ones(3), np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="rig"):
        pr.project("not a rig", np.zeros(3))


def test_cos_sin_roots_identity():
    """Both roots satisfy a cos(phi) + b sin(phi) = c; NaN exactly when |c| > hypot(a, b)."""
    from optiacoustic.geometry.projection import cos_sin_roots

    rng = np.random.default_rng(42)
    a, b = rng.normal(size=(2, 1000))
    c = rng.uniform(-1.5, 1.5, 1000) * np.hypot(a, b)
    roots = cos_sin_roots(a, b, c)
    solvable = np.abs(c) <= np.hypot(a, b)
    assert np.array_equal(np.isfinite(roots).all(0), solvable)
    res = a * np.cos(roots) + b * np.sin(roots) - c
    assert np.nanmax(np.abs(res)) < 1e-12
    assert np.all(np.abs(roots[:, solvable]) <= np.pi)
