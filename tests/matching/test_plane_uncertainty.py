"""A seabed plane given with a declared error (navigation): what that error does to a seabed point.

The seabed point is the pixel that sees where a feature's arc meets the plane. If the true seabed is
``delta`` higher there, that pixel sees another point, and the match is wrong once it is more than a
bin or a beam away (``matching.truth.correct``). ``plane_error_probability`` gives the chance it
stays right under ``delta ~ N(0, s^2)``. Checked here against the exact geometry (the pixel's ray
cut with the moved plane), against Monte Carlo draws of the plane's errors, and in the matcher: with no
declared error nothing changes; with one, the seabed points' scores follow what the truth says of them
(their over-confidence under a wrong plane removed) on seeded scenes.
"""

import dataclasses

import numpy as np
import pytest
from scipy.special import erfinv
from scipy.spatial.transform import Rotation

from optiacoustic.experiments.matching import _rig_for, navigation_plane, random_scene
from optiacoustic.frames import Pose, sonar_from_spherical, spherical_from_sonar
from optiacoustic.matching import SeabedPlane, match
from optiacoustic.matching.acoustic import moved_plane, plane_error_probability, seabed_elevation


def _seabed_points(rig, plane, rng, n):
    """Points of ``plane`` in the sonar's fan (random range and azimuth, the arc's seabed elevation)."""
    r = rng.uniform(2.0, 8.0, n)
    th = rng.uniform(-0.6, 0.6, n)
    phi = seabed_elevation(plane, r, th)
    keep = np.isfinite(phi)
    return sonar_from_spherical(r[keep], th[keep], phi[keep])


def _moved_hit(rig, plane, P, delta):
    """Exact: where the camera ray through ``P`` meets the plane raised by ``delta`` (sonar frame)."""
    C = np.asarray(rig.t, float)
    v = P - C
    s = (plane.offset + delta - C @ plane.normal) / (v @ plane.normal)
    return C + s[:, None] * v


def test_tolerance_matches_the_exact_geometry():
    """The plane error at which a seabed point stops being right (recovered from the probability,
    ``tau = sqrt(2) s erfinv(p)``) is where the exact ray-plane cut leaves one bin or one beam: inside at
    0.97 tau and outside at 1.03 tau, for either sign of the error (first order, small bins)."""
    sc = random_scene(331)
    rig, pose = _rig_for(sc.view.eye, sc.view.target)
    plane = SeabedPlane.from_pose(pose, sigma_height=0.004)
    rng = np.random.default_rng(7)
    P = _seabed_points(rig, plane, rng, 400)
    bin_w, beam_w = 0.005, np.deg2rad(0.05)  # small: the first-order gains hold to the tolerance
    p = plane_error_probability(rig, plane, P, bin_w, beam_w)
    assert np.all((p > 0.01) & (p < 0.999))
    tau = np.sqrt(2.0) * 0.004 * erfinv(p)
    r0, th0, _ = spherical_from_sonar(P)
    for sign in (1.0, -1.0):
        for f, inside in ((0.97, True), (1.03, False)):
            r1, th1, _ = spherical_from_sonar(_moved_hit(rig, plane, P, sign * f * tau))
            ok = (np.abs(r1 - r0) <= bin_w) & (np.abs(th1 - th0) <= beam_w)
            assert ok.all() if inside else not ok.any(), (sign, f)


