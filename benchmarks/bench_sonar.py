"""Sonar frame time against a bare two-thread Embree cast of the thesis's 512 x 750 rays."""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from _timing import median_ms

TITLE = "Sonar simulator (thesis scene 1, BlueView P900-90)"
DESCRIPTION = (
    "Reference: a bare two-thread Embree closest-hit query of 512 beams x 750 elevation rays "
    "(the thesis's 512 x 750 scan) against the same scene from the same pose, with no "
    "post-processing. A full frame is every stage: scan (128 rays per beam by default, plus "
    "edge sub-rays), footprint integration, decimation, seabed/target split, noise and "
    "reverberation, and the fan image (cv2.remap). Ground truth is computed on first access; "
    "its cost is listed separately. The thesis took 3.5 min per frame in MATLAB."
)


def run() -> list[dict]:
    from optiacoustic import Pose, SonarSpec, scenes, simulate_sonar
    from optiacoustic.raycast import caster_for
    from optiacoustic.sonar.formation import _ray_grid

    scene = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    pose = Pose.look_at(scene.view.eye, scene.view.target)
    t0 = time.perf_counter()
    caster = caster_for(scene)
    bvh_ms = 1e3 * (time.perf_counter() - t0)

    thesis_spec = dataclasses.replace(spec, elevation_samples=750)
    d, _ = _ray_grid(thesis_spec)
    d32 = np.ascontiguousarray(d @ pose.R.T, np.float32)
    o32 = np.ascontiguousarray(np.broadcast_to(pose.t, d32.shape), np.float32)
    bare = median_ms(lambda: caster.bare_intersect(o32, d32))

    seeds = iter(range(10_000))
    frame_ms = median_ms(lambda: simulate_sonar(scene, spec, pose, seed=next(seeds)).fan("image"))
    clean_ms = median_ms(lambda: simulate_sonar(scene, spec, pose, noise=False))

    def with_truth():
        f = simulate_sonar(scene, spec, pose, seed=1)
        f.ground_truth.body, f.ground_truth.shadow

    truth_ms = median_ms(with_truth, repeat=7)
    thesis_ms = median_ms(lambda: simulate_sonar(scene, thesis_spec, pose, seed=1).fan("image"), repeat=7)
    a = simulate_sonar(scene, spec, pose, noise=False).intensity.astype(float)
    b = simulate_sonar(scene, thesis_spec, pose, noise=False).intensity.astype(float)
    l1 = float(np.abs(a - b).sum() / b.sum())
    rows = [
        dict(name="bare Embree cast, 512 x 750 rays, 2 threads", value=bare, unit="ms", reference="itself", ratio=1.0,
             note=f"{512 * 750 / bare / 1e3:.1f} M rays/s"),
        dict(name="full sonar frame (noise on, fan image)", value=frame_ms, unit="ms", reference="bare cast", ratio=frame_ms / bare,
             note=f"{1e3 / frame_ms:.0f} Hz; requirement: ratio <= 2.0"),
        dict(name="sonar frame without noise", value=clean_ms, unit="ms", reference="bare cast", ratio=clean_ms / bare, note=""),
        dict(name="full frame + ground truth (body, elevation span, shadow)", value=truth_ms, unit="ms", reference="bare cast",
             ratio=truth_ms / bare, note="shadow needs continuation rays"),
        dict(name="full frame at the thesis's 750 elevation samples", value=thesis_ms, unit="ms", reference="bare cast",
             ratio=thesis_ms / bare, note=f"default 128 samples differ from it by {100 * l1:.2f}% (L1)"),
        dict(name="acceleration structure build (once per scene)", value=bvh_ms, unit="ms", reference="-", ratio=None,
             note=f"{sum(s.n_faces for s in scene.surfaces())} triangles"),
    ]
    return rows
