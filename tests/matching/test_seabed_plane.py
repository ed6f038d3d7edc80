"""The seabed plane the sonar fits (``acoustic.fit_seabed``, ``acoustic.far_edges``) against the true seabed.

Truth: the simulated scene's seabed is the world plane z = 0, and the sonar's pose is known, so the
seabed in the sonar frame is ``normal = R^T e_z``, ``offset = -t_z``; where the aperture's edges meet
it follows in closed form. Seeded scenes never used to fit or tune anything (round i15n).
"""

import numpy as np
import pytest

from optiacoustic.experiments.matching import random_scene, simulate_pair, varied_scene
from optiacoustic.matching.acoustic import SeabedPlane, far_edges, fit_seabed, seabed_elevation


def _true_plane(sonar) -> SeabedPlane:
    R, t = sonar.pose.R, sonar.pose.t
    return SeabedPlane(R.T @ np.array([0.0, 0.0, 1.0]), float(-t[2]), 0.0, 0)


def _edge_ranges(plane, azimuths, elevation):
    d = np.stack([np.cos(elevation) * np.sin(azimuths), np.cos(elevation) * np.cos(azimuths),
                  np.full(azimuths.shape, np.sin(elevation))], -1)
    with np.errstate(divide="ignore"):
        return plane.offset / (d @ plane.normal)


def _elevation_error_deg(sonar, plane, beyond_m):
    """Fitted minus true seabed elevation (deg) on every beam, ``beyond_m`` past the true near edge."""
    true = _true_plane(sonar)
    th = sonar.azimuths
    r = _edge_ranges(true, th, -sonar.spec.fov_elevation / 2) + beyond_m
    return np.rad2deg(seabed_elevation(plane, r, th) - seabed_elevation(true, r, th))


@pytest.fixture(scope="module")
def frames():
    out = []
    for sd in (311, 312, 313):
        out.append(simulate_pair(random_scene(sd), "thesis", "default", sd)[0])
    for sd in (8311, 8312, 8313):
        out.append(simulate_pair(varied_scene(sd), "thesis", "default", sd)[0])
    return out


def test_far_edges_lie_where_the_aperture_leaves_the_true_seabed(frames):
    """Where found and not an object's shadow, the far edge is the upper aperture edge's range on the true seabed."""
    pooled = []
    for s in frames:
        true = _true_plane(s)
        r_true = _edge_ranges(true, s.azimuths, s.spec.fov_elevation / 2)
        r_far, found = far_edges(s.image, s.ranges)
        inside = found & np.isfinite(r_true) & (r_true > 0) & (r_true < s.ranges[-1] - 1.0)
        assert inside.sum() > 50, s.pose
        bins = (r_far[inside] - r_true[inside]) / np.median(np.diff(s.ranges))
        # Most found edges are the seabed's (the rest: shadows running to the end, left to the fit's gate),
        # and those lie on both sides of the truth, within half a bin in the median (the seabed's echo
        # falls towards the edge, so the level it is measured against sits a little high).
        near = np.abs(bins) < 3
        assert near.mean() > 0.6
        assert abs(np.median(bins[near])) < 0.5
        pooled.append(bins[near])
    assert abs(np.median(np.concatenate(pooled))) < 0.3


def test_plane_from_both_aperture_edges_matches_the_true_seabed(frames):
    """Normal within 0.1 deg, offset within 1 cm, elevation 2.5 m past the near edge within 0.04 deg (both signs)."""
    for s in frames:
        true = _true_plane(s)
        plane = fit_seabed(s.image, s.ranges, s.azimuths, s.spec.fov_elevation)
        assert plane
        angle = np.rad2deg(np.arccos(np.clip(plane.normal @ true.normal, -1, 1)))
        assert angle < 0.1
        assert abs(plane.offset - true.offset) < 0.01
        err = _elevation_error_deg(s, plane, 2.5)
        assert np.nanmax(np.abs(err)) < 0.04


def test_far_edges_fix_the_tilt_the_onsets_alone_leave_loose(frames):
    """The onsets alone (one cone) tilt the plane: its elevation error 2.5 m past the edge is larger than with both edges."""
    one, two = [], []
    for s in frames:
        one.append(np.nanmedian(np.abs(_elevation_error_deg(
            s, fit_seabed(s.image, s.ranges, s.azimuths, s.spec.fov_elevation, far_edge=False), 2.5))))
        two.append(np.nanmedian(np.abs(_elevation_error_deg(
            s, fit_seabed(s.image, s.ranges, s.azimuths, s.spec.fov_elevation), 2.5))))
    assert np.median(two) < 0.5 * np.median(one)


def test_far_edges_of_a_beam_with_no_seabed_end():
    """Beams lit to the end of the window (the seabed runs past it) and empty ones have no far edge;
    a clean step is placed within a tenth of a bin (beams averaged over five neighbours: groups of nine)."""
    r = 0.5 + 0.025 * np.arange(400)
    img = np.full((400, 27), 1e-6)
    img[:, 0:9] = 1.0                      # lit to the end: no edge
    edge = r[0] + 0.025 * (250 - 0.5)      # the boundary between bins 249 and 250
    img[:250, 18:27] = 1.0
    e, found = far_edges(img, r)
    assert not found[2:7].any()            # lit to the end
    assert not found[11:16].any()          # nothing
    assert found[20:25].all()
    np.testing.assert_allclose(e[20:25], edge, atol=0.1 * 0.025)