def test_height_sigma_is_the_spread_of_drawn_planes():
    """Monte Carlo: planes drawn with the declared offset and tilt errors (a rotation of the normal about the
    two horizontal axes, pivoting at the sonar) move a point's height with the standard deviation
    ``offset_sigma_at`` gives (two-sided, 20 000 draws: within 3 %)."""
    n = np.array([0.1, -0.2, 0.97])
    n /= np.linalg.norm(n)
    plane = SeabedPlane(n, -2.0, 0.0, 0, sigma_offset=0.01, sigma_tilt=np.deg2rad(0.2))
    a = np.cross(n, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    rng = np.random.default_rng(8)
    P = plane.offset * n + np.array([[4.0], [1.0], [-6.0]]) * a + np.array([[2.0], [-5.0], [0.5]]) * b
    k = 20_000
    d = rng.normal(0.0, plane.sigma_offset, k)
    rot = Rotation.from_rotvec(rng.normal(0.0, plane.sigma_tilt, (k, 1)) * a + rng.normal(0.0, plane.sigma_tilt, (k, 1)) * b)
    n_k = rot.apply(n)
    h = P @ n_k.T - (plane.offset + d)  # each point's height above each drawn plane (it sat on the declared one)
    np.testing.assert_allclose(h.std(axis=1), plane.offset_sigma_at(P), rtol=0.03)
    assert plane.offset_sigma_at(np.zeros(3)) == pytest.approx(0.01)


def test_no_declared_error_changes_nothing():
    """A plane without declared errors gives probability 1, and the matcher's output is bit for bit what it
    was; the declared errors are validated, carried by ``from_pose`` and by the second view's plane."""
    sc = random_scene(332)
    rig, pose = _rig_for(sc.view.eye, sc.view.target)
    exact = SeabedPlane.from_pose(pose)
    assert not exact.uncertain
    P = _seabed_points(rig, exact, np.random.default_rng(9), 50)
    assert np.all(plane_error_probability(rig, exact, P, 0.025, 0.003) == 1.0)
    nav = SeabedPlane.from_pose(pose, sigma_height=0.01, sigma_tilt=0.001)
    assert (nav.sigma_offset, nav.sigma_tilt) == (0.01, 0.001) and nav.uncertain
    moved = moved_plane(rig, nav, np.eye(3), np.array([0.1, 0.0, 0.0]))
    assert (moved.sigma_offset, moved.sigma_tilt) == (0.01, 0.001)
    for bad in (-0.01, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="sigma_height"):
            SeabedPlane.from_pose(pose, sigma_height=bad)
        with pytest.raises(ValueError, match="sigma_tilt"):
            SeabedPlane(exact.normal, exact.offset, 0.0, 0, sigma_tilt=bad)
    from optiacoustic.experiments.matching import simulate_pair

    sonar, optical, rig = simulate_pair(sc, "thesis", "default", 332)
    a = match(sonar, optical.image, rig, seabed=exact, min_score=0.0)
    b = match(sonar, optical.image, rig, seabed=dataclasses.replace(exact, sigma_offset=0.0, sigma_tilt=0.0),
              min_score=0.0)
    assert a and np.array_equal(a.score, b.score) and np.array_equal(a.pixels, b.pixels)
    found = a.features["seabed_found"]
    assert np.all(a.features["seabed_plane_probability"][found] == 1.0)


def test_probability_is_the_fraction_right_over_drawn_planes():
    """Monte Carlo against the depth map: seabed points right with the exact plane (by the simulated camera's
    depth map, the independent truth) are placed again on 300 planes drawn with the declared errors (1 cm,
    0.05 deg); the fraction still right is the mean probability the declared plane gives them, within 0.03
    (the draws' sampling error is about 0.01)."""
    from optiacoustic.matching import truth
    from optiacoustic.matching.acoustic import seabed_points
    from optiacoustic.simulation import simulate_rig

    sc = random_scene(331)
    rig, pose = _rig_for(sc.view.eye, sc.view.target)
    depth = simulate_rig(sc, rig, pose, seed=331).optical.depth
    bw, aw = rig.sonar.bin_width, rig.sonar.beam_spacing
    exact = SeabedPlane.from_pose(pose)
    rng = np.random.default_rng(11)
    r, th = rng.uniform(2.0, 8.0, 2000), rng.uniform(-0.7, 0.7, 2000)
    _, px, found = seabed_points(rig, exact, r, th, rig.fov_elevation)
    ok0 = found.copy()
    ok0[found] = truth.correct(rig, depth, px[found], r[found], th[found], bin_width=bw, beam_width=aw)
    r, th = r[ok0], th[ok0]
    assert r.size >= 300, r.size
    sh, st = 0.01, np.deg2rad(0.05)
    el, _, _ = seabed_points(rig, exact, r, th, rig.fov_elevation)
    told = dataclasses.replace(exact, sigma_offset=sh, sigma_tilt=st)
    predicted = plane_error_probability(rig, told, sonar_from_spherical(r, th, el), bw, aw).mean()
    still = []
    for _ in range(300):
        _, px, found = seabed_points(rig, navigation_plane(pose, rng, sh, st), r, th, rig.fov_elevation)
        ok = np.zeros(r.size, bool)
        ok[found] = truth.correct(rig, depth, px[found], r[found], th[found], bin_width=bw, beam_width=aw)
        still.append(ok.mean())
    assert 0.2 < predicted < 0.9, predicted
    assert abs(np.mean(still) - predicted) < 0.03, (np.mean(still), predicted)


def test_declared_error_scales_the_seabed_points_probability():
    """In the matcher, on a realistic soft-beam frame (the frames where a navigation plane is needed): each
    feature's seabed-point probability told the sigmas is the untold one times the plane's probability
    (the same plane, the same geometry); the other candidates' are untouched."""
    from optiacoustic.experiments.matching import realistic_pair

    sonar, optical, rig, pose = realistic_pair(random_scene(332), 332)
    wrong = navigation_plane(pose, np.random.default_rng(12), 0.01, np.deg2rad(0.05))
    told = dataclasses.replace(wrong, sigma_offset=0.01, sigma_tilt=np.deg2rad(0.05))
    by = {}
    for name, plane in (("blind", wrong), ("told", told)):
        m = match(sonar, optical.image, rig, seabed=plane, min_score=0.0)
        f = m.features
        by[name] = {int(i): {k: f[k][j] for k in ("p_seabed", "seabed_plane_probability", "p_arc", "p_crease",
                                                   "p_plane", "p_foot", "seabed_found")}
                    for j, i in enumerate(m.sonar_index)}
    assert by["blind"].keys() == by["told"].keys()
    found = [i for i in by["told"] if by["told"][i]["seabed_found"]]
    assert len(found) >= 10, len(found)
    pp = np.array([by["told"][i]["seabed_plane_probability"] for i in found])
    assert np.all((pp > 0) & (pp < 1))
    np.testing.assert_allclose([by["told"][i]["p_seabed"] for i in found],
                               np.array([by["blind"][i]["p_seabed"] for i in found]) * pp, rtol=1e-12)
    for k in ("p_arc", "p_crease", "p_plane", "p_foot"):
        assert all(by["told"][i][k] == by["blind"][i][k] for i in by["told"])


def test_seabed_from_altitude_and_attitude():
    """``from_attitude``: the boresight of a sonar ``h`` above the seabed and pitched down ``p`` meets it at
    the slant range ``h / sin p`` straight ahead (elevation 0 there); a roll lifts the left side; the same
    plane as ``from_pose`` with the sonar's world pose built independently (look_at with the aim below)."""
    from optiacoustic.matching.acoustic import seabed_elevation

    for h, p in ((1.5, 20.0), (3.0, 35.0), (0.8, 8.0)):
        plane = SeabedPlane.from_attitude(h, p, sigma_height=0.01)
        r = h / np.sin(np.deg2rad(p))
        assert abs(seabed_elevation(plane, [r], [0.0])[0]) < 1e-9
        look = Pose.look_at((0.0, 0.0, h), (0.0, 10.0 * np.cos(np.deg2rad(p)), h - 10.0 * np.sin(np.deg2rad(p))))
        ref = SeabedPlane.from_pose(look)
        np.testing.assert_allclose(plane.normal, ref.normal, atol=1e-12)
        assert plane.offset == pytest.approx(ref.offset) and plane.sigma_offset == 0.01
    rolled = SeabedPlane.from_attitude(2.0, 20.0, 5.0)
    assert rolled.height(np.array([1.0, 0.0, 0.0])) < rolled.height(np.array([-1.0, 0.0, 0.0]))  # right side down
    for bad in (dict(altitude=0.0), dict(altitude=-1.0), dict(altitude=float("nan")), dict(altitude=2.0, pitch_deg=float("inf"))):
        with pytest.raises(ValueError):
            SeabedPlane.from_attitude(**bad)


def test_workbench_command_refuses_a_seabed_without_altitude(tmp_path):
    """``oas workbench``: the seabed's companions without ``--seabed-altitude``, or a bad altitude, are refused
    with a message naming the flag (before anything is served)."""
    from typer.testing import CliRunner

    from optiacoustic.cli import app

    runner = CliRunner()
    r = runner.invoke(app, ["workbench", "--no-browser", "--seabed-pitch", "20"])
    assert r.exit_code == 2 and "--seabed-altitude" in r.output
    r = runner.invoke(app, ["workbench", "--no-browser", "--seabed-altitude", "-1"])
    assert r.exit_code == 2 and "altitude" in r.output
    r = runner.invoke(app, ["workbench", "--no-browser", "--seabed-altitude", "2", "--seabed-sigma-z", "-0.1"])
    assert r.exit_code == 2 and "--seabed-sigma-z" in r.output
