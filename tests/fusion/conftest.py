"""Shared ground truth for the fusion tests: a rig and exact 3D features, observed by hand.

Truth never comes from :mod:`optiacoustic.fusion`: the features are chosen 3D points, seen by
the sonar through ``spherical_from_sonar`` / ``fan_from_polar`` and by the camera through
``PinholeCamera.project``.
"""

from dataclasses import dataclass

import numpy as np
import pytest

from optiacoustic.camera import PinholeCamera
from optiacoustic.frames import Pose, fan_from_polar, spherical_from_sonar
from optiacoustic.rig import Rig
from optiacoustic.sonar import SonarSpec

EYE = np.array([0.0, -3.5, 1.8])
TARGET = np.array([0.0, 0.0, 0.0])
BAR_TOP = 0.03


@dataclass
class Setup:
    sonar_pose: Pose
    camera_pose: Pose
    rig: Rig

    def observe(self, points_world):
        """Fan coordinates (N, 2), pixels (N, 2) and elevations (N,) of world points."""
        p_s = self.sonar_pose.to_body(points_world)
        r, th, ph = spherical_from_sonar(p_s)
        xy = np.stack(fan_from_polar(r, th), -1)
        px = self.rig.camera.project(self.camera_pose.to_body(points_world))
        return xy, px, ph


@pytest.fixture(scope="session")
def setup():
    sonar = Pose.look_at(EYE, TARGET)
    camera = Pose.look_at(EYE - 0.25 * sonar.R[:, 0], TARGET, body="camera")
    cam = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
    return Setup(sonar, camera, Rig.from_poses(sonar, camera, cam, SonarSpec.preset("blueview-p900-90")))


def grid_points(step):
    """Points on the 5 x 5 bar lines (x or y in {-1, -0.5, ..., 1}) of the 2 x 2 m grid, every ``step`` m."""
    lines = np.linspace(-1.0, 1.0, 5)
    along = np.arange(-1.0, 1.0 + 1e-9, step)
    pts = [(a, c) for c in lines for a in along] + [(c, a) for c in lines for a in along]
    pts = np.unique(np.round(pts, 9), axis=0)
    return np.column_stack([pts, np.full(len(pts), BAR_TOP)])


@pytest.fixture(scope="session")
def grid(setup):
    """Training at the cells' corners and edge midpoints, test a third along the cells' edges."""
    train = grid_points(0.25)
    lines = np.linspace(-1.0, 1.0, 5)
    thirds = np.sort(np.concatenate([lines[:-1] + 0.5 / 3, lines[:-1] + 1.0 / 3]))
    test = [(a, c) for c in lines for a in thirds] + [(c, a) for c in lines for a in thirds]
    test = np.column_stack([np.array(test), np.full(len(test), BAR_TOP)])
    xy_tr, px_tr, _ = setup.observe(train)
    xy_te, px_te, _ = setup.observe(test)
    return xy_tr, px_tr, xy_te, px_te
