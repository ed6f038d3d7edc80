"""Bad trajectory and dataset-configuration input: a ValueError naming the argument or field, never a hang,
a silently orthonormalised matrix or a NaN pose."""

import time

import numpy as np
import pytest

from optiacoustic.frames import are_rotations
from optiacoustic.simulation import Orbit, WaypointTrajectory, frame_times, lawnmower, look_rotations
from optiacoustic.simulation.sequence import load_config
from optiacoustic.simulation.trajectory import MAX_LEGS


# ----------------------------------------------------------------------------- lawnmower leg count
@pytest.mark.parametrize("spacing, legs", [(1e-5, "1e+08"), (1e-7, "1e+10"), (1e-320, "inf")])
def test_lawnmower_refuses_too_many_legs_at_once(spacing, legs):
    t0 = time.perf_counter()
    with pytest.raises(ValueError) as e:
        lawnmower((0, 10, 0, 1000), 3, spacing, 1.0)
    assert time.perf_counter() - t0 < 1.0  # it ran for minutes
    msg = str(e.value)
    assert msg.startswith("spacing:") and f"{legs} legs" in msg and str(MAX_LEGS) in msg


def test_lawnmower_at_the_leg_limit_is_built_and_right():
    # (y_max - y_min) / spacing + 1 legs: 99 999 + 1 = MAX_LEGS exactly
    L = lawnmower((0.0, 2.0, 0.0, 99_999.0), 3.0, 1.0, 1.0, turn_time=0.5)
    assert len(L.times) == 2 * (2 * MAX_LEGS - 1)  # 2 waypoints per segment: legs and crossings
    # leg k at y = k, along +X on even legs; the last leg (k = 99 999, odd) ends at x = 0
    np.testing.assert_array_equal(L.positions_world[-1], [0.0, 99_999.0, 3.0])
    # time: legs of 2 s, crossings of 1 s, a 0.5 s turn at each of the 2 * MAX_LEGS - 2 inner corners
    assert L.end == pytest.approx(MAX_LEGS * 2.0 + (MAX_LEGS - 1) * 1.0 + (2 * MAX_LEGS - 2) * 0.5, rel=1e-12)
    with pytest.raises(ValueError, match=r"spacing: .* makes 100001 legs"):
        lawnmower((0.0, 2.0, 0.0, 100_000.0), 3.0, 1.0, 1.0)


def test_dataset_lawnmower_spacing_is_named_by_field():
    cfg = {"scene": "flat_seabed", "duration": 2, "trajectory": {
        "kind": "lawnmower", "area": [0, 10, 0, 1000], "height": 3, "spacing": 1e-7, "speed": 1}}
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=r"field 'trajectory.spacing': spacing: 1e-07 m .* 1e\+10 legs"):
        load_config(cfg)
    assert time.perf_counter() - t0 < 1.0


# ----------------------------------------------------------------------------- rotations
@pytest.mark.parametrize("bad", [2 * np.eye(3), [[1, 0.5, 0], [0, 1, 0], [0, 0, 1.0]], np.diag([1, 1, -1.0]),
                                 np.zeros((3, 3))], ids=["2I", "shear", "reflection", "zeros"])
def test_waypoints_refuse_matrices_that_are_not_rotations(bad):
    R = np.stack([np.eye(3), bad])
    with pytest.raises(ValueError, match=r"^rotations\[1\]: not a rotation matrix"):
        WaypointTrajectory([0, 1], np.zeros((2, 3)), R)


def test_waypoints_keep_true_rotations_exactly():
    c, s = np.cos(0.3), np.sin(0.3)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    W = WaypointTrajectory([0, 1], np.zeros((2, 3)), np.stack([np.eye(3), Rz]), interpolation="linear")
    np.testing.assert_allclose(W.sample([1.0])[0][0], Rz, atol=1e-12)
    # half way: a rotation of 0.15 rad about Z (Slerp)
    h = W.sample([0.5])[0][0]
    np.testing.assert_allclose(h[:2, :2], [[np.cos(0.15), -np.sin(0.15)], [np.sin(0.15), np.cos(0.15)]], atol=1e-12)


