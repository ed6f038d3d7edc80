"""Trajectories against analytic paths: orbit circle, lawnmower legs, splines through waypoints, CSV."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from optiacoustic import Pose, Rig
from optiacoustic.camera import PinholeCamera
from optiacoustic.simulation import Orbit, WaypointTrajectory, frame_times, lawnmower, load_csv, look_rotations


def test_look_rotations_matches_pose_look_at():
    rng = np.random.default_rng(0)
    eyes = rng.normal(size=(20, 3)) * 5
    targets = rng.normal(size=(20, 3))
    R = look_rotations(targets - eyes)
    for r, e, t in zip(R, eyes, targets):
        np.testing.assert_allclose(r, Pose.look_at(e, t).R, atol=1e-12)


def test_orbit_keeps_radius_height_and_looks_at_target():
    orb = Orbit(center=(1.0, -2.0, 0.5), radius=6.0, height=2.0, period=60.0, target_height=0.0)
    t = np.linspace(0, 90, 181)
    R, p = orb.sample(t)
    rel = p - np.array([1.0, -2.0, 0.5])
    np.testing.assert_allclose(np.hypot(rel[:, 0], rel[:, 1]), 6.0, atol=1e-12)
    np.testing.assert_allclose(rel[:, 2], 2.0, atol=1e-12)
    # boresight (sonar +Y) points at the target
    to_target = np.array([1.0, -2.0, 0.5]) - p
    to_target /= np.linalg.norm(to_target, axis=1, keepdims=True)
    np.testing.assert_allclose(R[:, :, 1], to_target, atol=1e-12)
    # angle advances 2 pi t / period, counter-clockwise seen from above
    a = np.unwrap(np.arctan2(rel[:, 1], rel[:, 0]))
    np.testing.assert_allclose(a - a[0], 2 * np.pi * t / 60.0, atol=1e-12)
    # rotations are proper and level (sonar X stays horizontal)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(R[:, 2, 0], 0.0, atol=1e-12)


def test_lawnmower_legs_spacing_height_and_speed():
    traj = lawnmower((-10, 10, -6, 6), height=3.0, spacing=4.0, speed=0.5, turn_time=2.0)
    t = np.linspace(traj.start, traj.end, 4001)
    R, p = traj.sample(t)
    np.testing.assert_allclose(p[:, 2], 3.0, atol=1e-12)
    assert p[:, 0].min() >= -10 - 1e-9 and p[:, 0].max() <= 10 + 1e-9
    # legs sit at y = -6, -2, 2, 6
    ys = np.unique(np.round(traj.positions_world[:, 1], 9))
    np.testing.assert_allclose(ys, [-6, -2, 2, 6])
    np.testing.assert_allclose(np.diff(ys), 4.0)
    # duration: 4 legs of 20 m, 3 crossings of 4 m at 0.5 m/s, 6 turns of 2 s
    np.testing.assert_allclose(traj.end - traj.start, (4 * 20 + 3 * 4) / 0.5 + 6 * 2.0)
    # along a leg the heading is constant and the speed is 0.5 m/s
    leg = (t > traj.times[0] + 1) & (t < traj.times[1] - 1)
    np.testing.assert_allclose(np.linalg.norm(np.diff(p[leg], axis=0), axis=1) / np.diff(t[leg]), 0.5, rtol=1e-9)
    np.testing.assert_allclose(R[leg][:, :, 1], R[leg][0][:, 1][None].repeat(leg.sum(), 0), atol=1e-12)
    # the boresight is tilted 30 deg below horizontal
    np.testing.assert_allclose(R[:, 2, 1], -np.sin(np.deg2rad(30)), atol=1e-9)


def test_cubic_waypoints_pass_through_and_are_smooth():
    times = np.array([0.0, 2.0, 5.0, 6.0, 10.0])
    pos = np.array([[0, 0, 2], [3, 1, 2.5], [4, 5, 2], [2, 6, 1.5], [0, 3, 2.0]])
    rots = Rotation.from_euler("zyx", [[0, 0, 0], [40, 5, 0], [90, -10, 3], [150, 0, 0], [200, 10, -5]], degrees=True)
    traj = WaypointTrajectory(times, pos, rots)
    R, p = traj.sample(times)
    np.testing.assert_allclose(p, pos, atol=1e-12)
    np.testing.assert_allclose(R, rots.as_matrix(), atol=1e-9)
    # a quadratic path is not reproduced by natural ends, but a straight line at constant speed is
    line = WaypointTrajectory(times, np.outer(times, [1.0, -2.0, 0.5]), Rotation.identity(len(times)))
    tt = np.linspace(0, 10, 77)
    np.testing.assert_allclose(line.sample(tt)[1], np.outer(tt, [1.0, -2.0, 0.5]), atol=1e-12)
    # velocity is continuous across waypoints (finite differences either side of t = 5)
    h = 1e-5
    _, q = traj.sample([5 - 2 * h, 5 - h, 5 + h, 5 + 2 * h])
    np.testing.assert_allclose((q[1] - q[0]) / h, (q[3] - q[2]) / h, atol=1e-3)
    # rotation about a fixed axis at constant rate: the spline reproduces it
    ang = np.deg2rad([0, 20, 50, 60, 100])
    spin = WaypointTrajectory(times, pos, Rotation.from_rotvec(np.outer(ang, [0, 0, 1])))
    Rs, _ = spin.sample(tt)
    np.testing.assert_allclose(Rs, Rotation.from_rotvec(np.outer(np.deg2rad(10 * tt), [0, 0, 1])).as_matrix(),
                               atol=1e-9)


def test_samples_outside_the_span_are_refused():
    traj = lawnmower((0, 4, 0, 0), height=1.0, spacing=1.0, speed=1.0)
    with pytest.raises(ValueError, match="outside"):
        traj.sample([traj.end + 1])


def test_rig_moves_as_one_body():
    cam = PinholeCamera(fx=300, fy=300, cx=160, cy=120, width=320, height=240)
    rig = Rig.toed_in(cam, baseline=0.25, vergence=np.deg2rad(2.3))
    orb = Orbit(radius=5.0, height=2.0, period=30.0)
    for s in orb.poses([0.0, 3.3, 17.0]):
        c = rig.camera_pose(s)
        rel = s.inverse() @ c
        np.testing.assert_allclose(rel.R, rig.R, atol=1e-12)
        np.testing.assert_allclose(rel.t, rig.t, atol=1e-12)


def test_frame_times_per_sensor_rate():
    np.testing.assert_allclose(frame_times(5, 6.0), np.arange(30) / 5)
    np.testing.assert_allclose(frame_times(1, 6.0), np.arange(6.0))
    assert frame_times(0, 6.0).size == 0
    with pytest.raises(ValueError, match="rate"):
        frame_times(-1, 6.0)


def test_csv_poses_round_trip_and_errors(tmp_path):
    times = np.array([0.0, 1.0, 2.5])
    pos = np.array([[0, 0, 1], [1, 0, 1], [1, 2, 1.0]])
    q = Rotation.from_euler("z", [[0], [30], [90]], degrees=True)
    p = tmp_path / "poses.csv"
    rows = ["time,x,y,z,qx,qy,qz,qw"] + [",".join(str(float(v)) for v in [t, *x, *qq]) for t, x, qq in zip(times, pos, q.as_quat())]
    p.write_text("\n".join(rows) + "\n")
    traj = load_csv(p)
    R, t = traj.sample(times)
    np.testing.assert_allclose(t, pos, atol=1e-12)
    np.testing.assert_allclose(R, q.as_matrix(), atol=1e-12)
    R, t = traj.sample([0.5])
    np.testing.assert_allclose(t[0], [0.5, 0, 1], atol=1e-12)
    np.testing.assert_allclose(Rotation.from_matrix(R[0]).as_euler("zyx", degrees=True)[0], 15.0, atol=1e-9)
    bad = tmp_path / "bad.csv"
    bad.write_text("time,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0,0,0,0,0,0,2\n")
    with pytest.raises(ValueError, match=r"bad.csv: line 3: quaternion norm"):
        load_csv(bad)
    bad.write_text("time,x,y,z,qx,qy,qz\n0,0,0,0,0,0,0\n")
    with pytest.raises(ValueError, match="missing column"):
        load_csv(bad)
