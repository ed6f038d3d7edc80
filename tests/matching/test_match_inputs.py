"""match() and its helpers on unusual and bad inputs: clear errors naming the argument or field, and the
geometry kept where an input is legitimate (truths from the rig's transforms and trigonometry, not the matcher)."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from optiacoustic.experiments.matching import moved_view, random_scene, simulate_pair
from optiacoustic.matching import (CfarOptions, KeypointOptions, MatchOptions, SeabedPlane, detect_camera_features,
                                   detect_sonar_features, elevation_bounds, fit_seabed, match)
from optiacoustic.matching.acoustic import seabed_elevation
from optiacoustic.rig import Rig

SEED = 201


@pytest.fixture(scope="module")
def pair():
    """A seeded random scene of boxes, cylinders and spheres on a seabed, thesis water."""
    return simulate_pair(random_scene(SEED), "thesis", "default", SEED)


def _frame(s, spec=None, **kw):
    """A protocol sonar frame with the simulated one's arrays and the given spec (and attributes)."""
    return SimpleNamespace(image=np.asarray(s.image), ranges=np.asarray(s.ranges), azimuths=np.asarray(s.azimuths),
                           spec=s.spec if spec is None else spec, **kw)


def _sonar_coordinates(rig, points_camera):
    """Range, azimuth and elevation of camera-frame points in the sonar frame (P_s = R P_c + t, thesis eq. 4.5)."""
    P = np.asarray(points_camera, float) @ np.asarray(rig.R).T + np.asarray(rig.t)
    r = np.linalg.norm(P, axis=1)
    return r, np.arctan2(P[:, 0], P[:, 1]), np.arctan2(P[:, 2], np.hypot(P[:, 0], P[:, 1]))


# D1 -------------------------------------------------------------------------------------------------------------

def test_arc_match_without_acoustic_evidence(pair):
    """use_acoustic=False used to crash the default arc method (no seabed); now its matches lie on their arcs."""
    s, o, rig = pair
    opt = MatchOptions(use_acoustic=False)
    m = match(s, o.image, rig, options=opt, min_score=0.0)
    assert len(m) > 0 and m.seabed is None
    r, th, phi = _sonar_coordinates(rig, m.points)
    # every point is its sonar feature's (range, azimuth) inside the aperture, and projects to its pixel
    np.testing.assert_allclose(r, m.ranges, atol=0.05)
    np.testing.assert_allclose(th, m.azimuths, atol=np.deg2rad(0.5))
    assert np.all(np.abs(phi) <= rig.sonar.fov_elevation / 2 + np.deg2rad(0.5))
    P = np.asarray(m.points)
    K = rig.camera.K
    u = K[0, 0] * P[:, 0] / P[:, 2] + K[0, 2]
    v = K[1, 1] * P[:, 1] / P[:, 2] + K[1, 2]
    assert np.all(P[:, 2] > 0)
    np.testing.assert_allclose(np.column_stack([u, v]), m.pixels, atol=1.0)
    assert np.all((m.score > 0) & (m.score < 1))
    match(s, o.image, rig, options=opt)  # the default threshold: runs too (falsy or not)


# D2 -------------------------------------------------------------------------------------------------------------

def test_corner_matches_with_a_second_view(pair):
    """method='corners' with a second view used to fail on the corners' missing elevations."""
    s, o, rig = pair
    s2, o2, mo = moved_view(random_scene(SEED), dict(surge=0.3, sway=0.25, heave=0.0, yaw_deg=2.0), SEED)
    corners = MatchOptions(method="corners")
    one = match(s, o.image, rig, options=corners, min_score=0.0)
    assert len(one) > 0
    # the corner matches now carry their points' elevation (sonar frame, computed here from the rig)
    np.testing.assert_allclose(one.features["elevation"], _sonar_coordinates(rig, one.points)[2], atol=1e-9)
    two = match(s, o.image, rig, options=corners, min_score=0.0, second=(s2, o2.image), motion=mo)
    assert len(two) > 0 and "second view" in two.message
    fin = np.isfinite(two.points).all(axis=1)
    assert np.all(fin | np.isnan(two.points).all(axis=1))  # a point is whole or NaN
    assert np.all(two.points[fin, 2] > 0)
    r, th, _ = _sonar_coordinates(rig, two.points[fin])
    np.testing.assert_allclose(r, two.ranges[fin], atol=0.1)


