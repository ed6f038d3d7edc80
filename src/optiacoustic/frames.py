"""Frames, poses, rotations and the sonar's spherical coordinates.

Conventions (docs/conventions.md has the drawing):

* World: right-handed, Z up.
* :class:`Pose` maps body to world: ``P_world = R @ P_body + t``.
* Sonar frame: X right (starboard), Y forward (boresight), Z up. Range ``r = |P|``,
  azimuth ``theta = atan2(X, Y)`` (positive to the right), elevation
  ``phi = atan2(Z, hypot(X, Y))``. Fan-image coordinates ``(x_s, y_s) = r (sin theta, cos theta)``.
* Camera frame (OpenCV): X right, Y down, Z forward.

Every function broadcasts over leading axes: a point is ``(3,)`` or ``(..., 3)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, NamedTuple

import numpy as np

from ._validate import as_array

__all__ = [
    "Pose",
    "R_SONAR_FROM_CAMERA_FORWARD",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotation_from_euler_xyz",
    "euler_xyz_from_rotation",
    "orthonormalize",
    "is_rotation",
    "are_rotations",
    "skew",
    "sonar_from_spherical",
    "spherical_from_sonar",
    "fan_from_polar",
    "polar_from_fan",
    "SonarProjection",
    "project_to_sonar",
]

#: ``R_sonar_from_camera`` of a camera that looks where the sonar looks (no vergence):
#: camera X -> sonar X, camera Y (down) -> sonar -Z, camera Z (forward) -> sonar Y.
R_SONAR_FROM_CAMERA_FORWARD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


# --------------------------------------------------------------------------- rotations
def rot_x(angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about the X axis (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about the Y axis (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    """Rotation by ``angle`` (rad) about the Z axis (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_from_euler_xyz(angles) -> np.ndarray:
    """Rotation about fixed X, then fixed Y, then fixed Z: ``Rz(c) @ Ry(b) @ Rx(a)``.

    Parameters
    ----------
    angles : array_like, shape (3,)
        ``(a, b, c)`` in radians. This is the order of the scene files' ``rotation_deg``
        and of the thesis's eq. (A.2).
    """
    a, b, c = as_array(angles, "angles", (3,))
    return rot_z(c) @ rot_y(b) @ rot_x(a)


def euler_xyz_from_rotation(R) -> np.ndarray:
    """Inverse of :func:`rotation_from_euler_xyz` (angles in radians, ``|b| <= pi/2``)."""
    R = as_array(R, "R", (3, 3))
    b = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    if abs(np.cos(b)) > 1e-9:
        a = np.arctan2(R[2, 1], R[2, 2])
        c = np.arctan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: only a - c (or a + c) is defined; put it all in a
        a = np.arctan2(-R[1, 2], R[1, 1])
        c = 0.0
    return np.array([a, b, c])


def skew(v) -> np.ndarray:
    """Cross-product matrix ``[v]_x`` with ``[v]_x @ w == cross(v, w)``; ``(..., 3) -> (..., 3, 3)``."""
    v = np.asarray(v, float)
    z = np.zeros_like(v[..., 0])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def orthonormalize(R) -> np.ndarray:
    """Nearest rotation matrix (Frobenius norm) by SVD, with ``det = +1``; batched."""
    R = np.asarray(R, float)
    U, _, Vt = np.linalg.svd(R)
    d = np.sign(np.linalg.det(U @ Vt))
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


_EYE3 = np.eye(3)


def are_rotations(R, tol: float = 1e-6) -> np.ndarray:
    """:func:`is_rotation` of each ``(..., 3, 3)`` matrix at once: a bool array ``(...)``."""
    R = np.asarray(R, float)
    ok = np.isfinite(R).all(axis=(-2, -1))
    Rf = np.where(ok[..., None, None], R, _EYE3)
    ortho = (np.abs(np.einsum("...ji,...jk->...ik", Rf, Rf) - _EYE3) <= tol + 1e-5 * _EYE3).all(axis=(-2, -1))
    return ok & ortho & (np.abs(np.linalg.det(Rf) - 1.0) < tol)


def is_rotation(R, tol: float = 1e-6) -> bool:
    """True when ``R`` is a 3x3 proper rotation to within ``tol``."""
    R = np.asarray(R, float)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        return False
    # what np.allclose(R^T R, I, atol=tol) and det(R) = 1 test, without their per-call overhead
    # (scene files build one Pose per body: this check ran 20x longer than the rotation itself)
    if not (np.abs(R.T @ R - _EYE3) <= tol + 1e-5 * _EYE3).all():
        return False
    det = (R[0, 0] * (R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1]) - R[0, 1] * (R[1, 0] * R[2, 2] - R[1, 2] * R[2, 0])
           + R[0, 2] * (R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0]))
    return bool(abs(det - 1.0) < tol)


