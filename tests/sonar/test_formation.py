"""Sonar image formation against independent references.

The reference here shares nothing with the simulator: analytic ray-plane and ray-box
(slab) intersections in numpy, sampled 20 000 times per beam across the elevation
aperture, Lambert-weighted and histogrammed into range bins.
"""

import dataclasses

import numpy as np
import pytest
from scipy.integrate import quad

from optiacoustic import scenes
from optiacoustic.frames import Pose, rot_z, sonar_from_spherical
from optiacoustic.scene import Body, Box, Material, Plane, Scene, Sphere
from optiacoustic.sonar import SonarOptions, SonarSpec, simulate_sonar, two_way_gain

SEABED_R, BOX_R = 0.3, 0.8
BOX_C, BOX_SIZE, BOX_YAW = np.array([0.2, 0.0, 0.4]), np.array([1.0, 1.0, 0.8]), np.deg2rad(25)
EYE = np.array([0.0, -6.0, 2.0])

SPEC = SonarSpec(n_beams=48, n_bins=500, fov_azimuth=np.deg2rad(30), fov_elevation=np.deg2rad(20),
                 range_min=3.0, range_max=15.0, elevation_samples=128)


@pytest.fixture(scope="module")
def box_scene():
    return Scene([
        Body("seabed", Plane(size=(80, 80)), material=Material(reflectivity=SEABED_R)),
        Body("box", Box(size=tuple(BOX_SIZE)), Pose(rot_z(BOX_YAW), BOX_C), Material(reflectivity=BOX_R)),
    ])


def reference_energy(spec, pose, n_elev=20000):
    """Brute-force echo energy per (beam, bin) and body-free shadow info, independent of the simulator."""
    ph = -spec.fov_elevation / 2 + (np.arange(n_elev) + 0.5) * spec.fov_elevation / n_elev
    dphi = spec.fov_elevation / n_elev
    d = sonar_from_spherical(1.0, spec.azimuths[None, :], ph[:, None]) @ pose.R.T  # (E, J, 3) world
    o = pose.t
    t_plane = np.where(d[..., 2] < 0, -o[2] / np.where(d[..., 2] < 0, d[..., 2], -1.0), np.inf)
    # box in its own frame: slab method
    Rb = rot_z(BOX_YAW)
    ob = Rb.T @ (o - BOX_C)
    db = d @ Rb
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-BOX_SIZE / 2 - ob) / db
        t2 = (BOX_SIZE / 2 - ob) / db
    tmin = np.minimum(t1, t2)
    tmax = np.maximum(t1, t2)
    t_in = tmin.max(-1)
    t_out = tmax.min(-1)
    hit_box = (t_in <= t_out) & (t_out > 0) & (t_in > 0)
    t_box = np.where(hit_box, t_in, np.inf)
    axis = tmin.argmax(-1)
    nb = np.zeros(db.shape)
    np.put_along_axis(nb, axis[..., None], -np.sign(np.take_along_axis(db, axis[..., None], -1)), -1)
    on_box = t_box < t_plane
    t = np.where(on_box, t_box, t_plane)
    cos = np.where(on_box, np.abs(np.einsum("...i,...i", nb, db)), np.abs(d[..., 2]))
    e = np.where(on_box, BOX_R, SEABED_R) * cos * dphi
    b = np.floor((t - spec.range_min) / spec.bin_width)
    ok = np.isfinite(t) & (b >= 0) & (b < spec.n_bins)
    beam = np.broadcast_to(np.arange(spec.n_beams), t.shape)
    E = np.bincount((b[ok] * spec.n_beams + beam[ok]).astype(int), e[ok], minlength=spec.n_bins * spec.n_beams)
    return E.reshape(spec.n_bins, spec.n_beams)


def smooth5(a):
    k = np.ones(5) / 5
    return np.apply_along_axis(lambda c: np.convolve(c, k, mode="same"), 0, a)


@pytest.fixture(scope="module")
def box_frames(box_scene):
    pose = Pose.look_at(EYE, (0, 0, 0))
    frame = simulate_sonar(box_scene, SPEC, pose, noise=False)
    return pose, frame, reference_energy(SPEC, pose)


