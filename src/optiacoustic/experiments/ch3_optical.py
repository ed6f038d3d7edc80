"""Chapter 3: the underwater optical image simulator (thesis sec. 3.4, Figs. 3.7-3.8).

Renders scene 1 from the thesis's camera (0.25 m left of the sonar at (0, -6, 2), both
aimed at the origin) stage by stage: clear scene, attenuation, forward scatter and
backscatter; the same scene closer up in Jerlov II water where forward scatter shows; the
synchronised sonar + camera pair of the rig; and the contrast of a white target against
the veil as a function of range in four waters.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from . import ExperimentResult
from .._atomic import ensure_dir, savefig

NAME = "optical"
TITLE = "Underwater optical image simulator (Jaffe-McGlamery)"
CHAPTER = 3
SUMMARY = ("Renders thesis scene 1 through water stage by stage (clear, attenuated, forward scatter, backscatter) "
           "and the rig's synchronised sonar + camera pair; measures render time and contrast against range.")

THESIS_SONAR_EYE = (0.0, -6.0, 2.0)


def thesis_rig():
    """The thesis's rig (examples/rig_thesis.yaml): BlueView P900-90 at (0, -6, 2) and the
    600 x 400 / 50 mm camera 0.25 m to its left, both aimed at the origin, camera level."""
    from ..camera import PinholeCamera
    from ..frames import Pose
    from ..rig import Rig
    from ..sonar import SonarSpec

    sonar_pose = Pose.look_at(THESIS_SONAR_EYE, (0.0, 0.0, 0.0), body="sonar")
    camera_pose = Pose.look_at((-0.25, -6.0, 2.0), (0.0, 0.0, 0.0), body="camera")
    return Rig.from_poses(sonar_pose, camera_pose, PinholeCamera.from_sensor(), SonarSpec.preset("blueview-p900-90"))


def _contrast_sweep(waters, ranges, res=(160, 120)):
    """Michelson contrast of a white sphere (constant angular size) against open water."""
    from ..camera import PinholeCamera
    from ..frames import Pose
    from ..optical import simulate_optical
    from ..scene import Body, Material, Scene, Sphere

    cam = PinholeCamera.from_sensor(*res)
    pose = Pose.look_at((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), body="camera")
    lum_w = np.array([0.2126, 0.7152, 0.0722])
    table = np.zeros((len(waters), len(ranges)))
    for j, R in enumerate(ranges):
        scene = Scene([Body("target", Sphere(radius=0.08 * R), Pose.from_euler_deg((0.0, R, 0.0)),
                            Material(color=(0.9, 0.9, 0.9)))], name="target")
        for i, w in enumerate(waters):
            f = simulate_optical(scene, cam, pose, water=w)
            lum = f.image @ lum_w
            obj = lum[f.body == 0].mean()
            bg = lum[f.body < 0].mean()
            table[i, j] = (obj - bg) / (obj + bg)
    return table


def run(out_dir, *, quick: bool = False, seed: int = 0) -> ExperimentResult:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .. import scenes
    from ..frames import Pose
    from ..optical import Water, simulate_optical
    from ..optical.figures import save_ground_truth_figure, save_stage_figures
    from ..raycast import caster_for
    from ..simulation import simulate_rig
    from ..simulation.figures import save_pair_figure

    out = Path(out_dir)
    ensure_dir(out)
    scene = scenes.get("thesis_scene1")
    rig = thesis_rig()
    sonar_pose = Pose.look_at(THESIS_SONAR_EYE, (0.0, 0.0, 0.0), body="sonar")
    cam_pose = rig.camera_pose(sonar_pose)
    camera = rig.camera
    water = Water.preset("thesis")
    figures, numbers, tables = [], {}, []

    # ---- the stage figures of the thesis (Figs. 3.7-3.8), and the render time
    frame = simulate_optical(scene, camera, cam_pose, water=water)  # warm-up: builds the ray caster
    reps = 2 if quick else 7
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        frame = simulate_optical(scene, camera, cam_pose, water=water)
        times.append(time.perf_counter() - t0)
    caster = caster_for(scene)
    d_world = cam_pose.directions_to_world(camera.pixel_rays()).reshape(-1, 3)
    cast_times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        caster.cast(cam_pose.t, d_world)
        cast_times.append(time.perf_counter() - t0)
    render_ms = 1e3 * float(np.median(times))
    cast_ms = 1e3 * float(np.median(cast_times))
    numbers.update(render_ms=render_ms, bare_cast_ms=cast_ms, render_over_cast=render_ms / cast_ms,
                   thesis_render_s=180.0, image_size=[camera.width, camera.height], backscatter_slices=32)
    figures += save_stage_figures(frame, out, prefix="optical_thesis",
                                  title="Thesis scene 1 in the thesis's water, c = (0.41, 0.066, 0.018) /m")
    p = save_ground_truth_figure(frame, out / "optical_ground_truth.png")
    figures.append((p, "Ground truth of the camera frame: range along each pixel's ray and the body it sees."))

    lit = np.all(frame.clear > 0, axis=-1)
    tr = (frame.attenuated[lit] / frame.clear[lit]).mean(0)
    numbers["mean_transmittance_rgb"] = tr.tolist()
    numbers["veil_share_of_image"] = float(frame.backscatter.sum() / frame.image.sum())
    numbers["forward_scatter_share_of_image"] = float((frame.forward_scatter - frame.attenuated).sum() / frame.image.sum())
    numbers["mean_rgb"] = {s: np.asarray(frame.stage(s)).reshape(-1, 3).mean(0).tolist()
                           for s in ("clear", "attenuated", "forward_scatter", "image")}

    # ---- closer, in Jerlov II water: forward scatter becomes visible
    near_pose = Pose.look_at((-0.25, -3.5, 1.4), (0.0, 0.3, 0.3), body="camera")
    near = simulate_optical(scene, camera, near_pose, water="jerlov-II")
    figures += save_stage_figures(near, out, prefix="optical_jerlov2", individual=False,
                                  title="Scene 1 from 3.5 m in Jerlov II water (b = 0.2 /m): forward scatter blurs")
    numbers["jerlov2_forward_scatter_share"] = float((near.forward_scatter - near.attenuated).sum() / near.image.sum())

    # ---- the rig's synchronised sonar + camera pair
    pair = simulate_rig(scene, rig, sonar_pose, water=water, seed=seed)
    p = save_pair_figure(pair.sonar, pair.optical, out / "rig_pair.png",
                         title="Rig: BlueView P900-90 + camera 0.25 m to its left, both aimed at the origin")
    figures.append((p, "The synchronised pair of the thesis rig: sonar fan image (left, with noise and reverberation) "
                       "and camera image (right, thesis water, sensor noise) of scene 1."))
    numbers["rig"] = {"baseline_m": rig.baseline, "vergence_deg": float(np.rad2deg(rig.vergence)),
                      "camera_position": pair.optical.pose.t.tolist()}

    # ---- contrast against range
    wnames = ["thesis", "jerlov-IB", "jerlov-II", "jerlov-1C"]
    ranges = [1.0, 2.0, 4.0, 8.0] if quick else [0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0]
    table = _contrast_sweep([Water.preset(n) for n in wnames], ranges)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for n, row in zip(wnames, table):
        ax.plot(ranges, row, "o-", label=n)
    ax.set_xscale("log")
    ax.set_xlabel("range to the target (m)")
    ax.set_ylabel("Michelson contrast vs the veil")
    ax.set_title("White target (constant angular size), lamp beside the camera")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    p = out / "optical_contrast_vs_range.png"
    savefig(fig, p, dpi=90)
    plt.close(fig)
    figures.append((p, "Contrast of a white target against the veil falls with range, faster in more turbid water "
                       "(Jerlov 1C: gone by a few metres)."))
    numbers["contrast_vs_range"] = {"ranges_m": ranges, **{n: row.tolist() for n, row in zip(wnames, table)}}
    tables.append(("Contrast of a white target vs range", ["water"] + [f"{r:g} m" for r in ranges],
                   [[n] + [f"{v:.3f}" for v in row] for n, row in zip(wnames, table)]))
    tables.append(("Render time, 600 x 400, one light, 32 slices", ["quantity", "value"],
                   [["render (ms, median)", f"{render_ms:.0f}"], ["bare cast of the same rays (ms)", f"{cast_ms:.0f}"],
                    ["ratio", f"{render_ms / cast_ms:.1f}"], ["thesis (MATLAB, s)", "180"]]))
    summary = (f"Thesis scene 1 renders in {render_ms:.0f} ms at 600 x 400 with 32 backscatter slices "
               f"({render_ms / cast_ms:.1f}x a bare ray cast; the thesis took 3 min); in the thesis water red keeps "
               f"{100 * tr[0]:.0f} % and blue {100 * tr[2]:.0f} % of its light and the veil is "
               f"{100 * numbers['veil_share_of_image']:.0f} % of the image.")
    return ExperimentResult(NAME, figures=figures, numbers=numbers, summary=summary, tables=tables)
