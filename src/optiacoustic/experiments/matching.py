"""Automatic opti-acoustic correspondence (the thesis's open problem): precision, recall, baseline.

Ground truth comes from the simulators' depth maps only (``matching.truth``): a match is
correct when its camera pixel's true 3D point projects into the sonar within one range bin
and one beam of its sonar feature. A sonar feature is "visible in both sensors" when at
least one camera feature is a correct partner; recall is over those.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from . import ExperimentResult

NAME = "matching"
TITLE = "Automatic opti-acoustic matching: precision-recall against a nearest-conic baseline"
CHAPTER = 8
SUMMARY = ("Automatic matching of CFAR sonar features and camera corners on built-in and random seabed scenes: "
           "precision-recall, effect of turbidity and sonar noise, reconstruction error, and the baseline "
           "'nearest camera feature to each epipolar conic'.")

#: Score thresholds swept for the precision-recall curve: the score is a calibrated
#: probability, so the curve is swept over the pooled scores' quantiles (20 points) instead.
N_THRESHOLDS = 20
SCORE_CUT = 0.3  # the report's second operating point (the score is a calibrated P(correct))
WATERS = ("clear", "thesis", "jerlov-1C", "jerlov-3C")
NOISE_FLOORS_DB = (None, -30.0, -18.0, -10.0)  # None: no sonar noise at all; -18 dB is the default model


def _rig_for(eye, target):
    from ..camera import PinholeCamera
    from ..frames import Pose
    from ..rig import Rig
    from ..sonar import SonarSpec

    spec = SonarSpec.preset("blueview-p900-90", range_min=0.5)
    camera = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
    sp = Pose.look_at(eye, target, body="sonar")
    cam_eye = np.asarray(eye, float) - 0.25 * sp.R[:, 0]  # 0.25 m to the sonar's left
    cp = Pose.look_at(cam_eye, target, body="camera")
    return Rig.from_poses(sp, cp, camera, spec), sp


def _upright_shape(kind: str, rng):
    """A box, upright cylinder or sphere of :func:`random_scene`'s sizes, drawn from ``rng``, and the
    height of its centre above the seabed (m) when it stands on it."""
    from ..scene import Box, Cylinder, Sphere

    if kind == "box":
        s = rng.uniform(0.3, 1.0, 3)
        return Box(size=tuple(float(v) for v in s)), s[2] / 2
    if kind == "cylinder":
        rad, h = rng.uniform(0.1, 0.35), rng.uniform(0.4, 1.3)
        return Cylinder(radius=float(rad), height=float(h)), h / 2
    rad = rng.uniform(0.15, 0.5)
    return Sphere(radius=float(rad)), rad


def random_scene(seed: int, textured: bool = False):
    """Boxes, cylinders and spheres (3-7 of them) on a seabed within 3 m of the origin (seeded).

    ``textured``: the same scene with every surface checkered (squares of 5-15 cm, the body's colour
    and half of it; an optical texture only, the sonar sees the same scene), the case of surfaces
    with visible texture (fouling, rust, sand ripples) that a second camera view can follow.
    """
    from ..frames import Pose
    from ..scene import Body, Material, Plane, Scene, Texture, View

    rng = np.random.default_rng(seed)
    bodies = [Body("seabed", Plane(size=(40.0, 40.0)), Pose.identity(),
                   Material(reflectivity=0.3, color=(0.55, 0.50, 0.40), bottom_type="sand/shell"))]
    for i in range(int(rng.integers(3, 8))):
        kind = rng.choice(["box", "cylinder", "sphere"])
        x, y = rng.uniform(-2.5, 2.5), rng.uniform(-1.5, 3.0)
        col = tuple(float(c) for c in rng.uniform(0.15, 0.95, 3))
        mat = Material(reflectivity=float(rng.uniform(0.6, 0.95)), color=col)
        yaw = float(rng.uniform(0, 180))
        shape, z = _upright_shape(kind, rng)
        bodies.append(Body(f"{kind}_{i}", shape, Pose.from_euler_deg((x, y, float(z)), (0.0, 0.0, yaw)), mat))
    name = f"random_{seed}"
    if textured:
        rng_t = np.random.default_rng(seed + 10 ** 6)
        bodies = [dataclasses.replace(b, material=dataclasses.replace(
            b.material, texture=Texture("checker", float(rng_t.uniform(0.05, 0.15)),
                                        color2=tuple(0.5 * float(c) for c in b.material.color))))
                  for b in bodies]
        name = f"random_{seed}_textured"
    return Scene(bodies, name=name, view=View(eye=(0.0, -6.0, 2.0), target=(0.0, 0.0, 0.0)))


#: Seabed relief of the matching experiment's relief sweep: RMS heights (m) of :func:`relief_scene`'s seabed.
RELIEF_RMS_M = (0.0, 0.005, 0.01, 0.02, 0.05)


def relief_scene(seed: int, rms_m: float, folder):
    """:func:`random_scene` on a seabed with relief: eight seeded plane waves (wavelengths 1-4 m, random
    directions and phases) summed and scaled to ``rms_m`` RMS height, as a triangle mesh at 8 cm spacing
    over 32 m x 32 m (a PLY written to ``folder``). The bodies stay where they were (their bases sink into
    the crests by up to the relief's height, as on a real seabed). ``rms_m = 0``: the flat seabed as a mesh.
    """
    import trimesh

    from ..frames import Pose
    from ..scene import Mesh, Scene

    if not (np.isfinite(rms_m) and rms_m >= 0):
        raise ValueError(f"rms_m: expected a height >= 0 (m), got {rms_m!r}")
    rng = np.random.default_rng(seed + 7 * 10 ** 6)
    n = 401
    x = np.linspace(-16.0, 16.0, n)
    X, Y = np.meshgrid(x, x + 6.0, indexing="ij")
    Z = np.zeros_like(X)
    for _ in range(8):
        lam, ang, ph = rng.uniform(1.0, 4.0), rng.uniform(0.0, np.pi), rng.uniform(0.0, 2 * np.pi)
        Z += np.sin(2 * np.pi / lam * (X * np.cos(ang) + Y * np.sin(ang)) + ph)
    Z *= rms_m / Z.std()
    i = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([i, i + n, i + 1], 1), np.stack([i + 1, i + n, i + n + 1], 1)])
    path = Path(folder) / f"relief_{seed}_{rms_m * 1000:.0f}mm.ply"
    trimesh.Trimesh(np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1), faces, process=False).export(path)
    sc = random_scene(seed)
    bed = dataclasses.replace(sc.bodies[0], shape=Mesh(file=str(path), smooth_angle_deg=60.0), pose=Pose.identity())
    return Scene([bed] + list(sc.bodies[1:]), name=f"{sc.name}_relief_{rms_m * 100:g}cm", view=sc.view)


def varied_scene(seed: int):
    """A random scene drawn more widely than :func:`random_scene` (seeded): the mix the matcher meets.

    :func:`random_scene` fixes the vehicle's pose (6.3 m from the aim, 2 m up), the seabed (sand,
    reflectivity 0.3) and the bodies (upright boxes and cylinders, spheres). Here the vehicle stands
    3.5-6.5 m back (horizontally) and 1.2-2.5 m up, the seabed's reflectivity is 0.12-0.35 (sand or
    mud, its colour drawn), and besides those bodies (scaled to the view) come low bars (2-6 cm high,
    the seabed's neighbours in range), thin walls (0.6-2 m tall) and lying cylinders: 3-7 bodies.
    The camera and sonar are those of :func:`random_scene`'s rig.
    """
    from ..frames import Pose
    from ..scene import Body, Box, Cylinder, Material, Plane, Scene, View

    rng = np.random.default_rng(seed)
    d, h = float(rng.uniform(3.5, 6.5)), float(rng.uniform(1.2, 2.5))
    mud = bool(rng.random() < 0.5)
    bed_col = tuple(float(c) for c in rng.uniform(0.25, 0.6, 3))
    bodies = [Body("seabed", Plane(size=(40.0, 40.0)), Pose.identity(),
                   Material(reflectivity=float(rng.uniform(0.12, 0.35)), color=bed_col,
                            bottom_type="mud" if mud else "sand/shell"))]
    k = d / 6.0  # the visible footprint scales with the distance
    for i in range(int(rng.integers(3, 8))):
        kind = rng.choice(["box", "cylinder", "sphere", "bar", "wall", "lying"])
        x, y = k * rng.uniform(-2.5, 2.5), k * rng.uniform(-1.5, 3.0)
        col = tuple(float(c) for c in rng.uniform(0.15, 0.95, 3))
        mat = Material(reflectivity=float(rng.uniform(0.6, 0.95)), color=col)
        yaw, roll = float(rng.uniform(0, 180)), 0.0
        if kind in ("box", "cylinder", "sphere"):
            shape, z = _upright_shape(kind, rng)
        elif kind == "bar":
            sz = (rng.uniform(0.8, 2.5), rng.uniform(0.03, 0.1), rng.uniform(0.02, 0.06))
            shape, z = Box(size=tuple(float(v) for v in sz)), sz[2] / 2
        elif kind == "wall":
            sz = (rng.uniform(1.0, 2.0), 0.02, rng.uniform(0.6, 2.0))
            shape, z = Box(size=tuple(float(v) for v in sz)), sz[2] / 2
        else:  # a cylinder lying on the seabed
            rad, ln = rng.uniform(0.1, 0.3), rng.uniform(0.6, 1.6)
            shape, z, roll = Cylinder(radius=float(rad), height=float(ln)), rad, 90.0
        bodies.append(Body(f"{kind}_{i}", shape, Pose.from_euler_deg((x, y, float(z)), (roll, 0.0, yaw)), mat))
    return Scene(bodies, name=f"varied_{seed}", view=View(eye=(0.0, -d, h), target=(0.0, 0.0, 0.0)))


def _builtin_scenes():
    from .. import scenes

    out = []
    for n in ("thesis_scene1", "cuboids", "perpendicular_planes", "planar_grid", "flat_seabed"):
        if n in scenes.names():
            sc = scenes.get(n)
            if sc.view is not None:
                out.append(sc)
    return out


def _sonar_noise(noise_floor_db):
    """``simulate_rig``'s ``sonar_noise`` for a floor in dB: "default" the preset's, None no noise."""
    from ..sonar import NoiseModel

    if noise_floor_db == "default":
        return None
    if noise_floor_db is None:
        return False
    return NoiseModel(noise_floor_db=noise_floor_db)


def realistic_sonar():
    """The realistic sonar model of the benchmark (``bench_sonar``'s realistic frame): the spec's soft
    two-way beam patterns, two-way spreading and absorption, scatterer speckle, a device's gain and noise.
    Keyword arguments of :func:`optiacoustic.simulate_sonar`."""
    from ..sonar import SonarOptions
    from ..sonar.gain import DeviceGain
    from ..sonar.noise import ScattererNoise

    return dict(options=SonarOptions(beam_model="aperture", propagation="spreading"),
                noise=ScattererNoise(density=500.0, gain=DeviceGain(noise_db=-60.0, volume_db=-50.0, spreading_db=30.0)))


def realistic_pair(scene, seed=0, water=None):
    """The rig pair of ``scene`` from its view with the realistic sonar (:func:`realistic_sonar`): (sonar
    frame, optical frame, rig, sonar pose). ``water``: the camera's (``simulate_rig``'s default when None)."""
    from .. import simulate_sonar
    from ..simulation import simulate_rig

    rig, pose = _rig_for(scene.view.eye, scene.view.target)
    optical = simulate_rig(scene, rig, pose, water=water, seed=seed).optical
    return simulate_sonar(scene, rig.sonar, pose, seed=seed, **realistic_sonar()), optical, rig, pose


def simulate_pair(scene, water="thesis", noise_floor_db="default", seed=0):
    """One rig pair of ``scene`` from its view: (sonar frame, optical frame, rig)."""
    from ..optical import Water
    from ..simulation import simulate_rig

    rig, sp = _rig_for(scene.view.eye, scene.view.target)
    noise = _sonar_noise(noise_floor_db)
    pair = simulate_rig(scene, rig, sp, water=Water.preset(water), seed=seed, sonar_noise=noise)
    return pair.sonar, pair.optical, rig


def second_view(scene, seed=0, water="thesis", shift=(0.3, 0.25, 0.0)):
    """The rig moved by ``shift`` (m, world) from the scene's view, same target: (sonar, optical, motion).

    ``motion`` is ``(R_o, t_o)`` with ``P_camera2 = R_o P_camera1 + t_o``, from the true poses.
    """
    from ..optical import Water
    from ..simulation import simulate_rig

    rig, sp1 = _rig_for(scene.view.eye, scene.view.target)
    eye2 = np.asarray(scene.view.eye, float) + np.asarray(shift, float)
    _, sp2 = _rig_for(eye2, scene.view.target)
    pair = simulate_rig(scene, rig, sp2, water=Water.preset(water), seed=seed + 7919)
    c1, c2 = rig.camera_pose(sp1), rig.camera_pose(sp2)
    R_o = c2.R.T @ c1.R
    t_o = c2.R.T @ (c1.t - c2.t)
    return pair.sonar, pair.optical, (R_o, t_o)


#: Range of the vehicle's motion between the two frames of the two-view evaluation (uniform, drawn
#: per scene): surge along the horizontal viewing direction, sway to the right, heave up (m), yaw
#: (deg). A ROV or AUV surveying at 0.2-0.5 m/s with frames kept 1-3 s apart.
MOTION_RANGES = dict(surge=(0.2, 1.0), sway=(-0.5, 0.5), heave=(-0.15, 0.15), yaw_deg=(-5.0, 5.0))


def vehicle_motion(seed: int) -> dict:
    """A random vehicle motion between two frames (seeded): surge, sway, heave (m), yaw (deg)."""
    rng = np.random.default_rng(seed)
    return {k: float(rng.uniform(*v)) for k, v in MOTION_RANGES.items()}


def moved_view(scene, motion: dict, seed=0, water="thesis", noise_floor_db="default"):
    """The rig after the vehicle moved by ``motion`` (:func:`vehicle_motion`): (sonar, optical, (R_o, t_o)).

    The sonar keeps its height above its aim and its aim's distance, so the rig's camera is placed
    exactly as in view 1 (same rig). ``(R_o, t_o)`` with ``P_camera2 = R_o P_camera1 + t_o``, from
    the true poses (the motion is known, thesis ch. 6).
    """
    import warnings

    from ..frames import rot_z
    from ..optical import Water
    from ..simulation import simulate_rig
    from ..sonar.noise import NoEchoWarning

    eye = np.asarray(scene.view.eye, float)
    target = np.asarray(scene.view.target, float)
    rig, sp1 = _rig_for(eye, target)
    fwd = target - eye
    heading = np.array([fwd[0], fwd[1], 0.0]) / np.hypot(fwd[0], fwd[1])
    right = np.array([heading[1], -heading[0], 0.0])
    eye2 = eye + motion["surge"] * heading + motion["sway"] * right + np.array([0.0, 0.0, motion["heave"]])
    target2 = eye2 + rot_z(np.deg2rad(motion["yaw_deg"])) @ fwd
    _, sp2 = _rig_for(eye2, target2)
    noise = _sonar_noise(noise_floor_db)
    with warnings.catch_warnings():
        # the move may take every body out of the second sonar view (a random scene without a
        # seabed): a frame without echo, and without noise, is then the honest second view
        warnings.simplefilter("ignore", NoEchoWarning)
        pair = simulate_rig(scene, rig, sp2, water=Water.preset(water), seed=seed + 7919, sonar_noise=noise)
    c1, c2 = rig.camera_pose(sp1), rig.camera_pose(sp2)
    R_o = c2.R.T @ c1.R
    t_o = c2.R.T @ (c1.t - c2.t)
    return pair.sonar, pair.optical, (R_o, t_o)


def evaluate_pair(sonar, optical, rig, *, options=None, seabed=None):
    """Match one pair and score it against the depth-map truth; also the baseline on the same features.

    ``seabed``: a seabed plane given to the matcher (navigation) instead of the one it fits.
    """
    from ..geometry import reconstruct as rc
    from ..matching import detect_camera_features, match, truth
    from ..matching.gating import mahalanobis_sq

    bin_w = float(np.median(np.diff(sonar.ranges)))
    beam_w = float(np.median(np.diff(sonar.azimuths)))
    m = match(sonar, optical.image, rig, options=options, min_score=0.0, seabed=seabed)
    out = dict(n_visible=0, score=np.zeros(0), ok=np.zeros(0, bool), base_ok=np.zeros(0, bool), err=np.zeros(0),
               ok3=np.zeros(0, bool), base_ok3=np.zeros(0, bool),
               err_true=np.zeros(0), matches=m, correct=np.zeros(0, bool), range_error_bins=np.zeros(0),
               surface=np.zeros(0, dtype=object))
    sf = m.sonar_features
    # The baseline's (and the "true matches"') camera features: OpenCV corners, whatever the matcher used.
    cf = detect_camera_features(optical.image)
    if sf is None or len(sf) == 0 or len(cf) == 0:
        return out
    T = truth.true_pairs(rig, optical.depth, cf.pixels, sf.ranges, sf.azimuths, bin_width=bin_w, beam_width=beam_w)
    # Visible in both sensors: some pixel of the feature's arc sees its point (any detector).
    out["n_visible"] = int(truth.visible(rig, optical.depth, sf.ranges, sf.azimuths, bin_width=bin_w,
                                         beam_width=beam_w).sum())
    if m:
        ok = truth.correct(rig, optical.depth, m.pixels, m.ranges, m.azimuths, bin_width=bin_w, beam_width=beam_w)
        out["score"], out["ok"], out["correct"] = m.score, ok, ok
        P_true = truth.pixel_points(rig, optical.depth, m.pixels)
        out["err"] = np.linalg.norm(m.points - P_true, axis=-1)
        out["ok3"] = truth.correct(rig, optical.depth, m.pixels, m.ranges, m.azimuths, bin_width=3 * bin_w,
                                   beam_width=3 * beam_w)
        # Why a wrong match is wrong (evaluation only): how far in range the pixel's true point is from the
        # feature (bins), and the surface the pixel sees (the camera's body map).
        from ..geometry.projection import to_sonar

        seen = np.all(np.isfinite(P_true), axis=1)
        sp = to_sonar(rig, np.where(seen[:, None], P_true, 0.0))
        out["range_error_bins"] = np.where(seen, (sp.ranges - m.ranges) / bin_w, np.nan)
        out["surface"] = _surfaces(optical, m.pixels)
    # Baseline: every sonar feature takes the camera feature nearest (Mahalanobis) to its conic.
    d2 = mahalanobis_sq(rig, cf.pixels, cf.sigma_pixel, sf.ranges, sf.azimuths, sf.sigma_range, sf.sigma_azimuth)
    j = np.argmin(d2, axis=1)
    has = d2[np.arange(len(sf)), j] < 9.0
    out["base_ok"] = T[np.arange(len(sf))[has], j[has]]
    out["base_ok3"] = truth.correct(rig, optical.depth, cf.pixels[j[has]], sf.ranges[has], sf.azimuths[has],
                                    bin_width=3 * bin_w, beam_width=3 * beam_w)
    # Reconstruction from the same number of true matches (one per visible sonar feature).
    rows = np.nonzero(T.any(1))[0]
    n_auto = int(np.sum(out["ok"] | ~out["ok"]))
    if rows.size and n_auto:
        rows = rows[:n_auto]
        cols = np.argmax(T[rows], axis=1)
        sig = dict(sigma_pixel=float(np.median(cf.sigma_pixel)), sigma_range=float(np.median(sf.sigma_range)),
                   sigma_azimuth=float(np.median(sf.sigma_azimuth)))
        ref = rc.refine(rig, cf.pixels[cols], sf.ranges[rows], sf.azimuths[rows], **sig)
        P_true = truth.pixel_points(rig, optical.depth, cf.pixels[cols])
        e = np.linalg.norm(ref.points - P_true, axis=-1)
        out["err_true"] = e[np.isfinite(e)]
    return out


def _surfaces(optical, pixels) -> np.ndarray:
    """The kind of surface each pixel sees, from the camera's body map: the body's name up to its first
    underscore or digit (``box_3`` -> ``box``, ``cuboid_right`` -> ``cuboid``, ``bar_x0`` -> ``bar``), ``lying``
    for a cylinder lying on the seabed, ``"water"`` where the pixel sees no body. Evaluation only."""
    import re

    from ..matching.arc_search import pixel_values

    body = getattr(optical, "body", None)
    names = list(getattr(optical, "body_names", None) or ())
    px = np.asarray(pixels, float).reshape(-1, 2)
    if body is None or not names or px.size == 0:
        return np.full(len(px), "unknown", dtype=object)
    ids = pixel_values(np.asarray(body), px)
    kinds = ["lying" if "lying" in n else re.split(r"[_\d]", n)[0] or n for n in names]
    return np.array([kinds[i] if 0 <= i < len(kinds) else "water" for i in ids], dtype=object)


def top_failures(evals, recall: float = 0.5, near_bins: float = 1.5) -> dict:
    """The top of the pooled ranking, down to where recall reaches ``recall``: its matches and its wrong ones by
    the surface the pixel sees, and how many of the wrong ones are near misses (the pixel's true point within
    ``near_bins`` range bins of the feature, where one bin is right). Evaluation only.

    Returns ``dict(n, wrong, near_miss, by_surface={kind: (matches, wrong, near misses)})``; empty counts where
    the recall is never reached.
    """
    n_vis, score, ok, order, tp = _ranked(evals)
    dr = np.concatenate([e.get("range_error_bins", np.full(len(e["ok"]), np.nan)) for e in evals]) if evals else np.zeros(0)
    kind = np.concatenate([e.get("surface", np.full(len(e["ok"]), "unknown", dtype=object)) for e in evals]) \
        if evals else np.zeros(0, dtype=object)
    out = dict(n=0, wrong=0, near_miss=0, by_surface={})
    if score.size == 0 or n_vis == 0:
        return out
    reach = np.nonzero(tp >= recall * n_vis)[0]
    if reach.size == 0:
        return out
    top = order[:reach[0] + 1]
    wrong = top[~ok[top]]
    near = np.abs(np.nan_to_num(dr[wrong], nan=np.inf)) <= near_bins
    out.update(n=int(top.size), wrong=int(wrong.size), near_miss=int(near.sum()))
    for k in sorted(set(kind[top])):
        in_k = kind[top] == k
        w_k = kind[wrong] == k
        out["by_surface"][str(k)] = (int(in_k.sum()), int(w_k.sum()), int((w_k & near).sum()))
    return out


def evaluate_two_views(scene, sonar, optical, rig, motion: dict, seed=0):
    """Matches from two views after the vehicle ``motion`` (known); truth from view 1's depth map.

    Returns a dict: ``score`` (two-view), ``ok`` (correct), ``source`` (0: arc search re-scored,
    1: arc sweep), ``baseline_m`` (camera displacement, m), ``px_per_bin`` (median image
    displacement in the second view per range bin of depth, px), ``matches``.
    """
    from ..matching import match, truth

    s2, o2, mo = moved_view(scene, motion, seed)
    m = match(sonar, optical.image, rig, min_score=0.0, second=(s2, o2.image), motion=mo)
    bw, aw = float(np.median(np.diff(sonar.ranges))), float(np.median(np.diff(sonar.azimuths)))
    out = dict(score=np.zeros(0), ok=np.zeros(0, bool), source=np.zeros(0, int),
               baseline_m=float(np.linalg.norm(mo[1])), px_per_bin=float("nan"), matches=m)
    if m:
        out["ok"] = truth.correct(rig, optical.depth, m.pixels, m.ranges, m.azimuths, bin_width=bw, beam_width=aw)
        out["score"], out["source"] = m.score, m.features["source"]
        sens = np.concatenate([m.features["flow_px_per_m"], m.features["sweep_px_per_m"]])
        if np.isfinite(sens).any():
            out["px_per_bin"] = float(np.nanmedian(sens) * bw)
    return out


def _two_view_summary(evals_1, evals_2) -> dict:
    """One view against two views on the same scenes: PR figures of both."""
    r1, p1 = _fine_curve(evals_1)
    r2, p2 = _fine_curve(evals_2)
    op1, op2 = _operating_point(evals_1), _operating_point(evals_2)
    src = np.concatenate([e["source"] for e in evals_2]) if evals_2 else np.zeros(0)
    return dict(curve_1=(r1, p1), curve_2=(r2, p2), n_visible=sum(e["n_visible"] for e in evals_2),
                n_matches_1=int(r1.size), n_matches_2=int(r2.size),
                single_best_precision_at_recall_0_5=_best_at(r1, p1, 0.5),
                two_view_best_precision_at_recall_0_5=_best_at(r2, p2, 0.5),
                single_precision_at_recall_0_25=_best_at(r1, p1, 0.25),
                two_view_precision_at_recall_0_25=_best_at(r2, p2, 0.25),
                single_max_recall=float(r1[-1]) if r1.size else 0.0,
                two_view_max_recall=float(r2[-1]) if r2.size else 0.0,
                single_precision_all=float(p1[-1]) if p1.size else float("nan"),
                two_view_precision_all=float(p2[-1]) if p2.size else float("nan"),
                single_auc=op1["auc"], two_view_auc=op2["auc"],
                single_recall_at_precision_0_95=op1["recall"], two_view_recall_at_precision_0_95=op2["recall"],
                sweep_fraction=float(np.mean(src == 1)) if src.size else float("nan"),
                baseline_m_median=float(np.median([e["baseline_m"] for e in evals_2])) if evals_2 else float("nan"),
                px_per_bin_median=float(np.nanmedian([e["px_per_bin"] for e in evals_2])) if evals_2 else float("nan"))


def _pr(evals, thresholds=None):
    """Pooled precision and recall at score thresholds (default: 0 and the scores' quantiles)."""
    n_vis = sum(e["n_visible"] for e in evals)
    score = np.concatenate([e["score"] for e in evals]) if evals else np.zeros(0)
    ok = np.concatenate([e["ok"] for e in evals]) if evals else np.zeros(0, bool)
    if thresholds is None:
        q = np.quantile(score, np.linspace(0, 0.97, N_THRESHOLDS - 1)) if score.size else np.zeros(N_THRESHOLDS - 1)
        thresholds = np.concatenate([[0.0], q])
    prec, rec, n = [], [], []
    for t in thresholds:
        k = score >= t
        prec.append(float(ok[k].mean()) if k.any() else float("nan"))
        rec.append(float(ok[k].sum() / n_vis) if n_vis else float("nan"))
        n.append(int(k.sum()))
    return np.array(prec), np.array(rec), np.array(n), n_vis, np.asarray(thresholds, float)


def _arc_profiles_figure(path, sonar, optical, rig, m, n_rows: int = 6):
    """Along-arc profiles of some matches: image gradient, where the pixel's true point is within tolerance, the choice.

    Evaluation only (reads the depth map): for each match, its arc's pixels from the bottom to
    the top of the elevation aperture; green where the pixel's true point projects within one
    bin and one beam of the feature, magenta the true point's range minus the feature's (bins).
    """
    import matplotlib.pyplot as plt

    from .._atomic import savefig
    from ..geometry.projection import camera_from_sonar, to_pixels, to_sonar
    from ..matching import truth
    from ..matching.arc_search import gradient_image

    bw = float(np.median(np.diff(sonar.ranges)))
    aw = float(np.median(np.diff(sonar.azimuths)))
    ok = truth.correct(rig, optical.depth, m.pixels, m.ranges, m.azimuths, bin_width=bw, beam_width=aw)
    pick = list(np.nonzero(ok)[0][: n_rows // 2]) + list(np.nonzero(~ok)[0][: n_rows - n_rows // 2])
    half = rig.fov_elevation / 2
    phis = np.linspace(-half, half, 600)
    G = gradient_image(optical.image)
    fig, axes = plt.subplots(len(pick), 1, figsize=(9, 1.6 * len(pick) + 0.6), sharex=True, squeeze=False)
    for ax, i in zip(axes[:, 0], pick):
        P = camera_from_sonar(rig, np.full(phis.size, m.ranges[i]), np.full(phis.size, m.azimuths[i]), phis)
        pp = to_pixels(rig, P)
        uv = np.where(pp.in_image[:, None], pp.pixels, 0.0)
        Pt = truth.pixel_points(rig, optical.depth, uv)
        sp = to_sonar(rig, np.where(np.isfinite(Pt), Pt, 0.0))
        dr = np.where(pp.in_image & np.all(np.isfinite(Pt), -1), (sp.ranges - m.ranges[i]) / bw, np.nan)
        good = (np.abs(dr) <= 1) & (np.abs(sp.azimuths - m.azimuths[i]) <= aw)
        ui = np.clip(np.rint(uv[:, 0]).astype(int), 0, G.shape[1] - 1)
        vi = np.clip(np.rint(uv[:, 1]).astype(int), 0, G.shape[0] - 1)
        deg = np.rad2deg(phis)
        ax.fill_between(deg, 0, 10 * good, color="#3cb44b", alpha=0.35, lw=0)
        ax.plot(deg, np.where(pp.in_image, np.minimum(G[vi, ui], 10), np.nan), color="#4363d8", lw=0.8)
        lo = m.features["elevation"][i] - m.features["position"][i] * m.features["elevation_span"][i]
        ax.axvspan(np.rad2deg(lo), np.rad2deg(lo + m.features["elevation_span"][i]), color="0.85", zorder=0)
        ax.axvline(np.rad2deg(m.features["elevation"][i]), color="k" if ok[i] else "#e6194b", lw=1.5)
        ax2 = ax.twinx()
        ax2.plot(deg, np.clip(dr, -20, 20), color="#f032e6", lw=0.7)
        ax2.axhline(0, color="#f032e6", lw=0.4, ls=":")
        ax2.set_ylim(-21, 21)
        ax.set_ylim(0, 10)
        ax.set_ylabel(f"#{i} {'ok' if ok[i] else 'wrong'}", fontsize=8)
    axes[-1, 0].set_xlabel("elevation along the feature's arc (deg)")
    fig.suptitle("Arc profiles: image gradient (blue, left axis), pixels whose true point is within 1 bin and 1 beam "
                 "(green),\ntrue range - feature range in bins (magenta, right axis), acoustic elevation interval "
                 "(grey), the matcher's choice (black: right, red: wrong)", fontsize=8)
    fig.tight_layout()
    out = savefig(fig, path, dpi=100)
    plt.close(fig)
    return out


def _candidate_truth(m, sonar, optical, rig) -> dict:
    """Which of each one-view match's candidates (arc search, crease, face plane, foot, seabed) is right (evaluation only)."""
    from ..matching import truth

    bw, aw = float(np.median(np.diff(sonar.ranges))), float(np.median(np.diff(sonar.azimuths)))
    out = {}
    for name in ("arc", "crease", "plane", "foot", "seabed"):
        has = np.zeros(len(m), bool)
        ok = np.zeros(len(m), bool)
        if m and f"{name}_u" in m.features:
            px = np.column_stack([m.features[f"{name}_u"], m.features[f"{name}_v"]])
            has = np.all(np.isfinite(px), axis=1)
            if has.any():
                ok[has] = truth.correct(rig, optical.depth, px[has], m.ranges[has], m.azimuths[has], bin_width=bw,
                                        beam_width=aw)
        out[f"has_{name}"], out[f"ok_{name}"] = has, ok
    out["source"] = np.asarray(m.features.get("face_source", np.zeros(len(m), int)), int) if m else np.zeros(0, int)
    return out


def _face_plane_figure(path, scene_name, sonar, optical, rig, m, cand, pooled):
    """The face-plane model on one scene (faces, candidates, right or wrong) and its candidates' precision pooled."""
    import matplotlib.pyplot as plt

    from .._atomic import savefig
    from ..matching.arc_search import gradient_image
    from ..matching.face_plane import face_labels
    from ..matching.figures import _camera_display

    fig, ax = plt.subplots(1, 2, figsize=(13, 4.6), gridspec_kw=dict(width_ratios=[1.6, 1]))
    img = _camera_display(optical.image)
    labels = face_labels(gradient_image(optical.image))
    edges = labels == 0
    shown = img.copy()
    shown[edges] = 0.5 * shown[edges]
    ax[0].imshow(shown)
    f = m.features
    styles = (("arc", "o", "run's middle"), ("crease", "^", "below the crease"), ("plane", "s", "on the face plane"),
              ("foot", "D", "above the foot"), ("seabed", "v", "on the seabed"))
    for name, marker, label in styles:
        u, v = np.asarray(f[f"{name}_u"], float), np.asarray(f[f"{name}_v"], float)
        has, ok = cand[f"has_{name}"], cand[f"ok_{name}"]
        ax[0].scatter(u[has & ok], v[has & ok], marker=marker, s=22, facecolors="none", edgecolors="#3cb44b",
                      linewidths=1.1, label=f"{label}: right")
        ax[0].scatter(u[has & ~ok], v[has & ~ok], marker=marker, s=22, facecolors="none", edgecolors="#e6194b",
                      linewidths=1.1, label=f"{label}: wrong")
    ax[0].scatter(m.pixels[:, 0], m.pixels[:, 1], marker="+", s=14, color="k", linewidths=0.8,
                  label="chosen (most probable)")
    ax[0].set_title(f"{scene_name}: candidates of each sonar feature (edges darkened; faces = regions between them)",
                    fontsize=8)
    ax[0].legend(fontsize=6, loc="lower left", ncol=3)
    ax[0].set_axis_off()
    names = ["run's middle", "below the crease", "on the face plane", "above the foot", "on the seabed",
             "chosen (most probable)", "any of the five"]
    vals = [pooled["arc"], pooled["crease"], pooled["plane"], pooled["foot"], pooled["seabed"], pooled["chosen"],
            pooled["any"]]
    ax[1].barh(np.arange(7), vals, color=["#4363d8", "#f58231", "#911eb4", "#9a6324", "#469990", "#000000", "#aaaaaa"])
    for i, (v_, n_) in enumerate(zip(vals, pooled["n"])):
        ax[1].text(min(v_ + 0.01, 0.85), i, f"{v_:.2f} of {n_}", va="center", fontsize=8)
    ax[1].set_yticks(np.arange(7), names, fontsize=8)
    ax[1].set_xlim(0, 1)
    ax[1].invert_yaxis()
    ax[1].set_xlabel("fraction right (where the candidate exists)")
    ax[1].set_title(f"one view, {pooled['n_scenes']} scenes, thesis water", fontsize=9)
    fig.tight_layout()
    out = savefig(fig, path, dpi=100)
    plt.close(fig)
    return out


def _operating_point(evals, target: float = 0.95) -> dict:
    """The lowest score threshold whose precision is >= ``target`` (every distinct score tried), and the AUC."""
    n_vis, score, ok, order, tp = _ranked(evals)
    out = dict(target_precision=target, threshold=float("nan"), precision=float("nan"), recall=0.0, n=0,
               auc=float("nan"))
    if score.size == 0 or n_vis == 0:
        return out
    n = np.arange(1, score.size + 1)
    p = tp / n
    cuts = _cuts(score[order])
    good = cuts[p[cuts] >= target]
    if good.size:
        i = int(good[-1])
        out.update(threshold=float(score[order][i]), precision=float(p[i]), recall=float(tp[i] / n_vis), n=int(n[i]))
    out["auc"] = score_auc(score, ok)
    return out


def score_auc(score, ok) -> float:
    """P(a right match outscores a wrong one), ties counted half: the Mann-Whitney statistic of ``score`` over
    the right (``ok``) against the wrong matches; NaN unless both kinds are present."""
    score = np.asarray(score, float)
    ok = np.asarray(ok, bool)
    if not 0 < ok.sum() < ok.size:
        return float("nan")
    from scipy.stats import rankdata

    rk = rankdata(score)
    return float((rk[ok].sum() - ok.sum() * (ok.sum() + 1) / 2) / (ok.sum() * (~ok).sum()))


def _ranked(evals):
    """The evaluations pooled and ranked best first: ``(n_visible, score, ok, order, right matches down the
    ranking)``; ``order`` sorts by descending score (stable), ``tp[i]`` counts the right ones in ``order[:i + 1]``."""
    n_vis = sum(e["n_visible"] for e in evals)
    score = np.concatenate([e["score"] for e in evals]) if evals else np.zeros(0)
    ok = np.concatenate([e["ok"] for e in evals]) if evals else np.zeros(0, bool)
    order = np.argsort(-score, kind="stable")
    return n_vis, score, ok, order, np.cumsum(ok[order])


def _cuts(score_sorted: np.ndarray) -> np.ndarray:
    """Positions in a descending ranking where a threshold ``score >= t`` can cut it: the last match of each run
    of equal scores (a cut inside a tie is no threshold)."""
    n = score_sorted.size
    return np.nonzero(np.append(score_sorted[1:] != score_sorted[:-1], True))[0] if n else np.zeros(0, int)


def _fine_curve(evals):
    """The exact precision-recall curve: precision and recall at every distinct score threshold (pooled, best
    first; ``score >= t`` for each distinct score ``t``): arrays (recall, precision). The report's 20-point
    curve (:func:`_pr`) samples it; the target's verdict is taken here."""
    n_vis, score, _, order, tp = _ranked(evals)
    if score.size == 0 or n_vis == 0:
        return np.zeros(0), np.zeros(0)
    k = _cuts(score[order])
    return tp[k] / n_vis, tp[k] / (k + 1)


def _best_at(recall, precision, target: float) -> float:
    """The highest precision at recall >= ``target`` (NaN when never reached)."""
    k = recall >= target
    return float(np.max(precision[k])) if k.any() else float("nan")


def _baseline(evals):
    n_vis = sum(e["n_visible"] for e in evals)
    ok = np.concatenate([e["base_ok"] for e in evals]) if evals else np.zeros(0, bool)
    return (float(ok.mean()) if ok.size else float("nan"), float(ok.sum() / n_vis) if n_vis else float("nan"), int(ok.size))


def run(out_dir, *, quick: bool = False, seed: int = 0) -> ExperimentResult:
    """The matching experiment (docs/matching.md, "Evaluation"). The matcher's seabed-relief warnings are
    expected here (the relief sweep, and a built-in scene whose near edge is broken by its planes): they
    are counted in the relief table instead of printed."""
    import warnings

    from ..matching import SeabedReliefWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SeabedReliefWarning)
        return _run(out_dir, quick=quick, seed=seed)


def _run(out_dir, *, quick: bool = False, seed: int = 0) -> ExperimentResult:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._atomic import savefig
    from ..matching.figures import draw_matches

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    # Quick mode (tests): two small random scenes, no built-in (thesis_scene1 alone costs seconds to simulate).
    builtins = [] if quick else _builtin_scenes()
    n_random = 2 if quick else 20
    randoms = [random_scene(seed * 1000 + i) for i in range(n_random)]
    all_scenes = builtins + randoms

    # 1. Thesis water and the default sonar noise: the headline precision-recall.
    import warnings

    from ..matching import MatchOptions, SeabedPlane, SeabedReliefWarning
    from ..optical import BlindCameraWarning

    evals, evals_corners, per_scene, evals_two, sub_pairs, cands, random_pairs = [], [], [], [], [], [], []
    n_sub = 1 if quick else 8
    first = profile = None
    profile_name = ""
    for k, sc in enumerate(all_scenes):
        s, o, rig = simulate_pair(sc, "thesis", "default", seed + k)
        e = evaluate_pair(s, o, rig)
        evals.append(e)
        evals_corners.append(evaluate_pair(s, o, rig, options=MatchOptions(method="corners")))
        tv = evaluate_two_views(sc, s, o, rig, vehicle_motion(seed * 1000 + 500 + k), seed + k)
        tv["n_visible"] = e["n_visible"]
        evals_two.append(tv)
        if k < n_sub:
            sub_pairs.append((s, o, rig))
        if k >= len(builtins):  # for section 4; the random scenes' seabed is the world plane z = 0
            e_nav = evaluate_pair(s, o, rig, seabed=SeabedPlane.from_pose(s.pose))
            random_pairs.append((sc, s.pose, o, rig, e, e_nav, seed + k, seed * 1000 + k - len(builtins)))
        m = e["matches"]
        per_scene.append([sc.name, e["n_visible"], len(e["ok"]), int(np.sum(e["ok"])), len(e["base_ok"]),
                          int(np.sum(e["base_ok"]))])
        if first is None:
            first = (sc.name, s, o, m, e["correct"])
        if profile is None and sc.name.startswith("random") and m:
            profile, profile_name = (s, o, rig, m), sc.name
        cands.append(_candidate_truth(m, s, o, rig))
    prec, rec, npt, n_vis, thresholds = _pr(evals)
    b_prec, b_rec, b_n = _baseline(evals)
    c_prec, c_rec, _, c_vis, _ = _pr(evals_corners, [0.0])
    op = _operating_point(evals)
    # the verdict on the exact curve (every distinct score a threshold); the 20-point curve samples it
    rc_f, pc_f = _fine_curve(evals)
    best_at_half = _best_at(rc_f, pc_f, 0.5)
    target_met = bool(best_at_half >= 0.95)
    best_at_half_sampled = np.nanmax(np.where(rec >= 0.5, prec, np.nan)) if np.any(rec >= 0.5) else float("nan")
    i05 = int(np.argmin(np.abs(thresholds - SCORE_CUT)))
    top = top_failures(evals)

    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    ax.plot(rc_f, pc_f, "-", color="#4363d8", lw=0.8, alpha=0.6, label="arc search, every score a threshold")
    ax.plot(rec, prec, "o", color="#4363d8", label="arc search, 20 score thresholds")
    if np.isfinite(op["threshold"]):
        ax.plot([op["recall"]], [op["precision"]], "*", color="#f58231", ms=12, zorder=5,
                label=f"lowest threshold with precision >= 0.95 (score {op['threshold']:.2f})")
    ax.plot([c_rec[0]], [c_prec[0]], "D", color="#3cb44b", ms=8, label="first design: gated corners + assignment")
    ax.plot([b_rec], [b_prec], "s", color="#e6194b", ms=9, label="baseline: nearest camera feature to each conic")
    ax.axhline(0.95, color="0.6", ls=":", lw=1)
    ax.axvline(0.5, color="0.6", ls=":", lw=1)
    ax.set_xlabel("recall (of sonar features visible in both sensors)")
    ax.set_ylabel("precision")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_title(f"{len(all_scenes)} scenes, thesis water, default sonar noise")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    f_pr = savefig(fig, out_dir / "matching_pr.png", dpi=110)
    plt.close(fig)
    figures = [(f_pr, "Precision-recall of automatic matches (threshold on the score) and the nearest-conic baseline.")]
    name0, s0, o0, m0, c0 = first
    f_ex = draw_matches(out_dir / "matching_example.png", s0.image, s0.ranges, s0.azimuths, o0.image, m0,
                        title=name0, correct=c0)
    figures.append((f_ex, f"Matches on {name0}, colour = score, x = wrong by the depth-map ground truth."))
    if profile is not None:
        f_ar = _arc_profiles_figure(out_dir / "matching_arcs.png", *profile)
        figures.append((f_ar, f"Along-arc profiles of matches on {profile_name} (evaluation only: reads the depth "
                              "map): where the correct pixels lie against the edge-free runs the matcher chose."))
    cat = {k: np.concatenate([c[k] for c in cands]) for k in cands[0]} if cands else {}
    face_plane_numbers = {}
    if cat and cat["source"].size:
        ok_chosen = np.concatenate([e["ok"] for e in evals])
        pooled = dict(n=[int(cat["has_arc"].sum()), int(cat["has_crease"].sum()), int(cat["has_plane"].sum()),
                         int(cat["has_foot"].sum()), int(cat["has_seabed"].sum()), int(ok_chosen.size),
                         int(ok_chosen.size)], n_scenes=len(all_scenes))
        for name in ("arc", "crease", "plane", "foot", "seabed"):
            h = cat[f"has_{name}"]
            pooled[name] = float(cat[f"ok_{name}"][h].mean()) if h.any() else 0.0
        pooled["chosen"] = float(ok_chosen.mean())
        pooled["any"] = float(np.mean(cat["ok_arc"] | cat["ok_crease"] | cat["ok_plane"] | cat["ok_foot"]
                                      | cat["ok_seabed"]))
        face_plane_numbers = dict(pooled, source_counts=np.bincount(cat["source"], minlength=5).tolist())
        if profile is not None:
            s_p, o_p, rig_p, m_p = profile
            f_fp = _face_plane_figure(out_dir / "matching_face_plane.png", profile_name, s_p, o_p, rig_p, m_p,
                                      _candidate_truth(m_p, s_p, o_p, rig_p), pooled)
            figures.append((f_fp, f"The face-plane model on {profile_name} (evaluation only: right or wrong by the "
                                  "depth map): each sonar feature's four candidate pixels, and how often each is "
                                  f"right over the {len(all_scenes)} scenes."))

    # 2. Turbidity and sonar noise (on a subset of scenes).
    sub = all_scenes[:n_sub]
    waters = WATERS[1::2] if quick else WATERS
    floors = NOISE_FLOORS_DB[::3] if quick else NOISE_FLOORS_DB
    turb = []
    for w in waters:
        ev = [evaluate_pair(*simulate_pair(sc, w, "default", seed + k)) for k, sc in enumerate(sub)]
        p, r, _, nv, _ = _pr(ev, thresholds)
        bp, br, _ = _baseline(ev)
        turb.append([w, nv, p[i05], r[i05], p[0], r[0], bp, br])
    noi = []
    for nf in floors:
        ev = [evaluate_pair(*simulate_pair(sc, "thesis", nf, seed + k)) for k, sc in enumerate(sub)]
        p, r, _, nv, _ = _pr(ev, thresholds)
        bp, br, _ = _baseline(ev)
        noi.append(["off" if nf is None else f"{nf:g} dB", nv, p[i05], r[i05], p[0], r[0], bp, br])
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for a, rows_, xl in ((ax[0], turb, "water"), (ax[1], noi, "sonar noise floor")):
        x = np.arange(len(rows_))
        a.plot(x, [r_[4] for r_ in rows_], "o-", color="#4363d8", label="precision (all assigned)")
        a.plot(x, [r_[5] for r_ in rows_], "o--", color="#4363d8", alpha=0.6, label="recall (all assigned)")
        a.plot(x, [r_[6] for r_ in rows_], "s-", color="#e6194b", label="baseline precision")
        a.plot(x, [r_[7] for r_ in rows_], "s--", color="#e6194b", alpha=0.6, label="baseline recall")
        a.set_xticks(x, [r_[0] for r_ in rows_])
        a.set_xlabel(xl)
        a.set_ylim(0, 1)
    ax[0].legend(fontsize=7)
    fig.suptitle(f"precision / recall vs turbidity and sonar noise ({len(sub)} scenes)")
    fig.tight_layout()
    f_tn = savefig(fig, out_dir / "matching_conditions.png", dpi=110)
    plt.close(fig)
    figures.append((f_tn, "Precision and recall against turbidity (clear to Jerlov 3C) and the sonar's noise floor."))

    # 3. Two views with known motion (thesis ch. 6): every scene gets a random vehicle motion
    #    (vehicle_motion, MOTION_RANGES). The plain scenes' surfaces are uniformly coloured (the
    #    hardest case for a camera-to-camera correspondence); the textured copies of the random
    #    scenes checker every surface (optically only: the sonar sees the same scene).
    tex_scenes = [random_scene(seed * 1000 + i, textured=True) for i in range(n_random)]
    evals_tex, evals_tex_two, sub_tex = [], [], []
    for k, sc in enumerate(tex_scenes):
        s, o, rig = simulate_pair(sc, "thesis", "default", seed + len(builtins) + k)
        e = evaluate_pair(s, o, rig)
        evals_tex.append(e)
        tv = evaluate_two_views(sc, s, o, rig, vehicle_motion(seed * 1000 + 500 + len(builtins) + k),
                                seed + len(builtins) + k)
        tv["n_visible"] = e["n_visible"]
        evals_tex_two.append(tv)
        if k < n_sub:
            sub_tex.append((sc, (s, o, rig), e["n_visible"]))
        if k == 0:
            tex_example = (sc.name, s, o, tv)
    plain = _two_view_summary(evals, evals_two)
    textured = _two_view_summary(evals_tex, evals_tex_two)
    # Precision against the baseline's length: the vehicle moving 0.3 m forward and ``sway`` to
    # the side (no heave, no yaw), on the first scenes of both sets.
    sways = (0.25, 1.0) if quick else (0.0, 0.25, 0.5, 1.0, 2.0)
    sweep = []
    sub_plain = [(sc, pr_, evals[k]["n_visible"]) for k, (sc, pr_) in enumerate(zip(sub, sub_pairs))]
    for label, subset in (("plain", sub_plain), ("textured", sub_tex)):
        for sw in sways:
            ev = []
            for k, (sc, pr_, nv) in enumerate(subset):
                # At 2 m of sway the camera of the narrowest scene (perpendicular_planes, 2.8 m wide)
                # looks past it: a second view that sees nothing is part of the sweep (its matches
                # fall back to one view), not a mistake to warn the user about.
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", BlindCameraWarning)
                    e2 = evaluate_two_views(sc, *pr_, dict(surge=0.3, sway=sw, heave=0.0, yaw_deg=0.0), seed + k)
                e2["n_visible"] = nv
                ev.append(e2)
            rc_, pc_ = _fine_curve(ev)
            sweep.append(dict(scenes=label, sway_m=sw, baseline_m=float(np.hypot(0.3, sw)),
                              px_per_bin=float(np.nanmedian([e["px_per_bin"] for e in ev])),
                              precision_at_recall_0_25=_best_at(rc_, pc_, 0.25),
                              best_precision_at_recall_0_5=_best_at(rc_, pc_, 0.5),
                              max_recall=float(rc_[-1]) if rc_.size else 0.0, auc=_operating_point(ev)["auc"]))
    two_view = dict(motion_ranges=MOTION_RANGES,
                    plain={k: v for k, v in plain.items() if not k.startswith("curve")},
                    textured={k: v for k, v in textured.items() if not k.startswith("curve")},
                    baseline_sweep=sweep)
    fig, ax = plt.subplots(1, 2, figsize=(11.5, 4.5))
    for summ, ls, name in ((plain, "-", f"{len(evals_two)} plain scenes"),
                           (textured, "--", f"{len(evals_tex_two)} textured scenes")):
        ax[0].plot(*summ["curve_1"], ls, color="#4363d8", label=f"one view, {name}, AUC {summ['single_auc']:.2f}")
        ax[0].plot(*summ["curve_2"], ls, color="#f58231",
                   label=f"two views (known motion), {name}, AUC {summ['two_view_auc']:.2f}")
    ax[0].plot([b_rec], [b_prec], "s", color="#e6194b", ms=8, label="baseline (one view, plain scenes)")
    ax[0].axhline(0.95, color="0.6", ls=":", lw=1)
    ax[0].axvline(0.5, color="0.6", ls=":", lw=1)
    ax[0].set_xlim(0, 1)
    ax[0].set_ylim(0, 1.02)
    ax[0].set_xlabel("recall (of sonar features visible in both sensors)")
    ax[0].set_ylabel("precision")
    ax[0].set_title("PR, thesis water, random vehicle motion per scene", fontsize=9)
    ax[0].legend(fontsize=6.5, loc="lower left")
    for label, mk, col in (("plain", "o", "#4363d8"), ("textured", "s", "#f58231")):
        rows_ = [d for d in sweep if d["scenes"] == label]
        xb = [d["baseline_m"] for d in rows_]
        ax[1].plot(xb, [d["best_precision_at_recall_0_5"] for d in rows_], mk + "-", color=col,
                   label=f"{label}: precision at recall 0.5")
        ax[1].plot(xb, [d["precision_at_recall_0_25"] for d in rows_], mk + "--", color=col, alpha=0.6,
                   label=f"{label}: precision at recall 0.25")
        ax[1].plot(xb, [d["max_recall"] for d in rows_], mk + ":", color=col, alpha=0.4, mfc="none",
                   label=f"{label}: recall of all matches")
    ax[1].set_xlabel("baseline (m): 0.3 m forward and 0 - 2 m sideways")
    ax[1].set_ylabel("precision, recall (two views)")
    ax[1].set_ylim(0, 1.3)
    ax[1].set_yticks(np.linspace(0, 1, 6))
    ax2 = ax[1].twinx()
    rows_ = [d for d in sweep if d["scenes"] == "plain"]
    ax2.plot([d["baseline_m"] for d in rows_], [d["px_per_bin"] for d in rows_], "k:", lw=1)
    ax2.set_ylabel("image shift in view 2 per range bin of depth (px, dotted)", fontsize=8)
    ax[1].legend(fontsize=6.5, loc="upper center", ncol=2)
    ax[1].set_title(f"{len(sub)} scenes of each kind: precision against baseline length", fontsize=9)
    fig.tight_layout()
    f_tv = savefig(fig, out_dir / "matching_two_views.png", dpi=110)
    plt.close(fig)
    figures.append((f_tv, "Two views with known motion: PR curves with one view and with two (plain and textured "
                          "scenes), and precision against the baseline's length."))
    name_t, s_t, o_t, tv_t = tex_example
    if tv_t["matches"]:
        f_t0 = draw_matches(out_dir / "matching_two_view_example.png", s_t.image, s_t.ranges, s_t.azimuths,
                            o_t.image, tv_t["matches"], title=f"{name_t}, two views", correct=tv_t["ok"])
        figures.append((f_t0, f"Two-view matches on {name_t} (colour = two-view score, x = wrong by the depth map)."))

    # 4. The sonar's elevation beam: the random scenes again, with the realistic sonar model's soft beam
    #    (docs/matching.md, "Soft elevation beams"), the seabed plane fitted to the image or given by
    #    the vehicle's navigation (here the true one, from the sonar's pose).
    soft_beam, soft_example = _soft_beam_rows(random_pairs)
    if soft_example is not None:
        name_s, s_s, o_s, m_s, ok_s = soft_example
        f_sb = draw_matches(out_dir / "matching_soft_beam.png", s_s.image, s_s.ranges, s_s.azimuths, o_s.image, m_s,
                            title=f"{name_s}, realistic sonar (soft beam), seabed from navigation", correct=ok_s)
        figures.append((f_sb, f"Matches on {name_s} with the realistic sonar model (soft elevation beam, speckle) and "
                              "the seabed plane from the navigation (colour = score, x = wrong by the depth map)."))

    # 5. Seabed relief: the matcher's seabed is one plane; real seabeds have relief. The first random
    #    scenes again, their seabed a heightfield of RELIEF_RMS_M (relief_scene).
    import tempfile

    reliefs = RELIEF_RMS_M[::2] if quick else RELIEF_RMS_M
    relief_rows, relief_curves = [], []
    with tempfile.TemporaryDirectory(prefix="oas-relief-") as tmp:
        for rms in reliefs:
            ev, ev_err, flagged = [], [], 0
            for *_, sd, scene_seed in random_pairs[:n_sub]:
                pair = simulate_pair(relief_scene(scene_seed, rms, tmp), "thesis", "default", sd)
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always", SeabedReliefWarning)
                    ev.append(evaluate_pair(*pair))
                    # the same pair with the relief the fit's residual implies taken as the plane's error
                    ev_err.append(evaluate_pair(*pair, options=MatchOptions(relief_as_plane_error=True)))
                flagged += any(issubclass(w.category, SeabedReliefWarning) for w in caught)
            rc_e, pc_e = _fine_curve(ev_err)
            rc_, pc_ = _fine_curve(ev)
            bp, br, _ = _baseline(ev)
            ok_ = np.concatenate([e["ok"] for e in ev])
            nv = sum(e["n_visible"] for e in ev)
            relief_rows.append(dict(rms_m=rms, n_visible=int(nv), n_matches=int(ok_.size), pairs_warned=int(flagged),
                                    n_pairs=len(ev),
                                    precision_at_recall_0_5=_best_at(rc_, pc_, 0.5) if rc_.size else float("nan"),
                                    precision_at_recall_0_25=_best_at(rc_, pc_, 0.25) if rc_.size else float("nan"),
                                    precision_all=float(ok_.mean()) if ok_.size else float("nan"),
                                    recall_all=float(ok_.sum() / nv) if nv else float("nan"),
                                    baseline_precision=bp,
                                    plane_error_precision_at_recall_0_25=_best_at(rc_e, pc_e, 0.25) if rc_e.size
                                    else float("nan"),
                                    plane_error_precision_at_recall_0_5=_best_at(rc_e, pc_e, 0.5) if rc_e.size
                                    else float("nan")))
            relief_curves.append((rms, rc_, pc_))
    fig, ax = plt.subplots(figsize=(5.5, 4.5))
    for (rms, rc_, pc_), col in zip(relief_curves, plt.cm.viridis(np.linspace(0, 0.9, len(relief_curves)))):
        ax.plot(rc_, pc_, color=col, label=f"seabed relief {rms * 100:g} cm RMS")
    ax.axhline(0.95, color="0.6", ls=":", lw=1)
    ax.axvline(0.5, color="0.6", ls=":", lw=1)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("recall (of sonar features visible in both sensors)")
    ax.set_ylabel("precision")
    ax.set_title(f"{min(n_sub, len(random_pairs))} random scenes on a seabed with relief (waves 1-4 m)", fontsize=9)
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    f_rl = savefig(fig, out_dir / "matching_relief.png", dpi=110)
    plt.close(fig)
    figures.append((f_rl, "Precision-recall when the seabed is not flat: the matcher's seabed is one plane, and "
                          "centimetres of relief take its precision down (docs/matching.md, 'Seabed relief')."))

    err = np.concatenate([e["err"] for e in evals]) if evals else np.zeros(0)
    err_true = np.concatenate([e["err_true"] for e in evals]) if evals else np.zeros(0)
    err = err[np.isfinite(err)]
    med_auto = float(np.median(err)) if err.size else float("nan")
    med_true = float(np.median(err_true)) if err_true.size else float("nan")
    p_all = float(prec[0])
    ok3 = np.concatenate([e["ok3"] for e in evals]) if evals else np.zeros(0, bool)
    b_ok3 = np.concatenate([e["base_ok3"] for e in evals]) if evals else np.zeros(0, bool)
    loose = dict(precision=float(ok3.mean()) if ok3.size else float("nan"),
                 baseline_precision=float(b_ok3.mean()) if b_ok3.size else float("nan"),
                 within_10cm=float(np.mean(err < 0.10)) if err.size else float("nan"))
    ratio = p_all / b_prec if b_prec > 0 else float("nan")
    numbers = dict(
        n_scenes=len(all_scenes), n_visible=n_vis, thresholds=thresholds, score_cut=float(thresholds[i05]), precision=prec, recall=rec, n_matches=npt,
        precision_at_score_cut=float(prec[i05]), recall_at_score_cut=float(rec[i05]),
        precision_all_assigned=p_all, recall_all_assigned=float(rec[0]),
        best_precision_at_recall_0_5=best_at_half, target_met=target_met,
        best_precision_at_recall_0_5_sampled=best_at_half_sampled,
        operating_point_precision_0_95=op,
        corners_precision_all_assigned=float(c_prec[0]), corners_recall_all_assigned=float(c_rec[0]),
        baseline_precision=b_prec, baseline_recall=b_rec, baseline_n=b_n, precision_ratio_to_baseline=ratio,
        median_error_auto_m=med_auto, median_error_true_matches_m=med_true,
        two_view=two_view, three_bins_three_beams=loose, face_plane=face_plane_numbers,
        turbidity=[dict(zip(["water", "n_visible", "precision_cut", "recall_cut", "precision_all", "recall_all",
                             "baseline_precision", "baseline_recall"], r_)) for r_ in turb],
        sonar_noise=[dict(zip(["noise_floor", "n_visible", "precision_cut", "recall_cut", "precision_all",
                               "recall_all", "baseline_precision", "baseline_recall"], r_)) for r_ in noi],
        soft_beam=soft_beam,
        seabed_relief=relief_rows,
        top_failures=top,
    )
    fmt = lambda v: f"{v:.2f}" if isinstance(v, (float, np.floating)) and np.isfinite(v) else str(v)  # noqa: E731
    tables = [
        ("Precision-recall (thesis water, default sonar noise)", ["score >=", "matches", "precision", "recall"],
         [[f"{t:.3f}", int(n_), fmt(p_), fmt(r_)] for t, n_, p_, r_ in zip(thresholds[::2], npt[::2], prec[::2], rec[::2])]),
        ("Methods (thesis water, default sonar noise, all assigned matches)", ["method", "precision", "recall"],
         [["arc search (default)", fmt(p_all), fmt(float(rec[0]))],
          ["epipolar-gated corners + assignment (first design)", fmt(float(c_prec[0])), fmt(float(c_rec[0]))],
          ["baseline: nearest corner to each conic", fmt(b_prec), fmt(b_rec)],
          [f"arc search, score >= {op['threshold']:.3f} (highest recall at precision >= 0.95)"
           if op["n"] else "arc search: precision >= 0.95 at no score threshold", fmt(op["precision"]),
           fmt(op["recall"])]]),
        ("Per scene", ["scene", "visible", "matches", "correct", "baseline matches", "baseline correct"],
         per_scene),
        ("Turbidity", ["water", "visible", "prec@cut", "rec@cut", "prec all", "rec all", "base prec", "base rec"],
         [[r_[0], r_[1]] + [fmt(v) for v in r_[2:]] for r_ in turb]),
        ("Sonar noise", ["noise floor", "visible", "prec@cut", "rec@cut", "prec all", "rec all", "base prec", "base rec"],
         [[r_[0], r_[1]] + [fmt(v) for v in r_[2:]] for r_ in noi]),
        ("Two views with known motion (random vehicle motion per scene: surge 0.2-1 m, sway +-0.5 m, heave "
         "+-0.15 m, yaw +-5 deg); one view = one pair, the issue's figures",
         ["", "plain: one view", "plain: two views", "textured: one view", "textured: two views"],
         [[label, fmt(plain[k1]), fmt(plain[k2]), fmt(textured[k1]), fmt(textured[k2])] for label, k1, k2 in (
             ("best precision at recall >= 0.5", "single_best_precision_at_recall_0_5",
              "two_view_best_precision_at_recall_0_5"),
             ("best precision at recall >= 0.25", "single_precision_at_recall_0_25",
              "two_view_precision_at_recall_0_25"),
             ("all matches: precision", "single_precision_all", "two_view_precision_all"),
             ("all matches: recall", "single_max_recall", "two_view_max_recall"),
             ("recall at precision >= 0.95", "single_recall_at_precision_0_95", "two_view_recall_at_precision_0_95"),
             ("score AUC", "single_auc", "two_view_auc"))]
         + [["visible features", plain["n_visible"], "", textured["n_visible"], ""],
            ["two-view matches from the arc sweep", "", fmt(plain["sweep_fraction"]), "",
             fmt(textured["sweep_fraction"])],
            ["median baseline (m); shift per range bin (px)", "",
             f"{fmt(plain['baseline_m_median'])}; {plain['px_per_bin_median']:.3f}", "",
             f"{fmt(textured['baseline_m_median'])}; {textured['px_per_bin_median']:.3f}"]]),
        ("Two views: precision against baseline (0.3 m forward + sway, no yaw)",
         ["scenes", "sway (m)", "baseline (m)", "px per bin", "prec@rec 0.25", "prec@rec 0.5", "max recall", "AUC"],
         [[d["scenes"], f"{d['sway_m']:g}", fmt(d["baseline_m"]), f"{d['px_per_bin']:.3f}",
           fmt(d["precision_at_recall_0_25"]), fmt(d["best_precision_at_recall_0_5"]), fmt(d["max_recall"]),
           fmt(d["auc"])] for d in sweep]),
        ("Looser criterion (within 3 bins and 3 beams; not the issue's)", ["", "precision"],
         [["matcher (all assigned)", fmt(loose["precision"])], ["baseline", fmt(loose["baseline_precision"])],
          ["matcher, 3D error < 10 cm", fmt(loose["within_10cm"])]]),
        ("Reconstruction error (median, m)", ["automatic matches", "same number of true matches"],
         [[fmt(med_auto), fmt(med_true)]]),
        (f"The top of the ranking down to recall 0.5 ({top['n']} matches, {top['wrong']} wrong, {top['near_miss']} "
         "of them near misses: the pixel's true point within 1.5 bins of the feature, one bin being right), by the "
         "surface the pixel sees (the camera's body map)",
         ["surface", "matches", "wrong", "near misses", "precision"],
         [[k, n_, w_, nm_, fmt(1 - w_ / n_ if n_ else float("nan"))] for k, (n_, w_, nm_) in top["by_surface"].items()]),
        (f"Sonar elevation beam ({len(random_pairs)} random scenes): the thesis model's hard-edged aperture against "
         "the realistic model's soft beam, with the seabed plane fitted to the sonar image or given by the navigation",
         ["sonar", "seabed plane", "pairs declined", "visible", "matches", "prec@rec 0.25", "prec@rec 0.5",
          "prec all", "rec all", "mean score"],
         [[d["sonar"], d["seabed"], d["declined"], d["n_visible"], d["n_matches"], fmt(d["precision_at_recall_0_25"]),
           fmt(d["precision_at_recall_0_5"]), fmt(d["precision_all"]), fmt(d["recall_all"]), fmt(d["mean_score"])]
          for d in soft_beam]),
        (f"Seabed relief ({min(n_sub, len(random_pairs))} random scenes, their seabed a heightfield of plane waves "
         "1-4 m long; thesis water and sonar)",
         ["relief RMS (cm)", "pairs warned (SeabedReliefWarning)", "visible", "matches", "prec@rec 0.25",
          "prec@rec 0.5", "prec all", "rec all", "base prec", "relief as plane error: prec@rec 0.25",
          "prec@rec 0.5"],
         [[f"{d['rms_m'] * 100:g}", f"{d['pairs_warned']} of {d['n_pairs']}", d["n_visible"], d["n_matches"],
           fmt(d["precision_at_recall_0_25"]),
           fmt(d["precision_at_recall_0_5"]), fmt(d["precision_all"]), fmt(d["recall_all"]),
           fmt(d["baseline_precision"]), fmt(d["plane_error_precision_at_recall_0_25"]),
           fmt(d["plane_error_precision_at_recall_0_5"])] for d in relief_rows]),
    ]
    summary = (f"{len(all_scenes)} scenes, {n_vis} sonar features visible in both sensors (some pixel of the "
               f"feature's arc sees its point): arc search, all assigned matches have "
               f"precision {p_all:.2f} at recall {rec[0]:.2f} (score >= {thresholds[i05]:.2f}: {prec[i05]:.2f} at "
               f"{rec[i05]:.2f}); the "
               f"nearest-conic baseline {b_prec:.2f} at {b_rec:.2f} ({ratio:.1f}x better precision). Target "
               f"(precision >= 0.95 at recall >= 0.5) {'met' if target_met else 'NOT met'}: {best_at_half:.3f} at recall >= 0.5 "
               f"(every score a threshold; {best_at_half_sampled:.3f} on the 20-point curve). Median 3D error "
               f"{med_auto:.2f} m (automatic) vs {med_true:.3f} m (true matches). First design (corners): "
               f"{c_prec[0]:.2f} at {c_rec[0]:.2f}. Precision >= 0.95 reached at recall {op['recall']:.2f} "
               f"({op['n']} matches); score AUC {op['auc']:.2f}. Two views with known motion (random vehicle "
               f"motion, median baseline {plain['baseline_m_median']:.2f} m), all matches, one view vs two: plain "
               f"scenes precision {plain['single_precision_all']:.2f} vs {plain['two_view_precision_all']:.2f} at "
               f"recall {plain['single_max_recall']:.2f} vs {plain['two_view_max_recall']:.2f} (AUC "
               f"{plain['single_auc']:.2f} vs {plain['two_view_auc']:.2f}); textured scenes "
               f"{textured['single_precision_all']:.2f} vs {textured['two_view_precision_all']:.2f} at "
               f"{textured['single_max_recall']:.2f} vs {textured['two_view_max_recall']:.2f} (AUC "
               f"{textured['single_auc']:.2f} vs {textured['two_view_auc']:.2f}); precision >= 0.95 at recall >= 0.5 "
               f"reached by neither." + _soft_beam_sentence(soft_beam) + _relief_sentence(relief_rows))
    return ExperimentResult(NAME, figures, numbers, summary, tables)


def _soft_beam_rows(random_pairs):
    """Section 4 of :func:`run`: the random scenes' pairs with the thesis and the realistic sonar, the seabed
    fitted or from the navigation (the true plane, from the sonar's pose). Rows for the report, and the
    first realistic pair's navigation matches for its figure."""
    from .. import simulate_sonar
    from ..matching import MatchOptions, SeabedPlane

    real = realistic_sonar()
    err = f"{NAV_ERROR[0] * 100:g} cm / {np.rad2deg(NAV_ERROR[1]):g} deg"
    variants = (("thesis", "fitted"), ("thesis", "navigation"), ("realistic", "fitted (declined)"),
                ("realistic", "fitted (allow_soft_beam)"), ("realistic", "navigation"),
                ("realistic", f"navigation, {err} error, not declared"),
                ("realistic", f"navigation, {err} error, declared"))
    evs = {v: [] for v in variants}
    example = None
    for sc, pose, o, rig, e_fit, e_nav, sd, _ in random_pairs:
        s_real = simulate_sonar(sc, rig.sonar, pose, seed=sd, **real)
        evs[variants[0]].append(e_fit)
        evs[variants[1]].append(e_nav)
        evs[variants[2]].append(evaluate_pair(s_real, o, rig))
        evs[variants[3]].append(evaluate_pair(s_real, o, rig, options=MatchOptions(allow_soft_beam=True)))
        e_real = evaluate_pair(s_real, o, rig, seabed=SeabedPlane.from_pose(pose))
        evs[variants[4]].append(e_real)
        # the navigation's plane with an error drawn from its stated sigmas, given with and without them
        off = navigation_plane(pose, np.random.default_rng(sd), *NAV_ERROR)
        evs[variants[5]].append(evaluate_pair(s_real, o, rig, seabed=off))
        told = dataclasses.replace(off, sigma_offset=NAV_ERROR[0], sigma_tilt=NAV_ERROR[1])
        evs[variants[6]].append(evaluate_pair(s_real, o, rig, seabed=told))
        if example is None and e_real["matches"]:
            example = (sc.name, s_real, o, e_real["matches"], e_real["correct"])
    rows = []
    for (sonar, seabed), ev in evs.items():
        rc, pc = _fine_curve(ev)
        n_vis = sum(e["n_visible"] for e in ev)
        ok = np.concatenate([e["ok"] for e in ev]) if ev else np.zeros(0, bool)
        declined = sum(1 for e in ev if not e["matches"] and "soft elevation beam" in e["matches"].message)
        sc_ = np.concatenate([e["score"] for e in ev]) if ev else np.zeros(0)
        rows.append(dict(sonar=sonar, seabed=seabed, declined=declined, n_visible=int(n_vis), n_matches=int(ok.size),
                         precision_at_recall_0_25=_best_at(rc, pc, 0.25) if rc.size else float("nan"),
                         precision_at_recall_0_5=_best_at(rc, pc, 0.5) if rc.size else float("nan"),
                         mean_score=float(sc_.mean()) if sc_.size else float("nan"),
                         precision_all=float(ok.mean()) if ok.size else float("nan"),
                         recall_all=float(ok.sum() / n_vis) if n_vis else float("nan")))
    return rows, example


#: The navigation plane's error in the soft-beam section: altitude (m) and roll/pitch (rad) standard deviations,
#: a DVL's or altimeter's centimetre and a good attitude sensor's 0.05 deg.
NAV_ERROR = (0.01, float(np.deg2rad(0.05)))


def navigation_plane(pose, rng, sigma_height: float, sigma_tilt: float):
    """The seabed plane a navigation system with these errors reports: the true plane from the sonar's
    ``pose`` with its altitude off by a draw of ``N(0, sigma_height)`` and its normal rotated by draws of
    ``N(0, sigma_tilt)`` about the sonar's x and y axes (no sigmas declared on it)."""
    from scipy.spatial.transform import Rotation

    from ..matching import SeabedPlane

    true = SeabedPlane.from_pose(pose)
    rot = Rotation.from_rotvec([rng.normal(0.0, sigma_tilt), rng.normal(0.0, sigma_tilt), 0.0])
    return SeabedPlane(rot.apply(true.normal), float(true.offset - rng.normal(0.0, sigma_height)), 0.0, 0)


def _relief_sentence(rows) -> str:
    if len(rows) < 2:
        return ""
    parts = ", ".join(f"{d['rms_m'] * 100:g} cm {d['precision_all']:.2f}" for d in rows)
    return f" Seabed relief (RMS), all matches' precision: {parts}."


def _soft_beam_sentence(rows) -> str:
    d = {(r["sonar"], r["seabed"]): r for r in rows}
    nav, fit = d.get(("realistic", "navigation")), d.get(("realistic", "fitted (allow_soft_beam)"))
    if not nav or not fit:
        return ""
    return (f" Realistic sonar (soft elevation beam): declined by default; with the seabed from the navigation "
            f"precision {nav['precision_all']:.2f} at recall {nav['recall_all']:.2f} of all matches, with the fitted "
            f"plane {fit['precision_all']:.2f} at {fit['recall_all']:.2f}.")


def _training_scene(sd, generator: str = "random"):
    """The training scene of seed ``sd``: :func:`random_scene` (``"random"``) or :func:`varied_scene` (``"varied"``)."""
    if generator not in ("random", "varied"):
        raise ValueError(f"unknown training scene generator {generator!r}: 'random' or 'varied'")
    return random_scene(int(sd)) if generator == "random" else varied_scene(int(sd))


def calibrate_score(seeds=range(5000, 5024), *, ridge: float = 1.0, method: str = "arc",
                    varied_seeds=range(8000, 8024)) -> dict:
    """Refit ``matching.match.ARC_SCORE_MODEL`` (``method="arc"``) or ``SCORE_MODEL`` (``"corners"``).

    Logistic regression of correctness on the match evidence.

    Runs the matcher on random scenes seeded ``seeds`` (:func:`random_scene`) and ``varied_seeds``
    (:func:`varied_scene`; thesis water, default sonar noise), labels each assigned match by the
    depth-map truth (for ``"arc"`` the arc search's own pixel, whichever candidate the face models
    then choose) and fits the logistic model with a ridge penalty (``scipy.optimize.minimize``).
    Use seeds disjoint from the evaluation's.

    Returns
    -------
    dict
        ``weights`` (intercept first), ``mean``, ``std`` of the standardised features, and
        ``n`` (training matches), ``positive_rate``.
    """
    from ..matching import MatchOptions
    from ..matching.match import arc_score_features, score_features

    from ..matching import truth

    featurise = arc_score_features if method == "arc" else score_features
    X, y = [], []
    for sd, gen in [(sd, "random") for sd in seeds] + [(sd, "varied") for sd in varied_seeds]:
        s, o, rig = simulate_pair(_training_scene(sd, gen), "thesis", "default", int(sd))
        e = evaluate_pair(s, o, rig, options=MatchOptions(method=method))
        m = e["matches"]
        if m:
            X.append(featurise(m.features))
            ok = e["ok"]
            if method == "arc":  # the arc search's own pixel, whichever candidate the face models chose
                bw, aw = float(np.median(np.diff(s.ranges))), float(np.median(np.diff(s.azimuths)))
                ok = truth.correct(rig, o.depth, np.column_stack([m.features["arc_u"], m.features["arc_v"]]),
                                   m.ranges, m.azimuths, bin_width=bw, beam_width=aw)
            y.append(ok.astype(float))
    X, y = np.concatenate(X), np.concatenate(y)
    return _fit_logistic(X, y, ridge)


#: Training scenes of the vertical-face score models: (seeds, water). Turbid water is included
#: because it changes what the crease candidate is worth (its edge washes out).
FACE_TRAINING = ((range(5000, 5048), "thesis"), (range(5000, 5024), "jerlov-1C"), (range(8000, 8048), "thesis", "varied"))


def calibrate_face_score(scenes=FACE_TRAINING, *, ridge: float = 1.0) -> dict:
    """Refit ``matching.match.FACE_SCORE_MODEL``, ``FACE_PLANE_SCORE_MODEL``, ``CREASE_SCORE_MODEL``, ``PLANE_SCORE_MODEL``, ``FOOT_SCORE_MODEL``, ``SEABED_SCORE_MODEL``.

    Runs the matcher on the random scenes ``scenes`` (seeds, water and optionally the generator,
    ``"random"`` or ``"varied"``; default sonar noise; :data:`FACE_TRAINING`) and labels, by the depth-map truth, the arc search's pixel of every
    match, the point below the crease and the point on the face's fitted plane where there are
    ones; fits a logistic regression of each on :func:`matching.match.face_score_features` (all
    matches), :func:`matching.match.face_plane_score_features` (the matches where the plane is
    offered), :func:`matching.match.crease_score_features` and
    :func:`matching.match.plane_score_features`, :func:`matching.match.foot_score_features` and
    :func:`matching.match.seabed_score_features` (each where its candidate exists; the features do not
    depend on which candidate the current models choose). Refit after ``ARC_SCORE_MODEL``. Use seeds disjoint from the evaluation's.

    Returns
    -------
    dict
        ``face``, ``face_plane``, ``crease``, ``plane``, ``foot`` and ``seabed``: each ``weights`` (intercept first),
        ``mean``, ``std``, ``n``, ``positive_rate``.
    """
    from ..matching import match, truth
    from ..matching.match import (crease_score_features, face_plane_score_features, face_score_features,
                                  foot_score_features, plane_score_features, seabed_score_features)

    featurise = dict(face=face_score_features, face_plane=face_plane_score_features, crease=crease_score_features,
                     plane=plane_score_features, foot=foot_score_features, seabed=seabed_score_features)
    X = {k: [] for k in featurise}
    y = {k: [] for k in featurise}
    for sd, water, gen in ((sd, e[1], e[2] if len(e) > 2 else "random") for e in scenes for sd in e[0]):
        s, o, rig = simulate_pair(_training_scene(sd, gen), water, "default", int(sd))
        m = match(s, o.image, rig, min_score=0.0)
        if not m:
            continue
        bw, aw = float(np.median(np.diff(s.ranges))), float(np.median(np.diff(s.azimuths)))
        f = m.features
        for key, prefix, c in (("face", "arc", np.ones(len(m), bool)),
                               ("face_plane", "arc", np.asarray(f["plane_offered"], bool)),
                               ("crease", "crease", np.asarray(f["crease_found"], bool)),
                               ("plane", "plane", np.asarray(f["plane_found"], bool)),
                               ("foot", "foot", np.asarray(f["foot_found"], bool)),
                               ("seabed", "seabed", np.asarray(f["seabed_found"], bool))):
            if c.any():
                ok = truth.correct(rig, o.depth, np.column_stack([f[f"{prefix}_u"], f[f"{prefix}_v"]])[c],
                                   m.ranges[c], m.azimuths[c], bin_width=bw, beam_width=aw)
                X[key].append(featurise[key](f)[c])
                y[key].append(ok.astype(float))
    return {k: _fit_logistic(np.concatenate(X[k]), np.concatenate(y[k]), ridge) for k in X if X[k]}


#: Training scenes of the candidate trees (:mod:`optiacoustic.matching.ranking`), thesis water (the trees choose
#: and score only in clear water, where the face-plane model is offered): the thesis-water scenes of
#: :data:`FACE_TRAINING` and (round i15w) 192 more random and 192 more varied ones, 480 in all. The trees
#: were data-bound: fitted on 24, 48, 72 and 96 of the first 96, held-out precision at recall 0.5 rose
#: 0.893, 0.906, 0.910, 0.911 (docs/matching.md, "More training scenes for the trees"). The seeds keep
#: clear of the evaluation's (random 0-19, 6000-6047; varied 9000-9047) and the tests' (varied 8100-8129,
#: 8300-8307; random 203-216).
RANK_TRAINING = ((range(5000, 5240), "thesis"), (range(8000, 8048), "thesis", "varied"),
                 (range(8400, 8592), "thesis", "varied"))
#: And random scenes on seabeds with relief (:func:`relief_scene`): seeds and RMS heights (m), 192 pairs.
RANK_RELIEF_TRAINING = (range(5000, 5064), (0.005, 0.01, 0.02))


def rank_training_data(scenes=RANK_TRAINING, relief=RANK_RELIEF_TRAINING) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The candidate trees' training rows: one per offered candidate of every match where the face-plane model is
    offered, from the matcher with the trees off (``MatchOptions(rank_model=False)``) on ``scenes`` (as
    :data:`FACE_TRAINING`: seeds, water, optional generator) and on ``relief`` (seeds and RMS heights:
    :func:`relief_scene`, thesis water; ``None``: none). Returns the rows ``X`` ``(M, len(RANK_FEATURES))``
    (``ranking.candidate_rows``), labels ``y`` ``(M,)`` (1: that candidate's pixel sees a point within a bin and
    a beam of the feature, by the depth map) and each row's scene index ``(M,)``."""
    from ..matching import MatchOptions, SeabedReliefWarning, match, truth
    from ..matching.ranking import CANDIDATES, available, candidate_rows

    import tempfile
    import warnings

    X, y, g = [], [], []
    opts = MatchOptions(rank_model=False)
    todo = [(sd, e[1], e[2] if len(e) > 2 else "random", 0.0) for e in scenes for sd in e[0]]
    if relief:
        todo += [(sd, "thesis", "relief", rms) for rms in relief[1] for sd in relief[0]]
    with tempfile.TemporaryDirectory(prefix="oas-rank-relief-") as tmp:
        for k, (sd, water, gen, rms) in enumerate(todo):
            sc = relief_scene(int(sd), rms, tmp) if gen == "relief" else _training_scene(sd, gen)
            s, o, rig = simulate_pair(sc, water, "default", int(sd))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SeabedReliefWarning)
                m = match(s, o.image, rig, min_score=0.0, options=opts)
            if not m:
                continue
            avail = available(m.features)
            if not avail.any():
                continue
            Xk, row, cand = candidate_rows(m.features, avail)
            bw, aw = float(np.median(np.diff(s.ranges))), float(np.median(np.diff(s.azimuths)))
            ok = np.zeros(len(row), bool)
            for j, c in enumerate(CANDIDATES):
                r = row[cand == j]
                if r.size:
                    px = np.column_stack([m.features[f"{c}_u"], m.features[f"{c}_v"]]).astype(float)[r]
                    ok[cand == j] = truth.correct(rig, o.depth, px, m.ranges[r], m.azimuths[r], bin_width=bw,
                                                  beam_width=aw)
            X.append(Xk)
            y.append(ok.astype(float))
            g.append(np.full(len(row), k))
    if not X:
        raise ValueError("rank_training_data: no match with the face-plane model offered in the training scenes")
    return np.concatenate(X), np.concatenate(y), np.concatenate(g)


def calibrate_rank_model(scenes=RANK_TRAINING) -> str:
    """Refit the candidate trees (``matching.ranking``, shipped as ``data/match_candidate_trees.txt.gz``): LightGBM on
    :func:`rank_training_data` of ``scenes`` with ``ranking.RANK_PARAMS``. Returns the model's text (write it with
    ``ranking.write_model``). Refit after the candidate models (their probabilities are inputs). Use seeds
    disjoint from the evaluation's."""
    from ..matching.ranking import fit_rank_model

    X, y, _ = rank_training_data(scenes)
    return fit_rank_model(X, y)


def calibrate_soft_beam(random_seeds=range(5000, 5024), varied_seeds=range(8000, 8024)) -> dict:
    """Refit ``matching.match.SOFT_BEAM_RECALIBRATION``: per candidate kind ``(a, b)`` of
    ``p' = sigmoid(a + b logit p)``.

    Simulates the realistic model's frames (:func:`realistic_sonar`) of random scenes ``random_seeds`` and
    varied scenes ``varied_seeds`` (thesis water for the camera), matches them with the seabed from the
    navigation (the true plane, from the sonar's pose) and the recalibration off, and labels every offered
    candidate (arc pixel, crease, plane, foot and seabed points) by the depth-map truth. Each kind's
    ``(a, b)`` is the logistic regression of its labels on the logit of its thesis-frame probability, the
    slope shrunk towards 1 (penalty ``(b - 1)^2``), scipy BFGS. Returns ``{kind: dict(a, b, n,
    positive_rate, mean_probability)}``. Use seeds disjoint from the evaluation's.
    """
    from scipy.optimize import minimize

    from ..matching import MatchOptions, SeabedPlane, match, truth
    from ..matching.match import CANDIDATES, logit
    from ..optical import Water

    opts = MatchOptions(soft_beam_recalibration=False)
    x = {k: [] for k in CANDIDATES}
    y = {k: [] for k in CANDIDATES}
    scenes = [random_scene(int(sd)) for sd in random_seeds] + [varied_scene(int(sd)) for sd in varied_seeds]
    seeds = list(random_seeds) + list(varied_seeds)
    for sc, sd in zip(scenes, seeds):
        sonar, optical, rig, pose = realistic_pair(sc, int(sd), Water.preset("thesis"))
        m = match(sonar, optical.image, rig, seabed=SeabedPlane.from_pose(pose), options=opts, min_score=0.0)
        if not m:
            continue
        f = m.features
        bw, aw = float(np.median(np.diff(sonar.ranges))), float(np.median(np.diff(sonar.azimuths)))
        for k in CANDIDATES:
            p = np.asarray(f[f"p_{k}"], float)
            px = np.column_stack([f[f"{k}_u"], f[f"{k}_v"]])
            c = (p > 0) & np.all(np.isfinite(px), axis=1)
            if c.any():
                x[k].append(logit(p[c]))
                y[k].append(truth.correct(rig, optical.depth, px[c], m.ranges[c], m.azimuths[c], bin_width=bw,
                                          beam_width=aw).astype(float))
    out = {}
    for k in CANDIDATES:
        if not x[k]:
            continue
        xk, yk = np.concatenate(x[k]), np.concatenate(y[k])

        def nll(w, xk=xk, yk=yk):
            z = w[0] + w[1] * xk
            return np.sum(np.logaddexp(0.0, z) - yk * z) + (w[1] - 1.0) ** 2

        w = minimize(nll, np.array([0.0, 1.0]), method="BFGS").x
        out[k] = dict(a=float(w[0]), b=float(w[1]), n=int(xk.size), positive_rate=float(yk.mean()),
                      mean_probability=float(np.mean(1.0 / (1.0 + np.exp(-xk)))))
    return out


def _fit_logistic(X, y, ridge):
    """Ridge-penalised logistic regression of labels ``y`` on standardised features ``X`` (scipy BFGS)."""
    from scipy.optimize import minimize

    mu, sd_ = X.mean(0), X.std(0)
    sd_ = np.where(sd_ > 0, sd_, 1.0)
    Z = np.column_stack([np.ones(len(X)), (X - mu) / sd_])

    def nll(w):
        z = Z @ w
        return np.sum(np.logaddexp(0, z) - y * z) + ridge * np.sum(w[1:] ** 2)

    w = minimize(nll, np.zeros(Z.shape[1]), method="BFGS").x
    return dict(weights=tuple(np.round(w, 3)), mean=tuple(np.round(mu, 4)), std=tuple(np.round(sd_, 4)), n=len(y),
                positive_rate=float(y.mean()))


def calibrate_two_view_score(seeds=range(5000, 5024), *, ridge: float = 1.0) -> dict:
    """Refit ``matching.match.TWO_VIEW_SCORE_MODEL``, ``SWEEP_SCORE_MODEL`` and ``CORRELATION_SCORE_MODEL``.

    Each random scene seeded ``seeds``, plain and textured (:func:`random_scene`), is matched with
    a second pair after the random vehicle motion :func:`vehicle_motion` of the same seed (thesis
    water, default sonar noise); every candidate of both kinds is labelled by the depth-map
    truth. Use seeds disjoint from the evaluation's. (These seeds are among the candidate trees'
    training scenes, where their one-view score is optimistic. Fitted on random 5240-5263 or 5240-5287,
    outside it, two views did no better: docs/matching.md, round i15w.)

    Returns
    -------
    dict
        ``arc``, ``sweep`` and ``correlation`` (logistic regressions): each ``weights``
        (intercept first), ``mean``, ``std``, ``n``, ``positive_rate``.
    """
    from ..matching import MatchOptions, match, truth
    from ..matching.match import (_elevation_intervals, correlation_score_features, sweep_score_features,
                                  two_view_candidates, two_view_score_features)

    XA, yA, XB, yB, XC, yC = [], [], [], [], [], []
    opt = MatchOptions()
    for sd in seeds:
        for textured in (False, True):
            sc = random_scene(int(sd), textured=textured)
            s, o, rig = simulate_pair(sc, "thesis", "default", int(sd))
            s2, o2, motion = moved_view(sc, vehicle_motion(int(sd)), int(sd))
            out = match(s, o.image, rig, min_score=0.0)
            sf = out.sonar_features
            if sf is None or len(sf) == 0:
                continue
            bw, aw = float(np.median(np.diff(s.ranges))), float(np.median(np.diff(s.azimuths)))
            intervals = _elevation_intervals(sf, np.asarray(s.image, float), s.ranges, s.azimuths, rig, opt)
            arc, sweep, corr = two_view_candidates(out, sf, intervals, o.image, (s2, o2.image), motion, rig, None,
                                                   opt)
            if len(out):
                XA.append(two_view_score_features(arc))
                yA.append(truth.correct(rig, o.depth, out.pixels, out.ranges, out.azimuths, bin_width=bw,
                                        beam_width=aw).astype(float))
            for cand, featurise, X_, y_ in ((sweep, sweep_score_features, XB, yB),
                                            (corr, correlation_score_features, XC, yC)):
                f = np.asarray(cand["found"], bool)
                if f.any():
                    X_.append(featurise({k: np.asarray(v)[f] for k, v in cand.items() if k != "pixels"}))
                    y_.append(truth.correct(rig, o.depth, cand["pixels"][f], sf.ranges[f], sf.azimuths[f],
                                            bin_width=bw, beam_width=aw).astype(float))
    return dict(arc=_fit_logistic(np.concatenate(XA), np.concatenate(yA), ridge),
                sweep=_fit_logistic(np.concatenate(XB), np.concatenate(yB), ridge),
                correlation=_fit_logistic(np.concatenate(XC), np.concatenate(yC), ridge))


#: Failure classes of :func:`failure_classes`, in the order they are tested (mutually exclusive).
FAILURE_CLASSES = ("correct", "right_candidate_loses", "borderline", "no_match", "truth_on_edge",
                   "truth_outside_interval", "truth_in_other_run", "truth_in_run_wrong_place")


def failure_classes(pairs, *, n_samples: int = 800, options=None) -> dict:
    """Why each sonar feature visible in both sensors is, or is not, matched correctly (evaluation only).

    For every pair ``(sonar, optical, rig)`` the one-view matcher runs as in :func:`evaluate_pair`;
    every sonar feature that :func:`matching.truth.visible` counts (the recall's denominator) is
    put in the first class of :data:`FAILURE_CLASSES` that applies, from the depth-map truth along
    its arc (``n_samples`` elevations across the aperture):

    - ``correct``: the chosen pixel is right;
    - ``right_candidate_loses``: one of its other candidates (the arc search's run pixel, the point
      below the crease, the point on the face's plane) is right, the score chose another;
    - ``borderline``: no candidate is right, but the chosen pixel's true point is within 1.5 bins and
      1.5 beams of the feature (the criterion's edge);
    - ``no_match``: the arc search found no edge-free run in the interval (no candidate at all);
    - ``truth_on_edge``: every correct arc pixel has a gradient at or above the arc threshold (an
      image edge: no edge-free run can contain it);
    - ``truth_outside_interval``: correct edge-free pixels exist, all outside the acoustic elevation
      interval (with the arc search's 0.25 deg margin);
    - ``truth_in_other_run``: correct edge-free pixels inside the interval, none in the chosen run
      (the run, i.e. the surface, is the wrong one);
    - ``truth_in_run_wrong_place``: correct pixels inside the chosen run, no candidate on them.

    Returns
    -------
    dict
        ``counts`` (class -> int), ``n_visible``, and per feature arrays ``cls`` (index into
        :data:`FAILURE_CLASSES`), ``range_error_bins`` (chosen pixel's true range minus the
        feature's; NaN where unmatched or open water), ``correct_band_deg`` (elevation extent of the
        correct arc samples), ``kind`` (onset 1 / peak 0).
    """
    from ..geometry.projection import camera_from_sonar, to_pixels, to_sonar
    from ..matching import MatchOptions, match, truth
    from ..matching.arc_search import gradient_image
    from ..matching.match import _elevation_intervals

    opt = options or MatchOptions()
    cls_all, rerr_all, band_all, kind_all = [], [], [], []
    for sonar, optical, rig in pairs:
        m = match(sonar, optical.image, rig, options=opt, min_score=0.0)
        sf = m.sonar_features
        if sf is None or len(sf) == 0:
            continue
        bw, aw = float(np.median(np.diff(sonar.ranges))), float(np.median(np.diff(sonar.azimuths)))
        vis = truth.visible(rig, optical.depth, sf.ranges, sf.azimuths, bin_width=bw, beam_width=aw)
        idx = np.nonzero(vis)[0]
        if idx.size == 0:
            continue
        r, th = sf.ranges[idx], sf.azimuths[idx]
        half = rig.fov_elevation / 2
        phis = np.linspace(-half, half, n_samples)
        P = camera_from_sonar(rig, r[:, None], th[:, None], phis[None, :])
        pp = to_pixels(rig, P)
        uv = np.where(pp.in_image[..., None], pp.pixels, 0.0)
        Pt = truth.pixel_points(rig, optical.depth, uv.reshape(-1, 2)).reshape(P.shape)
        sp = to_sonar(rig, np.where(np.isfinite(Pt), Pt, 0.0))
        good = pp.in_image & np.all(np.isfinite(Pt), -1) & sp.in_fan & \
            (np.abs(sp.ranges - r[:, None]) <= bw) & (np.abs(sp.azimuths - th[:, None]) <= aw)
        grad = gradient_image(optical.image)
        H, W = grad.shape
        ui = np.clip(np.rint(uv[..., 0]).astype(int), 0, W - 1)
        vi = np.clip(np.rint(uv[..., 1]).astype(int), 0, H - 1)
        edge_free = grad[vi, ui] < opt.arc_threshold
        lo, hi, _, _ = _elevation_intervals(sf, np.asarray(sonar.image, float), np.asarray(sonar.ranges, float),
                                            np.asarray(sonar.azimuths, float), rig, opt)
        margin = np.deg2rad(0.25)
        inside = (phis[None, :] >= lo[idx, None] - margin) & (phis[None, :] <= hi[idx, None] + margin)
        band = np.rad2deg(good.sum(axis=1) * (phis[1] - phis[0]))  # total elevation extent of the correct samples
        # The matcher's choice and its candidates for these features.
        pos = np.full(len(sf), -1)
        pos[m.sonar_index] = np.arange(len(m))
        j = pos[idx]
        cls = np.zeros(idx.size, int)
        rerr = np.full(idx.size, np.nan)
        f = m.features
        for k in range(idx.size):
            if j[k] < 0:
                cls[k] = FAILURE_CLASSES.index("no_match")
                continue
            jj = j[k]
            cands = [np.array([f[f"{nm}_u"][jj], f[f"{nm}_v"][jj]]) for nm in ("arc", "crease", "plane", "foot", "seabed")
                     if f"{nm}_u" in f]
            cands = [c for c in cands if np.all(np.isfinite(c))]
            ok_c = truth.correct(rig, optical.depth, np.array(cands), np.full(len(cands), r[k]),
                                 np.full(len(cands), th[k]), bin_width=bw, beam_width=aw) if cands else []
            Pc = truth.pixel_points(rig, optical.depth, m.pixels[jj:jj + 1])
            spc = to_sonar(rig, np.where(np.isfinite(Pc), Pc, 0.0))
            if np.all(np.isfinite(Pc)):
                rerr[k] = (spc.ranges[0] - r[k]) / bw
            chosen_ok = truth.correct(rig, optical.depth, m.pixels[jj:jj + 1], r[k:k + 1], th[k:k + 1],
                                      bin_width=bw, beam_width=aw)[0]
            near = np.all(np.isfinite(Pc)) and abs(spc.ranges[0] - r[k]) <= 1.5 * bw and \
                abs(spc.azimuths[0] - th[k]) <= 1.5 * aw
            # The chosen run's elevation extent: the edge-free stretch around the arc search's elevation.

            run = _run_around(edge_free[k] & inside[k], phis, f, jj, rig, r[k], th[k])
            if chosen_ok:
                cls[k] = 0
            elif np.any(ok_c):
                cls[k] = 1
            elif near:
                cls[k] = 2
            elif not np.any(good[k] & edge_free[k]):
                cls[k] = 4
            elif not np.any(good[k] & edge_free[k] & inside[k]):
                cls[k] = 5
            elif not np.any(good[k] & run):
                cls[k] = 6
            else:
                cls[k] = 7

        cls_all.append(cls)
        rerr_all.append(rerr)
        band_all.append(band)
        kind_all.append(sf.kind[idx])
    cls = np.concatenate(cls_all) if cls_all else np.zeros(0, int)
    return dict(counts={c: int(np.sum(cls == i)) for i, c in enumerate(FAILURE_CLASSES)}, n_visible=int(cls.size),
                cls=cls, range_error_bins=np.concatenate(rerr_all) if rerr_all else np.zeros(0),
                correct_band_deg=np.concatenate(band_all) if band_all else np.zeros(0),
                kind=np.concatenate(kind_all) if kind_all else np.zeros(0, int))


def _run_around(flat, phis, feats, j, rig, r, th):
    """The edge-free run (bool over ``phis``) that contains the arc search's elevation for match ``j``."""
    from ..geometry.projection import camera_from_sonar, to_pixels

    # The arc search's pixel is on the arc: its elevation is the sample nearest to it in the image.
    P = camera_from_sonar(rig, r, th, phis)
    uv = to_pixels(rig, P).pixels
    d = np.linalg.norm(np.nan_to_num(uv, nan=1e9) - np.array([feats["arc_u"][j], feats["arc_v"][j]]), axis=-1)
    i0 = int(np.argmin(d))
    out = np.zeros(phis.size, bool)
    if not flat[i0]:
        return out
    a = i0
    while a > 0 and flat[a - 1]:
        a -= 1
    b = i0
    while b < phis.size - 1 and flat[b + 1]:
        b += 1
    out[a:b + 1] = True
    return out

