"""Speed of the underwater camera simulator against a bare ray cast of the same pixels."""

from __future__ import annotations

import os

import numpy as np

from _timing import busy_core, caster_threads, linear_fit, median_ms, paired_ms

TITLE = "Underwater camera (Jaffe-McGlamery)"
DESCRIPTION = (
    "Thesis scene 1 from the thesis camera (600 x 400 px, 50 mm on 36 x 24 mm, at (-0.25, -6, 2) aimed at the "
    "origin), one lamp with shadow rays, 32 backscatter slices on a 16-px grid. Reference: a bare Embree "
    "closest-hit query (`RayCaster.bare_intersect`: float32 rays in, no post-processing) of the frame's own "
    "240 000 primary pixel rays on the same triangles, with the same number of threads, in the same run; a "
    "frame also casts one shadow ray per pixel and lamp. Rows marked '1 thread' limit both the frame and "
    "the reference to one thread; 'second core busy' runs both while another process spins on a core. "
    "The per-pixel shading runs in compiled kernels (numba, cached on disk; the numpy reference path is "
    "a row of its own); the veil's coarse table is kept between frames while the lamps keep their place "
    "relative to the camera (the default, camera-mounted lamps); a row recomputes it every frame. "
    "Each frame row and its bare cast are timed alternately (medians of each), so that load falls on both alike. "
    "The cost is linear in pixels and in lights: the constants come from frames of 150 x 100 to 600 x 400 px "
    "and 1 to 4 lamps. The thesis's MATLAB simulator took 3 min per frame. Target: a frame <= 4x the bare cast."
)



