"""Warnings for renders that come out black for a reason the caller can fix."""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["BlindCameraWarning", "warn_if_blind"]


class BlindCameraWarning(UserWarning):
    """The camera sees none of the scene's bodies (the image is water only)."""


def warn_if_blind(hit: np.ndarray, pose, scene, stacklevel: int = 3) -> None:
    """Warn when no pixel's ray hits a body, naming the likely cause.

    The common cause is a pose built with the sonar's axes (``Pose.look_at(..., body="sonar")``,
    Z up) given to the camera, whose optical axis is its Z: the camera then looks up, at open
    water. A pose whose optical axis points within 30 degrees of the world's up is reported so.
    """
    if np.any(hit):
        return
    axis = np.asarray(pose.R, float)[:, 2]
    hint = ""
    if axis[2] > np.cos(np.deg2rad(30.0)):
        hint = (" Its optical axis (camera Z) points up, at the surface: is this a sonar-axes pose? Use "
                "Pose.look_at(eye, target, body='camera') or rig.camera_pose(sonar_pose).")
    names = ", ".join(scene.body_names()[:5])
    warnings.warn(f"simulate_optical: the camera at {np.round(pose.t, 3).tolist()} sees none of the bodies "
                  f"({names}{', ...' if len(scene) > 5 else ''}); the image is open water only.{hint}",
                  BlindCameraWarning, stacklevel=stacklevel)
