"""What a sonar frame returns owns its memory: the scratch that frames reuse never leaks into results.

The thesis-model frame reuses per-thread scratch (``sonar._kernels.workspace``: the scan's rays and
normals, the cell extents, the bucketed records, the shadow's continuation rays) and pooled noise
buffers (``sonar._kernels.pooled``) from frame to frame. Truths here do not come from that code:
a frame's arrays, copied when it is made, must be bit for bit the same after later frames (other
poses, seeds, sizes, thread counts, frames made at once on other threads), and a ground truth read
late must equal that of the same frame made afresh.
"""

import dataclasses
import threading

import numpy as np
import pytest

from optiacoustic import Pose, scenes
from optiacoustic.raycast import caster_for
from optiacoustic.sonar import SonarOptions, SonarSpec, simulate_sonar
from optiacoustic.sonar.gain import DeviceGain
from optiacoustic.sonar.noise import ScattererNoise

SPEC = dataclasses.replace(SonarSpec.preset("blueview-p900-90"), n_beams=96, n_bins=240, elevation_samples=48)
SPEC_BIG = dataclasses.replace(SPEC, n_beams=128, elevation_samples=64)


@pytest.fixture(scope="module")
def scene():
    return scenes.get("thesis_scene1")


def _pose(scene, shift=0.0):
    eye = np.asarray(scene.view.eye, float) + [shift, 0.0, 0.0]
    return Pose.look_at(eye, scene.view.target)


def _arrays(frame, fan) -> dict:
    """Every array a frame hands out before its ground truth is read."""
    out = {"image": frame.image, "intensity": frame.intensity, "fan": fan.data,
           "range_map": frame.ground_truth.range_map}
    out.update({f"share_{k}": v for k, v in frame.seabed_share.items()})
    out.update({f"ray_{f.name}": getattr(frame.rays, f.name) for f in dataclasses.fields(frame.rays)
                if f.name != "elevation_step"})
    return out


def _truth(frame) -> dict:
    gt = frame.ground_truth
    return {"body": gt.body, "elevation_min": gt.elevation_min, "elevation_max": gt.elevation_max,
            "shadow": gt.shadow}


def _same(a: dict, b: dict, what: str) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, f"{what}: {k}"
        assert np.array_equal(a[k], b[k], equal_nan=True), f"{what}: {k} changed"


def _later_frames(scene, noise=None, options=None):
    """Frames B and C: other poses, seeds and sizes, their fans and ground truth all read."""
    for spec, shift, seed in ((SPEC, 0.7, 11), (SPEC_BIG, -0.4, 12)):
        f = simulate_sonar(scene, spec, _pose(scene, shift), seed=seed, noise=noise, options=options)
        f.fan("image")
        _truth(f)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("kernels", ["numba", "numpy"])
def test_a_frame_is_unchanged_by_later_frames(scene, threads, kernels, monkeypatch):
    monkeypatch.setenv("OAS_KERNELS", kernels)
    caster = caster_for(scene)
    old = caster.threads
    caster.threads = threads
    try:
        a = simulate_sonar(scene, SPEC, _pose(scene), seed=5)
        copies = {k: v.copy() for k, v in _arrays(a, a.fan("image")).items()}
        _later_frames(scene)
        # nothing A handed out moved, and its ground truth, read only now, is a fresh A's
        _same(_arrays(a, a.fan("image")), copies, "frame A after B and C")
        fresh = simulate_sonar(scene, SPEC, _pose(scene), seed=5)
        _same(_arrays(a, a.fan("image")), _arrays(fresh, fresh.fan("image")), "frame A against a fresh A")
        truth_a = _truth(a)
        _same(truth_a, _truth(fresh), "A's late ground truth against a fresh A's")
        truth_copies = {k: v.copy() for k, v in truth_a.items()}
        _later_frames(scene)
        _same(_truth(a), truth_copies, "A's ground truth after more frames")
    finally:
        caster.threads = old


def test_returned_arrays_share_no_memory_across_frames(scene):
    a = simulate_sonar(scene, SPEC, _pose(scene), seed=1)
    b = simulate_sonar(scene, SPEC, _pose(scene, 0.3), seed=2)
    arrays_a = {**_arrays(a, a.fan("image")), **_truth(a)}
    arrays_b = {**_arrays(b, b.fan("image")), **_truth(b)}
    for ka, va in arrays_a.items():
        for kb, vb in arrays_b.items():
            if not np.shares_memory(va, vb):
                continue
            # the only arrays frames share: the per-spec ray grids, which are read-only constants
            assert ka == kb and ka in ("ray_beam_index", "ray_elevation"), (ka, kb)
            assert not va.flags.writeable and not vb.flags.writeable, ka


def test_frames_made_at_once_on_several_threads_are_the_serial_frames(scene):
    """Per-thread scratch and the shared noise pool: frames made on four threads at once (each its
    own pose, seed and size) equal the same frames made one after another."""
    jobs = [(SPEC, 0.0, 21), (SPEC_BIG, 0.5, 22), (SPEC, -0.5, 23), (SPEC_BIG, 0.2, 24)]

    def make(job):
        spec, shift, seed = job
        f = simulate_sonar(scene, spec, _pose(scene, shift), seed=seed)
        return {**_arrays(f, f.fan("image")), **_truth(f)}

    serial = [make(j) for j in jobs]
    got = [None] * len(jobs)
    errors = []

    def run(i):
        try:
            for _ in range(2):
                got[i] = make(jobs[i])
        except Exception as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for i in range(len(jobs)):
        _same(got[i], serial[i], f"frame {i} made on a thread")


def test_realistic_frame_is_unchanged_by_later_frames(scene):
    """The aperture model and scatterer noise reuse their own scratch (issue 10); the same check."""
    opts = SonarOptions(beam_model="aperture", propagation="spreading")
    noise = ScattererNoise(density=500.0, gain=DeviceGain(noise_db=-60.0, volume_db=-50.0, spreading_db=30.0))
    a = simulate_sonar(scene, SPEC, _pose(scene), seed=5, noise=noise, options=opts)
    copies = {k: v.copy() for k, v in _arrays(a, a.fan("image")).items()}
    _later_frames(scene, noise=noise, options=opts)
    _later_frames(scene)
    _same(_arrays(a, a.fan("image")), copies, "realistic frame A after B and C")
    fresh = simulate_sonar(scene, SPEC, _pose(scene), seed=5, noise=noise, options=opts)
    _same(_truth(a), _truth(fresh), "realistic A's late ground truth against a fresh A's")