def test_seabed_box_profiles_match_brute_force(box_frames):
    _, frame, ref = box_frames
    sim = frame.intensity * SPEC.bin_width  # energy per bin
    s, r = smooth5(sim), smooth5(ref)
    lit = r.sum(0) > 0
    assert lit.sum() == SPEC.n_beams
    l1 = np.abs(s / s.sum(0) - r / r.sum(0)).sum(0)
    assert l1.max() <= 0.10, l1.max()
    assert l1.mean() < 0.05
    rc = SPEC.ranges[:, None]
    cs = (rc * sim).sum(0) / sim.sum(0)
    cr = (rc * ref).sum(0) / ref.sum(0)
    assert np.max(np.abs(cs - cr)) <= SPEC.bin_width
    # total energy per beam agrees (the brute force integrates the same Lambert law)
    assert np.allclose(sim.sum(0), ref.sum(0), rtol=0.01)  # measured: within 0.65%


def test_energy_behind_the_box_and_shadow_mask(box_frames):
    _, frame, ref = box_frames
    sim = frame.intensity * SPEC.bin_width
    # shadow in the reference: empty bins between the first and last echo of a beam
    idx = np.arange(SPEC.n_bins)[:, None]
    lit = ref > 0
    first = np.where(lit.any(0), lit.argmax(0), SPEC.n_bins)
    last = SPEC.n_bins - 1 - lit[::-1].argmax(0)
    shadow = (~lit) & (idx > first) & (idx < last)
    assert shadow.sum() > 200  # the box does cast a shadow
    assert sim[shadow].sum() <= 0.01 * sim.sum()
    gt = frame.ground_truth.shadow
    inter = (gt & shadow).sum()
    union = (gt | shadow).sum()
    assert inter / union > 0.85, inter / union


def test_elevation_sampling_convergence_thesis_scene():
    scene = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    pose = Pose.look_at(scene.view.eye, scene.view.target)
    a = simulate_sonar(scene, spec, pose, noise=False).intensity.astype(float)
    b = simulate_sonar(scene, dataclasses.replace(spec, elevation_samples=2 * spec.elevation_samples), pose,
                       noise=False).intensity.astype(float)
    change = np.abs(a - b).sum() / b.sum()
    assert 0 < change < 0.02, change


def test_energy_is_conserved(box_frames):
    _, frame, _ = box_frames
    rays = frame.rays
    inside = (rays.footprint_lo > SPEC.range_min + 0.2) & (rays.footprint_hi < SPEC.range_max - 0.2)
    assert np.isclose(frame.intensity.sum() * SPEC.bin_width, rays.energy[inside].sum(), rtol=2e-3)


def _open_water_sphere(center, radius, reflectivity=1.0):
    return Scene([Body("ball", Sphere(radius=radius), Pose(np.eye(3), center), Material(reflectivity=reflectivity))])


def test_sphere_both_halves_add_up():
    """The centre beam's echo energy equals the analytic elevation integral of cos(incidence)."""
    spec = dataclasses.replace(SPEC, n_beams=65, elevation_samples=256)
    d, R = 5.0, 0.5
    scene = _open_water_sphere([0.0, d, 0.0], R)
    frame = simulate_sonar(scene, spec, Pose.look_at((0, 0, 0), (0, 1, 0)), noise=False)
    j = 32
    assert abs(spec.azimuths[j]) < 1e-12
    energy = frame.intensity[:, j].sum() * spec.bin_width
    phi_m = np.arcsin(R / d)
    analytic, _ = quad(lambda p: np.sqrt(max(0.0, 1 - (d * np.sin(p) / R) ** 2)), -phi_m, phi_m)
    assert np.isclose(energy, analytic, rtol=0.01), (energy, analytic)
    # and the echo spans the sphere's front half in range, brightest at its nearest point
    prof = frame.intensity[:, j]
    nz = np.flatnonzero(prof > 1e-3 * prof.max())
    assert spec.ranges[nz[0]] == pytest.approx(d - R, abs=2 * spec.bin_width)
    assert spec.ranges[np.argmax(prof)] == pytest.approx(d - R, abs=1.5 * spec.bin_width)


