"""Chapter 4: opti-acoustic epipolar geometry on the rendered scene-1 pair (thesis Figs. 4.3-4.5)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import ExperimentResult
from .._atomic import ensure_dir, savefig

NAME = "epipolar"
TITLE = "Opti-acoustic epipolar geometry (scene 1, BlueView P900-90 + 50 mm camera)"
CHAPTER = 4
SUMMARY = ("Sonar features (leading edges) map to conics in the optical image, hyperbolas for the thesis's "
           "nearly parallel rig and ellipses at large vergence; optical features map to curves r(theta) in "
           "the sonar image that all start at the epipole; true matches lie on their curves.")

SONAR_EYE = (0.0, -6.0, 2.0)
CAMERA_EYE = (-0.25, -6.0, 2.0)
TARGET = (0.0, 0.0, 0.0)
#: The large-vergence camera: 75 deg around the scene from the sonar, 6 m out, 2 m up.
SIDE_ANGLE_DEG = 75.0


def _side_eye():
    a = np.deg2rad(-90.0 + SIDE_ANGLE_DEG)
    return (6.0 * np.cos(a), 6.0 * np.sin(a), 2.0)


def _sonar_features(frame, rig, optical):
    """Leading edge of every object: the nearest echoing ray hit per body (from the scan's truth).

    Returns the 3D points (camera frame), their exact sonar measurements and the marked ones
    (the centre of the cell the echo falls in), keeping those the camera sees unoccluded.
    """
    from ..geometry import projection as pr

    spec, rays = frame.spec, frame.rays
    feats = []
    for bid, name in enumerate(frame.body_names):
        if name == "seabed":
            continue
        hit = (rays.body == bid) & np.isfinite(rays.range)
        if not hit.any():
            continue
        k = np.argmin(np.where(hit, rays.range, np.inf))
        i, j = np.unravel_index(k, rays.range.shape)
        r, th, ph = float(rays.range[i, j]), float(spec.azimuths[rays.beam_index[i, j]]), float(rays.elevation[i, j])
        p_s = r * np.array([np.cos(ph) * np.sin(th), np.cos(ph) * np.cos(th), np.sin(ph)])
        p_c = rig.camera_from_sonar(p_s)
        pix = pr.to_pixels(rig, p_c)
        if not pix.in_image:
            continue
        u, v = np.round(pix.pixels).astype(int)
        if abs(optical.depth[v, u] - np.linalg.norm(p_c)) > 0.05:  # occluded for the camera
            continue
        b = int(np.clip(np.floor(spec.bin_index(r)), 0, spec.n_bins - 1))
        feats.append(dict(name=name, point=p_c, range=r, azimuth=th, elevation=ph, pixel=pix.pixels,
                          marked_range=float(spec.ranges[b]), marked_azimuth=th))
    return feats


def _optical_features(optical, rig):
    """One point per object: the visible pixel nearest the centre of the object's part inside the fan.

    Its 3D point comes from the rendered depth (the ground truth), so the true sonar match is exact.
    """
    from ..geometry import projection as pr

    cam = optical.camera
    feats = []
    rays = cam.pixel_rays()
    for bid, name in enumerate(optical.body_names):
        if name == "seabed":
            continue
        vv, uu = np.nonzero(optical.body == bid)
        if vv.size < 20:
            continue
        pts = rays[vv, uu] * optical.depth[vv, uu][:, None]
        son = pr.to_sonar(rig, pts)
        ok = son.in_fan
        if ok.sum() < 20:
            continue
        uv = np.stack([uu, vv], -1)[ok].astype(float)
        k = np.argmin(np.linalg.norm(uv - uv.mean(0), axis=-1))
        idx = np.nonzero(ok)[0][k]
        feats.append(dict(name=name, point=pts[idx], pixel=uv[k], range=float(son.ranges[idx]),
                          azimuth=float(son.azimuths[idx]), elevation=float(son.elevations[idx])))
    return feats


def _polyline_distance(point, lines):
    best = np.inf
    for line in lines:
        a, b = line[:-1], line[1:]
        ab = b - a
        s = np.clip(np.einsum("ij,ij->i", point - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
        best = min(best, float(np.min(np.linalg.norm(a + s[:, None] * ab - point, axis=-1))))
    return best


def _full_conic(rig, r, th, n=721):
    """Both half-planes of the conic, every elevation, in front of the camera (the dashed context)."""
    from ..geometry import epipolar as ep

    out = []
    for az in (th, th + np.pi):
        out += ep.sonar_to_optical_curves(rig, r, az, n_samples=n, clip_elevation=False)[0]
    return out


def _algebraic_conic(rig, r, th, n=4001):
    """Every point of the conic: the whole circle (sphere x azimuth plane, both half-planes)
    projected through the pinhole, points behind the camera included; split where Z changes sign."""
    psi = np.linspace(0.0, 2 * np.pi, n)
    e = np.array([np.sin(th), np.cos(th), 0.0])
    p_s = r * (np.cos(psi)[:, None] * e + np.sin(psi)[:, None] * np.array([0.0, 0.0, 1.0]))
    p_o = (p_s - rig.t) @ rig.R
    cam = rig.camera
    z = p_o[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([cam.fx * p_o[:, 0] / z + cam.cx, cam.fy * p_o[:, 1] / z + cam.cy], -1)
    cut = np.nonzero(np.sign(z[:-1]) != np.sign(z[1:]))[0] + 1
    return [seg for seg in np.split(uv, cut) if len(seg) > 1]


def _show_optical(ax, optical, title):
    from ..optical import to_srgb8

    img = to_srgb8(optical.image)
    ax.imshow(img, extent=(-0.5, img.shape[1] - 0.5, img.shape[0] - 0.5, -0.5))
    ax.set_xlim(-0.5, img.shape[1] - 0.5)
    ax.set_ylim(img.shape[0] - 0.5, -0.5)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")


def _show_fan(ax, frame, title, crop):
    from ..sonar import to_display

    fan = frame.fan("image", width=900)
    img = np.where(fan.mask, to_display(fan.data), np.nan)
    ax.imshow(img, extent=fan.extent, cmap="copper", origin="upper", vmin=0, vmax=1)
    ax.set_facecolor("black")
    ax.set_xlim(*crop[:2])
    ax.set_ylim(*crop[2:])
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x_s (m)")
    ax.set_ylabel("y_s (m)")


COLORS = ["#e6194b", "#3cb44b", "#ffe119", "#4363d8", "#f58231", "#911eb4", "#46f0f0", "#f032e6", "#bcf60c"]


def run(out_dir, *, quick: bool = False, seed: int = 0) -> ExperimentResult:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .. import scenes
    from ..camera import PinholeCamera
    from ..frames import Pose, fan_from_polar
    from ..geometry import epipolar as ep
    from ..geometry import projection as pr
    from ..optical import simulate_optical
    from ..rig import Rig
    from ..sonar import SonarSpec, simulate_sonar

    out = Path(out_dir)
    ensure_dir(out)
    scene = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    camera = PinholeCamera.from_sensor(600, 400, (36, 24), 50)
    sonar_pose = Pose.look_at(SONAR_EYE, TARGET)
    camera_pose = Pose.look_at(CAMERA_EYE, TARGET, body="camera")
    rig = Rig.from_poses(sonar_pose, camera_pose, camera, spec)
    frame = simulate_sonar(scene, spec, sonar_pose, seed=seed)
    optical = simulate_optical(scene, camera, camera_pose, seed=seed)
    numbers: dict = {"rig": {"R": rig.R, "t": rig.t, "vergence_deg": np.rad2deg(rig.vergence),
                             "baseline_m": rig.baseline}}
    figures, tables = [], []

    # ---------------------------------------------------------------- sonar -> optical (Fig. 4.4)
    sf = _sonar_features(frame, rig, optical)
    r_m = np.array([f["marked_range"] for f in sf])
    th_m = np.array([f["marked_azimuth"] for f in sf])
    r_x = np.array([f["range"] for f in sf])
    th_x = np.array([f["azimuth"] for f in sf])
    true_pix = np.array([f["pixel"] for f in sf])
    C_marked = ep.conic(rig, r_m, th_m)
    C_exact = ep.conic(rig, r_x, th_x)
    types = ep.conic_type(C_marked)
    curves = ep.sonar_to_optical_curves(rig, r_m, th_m)
    curves_exact = ep.sonar_to_optical_curves(rig, r_x, th_x)
    rows = []
    for k, f in enumerate(sf):
        f["type"] = str(types[k])
        f["sampson_exact_px"] = float(ep.sampson_distance(C_exact[k], f["pixel"]))
        f["curve_exact_px"] = _polyline_distance(f["pixel"], curves_exact[k])
        f["sampson_marked_px"] = float(ep.sampson_distance(C_marked[k], f["pixel"]))
        f["curve_marked_px"] = _polyline_distance(f["pixel"], curves[k])
        rows.append([k + 1, f["name"], f"{f['marked_range']:.3f}", f"{np.rad2deg(th_m[k]):.2f}",
                     f"{np.rad2deg(f['elevation']):.2f}", f["type"], f"{f['sampson_exact_px']:.1e}",
                     f"{f['curve_marked_px']:.2f}"])
    tables.append(("Sonar features (leading edges) and their epipolar conics in the optical image",
                   ["#", "object", "r (m)", "theta (deg)", "true phi (deg)", "conic", "true match: Sampson (px), exact (r, theta)",
                    "true match to curve of the marked cell (px)"], rows))
    numbers["sonar_features"] = [{k: v for k, v in f.items() if k not in ("point",)} for f in sf]

    fig, axs = plt.subplots(1, 2, figsize=(13, 4.6))
    _show_fan(axs[0], frame, "(a) sonar features: leading edges (fan image)", (-3.5, 3.5, 3.0, 9.5))
    for k, f in enumerate(sf):
        xs, ys = fan_from_polar(f["marked_range"], f["marked_azimuth"])
        axs[0].plot(xs, ys, "o", mfc="none", mec=COLORS[k % 9], ms=9, mew=1.6)
        axs[0].annotate(str(k + 1), (xs, ys), xytext=(6, 4), textcoords="offset points", color=COLORS[k % 9], fontsize=9)
    _show_optical(axs[1], optical, "(b) epipolar conics in the optical image (solid: +-10 deg aperture)")
    for k, f in enumerate(sf):
        for line in _full_conic(rig, f["marked_range"], f["marked_azimuth"]):
            axs[1].plot(line[:, 0], line[:, 1], "--", color=COLORS[k % 9], lw=0.6, alpha=0.7)
        for line in curves[k]:
            axs[1].plot(line[:, 0], line[:, 1], "-", color=COLORS[k % 9], lw=1.8)
        axs[1].plot(*f["pixel"], "+", color="white", ms=11, mew=1.5)
        axs[1].annotate(str(k + 1), f["pixel"], xytext=(5, -8), textcoords="offset points", color=COLORS[k % 9], fontsize=9)
    fig.tight_layout()
    p = out / "epipolar_sonar_to_optical.png"
    savefig(fig, p, dpi=110)
    plt.close(fig)
    figures.append((p, "Fig. 4.4: (a) leading edges of the objects marked in the sonar fan image; (b) their epipolar "
                       "conics in the optical image: solid, the arc the sonar's +-10 deg elevation aperture allows; dashed, "
                       "the rest of the conic (other elevations and the spurious azimuth + 180 deg half-plane); white "
                       "crosses, the true matches."))

    # ---------------------------------------------------------------- optical -> sonar (Fig. 4.5)
    of = _optical_features(optical, rig)
    pix_o = np.array([f["pixel"] for f in of])
    oc_clip = ep.optical_to_sonar_curves(rig, pix_o, coords="fan")
    oc_full = ep.optical_to_sonar_curves(rig, pix_o, coords="fan", clip_elevation=False, clip_to_fan=False,
                                         max_range=spec.range_max)
    epi = ep.epipole(rig)
    rows = []
    for k, f in enumerate(of):
        r_curve = float(ep.sonar_range(rig, f["pixel"], f["azimuth"]))
        f["range_error_m"] = abs(r_curve - f["range"])
        xs, ys = fan_from_polar(f["range"], f["azimuth"])
        f["fan_distance_m"] = _polyline_distance(np.array([xs, ys]), oc_clip[k]) if oc_clip[k] else float("nan")
        rows.append([k + 1, f["name"], f"({f['pixel'][0]:.0f}, {f['pixel'][1]:.0f})", f"{f['range']:.3f}",
                     f"{np.rad2deg(f['azimuth']):.2f}", f"{np.rad2deg(f['elevation']):.2f}", f"{f['range_error_m']:.1e}",
                     f"{f['fan_distance_m']:.1e}"])
    tables.append(("Optical features (a visible point of each object, inside the fan) and their curves in the sonar image",
                   ["#", "object", "pixel", "true r (m)", "true theta (deg)", "true phi (deg)",
                    "|r(theta) - r| (m)", "true match to sampled curve (m)"], rows))
    numbers["optical_features"] = [{k: v for k, v in f.items() if k not in ("point",)} for f in of]
    numbers["epipole"] = {"range_m": epi.range, "azimuth_deg": np.rad2deg(epi.azimuth), "x_s": epi.x_s,
                          "y_s": epi.y_s, "in_fan": epi.in_fan}

    fig, axs = plt.subplots(1, 2, figsize=(13, 4.6))
    _show_optical(axs[0], optical, "(a) optical features: a visible point on each object")
    for k, f in enumerate(of):
        axs[0].plot(*f["pixel"], "o", mfc="none", mec=COLORS[k % 9], ms=9, mew=1.6)
        axs[0].annotate(str(k + 1), f["pixel"], xytext=(6, 4), textcoords="offset points", color=COLORS[k % 9], fontsize=9)
    _show_fan(axs[1], frame, "(b) curves r(theta) in the sonar image (solid: +-10 deg aperture)", (-3.0, 3.5, -0.3, 9.5))
    for k, f in enumerate(of):
        for line in oc_full[k]:
            axs[1].plot(line[:, 0], line[:, 1], "--", color=COLORS[k % 9], lw=0.7)
        for line in oc_clip[k]:
            axs[1].plot(line[:, 0], line[:, 1], "-", color=COLORS[k % 9], lw=2.0)
        xs, ys = fan_from_polar(f["range"], f["azimuth"])
        axs[1].plot(xs, ys, "+", color="white", ms=11, mew=1.5)
        axs[1].annotate(str(k + 1), (xs, ys), xytext=(5, -9), textcoords="offset points", color=COLORS[k % 9], fontsize=9)
    axs[1].plot(epi.x_s, epi.y_s, "*", color="cyan", ms=12)
    axs[1].annotate("epipole (camera centre)", (epi.x_s, epi.y_s), xytext=(8, 6), textcoords="offset points",
                    color="cyan", fontsize=8)
    fig.tight_layout()
    p = out / "epipolar_optical_to_sonar.png"
    savefig(fig, p, dpi=110)
    plt.close(fig)
    figures.append((p, "Fig. 4.5: (a) optical features; (b) their curves r(theta) in the sonar fan image: solid where the "
                       "point would lie inside the +-10 deg elevation aperture and the fan, dashed beyond; every curve starts "
                       "at the epipole, the camera centre 0.25 m to the sonar's left; white crosses, the true matches."))

    # ---------------------------------------------------------------- large vergence (Fig. 4.3b)
    side_pose = Pose.look_at(_side_eye(), TARGET, body="camera")
    side = Rig.from_poses(sonar_pose, side_pose, camera, spec)
    side_opt = simulate_optical(scene, camera, side_pose, seed=seed)
    P_world = camera_pose.to_world(np.array([f["point"] for f in sf]))
    P_side = side_pose.to_body(P_world)
    ps = pr.project(side, P_side)
    C_side = ep.conic(side, ps.ranges, ps.azimuths)
    types_side = ep.conic_type(C_side)
    curves_side = ep.sonar_to_optical_curves(side, ps.ranges, ps.azimuths)
    fig, axs = plt.subplots(2, 2, figsize=(13, 9.2))
    _show_optical(axs[0, 0], optical, f"(a) thesis rig, vergence {np.rad2deg(rig.vergence):.1f} deg")
    _show_optical(axs[0, 1], side_opt, f"(b) side camera, vergence {np.rad2deg(side.vergence):.1f} deg")
    panels = ((0, rig, r_x, th_x, curves_exact, true_pix, types), (1, side, ps.ranges, ps.azimuths, curves_side, ps.pixels,
                                                                   types_side))
    for col, rg, rr, tt, cv, px, ty in panels:
        ax, big = axs[0, col], axs[1, col]
        for k in range(len(rr)):
            for line in _full_conic(rg, rr[k], tt[k]):
                ax.plot(line[:, 0], line[:, 1], "--", color=COLORS[k % 9], lw=0.8)
            for line in _algebraic_conic(rg, rr[k], tt[k]):
                big.plot(line[:, 0], line[:, 1], "-", color=COLORS[k % 9], lw=1.0)
            for line in cv[k]:
                ax.plot(line[:, 0], line[:, 1], "-", color=COLORS[k % 9], lw=2.0)
                big.plot(line[:, 0], line[:, 1], "-", color=COLORS[k % 9], lw=3.0)
            if np.all(np.isfinite(px[k])):
                ax.plot(*px[k], "+", color="white", ms=10, mew=1.4)
        w, h = camera.width, camera.height
        big.plot([-0.5, w - 0.5, w - 0.5, -0.5, -0.5], [-0.5, -0.5, h - 0.5, h - 0.5, -0.5], "k-", lw=1.2)
        if col == 0:  # hyperbolas run off to infinity: show a window around the image
            lim = (-2.5 * w, 3.5 * w, 4.5 * h, -3.5 * h)
        else:  # ellipses are closed: show them whole
            allp = np.concatenate([seg for k in range(len(rr)) for seg in _algebraic_conic(rg, rr[k], tt[k])])
            lo, hi = allp.min(0), allp.max(0)
            pad = 0.05 * (hi - lo)
            lim = (lo[0] - pad[0], hi[0] + pad[0], hi[1] + pad[1], lo[1] - pad[1])
        big.set_xlim(*lim[:2])
        big.set_ylim(*lim[2:])
        big.set_aspect("equal")
        big.set_title(f"({'c' if col == 0 else 'd'}) the whole conics on the image plane (black: the image): "
                      f"{', '.join(sorted(set(map(str, ty))))}", fontsize=9)
        big.set_xlabel("u (px)")
        big.set_ylabel("v (px)")
    fig.tight_layout()
    p = out / "epipolar_vergence.png"
    savefig(fig, p, dpi=110)
    plt.close(fig)
    figures.append((p, "Fig. 4.3: the same sonar features' conics for (a) the nearly parallel thesis rig and "
                       f"(b) a camera {SIDE_ANGLE_DEG:.0f} deg around the scene (vergence {np.rad2deg(side.vergence):.0f} deg); "
                       "thick: the +-10 deg aperture; dashed: the rest of the conic in the image. (c), (d): the whole "
                       "conics on the image plane (points behind the camera included): hyperbolas for (a), ellipses for (b)."))

    d_exact = [f["sampson_exact_px"] for f in sf]
    d_mark = [f["curve_marked_px"] for f in sf]
    r_err = [f["range_error_m"] for f in of]
    numbers.update({
        "conic_types_thesis_rig": [str(t) for t in types],
        "conic_types_side_rig": [str(t) for t in types_side],
        "side_rig": {"vergence_deg": np.rad2deg(side.vergence), "baseline_m": side.baseline},
        "max_sampson_exact_px": max(d_exact) if d_exact else float("nan"),
        "max_curve_distance_marked_px": max(d_mark) if d_mark else float("nan"),
        "max_range_error_optical_m": max(r_err) if r_err else float("nan"),
        "n_sonar_features": len(sf),
        "n_optical_features": len(of),
    })
    tables.append(("Conic types of the sonar features (thesis eq. 4.15, Table 4.1)",
                   ["#", "object", f"thesis rig ({np.rad2deg(rig.vergence):.1f} deg)",
                    f"side camera ({np.rad2deg(side.vergence):.1f} deg)"],
                   [[k + 1, f["name"], str(types[k]), str(types_side[k])] for k, f in enumerate(sf)]))
    summary = (f"{len(sf)} sonar leading edges give {', '.join(sorted(set(map(str, types))))} conics for the thesis rig "
               f"(vergence {np.rad2deg(rig.vergence):.1f} deg) and {', '.join(sorted(set(map(str, types_side))))} at "
               f"{np.rad2deg(side.vergence):.0f} deg; true matches lie within {max(d_exact):.1e} px of the exact conics "
               f"and {max(d_mark):.2f} px of those of the marked (bin-quantised) cells; {len(of)} optical features' "
               f"curves r(theta) pass within {max(r_err):.1e} m of their true sonar matches.")
    return ExperimentResult(NAME, figures, numbers, summary, tables)
