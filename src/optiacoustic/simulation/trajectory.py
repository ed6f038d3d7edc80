"""Trajectories of a rig: the sonar's world pose as a smooth function of time.

The rig moves as one body whose frame is the sonar's (X right, Y forward, Z up); the
camera's pose at any time is ``rig.camera_pose(sonar_pose)``. A trajectory is sampled at
each sensor's own frame times (:func:`frame_times`).

Kinds
-----
- :class:`WaypointTrajectory`: timed waypoints, positions through a cubic spline
  (``scipy.interpolate.CubicSpline``) and rotations through a rotation spline
  (``scipy.spatial.transform.RotationSpline``), or piecewise linear + Slerp.
- :func:`lawnmower`: a survey over a rectangle at a height, legs along X spaced along Y,
  turning on the spot at each corner (linear + Slerp waypoints).
- :class:`Orbit`: a circle around a target at a height, looking at the target (analytic).
- :func:`load_csv`: timestamped poses ``time,x,y,z,qx,qy,qz,qw`` (ROS quaternion order,
  sonar to world), linear + Slerp between rows.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import as_array
from ..frames import Pose

__all__ = ["Trajectory", "WaypointTrajectory", "Orbit", "lawnmower", "load_csv", "frame_times", "look_rotations"]


def look_rotations(forward_world, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Rotations (sonar axes to world) of bodies looking along ``forward_world``, level w.r.t. ``up``.

    The batched form of :meth:`Pose.look_at` with ``body="sonar"``.

    Parameters
    ----------
    forward_world : array_like, (..., 3)
        Boresight directions in the world frame (need not be unit).
    up : array_like, (3,)

    Returns
    -------
    (..., 3, 3) rotation matrices with columns (right, forward, up).
    """
    f = as_array(forward_world, "forward_world", ("...", 3))
    f = f / np.linalg.norm(f, axis=-1, keepdims=True)
    up = as_array(up, "up", (3,))
    right = np.cross(f, up / np.linalg.norm(up))
    nr = np.linalg.norm(right, axis=-1, keepdims=True)
    if np.any(nr < 1e-6):
        raise ValueError("look_rotations: a viewing direction is parallel to up (looking straight up or down)")
    right = right / nr
    body_up = np.cross(right, f)
    return np.stack([right, f, body_up], axis=-1)


def frame_times(rate: float, duration: float, start: float = 0.0) -> np.ndarray:
    """Frame times of a sensor running at ``rate`` Hz over ``[start, start + duration)`` (s).

    ``rate = 0`` gives no frames. Frame ``k`` is at ``start + k / rate``.
    """
    if not np.isfinite(rate) or rate < 0:
        raise ValueError(f"rate: expected a finite rate >= 0 Hz, got {rate!r}")
    if not np.isfinite(duration) or duration <= 0:
        raise ValueError(f"duration: expected a finite duration > 0 s, got {duration!r}")
    if rate == 0:
        return np.zeros(0)
    n = int(np.ceil(duration * rate - 1e-9))  # k / rate < duration
    return start + np.arange(n) / rate


class Trajectory:
    """The sonar's world pose over time. Subclasses implement :meth:`sample`.

    Attributes
    ----------
    start, end : float
        Times (s) between which the trajectory is defined.
    """

    start: float = 0.0
    end: float = np.inf

    def sample(self, times) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)``: rotations ``(n, 3, 3)`` (sonar axes to world) and positions ``(n, 3)`` (m)."""
        raise NotImplementedError

    def _times(self, times) -> np.ndarray:
        t = np.atleast_1d(np.asarray(times, float))
        if t.ndim != 1 or not np.all(np.isfinite(t)):
            raise ValueError(f"times: expected a 1-D array of finite times (s), got shape {t.shape}")
        tol = 1e-9 * max(1.0, abs(self.end) if np.isfinite(self.end) else 1.0)
        if t.size and (t.min() < self.start - tol or t.max() > self.end + tol):
            raise ValueError(f"times: {t.min():g}..{t.max():g} s lies outside the trajectory's "
                             f"{self.start:g}..{self.end:g} s")
        return t

    def matrices(self, times) -> np.ndarray:
        """Homogeneous sonar-to-world transforms ``(n, 4, 4)`` at ``times`` (s)."""
        R, t = self.sample(times)
        T = np.zeros((len(t), 4, 4))
        T[:, :3, :3] = R
        T[:, :3, 3] = t
        T[:, 3, 3] = 1.0
        return T

    def poses(self, times) -> list[Pose]:
        """The sonar's :class:`Pose` at each of ``times`` (s)."""
        R, t = self.sample(times)
        return [Pose(r, p) for r, p in zip(R, t)]