def test_small_sphere_peaks_in_its_bin_and_beam():
    spec = SPEC
    j, b = 31, 120
    r_near = spec.ranges[b]
    radius = 0.05
    th, ph = spec.azimuths[j], np.deg2rad(2.0)
    centre = sonar_from_spherical(r_near + radius, th, ph)
    frame = simulate_sonar(_open_water_sphere(centre, radius), spec, Pose.identity(), noise=False)
    peak = np.unravel_index(np.argmax(frame.intensity), frame.intensity.shape)
    assert peak == (b, j)
    gt = frame.ground_truth
    assert gt.body[b, j] == 0
    assert gt.elevation_min[b, j] <= ph <= gt.elevation_max[b, j]
    # the fan image puts it where its fan coordinates say
    fan = frame.fan("intensity", width=1200)
    u, v = fan.to_pixel(*np.array([r_near * np.sin(th), r_near * np.cos(th)]))
    pv, pu = np.unravel_index(np.argmax(fan.data), fan.data.shape)
    assert abs(pu - u) <= 2 and abs(pv - v) <= 2


def test_spreading_option_follows_two_way_gain(box_scene):
    pose = Pose.look_at(EYE, (0, 0, 0))
    scene = Scene([box_scene.bodies[0]])
    a = simulate_sonar(scene, SPEC, pose, noise=False).intensity
    b = simulate_sonar(scene, SPEC, pose, noise=False, options=SonarOptions(propagation="spreading")).intensity
    j = SPEC.n_beams // 2
    ok = a[:, j] > 0.2 * a[:, j].max()
    ratio = b[ok, j] / a[ok, j]
    expect = two_way_gain(SPEC.ranges[ok], SPEC.frequency)
    assert np.allclose(ratio, expect, rtol=0.03)
    assert expect[-1] < expect[0]


def test_gaussian_elevation_pattern_weights_a_target():
    spec = SPEC
    centre = sonar_from_spherical(6.0, 0.01, np.deg2rad(5.0))
    scene = _open_water_sphere(centre, 0.05)
    u = simulate_sonar(scene, spec, Pose.identity(), noise=False).intensity.sum()
    g = simulate_sonar(scene, spec, Pose.identity(), noise=False,
                       options=SonarOptions(elevation_pattern="gaussian")).intensity.sum()
    # -3 dB at the aperture edge (10 deg): the weight at 5 deg is 2^(-1/4)
    assert g / u == pytest.approx(2 ** -0.25, rel=0.02)


def test_azimuth_pattern_spreads_but_conserves(box_frames, box_scene):
    pose, frame, _ = box_frames
    f2 = simulate_sonar(box_scene, SPEC, pose, noise=False, options=SonarOptions(azimuth_pattern=True))
    inner = slice(8, SPEC.n_beams - 8)
    assert np.isclose(f2.intensity[:, inner].sum(), frame.intensity[:, inner].sum(), rtol=0.02)
    # the beam-to-beam variation is smoothed
    assert np.abs(np.diff(f2.intensity, axis=1)).sum() < np.abs(np.diff(frame.intensity, axis=1)).sum()


def test_bad_input(box_scene):
    with pytest.raises(ValueError, match="n_beams"):
        SonarSpec(n_beams=0)
    with pytest.raises(ValueError, match="range_max"):
        SonarSpec(range_min=5, range_max=4)
    with pytest.raises(ValueError, match="fov_elevation"):
        SonarSpec(fov_elevation=float("nan"))
    with pytest.raises(KeyError, match="unknown sonar preset"):
        SonarSpec.preset("blueview-p901")
    with pytest.raises(TypeError, match="Pose"):
        simulate_sonar(box_scene, SPEC, np.eye(4))
    with pytest.raises(ValueError, match="propagation"):
        SonarOptions(propagation="tvgg")


def test_presets_are_consistent():
    for name in SonarSpec.preset_names():
        s = SonarSpec.preset(name)
        assert s.name == name and s.source
        assert len(s.azimuths) == s.n_beams and np.isclose(np.ptp(s.azimuths), s.fov_azimuth - s.beam_spacing)
    p = SonarSpec.preset("blueview-p900-90")
    assert (p.n_beams, p.frequency) == (512, 900e3)
    assert np.isclose(np.rad2deg(p.fov_azimuth), 90) and np.isclose(np.rad2deg(p.fov_elevation), 20)
    assert abs(p.bin_width - 0.0254) < 0.001
    q = dataclasses.replace(p, n_bins=1000)
    assert q.n_bins == 1000 and q.bin_width < p.bin_width