# D3 -------------------------------------------------------------------------------------------------------------

def test_rig_sonar_that_disagrees_with_the_frame_is_refused(pair):
    s, o, rig = pair
    narrow = dataclasses.replace(s.spec, fov_elevation=float(np.deg2rad(12.0)))
    with pytest.raises(ValueError, match=r"rig\.sonar\.fov_elevation.*12 deg.*sonar\.spec\.fov_elevation.*20 deg"):
        match(s, o.image, rig.with_sonar(narrow))
    with pytest.raises(ValueError, match=r"sonar\.azimuths: beam .* lies outside rig\.sonar\.fov_azimuth = 1\.047 rad"):
        match(s, o.image, rig.with_sonar(dataclasses.replace(s.spec, fov_azimuth=float(np.deg2rad(60.0)))))
    # another range window or a wider fan on the rig is not a disagreement: the frame's own ranges and azimuths
    # are the measurements (a log recorded at a shorter range than the rig's preset)
    b = match(s, o.image, rig, min_score=0.0)
    for other in (dataclasses.replace(s.spec, range_max=30.0),
                  dataclasses.replace(s.spec, fov_azimuth=float(np.deg2rad(130.0)))):
        np.testing.assert_array_equal(match(s, o.image, rig.with_sonar(other), min_score=0.0).pixels, b.pixels)
    # a field the frame's spec marks unverified (not in the data) is not compared: the rig's is the better word
    unverified = dataclasses.replace(s.spec, fov_elevation=float(np.deg2rad(12.0)),
                                     unverified=("fov_elevation (not in the ping)",))
    a = match(_frame(s, unverified), o.image, rig, min_score=0.0)
    np.testing.assert_array_equal(a.pixels, b.pixels)


# D4 -------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("normal, what", [(np.array([0.0, 1.0]), "shape"), (np.array([0.0, np.inf, 1.0]), "finite"),
                                          (np.array([0.0, 0.0, 2.0]), "unit"), (np.zeros(3), "unit"),
                                          (np.array([0.0, np.nan, 1.0]), "finite")])
def test_seabed_plane_normal_is_checked(normal, what):
    with pytest.raises(ValueError, match=rf"SeabedPlane\.normal.*{what}"):
        SeabedPlane(normal, -2.0, 0.0, 0)
    with pytest.raises(ValueError, match=r"SeabedPlane\.offset"):
        SeabedPlane(np.array([0.0, 0.0, 1.0]), float("nan"), 0.0, 0)
    assert not SeabedPlane(np.full(3, np.nan), np.nan, np.nan, 0, "none")  # "no plane" is still allowed


def test_seabed_with_the_sonar_under_it_is_refused(pair):
    """(-n, -d) is the same plane with its normal pointing down: heights change sign, the matcher's evidence with
    them; the sonar (at the origin, height -offset) is then under the seabed, which match() refuses."""
    s, o, rig = pair
    up = SeabedPlane.from_pose(s.pose, 0.0)
    assert up.offset < 0 and up.height(np.zeros(3)) == pytest.approx(s.pose.t[2])  # the sonar's altitude
    down = SeabedPlane(-up.normal, -up.offset, 0.0, 0)
    with pytest.raises(ValueError, match=r"seabed: the sonar must be above.*offset = [0-9.]+ m.*pointing down"):
        match(s, o.image, rig, seabed=down)
    assert match(s, o.image, rig, seabed=up, min_score=0.0)


# D5 -------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("fov", [0.0, -0.35, 20.0, float("nan"), "wide"])
def test_frame_spec_fov_elevation_is_checked(pair, fov):
    s, o, rig = pair
    bare = Rig(rig.R, rig.t, rig.camera)
    spec = SimpleNamespace(fov_azimuth=s.spec.fov_azimuth, fov_elevation=fov)
    with pytest.raises(ValueError, match=r"sonar\.spec\.fov_elevation") as e:
        match(_frame(s, spec, beam_model="thesis"), o.image, bare)
    if fov == 20.0:
        assert "degrees" in str(e.value)