def run(reps: int = 9) -> list[dict]:
    from optiacoustic import PinholeCamera, Pose, scenes
    from optiacoustic.optical import OpticalOptions, simulate_optical
    from optiacoustic.optical.lights import Light, default_lights
    from optiacoustic.optical.render import _coarse_table
    from optiacoustic.raycast import caster_for

    scene = scenes.get("thesis_scene1")
    camera = PinholeCamera.from_sensor()
    pose = Pose.look_at((-0.25, -6.0, 2.0), (0.0, 0.0, 0.0), body="camera")
    caster = caster_for(scene)

    def rays(cam):
        d = np.einsum("ij,kj->ik", cam.pixel_rays().reshape(-1, 3), pose.R)
        return (np.ascontiguousarray(np.broadcast_to(pose.t, d.shape), np.float32),
                np.ascontiguousarray(d, np.float32))

    o32, d32 = rays(camera)
    n_px = len(d32)
    bare = lambda: caster.bare_intersect(o32, d32)  # noqa: E731
    frame = lambda water=None, **kw: simulate_optical(scene, camera, pose, water=water, **kw)  # noqa: E731
    rows = []
    ref = f"bare cast of the {n_px} primary rays"
    bare_ms = median_ms(bare, reps)
    rows.append(dict(name="bare Embree cast, 600 x 400 primary rays, 2 threads", value=bare_ms, unit="ms",
                     reference="itself", ratio=1.0, note=f"{n_px / bare_ms / 1e3:.1f} M rays/s"))
    cast_ms = median_ms(lambda: caster.cast(pose.t, d32), reps)
    rows.append(dict(name="RayCaster.cast of the same rays (validated, float64 out, smooth normals)", value=cast_ms,
                     unit="ms", reference=ref, ratio=cast_ms / bare_ms, note="the public cast; frames use cast_raw"))
    for label, water in (("thesis water", None), ("Jerlov II water", "jerlov-II"), ("Jerlov 3C water", "jerlov-3C")):
        b, t = paired_ms(bare, lambda: frame(water), reps)
        rows.append(dict(name=f"optical frame, {label}, 2 threads", value=t, unit="ms", reference=ref,
                         ratio=t / b, note=f"target <= 4x; {180e3 / t:.0f}x faster than the thesis's 3 min"))

    def fresh_veil():  # lamps that move with respect to the camera: the veil's coarse table is recomputed
        _coarse_table.cache_clear()
        return frame()

    b, t = paired_ms(bare, fresh_veil, reps)
    rows.append(dict(name="optical frame, thesis water, veil table recomputed", value=t, unit="ms", reference=ref,
                     ratio=t / b, note="as for lamps fixed in the world: no reuse of the veil's coarse table"))
    saved = os.environ.get("OAS_KERNELS")
    os.environ["OAS_KERNELS"] = "numpy"
    try:
        b, t = paired_ms(bare, lambda: frame(), max(3, reps // 3))
    finally:
        if saved is None:
            del os.environ["OAS_KERNELS"]
        else:
            os.environ["OAS_KERNELS"] = saved
    rows.append(dict(name="optical frame, thesis water, numpy reference path", value=t, unit="ms", reference=ref,
                     ratio=t / b, note="OAS_KERNELS=numpy: the same frame without the compiled kernels"))
    with caster_threads(caster, 1):
        b1, t1 = paired_ms(bare, lambda: frame(), reps)
    rows.append(dict(name="optical frame, thesis water, 1 thread", value=t1, unit="ms",
                     reference="bare cast, 1 thread", ratio=t1 / b1, note=f"the 1-thread bare cast takes {b1:.1f} ms"))
    with busy_core():
        bb, tb = paired_ms(bare, lambda: frame(), reps)
    rows.append(dict(name="optical frame, thesis water, second core busy", value=tb, unit="ms",
                     reference="bare cast, second core busy", ratio=tb / bb,
                     note=f"the bare cast takes {bb:.1f} ms with the core busy"))
    full_ms = median_ms(lambda: frame(options=OpticalOptions(backscatter_step=1)), max(3, reps // 3))
    rows.append(dict(name="optical frame, per-pixel backscatter", value=full_ms, unit="ms", reference=ref,
                     ratio=full_ms / bare_ms, note="backscatter_step=1: the validation path, 32 slices for every pixel"))
    # linear in pixels
    sizes, times = [], []
    for scale in (0.25, 0.5, 0.75, 1.0):
        cam = PinholeCamera.from_sensor(int(600 * scale), int(400 * scale))
        times.append(median_ms(lambda: simulate_optical(scene, cam, pose), reps))
        sizes.append(cam.width * cam.height)
    a, b, res = linear_fit(sizes, times)
    rows.append(dict(name="cost per pixel (1 lamp)", value=1e6 * b, unit="ns/pixel", reference=ref,
                     ratio=(1e6 * b) / (1e6 * bare_ms / n_px),
                     note=f"fit t = a + b n over 150x100 to 600x400 px: a = {a:.1f} ms, worst residual "
                          f"{100 * res:.0f}%; the bare cast costs {1e6 * bare_ms / n_px:.0f} ns/ray"))
    base = default_lights()[0]
    counts, times = [], []
    for k in (1, 2, 4):
        lamps = [Light(tuple(np.asarray(base.position) + [0.15 * j, -0.1 * j, 0.0]), base.intensity, base.direction,
                       base.cone_deg, base.frame) for j in range(k)]
        times.append(median_ms(lambda: simulate_optical(scene, camera, pose, lights=lamps), max(3, reps // 2)))
        counts.append(k)
    a, b, res = linear_fit(counts, times)
    rows.append(dict(name="cost per lamp (600 x 400 px, shadow rays on)", value=b, unit="ms/lamp", reference=ref,
                     ratio=b / bare_ms, note=f"fit over 1, 2, 4 lamps: a = {a:.1f} ms, worst residual {100 * res:.0f}%"))
    return rows


if __name__ == "__main__":
    for r in run():
        print(f"{r['name']}: {r['value']:.1f} {r['unit']} (x{r['ratio']:.2f} {r['reference']}) {r['note']}")
