"""Cost of the realistic (device-profile) sonar model against the thesis model, per frame, in one run."""

from __future__ import annotations

import dataclasses
import time

from _timing import median_ms, paired_ms

TITLE = "Realistic sonar model (aperture beams, scatterer speckle, device gain) vs the thesis model"
DESCRIPTION = (
    "Thesis scene 1 with the BlueView P900-90 preset (512 beams x 750 bins, 128 elevation rays per beam). "
    "Reference: the thesis model (hard elevation cut, ideal TVG, Table 2.2 reverberation). Realistic: "
    "beam_model='aperture' (rays to the elevation pattern's second null weighted by F^4, sub-cells along "
    "long footprints, F^4 across beams), spreading and absorption, ScattererNoise (Poisson counts per cell "
    "from cell areas, pulse- and beam-filtered complex fields, receiver noise before the device TVG). "
    "Issue 10's target: ratio <= 1.5. One numba pass per beam forms the aperture model's sub-cells (never "
    "stored), their echo with the seabed split and the seabed area per cell; the beams are mixed in that "
    "pass's rows layout and finished by the thesis path's kernel. The noise runs in two numba passes split by "
    "rows over the threads: per cell its random words (Philox4x32-10 of the cell index, no array of draws), "
    "Poisson count, power and complex normal (exp, log and cos/sin without libm calls, so the loops vectorise), "
    "then the field's and the mean's separable filters and the |f|^2 x mean / expected x TVG image in one pass."
)


def run() -> list[dict]:
    from optiacoustic import Pose, SonarSpec, scenes, simulate_sonar

    scene = scenes.get("thesis_scene1")
    spec = SonarSpec.preset("blueview-p900-90")
    pose = Pose.look_at(scene.view.eye, scene.view.target)
    from optiacoustic.experiments.matching import realistic_sonar

    real = realistic_sonar()  # the benchmark's realistic frame, one definition
    real_opts, noise = real["options"], real["noise"]
    seeds = iter(range(10_000))

    # timed alternately (medians of each), so that load falls on both alike
    thesis_ms, real_ms = paired_ms(lambda: simulate_sonar(scene, spec, pose, seed=next(seeds)),
                                   lambda: simulate_sonar(scene, spec, pose, seed=next(seeds), noise=noise,
                                                          options=real_opts), repeat=11)
    clean_thesis = median_ms(lambda: simulate_sonar(scene, spec, pose, noise=False), repeat=7)
    clean_real = median_ms(lambda: simulate_sonar(scene, spec, pose, noise=False, options=real_opts), repeat=7)
    thesis_cpu, real_cpu = paired_ms(lambda: simulate_sonar(scene, spec, pose, seed=next(seeds)),
                                     lambda: simulate_sonar(scene, spec, pose, seed=next(seeds), noise=noise,
                                                            options=real_opts), repeat=11, clock=time.process_time)
    small = dataclasses.replace(spec, elevation_samples=64)
    small_ms = median_ms(lambda: simulate_sonar(scene, small, pose, seed=next(seeds), noise=noise, options=real_opts), repeat=7)
    return [
        dict(name="thesis model frame (noise on)", value=thesis_ms, unit="ms", reference="itself", ratio=1.0, note=""),
        dict(name="realistic model frame (noise on)", value=real_ms, unit="ms", reference="thesis model frame",
             ratio=real_ms / thesis_ms, note="requirement: ratio <= 1.5"),
        dict(name="realistic model frame, CPU time of all threads", value=real_cpu, unit="ms",
             reference="thesis model frame, CPU time", ratio=real_cpu / thesis_cpu,
             note=f"thesis frame {thesis_cpu:.1f} ms CPU; the work, less sensitive to load than wall time"),
        dict(name="thesis model, no noise", value=clean_thesis, unit="ms", reference="thesis model frame",
             ratio=clean_thesis / thesis_ms, note=""),
        dict(name="aperture beams, no noise", value=clean_real, unit="ms", reference="thesis model, no noise",
             ratio=clean_real / clean_thesis, note="beam patterns and sub-cells alone"),
        dict(name="realistic model, 64 elevation rays per beam", value=small_ms, unit="ms", reference="thesis model frame",
             ratio=small_ms / thesis_ms, note="half the rays: the aperture model's samples span a wider elevation"),
    ]