class WaypointTrajectory(Trajectory):
    """Smooth motion through timed waypoints.

    Parameters
    ----------
    times : array_like, (n,)
        Strictly increasing waypoint times (s), n >= 2.
    positions_world : array_like, (n, 3)
        Sonar positions (m).
    rotations : array_like, (n, 3, 3), or scipy Rotation
        Sonar-to-world rotations at the waypoints.
    interpolation : {"cubic", "linear"}
        ``"cubic"``: ``CubicSpline`` (natural ends) through the positions and
        ``RotationSpline`` through the rotations (continuous angular velocity);
        ``"linear"``: straight segments and Slerp (constant velocity per segment).
    """

    def __init__(self, times, positions_world, rotations, *, interpolation: str = "cubic"):
        from scipy.interpolate import CubicSpline, make_interp_spline
        from scipy.spatial.transform import Rotation, RotationSpline, Slerp

        t = np.asarray(times, float)
        if t.ndim != 1 or len(t) < 2:
            raise ValueError(f"times: expected at least 2 waypoint times, got shape {t.shape}")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError(f"times: waypoint times must be finite and strictly increasing, got {t.tolist()}")
        p = as_array(positions_world, "positions_world", (len(t), 3))
        rot = rotations if isinstance(rotations, Rotation) else Rotation.from_matrix(
            as_array(rotations, "rotations", (len(t), 3, 3)))
        if len(rot) != len(t):
            raise ValueError(f"rotations: expected {len(t)} rotations, got {len(rot)}")
        if interpolation == "cubic":
            self._pos = CubicSpline(t, p, axis=0, bc_type="natural")
            self._rot = RotationSpline(t, rot)
        elif interpolation == "linear":
            self._pos = make_interp_spline(t, p, k=1, axis=0)
            self._rot = Slerp(t, rot)
        else:
            raise ValueError(f"interpolation: expected 'cubic' or 'linear', got {interpolation!r}")
        self.times = t
        self.positions_world = p
        self.interpolation = interpolation
        self.start, self.end = float(t[0]), float(t[-1])

    @classmethod
    def looking_at(cls, times, positions_world, targets_world, *, up=(0.0, 0.0, 1.0), interpolation="cubic"):
        """Waypoints whose sonar looks from each position at the matching target (world, m)."""
        p = np.asarray(positions_world, float)
        q = np.broadcast_to(np.asarray(targets_world, float), p.shape)
        return cls(times, p, look_rotations(q - p, up), interpolation=interpolation)

    def sample(self, times):
        t = np.clip(self._times(times), self.start, self.end)
        return self._rot(t).as_matrix(), np.asarray(self._pos(t), float)


@dataclass(frozen=True)
class Orbit(Trajectory):
    """A circle of ``radius`` around ``center`` at ``height`` above it, looking at the target.

    Position at time ``t``: ``center + (r cos a, r sin a, height)`` with
    ``a = phase + 2 pi t / period`` (a negative period turns clockwise seen from above).
    The sonar's boresight points at ``center + (0, 0, target_height)``.

    Parameters (all SI): ``center`` (3,) m, ``radius`` m, ``height`` m, ``period`` s,
    ``phase`` rad, ``target_height`` m.
    """

    center: tuple = (0.0, 0.0, 0.0)
    radius: float = 6.0
    height: float = 2.0
    period: float = 60.0
    phase: float = -np.pi / 2
    target_height: float = 0.0
    start: float = 0.0
    end: float = np.inf

    def __post_init__(self):
        c = as_array(self.center, "center", (3,))
        object.__setattr__(self, "center", tuple(float(x) for x in c))
        if not self.radius > 0:
            raise ValueError(f"radius: expected > 0 m, got {self.radius!r}")
        if not np.isfinite(self.period) or self.period == 0:
            raise ValueError(f"period: expected a finite non-zero time (s), got {self.period!r}")
        if abs(self.height - self.target_height) < 1e-9 and self.radius < 1e-9:
            raise ValueError("orbit: the sonar would sit on its target")

    def sample(self, times):
        t = self._times(times)
        a = self.phase + 2 * np.pi * t / self.period
        c = np.asarray(self.center)
        pos = c + np.column_stack([self.radius * np.cos(a), self.radius * np.sin(a), np.full_like(a, self.height)])
        target = c + np.array([0.0, 0.0, self.target_height])
        return look_rotations(target - pos), pos


