"""Frames, poses and the sonar's spherical coordinates: identities on seeded random inputs."""

import numpy as np
import pytest

from optiacoustic.frames import (
    Pose,
    R_SONAR_FROM_CAMERA_FORWARD,
    euler_xyz_from_rotation,
    fan_from_polar,
    orthonormalize,
    polar_from_fan,
    project_to_sonar,
    rot_x,
    rot_y,
    rot_z,
    rotation_from_euler_xyz,
    skew,
    sonar_from_spherical,
    spherical_from_sonar,
)

rng = np.random.default_rng(1)


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def test_elementary_rotations_are_right_handed():
    # a quarter turn about Z takes X to Y, about X takes Y to Z, about Y takes Z to X
    assert np.allclose(rot_z(np.pi / 2) @ [1, 0, 0], [0, 1, 0])
    assert np.allclose(rot_x(np.pi / 2) @ [0, 1, 0], [0, 0, 1])
    assert np.allclose(rot_y(np.pi / 2) @ [0, 0, 1], [1, 0, 0])


def test_euler_roundtrip_and_order():
    for _ in range(50):
        a = rng.uniform(-np.pi, np.pi, 3)
        a[1] = rng.uniform(-1.5, 1.5)
        R = rotation_from_euler_xyz(a)
        assert np.allclose(R, rot_z(a[2]) @ rot_y(a[1]) @ rot_x(a[0]))
        assert np.allclose(euler_xyz_from_rotation(R), a)


def test_pose_compose_inverse_and_batching():
    for _ in range(20):
        A = Pose(random_rotation(rng), rng.normal(size=3))
        B = Pose(random_rotation(rng), rng.normal(size=3))
        p = rng.normal(size=(4, 5, 3))
        assert np.allclose((A @ B).to_world(p), A.to_world(B.to_world(p)))
        assert np.allclose(A.inverse().to_world(A.to_world(p)), p)
        assert np.allclose(A.to_body(A.to_world(p)), p)
        # batched equals a loop of single points
        loop = np.array([[A.to_world(q) for q in row] for row in p])
        assert np.allclose(A.to_world(p), loop)


def test_look_at_sonar_axes():
    eye, target = np.array([0.0, -6.0, 2.0]), np.zeros(3)
    pose = Pose.look_at(eye, target)
    fwd = (target - eye) / np.linalg.norm(target - eye)
    assert np.allclose(pose.R[:, 1], fwd)  # sonar Y is the boresight
    assert abs(pose.R[2, 0]) < 1e-12  # sonar X (right) is level
    assert pose.R[2, 2] > 0  # sonar Z leans up
    assert np.allclose(pose.R[:, 0], [1, 0, 0])  # looking along +Y, right is +X
    # the target lies on the boresight at the right range
    assert np.allclose(pose.to_body(target), [0, np.linalg.norm(target - eye), 0])


def test_look_at_camera_axes_match_the_rig_convention():
    eye, target = np.array([1.0, -4.0, 1.5]), np.array([0.3, 0.2, 0.0])
    s = Pose.look_at(eye, target, body="sonar")
    c = Pose.look_at(eye, target, body="camera")
    # a camera looking where the sonar looks: R_sonar_from_camera = the documented base
    assert np.allclose(s.R.T @ c.R, R_SONAR_FROM_CAMERA_FORWARD)
    assert np.allclose(c.R[:, 2], (target - eye) / np.linalg.norm(target - eye))  # camera Z forward
    assert c.R[2, 1] < 0  # camera Y points down


@pytest.mark.parametrize("target", [(0, 0, -5), (0, 0, 9)])
def test_look_at_straight_down_or_up_is_an_error(target):
    with pytest.raises(ValueError, match="parallel to up"):
        Pose.look_at((0, 0, 1), target)
    Pose.look_at((0, 0, 1), target, up=(0, 1, 0))  # another up resolves it


def test_look_at_bad_input():
    with pytest.raises(ValueError, match="coincide"):
        Pose.look_at((1, 2, 3), (1, 2, 3))
    with pytest.raises(ValueError, match="eye"):
        Pose.look_at((np.nan, 0, 0), (1, 0, 0))
    with pytest.raises(ValueError, match="shape"):
        Pose.look_at((0, 0), (1, 0, 0))
    with pytest.raises(ValueError, match="body"):
        Pose.look_at((0, 0, 0), (1, 0, 0), body="lidar")
    with pytest.raises(ValueError, match="rotation"):
        Pose(np.eye(3) * 2, np.zeros(3))


def test_spherical_roundtrip_and_definitions():
    r = rng.uniform(0.5, 30, (7, 3))
    th = rng.uniform(-1.4, 1.4, (7, 3))
    ph = rng.uniform(-1.4, 1.4, (7, 3))
    P = sonar_from_spherical(r, th, ph)
    assert P.shape == (7, 3, 3)
    r2, th2, ph2 = spherical_from_sonar(P)
    assert np.allclose(r2, r) and np.allclose(th2, th) and np.allclose(ph2, ph)
    # definitions of DESIGN.md, computed independently
    assert np.allclose(r2, np.linalg.norm(P, axis=-1))
    assert np.allclose(th2, np.arctan2(P[..., 0], P[..., 1]))
    assert np.allclose(np.sin(ph2), P[..., 2] / r2)


def test_fan_roundtrip():
    r = rng.uniform(0.1, 50, 100)
    th = rng.uniform(-1.5, 1.5, 100)
    x, y = fan_from_polar(r, th)
    assert np.allclose(np.hypot(x, y), r)
    r2, th2 = polar_from_fan(x, y)
    assert np.allclose(r2, r) and np.allclose(th2, th)


def test_project_to_sonar_mask():
    P = np.array([[0, 5, 0], [5, 0.1, 0], [0, 5, 3], [0, 0, 0], [0, -5, 0]], float)
    proj = project_to_sonar(P, fov_azimuth=np.deg2rad(90), fov_elevation=np.deg2rad(20), range_min=1, range_max=20)
    assert proj.in_fan.tolist() == [True, False, False, False, False]
    assert np.isnan(proj.ranges[3])  # the origin has no direction


def test_orthonormalize_and_skew():
    R = random_rotation(rng)
    noisy = R + 1e-3 * rng.normal(size=(3, 3))
    Q = orthonormalize(noisy)
    assert np.allclose(Q.T @ Q, np.eye(3)) and np.isclose(np.linalg.det(Q), 1)
    assert np.linalg.norm(Q - R) < 5e-3
    v, w = rng.normal(size=3), rng.normal(size=3)
    assert np.allclose(skew(v) @ w, np.cross(v, w))
