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

from .._validate import as_array, check_memory, is_number
from ..frames import Pose, are_rotations

__all__ = ["Trajectory", "WaypointTrajectory", "Orbit", "lawnmower", "load_csv", "frame_times", "look_rotations",
           "MAX_LEGS"]

#: Most legs a :func:`lawnmower` survey may have: more is a mistyped ``spacing`` (1e-7 m over a
#: 1000 m wide area is 1e10 legs, which built waypoints for hours without a word).
MAX_LEGS = 100_000


def _number(v, name: str) -> float:
    """A finite real number (bools and strings refused), as float; a ValueError naming ``name``."""
    if not is_number(v):
        raise ValueError(f"{name}: expected a number, got {v!r} ({type(v).__name__})")
    v = float(v)
    if not np.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {v!r}")
    return v


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
    nf = np.linalg.norm(f, axis=-1, keepdims=True)
    if np.any(nf < 1e-12):
        i = tuple(int(k) for k in np.argwhere(nf[..., 0] < 1e-12)[0])
        raise ValueError(f"forward_world: a viewing direction is the zero vector (at index {i}); "
                         "the body would look at its own position")
    f = f / nf
    up = as_array(up, "up", (3,))
    nu = np.linalg.norm(up)
    if nu < 1e-12:
        raise ValueError(f"up: must be a non-zero vector, got {up.tolist()}")
    right = np.cross(f, up / nu)
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
    rate, duration, start = _number(rate, "rate"), _number(duration, "duration"), _number(start, "start")
    if rate < 0:
        raise ValueError(f"rate: expected a finite rate >= 0 Hz, got {rate!r}")
    if duration <= 0:
        raise ValueError(f"duration: expected a finite duration > 0 s, got {duration!r}")
    if rate == 0:
        return np.zeros(0)
    n = int(np.ceil(duration * rate - 1e-9))  # k / rate < duration
    check_memory(16.0 * n, f"{n} frame times (duration {duration:g} s x rate {rate:g} Hz)")
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
        if isinstance(rotations, Rotation):
            rot = rotations
        else:
            m = as_array(rotations, "rotations", (len(t), 3, 3))
            ok = are_rotations(m)
            if not ok.all():  # scipy would orthonormalise any matrix into some rotation without a word
                k = int(np.flatnonzero(~ok)[0])
                raise ValueError(f"rotations[{k}]: not a rotation matrix (orthonormal, det +1; "
                                 f"det = {np.linalg.det(m[k]):.6g}), got {m[k].tolist()}")
            rot = Rotation.from_matrix(m)
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
        p = as_array(positions_world, "positions_world", (None, 3))
        q = as_array(targets_world, "targets_world", ("...", 3))
        try:
            q = np.broadcast_to(q, p.shape)
        except ValueError:
            raise ValueError(f"targets_world: expected shape (3,) or {p.shape}, got {q.shape}") from None
        same = np.linalg.norm(q - p, axis=-1) < 1e-12
        if np.any(same):
            k = int(np.flatnonzero(same)[0])
            raise ValueError(f"waypoint {k}: target == position ({p[k].tolist()}); the sonar cannot look at "
                             "its own position")
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
        for name in ("radius", "height", "period", "phase", "target_height", "start"):
            object.__setattr__(self, name, _number(getattr(self, name), f"Orbit.{name}"))
        end = self.end
        if not (is_number(end) and not np.isnan(end) and end != -np.inf):
            raise ValueError(f"Orbit.end: expected a number or inf, got {end!r}")
        object.__setattr__(self, "end", float(end))
        if not self.end > self.start:
            raise ValueError(f"Orbit.end: must be after start ({self.start:g} s), got {self.end:g} s")
        if not self.radius > 0:
            raise ValueError(f"radius: expected > 0 m, got {self.radius!r}")
        if self.period == 0:
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


def lawnmower_legs(area, spacing) -> int:
    """Number of legs of a :func:`lawnmower` survey of ``area`` with legs ``spacing`` apart.

    Raises a ValueError naming ``spacing`` and the count when it exceeds :data:`MAX_LEGS`.
    """
    x0, x1, y0, y1 = (float(v) for v in area)
    spacing = _number(spacing, "spacing")
    if not spacing > 0:
        raise ValueError(f"spacing: expected > 0, got {spacing!r}")
    n = np.floor((y1 - y0) / spacing + 1e-9) + 1
    if not n <= MAX_LEGS:  # also inf: a width of 1e300 m or a spacing of 1e-320 m
        raise ValueError(f"spacing: {spacing:g} m across {y1 - y0:g} m (y_max - y_min) makes {n:.6g} legs; "
                         f"at most {MAX_LEGS} (is the spacing in metres?)")
    return int(n)


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
    a = as_array(area, "area", (4,))
    x0, x1, y0, y1 = (float(v) for v in a)
    if not (x1 > x0 and y1 >= y0):
        raise ValueError(f"area: expected x_min < x_max and y_min <= y_max, got {a.tolist()}")
    height, tilt, start = _number(height, "height"), _number(tilt, "tilt"), _number(start, "start")
    for name, v in (("spacing", spacing), ("speed", speed), ("turn_time", turn_time)):
        if not _number(v, name) > 0:
            raise ValueError(f"{name}: expected > 0, got {v!r}")
    n_legs = lawnmower_legs((x0, x1, y0, y1), spacing)
    # corners of the legs: leg k at y0 + k spacing, flown +X on even legs and -X on odd ones
    y = y0 + np.arange(n_legs) * float(spacing)
    even = np.arange(n_legs) % 2 == 0
    xs = np.column_stack([np.where(even, x0, x1), np.where(even, x1, x0)]).reshape(-1)
    corners = np.column_stack([xs, np.repeat(y, 2)])
    # each straight segment is flown at constant heading; at a corner the body turns on the spot
    seg = np.diff(corners, axis=0)
    dur = np.linalg.norm(seg, axis=1) / float(speed)
    t0 = start + np.concatenate([[0.0], np.cumsum(dur[:-1])]) + np.arange(len(seg)) * float(turn_time)
    times = np.column_stack([t0, t0 + dur]).reshape(-1)
    pos = np.stack([corners[:-1], corners[1:]], axis=1).reshape(-1, 2)
    heading = np.repeat(np.arctan2(seg[:, 1], seg[:, 0]), 2)
    fwd = np.column_stack([np.cos(heading) * np.cos(tilt), np.sin(heading) * np.cos(tilt),
                           np.full_like(heading, -np.sin(tilt))])
    p3 = np.column_stack([pos, np.full(len(pos), height)])
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