def lawnmower(area, height: float, spacing: float, speed: float, *, tilt: float = np.deg2rad(30.0),
              turn_time: float = 2.0, start: float = 0.0) -> WaypointTrajectory:
    """A lawnmower survey of a rectangle at a constant height, legs along X spaced ``spacing`` along Y.

    Parameters
    ----------
    area : (x_min, x_max, y_min, y_max)
        The rectangle (world, m); legs run from ``x_min`` to ``x_max`` and back, the
        first at ``y_min``, the last at or before ``y_max``.
    height : float
        Sonar height (world Z, m).
    spacing : float
        Distance between neighbouring legs (m).
    speed : float
        Speed along the track (m/s).
    tilt : float
        Boresight depression below the horizontal (rad).
    turn_time : float
        Time (s) spent turning on the spot at each corner (heading changes there only).
    start : float
        Time of the first waypoint (s).

    Returns
    -------
    WaypointTrajectory
        Linear segments with Slerp: constant heading along each leg and each crossing.
    """
    x0, x1, y0, y1 = (float(v) for v in area)
    if not (x1 > x0 and y1 >= y0):
        raise ValueError(f"area: expected x_min < x_max and y_min <= y_max, got {list(area)}")
    for name, v in (("spacing", spacing), ("speed", speed), ("turn_time", turn_time)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name}: expected > 0, got {v!r}")
    n_legs = int(np.floor((y1 - y0) / spacing + 1e-9)) + 1
    corners = []
    for k in range(n_legs):
        y = y0 + k * spacing
        xs = (x0, x1) if k % 2 == 0 else (x1, x0)
        corners += [(xs[0], y), (xs[1], y)]
    corners = np.array(corners)
    # each straight segment is flown at constant heading; at a corner the body turns on the spot
    times, pos, heading = [], [], []
    t = start
    for i in range(len(corners) - 1):
        a, b = corners[i], corners[i + 1]
        h = np.arctan2(*(b - a)[::-1])
        if i > 0:
            t += turn_time
        times += [t, t + np.linalg.norm(b - a) / speed]
        pos += [a, b]
        heading += [h, h]
        t = times[-1]
    times, pos, heading = np.array(times), np.array(pos), np.array(heading)
    fwd = np.column_stack([np.cos(heading) * np.cos(tilt), np.sin(heading) * np.cos(tilt),
                           np.full_like(heading, -np.sin(tilt))])
    p3 = np.column_stack([pos, np.full(len(pos), float(height))])
    return WaypointTrajectory(times, p3, look_rotations(fwd), interpolation="linear")


def load_csv(path) -> WaypointTrajectory:
    """Timestamped sonar poses from a CSV file, linear + Slerp between rows.

    Header ``time,x,y,z,qx,qy,qz,qw``: time (s), position (world, m), unit quaternion
    of the sonar-to-world rotation in ROS order (x, y, z, w).
    """
    from scipy.spatial.transform import Rotation

    path = Path(path)
    cols = ["time", "x", "y", "z", "qx", "qy", "qz", "qw"]
    try:
        with open(path, newline="") as fh:
            reader = csv.DictReader(fh)
            header = [h.strip() for h in (reader.fieldnames or [])]
            missing = [c for c in cols if c not in header]
            if missing:
                raise ValueError(f"{path}: header: missing column(s) {missing}; expected {','.join(cols)}")
            rows = []
            for i, row in enumerate(reader, start=2):
                row = {k.strip(): v for k, v in row.items() if k is not None}
                try:
                    rows.append([float(row[c]) for c in cols])
                except (TypeError, ValueError):
                    raise ValueError(f"{path}: line {i}: expected numbers in {','.join(cols)}, got {row}") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None
    a = np.array(rows, float).reshape(-1, 8)
    if len(a) < 2:
        raise ValueError(f"{path}: expected at least 2 poses, got {len(a)}")
    if not np.all(np.isfinite(a)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(a), axis=1))[0])
        raise ValueError(f"{path}: line {bad + 2}: non-finite value")
    bad = np.flatnonzero(np.diff(a[:, 0]) <= 0)
    if bad.size:
        raise ValueError(f"{path}: line {bad[0] + 3}: time {a[bad[0] + 1, 0]!r} does not increase")
    nq = np.linalg.norm(a[:, 4:], axis=1)
    bad = np.flatnonzero(np.abs(nq - 1) > 1e-3)
    if bad.size:
        raise ValueError(f"{path}: line {bad[0] + 2}: quaternion norm {nq[bad[0]]:.6g}, expected 1")
    return WaypointTrajectory(a[:, 0], a[:, 1:4], Rotation.from_quat(a[:, 4:]), interpolation="linear")
