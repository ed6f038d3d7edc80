"""The thesis noise model (``NoiseModel``: draw + apply) on a thesis frame, against one numpy exponential array."""

from __future__ import annotations

import time

import numpy as np

from _timing import paired_ms

TITLE = "Thesis noise model (NoiseModel draw + apply, thesis scene 1, BlueView P900-90)"
DESCRIPTION = (
    "The default `NoiseModel` (Rayleigh-mixture bottom, target speckle, noise floor) applied to the noise-free "
    "intensity of one thesis frame (750 x 512 cells): `draw` (a key of two words) plus `apply` (noise power, then "
    "every cell's Philox4x32-10 words, exponential, mixture component and intensity in one compiled pass; "
    "issue 14, branch i14p). Reference: numpy's `Generator.standard_exponential` of one float32 per cell (the "
    "cheapest array draw of a single variate per cell; before i14p the model drew that plus a uniform array). "
    "Both timed alternately in thread CPU time at one thread, and in wall time with the frame's two threads."
)


def run() -> list[dict]:
    from optiacoustic import Pose, SonarSpec, scenes, simulate_sonar
    from optiacoustic.sonar import SonarOptions
    from optiacoustic.sonar.noise import NoiseModel

    scene = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    pose = Pose.look_at(scene.view.eye, scene.view.target)
    f = simulate_sonar(scene, spec, pose, seed=1)
    I, shares, opts = f.intensity, dict(f.seabed_share), SonarOptions()
    model = NoiseModel()
    rng = np.random.default_rng(0)

    def noise(threads):
        def go():
            d = model.draw(I.shape, list(shares), rng)
            model.apply(I, spec=spec, seabed_share=shares, options=opts, draws=d, threads=threads)
        return go

    ref = lambda: rng.standard_exponential(I.shape, dtype=np.float32)  # noqa: E731
    name = f"numpy Generator.standard_exponential, {I.size} float32"
    r1, t1 = paired_ms(ref, noise(1), repeat=31, clock=time.thread_time)
    r2, t2 = paired_ms(ref, noise(2), repeat=31)
    return [
        dict(name="NoiseModel draw + apply, 1 thread (thread CPU)", value=t1, unit="ms", reference=name,
             ratio=t1 / r1, note=f"the reference takes {r1:.2f} ms; {1e6 * t1 / I.size:.1f} ns per cell"),
        dict(name="NoiseModel draw + apply, 2 threads (wall)", value=t2, unit="ms", reference=name,
             ratio=t2 / r2, note=f"the reference takes {r2:.2f} ms (one thread: numpy's draws cannot be split)"),
    ]