def test_frame_spec_fov_azimuth(pair):
    s, o, rig = pair
    bare = Rig(rig.R, rig.t, rig.camera)
    with pytest.raises(ValueError, match=r"sonar\.spec\.fov_azimuth.*degrees"):
        match(_frame(s, SimpleNamespace(fov_azimuth=90.0, fov_elevation=s.spec.fov_elevation)), o.image, bare)
    with pytest.raises(ValueError, match=r"sonar\.spec\.range_resolution"):
        match(_frame(s, SimpleNamespace(fov_azimuth=s.spec.fov_azimuth, fov_elevation=s.spec.fov_elevation,
                                        range_resolution=float("nan"))), o.image, bare)
    # without fov_azimuth the beams' span stands in (the docstring's promise: only fov_elevation is needed)
    m = match(_frame(s, SimpleNamespace(fov_elevation=s.spec.fov_elevation)), o.image, bare, min_score=0.0)
    assert len(m) > 0


# D6 -------------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kw, field", [(dict(min_run=0), "min_run"), (dict(factor=-1.0), "factor"),
                                       (dict(factor=float("nan")), "factor"), (dict(max_features=-5), "max_features"),
                                       (dict(max_features=2.5), "max_features"), (dict(nms=(0, 0)), "nms"),
                                       (dict(guard=3), "guard"), (dict(train=(0, 0)), "train"),
                                       (dict(onsets="yes"), "onsets")])
def test_cfar_options_are_checked(kw, field):
    with pytest.raises(ValueError, match=rf"CfarOptions\.{field}: ") as e:
        CfarOptions(**kw)
    assert repr(kw[field]) in str(e.value)  # the value given


@pytest.mark.parametrize("field, value", [("gate", -1.0), ("null_cost", -1.0), ("elevation_sigma", -0.01),
                                          ("elevation_sigma", float("nan")), ("arc_threshold", -1.0),
                                          ("seabed_clearance", -0.1), ("occupancy_factor", 0.0),
                                          ("use_acoustic", "no"), ("cfar", {"factor": 6})])
def test_match_options_are_checked(field, value):
    with pytest.raises(ValueError, match=rf"MatchOptions\.{field}"):
        MatchOptions(**{field: value})


@pytest.mark.parametrize("field, value", [("max_corners", -1), ("max_corners", 2.5), ("quality", 0.0),
                                          ("quality", 1.5), ("min_distance", -1.0), ("clahe_clip", float("nan"))])
def test_keypoint_options_are_checked(field, value):
    with pytest.raises(ValueError, match=rf"KeypointOptions\.{field}"):
        KeypointOptions(**{field: value})
    with pytest.raises(ValueError, match="options"):
        detect_camera_features(np.zeros((8, 8, 3)), {"quality": 0.1})


@pytest.mark.parametrize("min_score", ["0.5", float("nan"), 1.5, -0.1, None])
def test_min_score_is_checked(pair, min_score):
    s, o, rig = pair
    with pytest.raises(ValueError, match=r"min_score: .*\[0, 1\]"):
        match(s, o.image, rig, min_score=min_score)


def test_options_must_be_match_options(pair):
    s, o, rig = pair
    for bad in ({"gate": 3}, {}, "arc"):
        with pytest.raises(ValueError, match=r"options: expected a MatchOptions"):
            match(s, o.image, rig, options=bad)


# D7 -------------------------------------------------------------------------------------------------------------