def _rotate(v: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``R @ v`` for vectors ``(..., 3)``.

    ``einsum`` rather than ``v @ R.T``: a ``(N, 3) @ (3, 3)`` product goes to the
    threaded BLAS, which on a 2-core machine busy with ray-casting threads can stall for
    tens of milliseconds; einsum's own loop costs a predictable ~12 ns per vector.
    """
    return np.einsum("ij,...j->...i", R, v)


def checked_rigid(R, t, owner: str, tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Validated, read-only copies of a rigid transform's ``R`` (3, 3) and ``t`` (3,).

    The one check behind :class:`Pose`, ``Rig`` and ``StereoRig``: finite, the right
    shapes, ``R`` a proper rotation to ``tol``; errors name ``owner.R`` / ``owner.t``.
    """
    R = as_array(R, f"{owner}.R", (3, 3))
    t = as_array(t, f"{owner}.t", (3,))
    if not is_rotation(R, tol):
        raise ValueError(f"{owner}.R: not a proper rotation (R^T R != I or det != 1): {np.round(R, 6).tolist()}")
    R, t = R.copy(), t.copy()
    R.setflags(write=False)
    t.setflags(write=False)
    return R, t


# --------------------------------------------------------------------------- pose
@dataclass(frozen=True, eq=False)
class Pose:
    """A rigid transform from a body frame to the world: ``P_world = R @ P_body + t``.

    Parameters
    ----------
    R : array_like, shape (3, 3)
        Rotation; its columns are the body's axes expressed in the world.
    t : array_like, shape (3,)
        Position of the body's origin in the world (m).
    """

    R: np.ndarray
    t: np.ndarray

    def __post_init__(self):
        R, t = checked_rigid(self.R, self.t, "Pose", tol=1e-5)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    # construction ---------------------------------------------------------------
    @classmethod
    def identity(cls) -> "Pose":
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_euler_deg(cls, position=(0.0, 0.0, 0.0), rotation_deg=(0.0, 0.0, 0.0)) -> "Pose":
        """Pose from a position (m) and rotations (deg) about fixed x, then y, then z."""
        ang = np.deg2rad(as_array(rotation_deg, "rotation_deg", (3,)))
        return cls(rotation_from_euler_xyz(ang), as_array(position, "position", (3,)))

    @classmethod
    def look_at(
        cls,
        eye,
        target,
        up=(0.0, 0.0, 1.0),
        body: Literal["sonar", "camera"] = "sonar",
    ) -> "Pose":
        """Pose of a sensor at ``eye`` aimed at ``target``, level with respect to ``up``.

        Parameters
        ----------
        eye, target : array_like, shape (3,)
            World positions (m).
        up : array_like, shape (3,)
            World direction that the sensor's "up" should lean towards.
        body : {"sonar", "camera"}
            Axis convention of the body: the sonar's (X right, Y forward, Z up) or the
            camera's (OpenCV: X right, Y down, Z forward).

        Raises
        ------
        ValueError
            If ``eye == target`` or the viewing direction is parallel to ``up`` (looking
            straight up or down leaves the roll undefined: pass another ``up``).
        """
        eye = as_array(eye, "eye", (3,))
        target = as_array(target, "target", (3,))
        up = as_array(up, "up", (3,))
        forward = target - eye
        n = np.linalg.norm(forward)
        if n < 1e-12:
            raise ValueError(f"look_at: eye and target coincide at {eye.tolist()}")
        forward = forward / n
        if np.linalg.norm(up) < 1e-12:
            raise ValueError("look_at: up must be a non-zero vector")
        right = np.cross(forward, up / np.linalg.norm(up))
        nr = np.linalg.norm(right)
        if nr < 1e-6:
            raise ValueError(
                f"look_at: the viewing direction {np.round(forward, 6).tolist()} is parallel to "
                f"up={up.tolist()} (looking straight up or down); pass a different up vector"
            )
        right /= nr
        body_up = np.cross(right, forward)
        if body == "sonar":
            R = np.column_stack([right, forward, body_up])
        elif body == "camera":
            R = np.column_stack([right, -body_up, forward])
        else:
            raise ValueError(f"look_at: body must be 'sonar' or 'camera', got {body!r}")
        return cls(R, eye)

    # algebra --------------------------------------------------------------------
    def __matmul__(self, other: "Pose") -> "Pose":
        """Composition: ``(a @ b).to_world(p) == a.to_world(b.to_world(p))``."""
        if not isinstance(other, Pose):
            return NotImplemented
        return Pose(self.R @ other.R, self.R @ other.t + self.t)

    def inverse(self) -> "Pose":
        return Pose(self.R.T, -self.R.T @ self.t)

    def to_world(self, points_body) -> np.ndarray:
        """Body-frame points ``(..., 3)`` to world-frame points ``(..., 3)``."""
        p = as_array(points_body, "points_body", ("...", 3))
        return _rotate(p, self.R) + self.t

    def to_body(self, points_world) -> np.ndarray:
        """World-frame points ``(..., 3)`` to body-frame points ``(..., 3)``."""
        p = as_array(points_world, "points_world", ("...", 3))
        return _rotate(p - self.t, self.R.T)

    def directions_to_world(self, directions_body) -> np.ndarray:
        """Rotate body-frame directions ``(..., 3)`` into the world (no translation)."""
        d = as_array(directions_body, "directions_body", ("...", 3))
        return _rotate(d, self.R)

    def as_matrix(self) -> np.ndarray:
        """Homogeneous 4x4 matrix."""
        M = np.eye(4)
        M[:3, :3] = self.R
        M[:3, 3] = self.t
        return M

    def __repr__(self) -> str:
        e = np.rad2deg(euler_xyz_from_rotation(self.R))
        return f"Pose(t={np.round(self.t, 4).tolist()}, euler_xyz_deg={np.round(e, 3).tolist()})"

    def __eq__(self, other) -> bool:
        return isinstance(other, Pose) and np.array_equal(self.R, other.R) and np.array_equal(self.t, other.t)

    __hash__ = None  # type: ignore[assignment]


# --------------------------------------------------------------------------- sonar spherical
def sonar_from_spherical(ranges, azimuths, elevations) -> np.ndarray:
    """Sonar-frame points from range (m), azimuth and elevation (rad) (eq. 4.1).

    ``P = r (cos(phi) sin(theta), cos(phi) cos(theta), sin(phi))``. Inputs broadcast;
    the result has shape ``broadcast + (3,)``.
    """
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    ph = np.asarray(elevations, float)
    cp = np.cos(ph)
    return np.stack(np.broadcast_arrays(r * cp * np.sin(th), r * cp * np.cos(th), r * np.sin(ph)), -1)


def spherical_from_sonar(points_sonar) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Range (m), azimuth and elevation (rad) of sonar-frame points ``(..., 3)`` (eq. 4.2)."""
    p = as_array(points_sonar, "points_sonar", ("...", 3), finite=False)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    rho = np.hypot(x, y)
    return np.sqrt(rho * rho + z * z), np.arctan2(x, y), np.arctan2(z, rho)


def fan_from_polar(ranges, azimuths) -> tuple[np.ndarray, np.ndarray]:
    """Fan-image coordinates ``(x_s, y_s) = r (sin theta, cos theta)`` (m)."""
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    return r * np.sin(th), r * np.cos(th)


def polar_from_fan(x_s, y_s) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`fan_from_polar`: ``(range, azimuth)``."""
    x_s = np.asarray(x_s, float)
    y_s = np.asarray(y_s, float)
    return np.hypot(x_s, y_s), np.arctan2(x_s, y_s)


class SonarProjection(NamedTuple):
    """What a sonar measures of points, and whether it can see them.

    ``ranges``, ``azimuths``, ``elevations`` have the points' leading shape; ``in_fan`` is
    True where the point lies inside the fan (azimuth and elevation apertures and range
    window). Measurements are returned for every point; use ``in_fan`` to mask.
    """

    ranges: np.ndarray
    azimuths: np.ndarray
    elevations: np.ndarray
    in_fan: np.ndarray


def project_to_sonar(
    points_sonar,
    *,
    fov_azimuth: float = np.pi,
    fov_elevation: float = np.pi,
    range_min: float = 0.0,
    range_max: float = np.inf,
) -> SonarProjection:
    """Project sonar-frame points ``(..., 3)`` to (range, azimuth, elevation) with an in-fan mask.

    Points at the sonar's origin get NaN measurements and ``in_fan = False``.
    """
    p = as_array(points_sonar, "points_sonar", ("...", 3), finite=False)
    r, th, ph = spherical_from_sonar(p)
    bad = ~np.all(np.isfinite(p), axis=-1) | (r <= 0)
    r = np.where(bad, np.nan, r)
    th = np.where(bad, np.nan, th)
    ph = np.where(bad, np.nan, ph)
    with np.errstate(invalid="ignore"):
        inside = (
            ~bad
            & (np.abs(th) <= fov_azimuth / 2)
            & (np.abs(ph) <= fov_elevation / 2)
            & (r >= range_min)
            & (r <= range_max)
        )
    return SonarProjection(r, th, ph, inside)