def test_look_rotations_refuse_zero_vectors():
    with pytest.raises(ValueError, match="forward_world: a viewing direction is the zero vector"):
        look_rotations([0, 0, 0])
    with pytest.raises(ValueError, match=r"forward_world: .* \(at index \(1,\)\)"):
        look_rotations([[0, 1, 0], [0, 0, 0]])
    with pytest.raises(ValueError, match="up: must be a non-zero vector"):
        look_rotations([1, 0, 0], up=[0, 0, 0])
    assert are_rotations(look_rotations([[1, 2, -0.5], [0, 1, 0]])).all()


def test_waypoint_looking_at_its_own_position_is_named():
    with pytest.raises(ValueError, match=r"waypoint 1: target == position"):
        WaypointTrajectory.looking_at([0, 1], [[0, 0, 0], [1, 0, 0]], [[5, 0, 0], [1, 0, 0]])
    cfg = {"scene": "flat_seabed", "duration": 1, "trajectory": {"kind": "waypoints", "points": [
        {"time": 0, "position": [0, 0, 2], "target": [0, 5, 0]},
        {"time": 1, "position": [1, 0, 2], "target": [1, 0, 2]}]}}
    with pytest.raises(ValueError, match=r"field 'trajectory.points.1': target == position"):
        load_config(cfg)


# ----------------------------------------------------------------------------- orbit and frame times
@pytest.mark.parametrize("kw, field", [({"height": np.nan}, "Orbit.height"), ({"phase": np.inf}, "Orbit.phase"),
                                       ({"target_height": np.nan}, "Orbit.target_height"),
                                       ({"radius": "5"}, "Orbit.radius"), ({"radius": np.inf}, "Orbit.radius"),
                                       ({"period": True}, "Orbit.period"),
                                       ({"start": 5.0, "end": 1.0}, "Orbit.end")])
def test_orbit_names_the_bad_field(kw, field):
    with pytest.raises(ValueError) as e:
        Orbit(**kw)
    assert str(e.value).startswith(field + ":"), str(e.value)


def test_frame_times_refuse_a_non_finite_start():
    with pytest.raises(ValueError, match="start: must be finite"):
        frame_times(1.0, 1.0, start=np.nan)
    with pytest.raises(ValueError, match="rate: expected a number"):
        frame_times("5", 1.0)
    np.testing.assert_allclose(frame_times(4.0, 1.0, start=2.0), [2.0, 2.25, 2.5, 2.75])


# ----------------------------------------------------------------------------- dataset config: strict values
_BASE = {"scene": "flat_seabed", "duration": 2, "trajectory": {"kind": "orbit"}}


@pytest.mark.parametrize("patch, field", [
    ({"seed": True}, "seed"), ({"seed": "5"}, "seed"), ({"seed": 1.5}, "seed"), ({"duration": "2"}, "duration"),
    ({"start": True}, "start"), ({"ground_truth": 1}, "ground_truth"), ({"noise": {"sonar": "no"}}, "noise.sonar"),
    ({"optical": {"shadows": "no"}}, "optical.shadows"), ({"optical": {"slices": "32"}}, "optical.slices"),
    ({"optical": {"backscatter_step": 100}}, "optical.backscatter_step"),
    ({"rates": {"sonar": True}}, "rates.sonar"),
    ({"trajectory": {"kind": "orbit", "center": [0, True, 0]}}, "trajectory.center.1"),
    ({"trajectory": {"kind": "orbit", "radius": "6"}}, "trajectory.radius"),
])
def test_dataset_config_refuses_lax_values(patch, field):
    with pytest.raises(ValueError) as e:
        load_config({**_BASE, **patch})
    assert f"field '{field}'" in str(e.value), str(e.value)


def test_dataset_config_still_takes_ints_for_floats_and_lists_for_vectors():
    c, _ = load_config({**_BASE, "seed": 3, "duration": 2, "optical": {"backscatter_step": 64},
                        "trajectory": {"kind": "orbit", "center": [1, 2, 0], "radius": 4}})
    assert c.seed == 3 and c.duration == 2.0 and c.trajectory.center == (1.0, 2.0, 0.0)
    assert c.optical.backscatter_step == 64