def test_detect_sonar_features_checks_its_inputs(pair):
    s, _, _ = pair
    img, r, th = np.asarray(s.image, float), np.asarray(s.ranges), np.asarray(s.azimuths)
    kw = dict(range_resolution=0.03, beamwidth=0.018)
    for bad in (np.nan, np.inf):
        a = img.copy()
        a[100, 100] = bad
        with pytest.raises(ValueError, match=r"image: must be finite.*\(100, 100\)"):
            detect_sonar_features(a, r, th, **kw)
    with pytest.raises(ValueError, match=r"ranges: must be strictly increasing"):
        detect_sonar_features(img, r[::-1], th, **kw)
    with pytest.raises(ValueError, match=r"azimuths: must be strictly increasing"):
        detect_sonar_features(img, r, th[::-1], **kw)
    r_nan = r.copy()
    r_nan[5] = np.nan
    with pytest.raises(ValueError, match=r"ranges: must be finite"):
        detect_sonar_features(img, r_nan, th, **kw)
    with pytest.raises(ValueError, match=r"range_resolution"):
        detect_sonar_features(img, r, th, range_resolution=-0.03, beamwidth=0.018)


def test_fit_seabed_checks_its_inputs(pair):
    s, _, rig = pair
    img, r, th = np.asarray(s.image, float), np.asarray(s.ranges), np.asarray(s.azimuths)
    fov = rig.fov_elevation
    with pytest.raises(ValueError, match=r"image: expected shape \(100, "):
        fit_seabed(img, r[:100], th, fov)
    with pytest.raises(ValueError, match=r"fov_elevation.*nan"):
        fit_seabed(img, r, th, float("nan"))
    with pytest.raises(ValueError, match=r"fov_elevation.*20.*degrees"):
        fit_seabed(img, r, th, 20.0)
    with pytest.raises(ValueError, match=r"min_beams.*0"):
        fit_seabed(np.zeros_like(img), r, th, fov, min_beams=0)
    assert fit_seabed(img, r, th, fov)  # the legitimate call still fits


def test_elevation_bounds_needs_cells_inside_the_image(pair):
    s, _, rig = pair
    img, r, th = np.asarray(s.image, float), np.asarray(s.ranges), np.asarray(s.azimuths)
    plane = fit_seabed(img, r, th, rig.fov_elevation)
    for bins, beams, name in (([-1], [10], "bins"), ([img.shape[0]], [10], "bins"), ([10.5], [10], "bins"),
                              ([10], [-1], "beams"), ([10], [img.shape[1]], "beams")):
        with pytest.raises(ValueError, match=rf"{name}: expected"):
            elevation_bounds(img, r, th, bins, beams, plane, rig.fov_elevation)
    lo, hi, _ = elevation_bounds(img, r, th, [10.0, 200], [10, 30], plane, rig.fov_elevation)  # integral floats
    assert lo.shape == hi.shape == (2,)


def test_seabed_elevation_is_nan_without_an_arc():
    """Flat seabed 2 m under a level sonar: the arc at range r meets it at elevation -asin(2 / r); a range that is
    not > 0 (or shorter than the altitude) has no crossing: NaN."""
    plane = SeabedPlane(np.array([0.0, 0.0, 1.0]), -2.0, 0.0, 0)
    r = np.array([4.0, 8.0, -4.0, 0.0, 1.0, np.nan])
    phi = seabed_elevation(plane, r, np.zeros(r.size))
    np.testing.assert_allclose(phi[:2], -np.arcsin(2.0 / r[:2]), atol=1e-12)
    assert np.all(np.isnan(phi[2:]))


# D8 -------------------------------------------------------------------------------------------------------------

def test_second_view_arguments(pair):
    s, o, rig = pair
    with pytest.raises(ValueError, match=r"motion: given without 'second'"):
        match(s, o.image, rig, motion=(np.eye(3), np.zeros(3)))
    bad = _frame(s)
    bad.image = np.asarray(s.image, float).copy()
    bad.image[3, 3] = np.nan
    with pytest.raises(ValueError, match=r"second view.*sonar\.image"):
        match(s, o.image, rig, second=(bad, o.image), motion=(np.eye(3), np.zeros(3)))


def test_unknown_beam_model_is_refused(pair):
    s, o, rig = pair
    with pytest.raises(ValueError, match=r"sonar\.beam_model.*'soft'"):
        match(_frame(s, beam_model="soft"), o.image, rig)