def test_flat_seabed_residual_is_the_onsets_bin_quantisation(frames):
    """Physics of the fit's residual on a flat seabed: the onsets sit uniformly within their range bin, so the
    median absolute height residual is a quarter of a bin times |n . d| (``flat_rms``): ratio about 1."""
    for s in frames:
        plane = fit_seabed(s.image, s.ranges, s.azimuths, s.spec.fov_elevation)
        assert 0.8 < plane.relief_ratio < 1.35, (s.pose, plane.rms, plane.flat_rms)


def test_relief_raises_the_residual_and_the_matcher_warns(tmp_path, frames):
    """2 cm RMS of seabed relief: the residual is well above a flat seabed's, and match() says so (a
    SeabedReliefWarning and a note in the message); on a flat seabed it does not."""
    import warnings

    from optiacoustic.experiments.matching import relief_scene
    from optiacoustic.matching import SeabedReliefWarning, match

    ratios, sigmas = [], []
    for sd in (6101, 6102, 6103):
        s, o, rig = simulate_pair(relief_scene(sd, 0.02, tmp_path), "thesis", "default", sd)
        plane = fit_seabed(s.image, s.ranges, s.azimuths, s.spec.fov_elevation)
        ratios.append(plane.relief_ratio)
        sigmas.append(plane.relief_sigma)
    assert min(ratios) > 1.5, ratios
    # the relief the residual implies, against the heightfield's own RMS (2 cm): the onsets sample it along
    # one line, so a scene's estimate varies (0.45-1.35 times the RMS over 15 scenes of 1 and 2 cm)
    assert all(0.006 < x < 0.04 for x in sigmas) and 0.01 < np.mean(sigmas) < 0.03, sigmas
    with pytest.warns(SeabedReliefWarning, match="depart from one plane"):
        m = match(s, o.image, rig)
    assert m and "depart from one plane" in m.message
    # by default the plane stays as fitted and the message names the option; with relief_as_plane_error the
    # plane is uncertain by that relief: its seabed points are scored by the chance it leaves them right
    # (acoustic.plane_error_probability), and the message says by how much
    assert m.seabed.sigma_offset == 0.0 and "relief_as_plane_error" in m.message
    from optiacoustic.matching import MatchOptions

    with pytest.warns(SeabedReliefWarning):
        m2 = match(s, o.image, rig, options=MatchOptions(relief_as_plane_error=True))
    assert m2.seabed.sigma_offset == pytest.approx(sigmas[-1]) and f"{sigmas[-1] * 1000:.0f} mm" in m2.message
    found = m2.features["seabed_found"]
    assert np.all(m2.features["seabed_plane_probability"][found] < 1.0)
    # given the plane (navigation), nothing is fitted and nothing is said
    from optiacoustic.matching import SeabedPlane

    with warnings.catch_warnings():
        warnings.simplefilter("error", SeabedReliefWarning)
        match(s, o.image, rig, seabed=SeabedPlane.from_pose(s.pose))
    flat, o_f, rig_f = simulate_pair(random_scene(6101), "thesis", "default", 6101)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SeabedReliefWarning)
        m_f = match(flat, o_f.image, rig_f, options=MatchOptions(relief_as_plane_error=True))
    assert "depart from one plane" not in m_f.message and m_f.seabed.sigma_offset == 0.0


def test_relief_sigma_is_the_residual_beyond_a_flat_seabeds():
    """``relief_sigma``: a normal height of standard deviation s has median absolute value 0.6745 s, and adds
    in quadrature to the flat seabed's median residual, approximately (Monte Carlo, 200 000 draws of a normal
    relief plus a uniform placement of comparable size: within 2 %); 0 where the
    residual is no more than a flat seabed's; NaN when that is unknown."""
    from optiacoustic.matching import SeabedPlane

    rng = np.random.default_rng(3)
    s_true, flat_half = 0.012, 0.004          # relief sd; the onsets' placement, uniform in +-flat_half
    x = rng.normal(0.0, s_true, 200_000) + rng.uniform(-flat_half, flat_half, 200_000)
    flat = np.median(np.abs(rng.uniform(-flat_half, flat_half, 200_000)))
    plane = SeabedPlane(np.array([0.0, 0.0, 1.0]), -2.0, float(np.median(np.abs(x))), 50, flat_rms=float(flat))
    assert plane.relief_sigma == pytest.approx(s_true, rel=0.02)
    assert SeabedPlane(np.array([0.0, 0.0, 1.0]), -2.0, 0.001, 50, flat_rms=0.002).relief_sigma == 0.0
    assert np.isnan(SeabedPlane(np.array([0.0, 0.0, 1.0]), -2.0, 0.001, 50).relief_sigma)
