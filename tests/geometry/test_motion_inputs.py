"""motion.estimate's caller mistakes: each is a ValueError naming the argument and the value."""

import numpy as np
import pytest

from optiacoustic import PinholeCamera, Pose, Rig, SonarSpec
from optiacoustic.frames import project_to_sonar, rot_x, rot_z
from optiacoustic.geometry import motion

CAM = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
SPEC = SonarSpec.preset("blueview-p900-90")
RIG = Rig.toed_in(CAM, baseline=0.25, vergence=np.deg2rad(2.3), sonar=SPEC)
SIG = dict(sigma_pixel=1.0, sigma_range=0.01, sigma_azimuth=0.005)


def _plane_views(n_son=20):
    """Noise-free matches of a plane (the sonar ones as (ranges, azimuths) arrays)."""
    rng = np.random.default_rng(0)
    s1 = Pose.look_at([0, -1, 0], [0, 0.7, 0])
    s2 = Pose(rot_z(0.08) @ rot_x(0.05) @ s1.R, s1.t + np.array([0.25, 0.05, 0.1]))
    n = np.array([0.3, -1, 0.2]) / np.linalg.norm([0.3, -1, 0.2])
    a = np.cross(n, [0, 0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    uv = rng.uniform(-1.5, 1.5, (4000, 2))
    pts = np.array([0, 0.7, 0]) + uv[:, :1] * a + uv[:, 1:] * b
    c1, c2 = RIG.camera_pose(s1), RIG.camera_pose(s2)
    u1, u2 = CAM.project(c1.to_body(pts)), CAM.project(c2.to_body(pts))
    io = np.flatnonzero(CAM.in_image(u1) & CAM.in_image(u2))[:100]
    kw = dict(fov_azimuth=SPEC.fov_azimuth, fov_elevation=SPEC.fov_elevation, range_min=SPEC.range_min,
              range_max=SPEC.range_max)
    m1, m2 = project_to_sonar(s1.to_body(pts), **kw), project_to_sonar(s2.to_body(pts), **kw)
    is_ = np.flatnonzero(m1.in_fan & m2.in_fan)[:n_son]
    return (u1[io], u2[io], np.array([m1.ranges[is_], m1.azimuths[is_]]),
            np.array([m2.ranges[is_], m2.azimuths[is_]]))


P1, P2, SON1, SON2 = _plane_views()


def test_the_sonar_matches_as_a_2_by_m_array_or_a_pair_give_the_same_motion():
    a = motion.estimate(RIG, P1, P2, SON1, SON2, **SIG)
    b = motion.estimate(RIG, P1, P2, tuple(SON1), tuple(SON2), **SIG)
    assert a and b, (a.message, b.message)
    assert np.allclose(a.t_o, b.t_o) and np.allclose(a.R_o, b.R_o)


def test_azimuths_in_degrees_are_refused_naming_the_argument():
    deg1 = np.array([SON1[0], np.rad2deg(SON1[1])])
    with pytest.raises(ValueError, match=r"sonar_1 azimuths.*radians.*deg2rad"):
        motion.estimate(RIG, P1, P2, deg1, SON2, **SIG)
    deg2 = (SON2[0], np.rad2deg(SON2[1]))
    with pytest.raises(ValueError, match=r"sonar_2 azimuths.*radians"):
        motion.estimate(RIG, P1, P2, SON1, deg2, **SIG)


def test_an_m_by_2_sonar_array_is_refused_with_the_layout_expected():
    with pytest.raises(ValueError, match=r"sonar_1.*\(2, M\).*got shape \(20, 2\).*sonar_1\.T"):
        motion.estimate(RIG, P1, P2, SON1.T, SON2, **SIG)


def test_a_2_by_2_sonar_array_is_ambiguous_and_refused():
    # two matches as (M, 2) = (2, 2) used to be read as (2, M): ranges and azimuths mixed up
    with pytest.raises(ValueError, match=r"sonar_1: a \(2, 2\) array is ambiguous.*tuple"):
        motion.estimate(RIG, P1, P2, SON1[:, :2].T, SON2[:, :2], **SIG)
    # the same two matches as a pair of arrays are accepted
    res = motion.estimate(RIG, P1, P2, (SON1[0, :2], SON1[1, :2]), (SON2[0, :2], SON2[1, :2]), **SIG)
    assert res, res.message


@pytest.mark.parametrize("kw, match", [
    (dict(ransac_confidence=2.0), r"ransac_confidence: must be in \(0, 1\), got 2"),
    (dict(ransac_confidence=0.0), r"ransac_confidence"),
    (dict(ransac_confidence=1.0), r"ransac_confidence"),
    (dict(ransac_max_iters=0), r"ransac_max_iters: expected a positive integer, got 0"),
    (dict(ransac_max_iters=-5), r"ransac_max_iters"),
    (dict(ransac_max_iters=2.5), r"ransac_max_iters"),
    (dict(ransac_max_iters=True), r"ransac_max_iters"),
])
def test_ransac_settings_out_of_range_raise_value_error(kw, match):
    for model in ("homography", "essential"):
        with pytest.raises(ValueError, match=match):
            motion.estimate(RIG, P1, P2, SON1, SON2, model=model, **SIG, **kw)
