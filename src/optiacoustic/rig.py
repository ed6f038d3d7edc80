"""The opti-acoustic rig: a sonar and a camera rigidly mounted together.

Convention (thesis eq. 4.5): ``P_s = R @ P_o + t``, ``R = R_sonar_from_camera`` and ``t``
the camera centre in the sonar frame. A camera looking where the sonar looks, without
vergence, has ``R = R_SONAR_FROM_CAMERA_FORWARD``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ._validate import as_array
from .camera import PinholeCamera
from .frames import Pose, R_SONAR_FROM_CAMERA_FORWARD, _rotate, checked_rigid, rot_z, rotation_from_euler_xyz

__all__ = ["Rig"]


@dataclass(frozen=True, eq=False)
class Rig:
    """A calibrated sonar + camera pair.

    Parameters
    ----------
    R : array_like (3, 3)
        ``R_sonar_from_camera``.
    t : array_like (3,)
        Camera centre in the sonar frame (m).
    camera : PinholeCamera
    sonar : SonarSpec, optional
        The sonar; geometry reads its apertures (``fov_elevation``) from here.
    """

    R: np.ndarray
    t: np.ndarray
    camera: PinholeCamera
    sonar: Any = None

    def __post_init__(self):
        R, t = checked_rigid(self.R, self.t, "Rig")
        if not isinstance(self.camera, PinholeCamera):
            raise ValueError(f"Rig.camera: expected a PinholeCamera, got {type(self.camera).__name__}")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_poses(cls, sonar_pose: Pose, camera_pose: Pose, camera: PinholeCamera, sonar=None) -> "Rig":
        """The rig of a sonar and a camera at given world poses (camera pose with camera axes)."""
        rel = sonar_pose.inverse() @ camera_pose
        return cls(rel.R, rel.t, camera, sonar)

    @classmethod
    def toed_in(cls, camera: PinholeCamera, *, baseline: float = 0.25, vergence: float = 0.0, sonar=None) -> "Rig":
        """Camera ``baseline`` metres to the sonar's left, turned ``vergence`` (rad) towards the sonar's axis.

        The thesis's rig (sec. 4.3) is ``baseline=0.25`` with the vergence that aims both
        at a point about 6.3 m ahead (about 2.3 deg): its ``R ~ Rz(-2.3 deg)`` in the
        sonar's axes, times the axis change of a forward-looking camera.
        """
        return cls(rot_z(-vergence) @ R_SONAR_FROM_CAMERA_FORWARD, np.array([-baseline, 0.0, 0.0]), camera, sonar)

    @classmethod
    def from_dict(cls, data: dict, source: str = "<rig>") -> "Rig":
        """A rig from the rig-file mapping (see :meth:`load`)."""
        from .sonar.spec import SonarSpec

        if not isinstance(data, dict):
            raise ValueError(f"{source}: expected a mapping, got {type(data).__name__}")
        allowed = {"sonar", "camera", "camera_in_sonar", "R", "t"}
        extra = set(data) - allowed
        if extra:
            raise ValueError(f"{source}: field '{sorted(extra)[0]}': unknown; expected {sorted(allowed)}")
        sonar = SonarSpec.from_dict(data.get("sonar", "blueview-p900-90"), f"{source}: field 'sonar'")
        cam = data.get("camera", {"width_px": 600, "height_px": 400, "sensor_mm": [36, 24], "focal_mm": 50})
        if not isinstance(cam, dict):
            raise ValueError(f"{source}: field 'camera': expected a mapping, got {cam!r}")
        try:
            if "focal_mm" in cam:
                camera = PinholeCamera.from_sensor(**cam)
            else:
                camera = PinholeCamera(**cam)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: field 'camera': {exc}") from None
        if "R" in data or "t" in data:
            if "camera_in_sonar" in data:
                raise ValueError(f"{source}: fields 'R'/'t' and 'camera_in_sonar' both place the camera; give one")
            missing = [k for k in ("R", "t") if k not in data]
            if missing:
                raise ValueError(f"{source}: field '{missing[0]}' missing (R and t go together)")
            try:
                return cls(data["R"], data["t"], camera, sonar)
            except ValueError as exc:
                raise ValueError(f"{source}: fields 'R' and 't': {exc}") from None
        ext = data.get("camera_in_sonar", {}) or {}
        if not isinstance(ext, dict) or set(ext) - {"position", "rotation_deg"}:
            raise ValueError(f"{source}: field 'camera_in_sonar': expected a mapping with position and rotation_deg")
        try:
            pos = as_array(ext.get("position", [-0.25, 0.0, 0.0]), "camera_in_sonar.position", (3,))
            rot = np.deg2rad(as_array(ext.get("rotation_deg", [0.0, 0.0, 0.0]), "camera_in_sonar.rotation_deg", (3,)))
        except ValueError as exc:
            raise ValueError(f"{source}: {exc}") from None
        return cls(rotation_from_euler_xyz(rot) @ R_SONAR_FROM_CAMERA_FORWARD, pos, camera, sonar)

    @classmethod
    def load(cls, path) -> "Rig":
        """Read a rig file (YAML or JSON)::

            sonar: blueview-p900-90          # a preset, or {preset: ..., n_bins: ..., fov_elevation_deg: ...}
            camera: {width_px: 600, height_px: 400, sensor_mm: [36, 24], focal_mm: 50}
                    # or {fx, fy, cx, cy, width, height, dist}
            camera_in_sonar:                 # the camera on the rig, in the sonar frame
              position: [-0.25, 0, 0]        # t (m)
              rotation_deg: [0, 0, -2.27]    # about sonar x, y, z, applied to a forward-looking camera

        or ``R`` and ``t`` (the camera-to-sonar rotation and translation) instead of
        ``camera_in_sonar`` (not both). Every key may be left out, and takes the thesis's
        value (sec. 4.3): ``sonar`` the BlueView P900-90, ``camera`` 600 x 400 px, 36 x 24 mm,
        50 mm, ``camera_in_sonar`` position ``[-0.25, 0, 0]`` and rotation ``[0, 0, 0]`` (a
        forward-looking camera beside the sonar, no vergence). Unknown keys are refused.
        """
        from ._config import load_config

        path = Path(path)
        data = load_config(path, what="rig file")  # a ValueError naming the file and what is wrong
        return cls.from_dict(data, str(path))

    # ------------------------------------------------------------------ use
    def camera_pose(self, sonar_pose: Pose) -> Pose:
        """World pose of the camera (camera axes) given the sonar's world pose."""
        return sonar_pose @ Pose(self.R, self.t)

    def sonar_from_camera(self, points_camera) -> np.ndarray:
        """``P_s = R P_o + t`` for points ``(..., 3)``."""
        p = as_array(points_camera, "points_camera", ("...", 3), finite=False)
        return _rotate(p, self.R) + self.t

    def camera_from_sonar(self, points_sonar) -> np.ndarray:
        """``P_o = R^T (P_s - t)`` for points ``(..., 3)``."""
        p = as_array(points_sonar, "points_sonar", ("...", 3), finite=False)
        return _rotate(p - self.t, self.R.T)

    @property
    def baseline(self) -> float:
        """Distance between the sonar and camera centres (m)."""
        return float(np.linalg.norm(self.t))

    @property
    def vergence(self) -> float:
        """Angle (rad) between the camera's optical axis and the sonar's boresight."""
        axis = self.R[:, 2]
        return float(np.arccos(np.clip(axis[1], -1.0, 1.0)))

    @property
    def fov_elevation(self) -> float:
        """The sonar's elevation aperture (rad); pi when no sonar is attached."""
        return float(self.sonar.fov_elevation) if self.sonar is not None else np.pi

    def with_sonar(self, sonar) -> "Rig":
        return Rig(self.R, self.t, self.camera, sonar)

    def __repr__(self) -> str:
        name = getattr(self.sonar, "name", None)
        return (f"Rig(t={np.round(self.t, 4).tolist()}, vergence={np.rad2deg(self.vergence):.3f} deg, "
                f"camera={self.camera.width}x{self.camera.height}, sonar={name})")
