"""What a camera frame returns owns its memory: the per-thread scratch of its rays never leaks into results.

``simulate_optical`` puts the world rays of its pixels (origins and directions, float32) in
per-thread scratch (``render._workspace``) that the next frame on the same thread overwrites.
Truths here do not come from that code: a frame's arrays, copied when it is made, must be bit
for bit the same after later frames (other poses, waters, sizes, seeds, thread counts, frames
made at once on other threads), and equal to the same frame made afresh.
"""

import threading

import numpy as np
import pytest

from optiacoustic import PinholeCamera, Pose, scenes
from optiacoustic.optical import simulate_optical
from optiacoustic.raycast import caster_for

CAM = PinholeCamera.from_sensor(150, 100)
CAM_BIG = PinholeCamera.from_sensor(180, 120)
ARRAYS = ("clear", "attenuated", "forward_scatter", "backscatter", "image", "depth", "body", "normal")


@pytest.fixture(scope="module")
def scene():
    return scenes.get("thesis_scene1")


def _pose(shift=0.0):
    return Pose.look_at((-0.25 + shift, -6.0, 2.0), (0.0, 0.0, 0.0), body="camera")


def _arrays(frame) -> dict:
    return {k: getattr(frame, k) for k in ARRAYS}


def _same(a: dict, b: dict, what: str) -> None:
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, f"{what}: {k}"
        assert np.array_equal(a[k], b[k], equal_nan=True), f"{what}: {k} changed"


def _later_frames(scene):
    """Frames B and C: other poses, waters, seeds and sizes."""
    simulate_optical(scene, CAM, _pose(0.8), water="jerlov-II", seed=11)
    simulate_optical(scene, CAM_BIG, _pose(-0.6), seed=12)


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("kernels", ["numba", "numpy"])
def test_a_frame_is_unchanged_by_later_frames(scene, threads, kernels, monkeypatch):
    monkeypatch.setenv("OAS_KERNELS", kernels)
    caster = caster_for(scene)
    old = caster.threads
    caster.threads = threads
    try:
        a = simulate_optical(scene, CAM, _pose(), seed=5)
        copies = {k: v.copy() for k, v in _arrays(a).items()}
        _later_frames(scene)
        _same(_arrays(a), copies, "frame A after B and C")
        fresh = simulate_optical(scene, CAM, _pose(), seed=5)
        _same(_arrays(a), _arrays(fresh), "frame A against a fresh A")
    finally:
        caster.threads = old


def test_returned_arrays_share_no_memory_with_other_frames_or_the_scratch(scene):
    from optiacoustic.optical import render

    a = simulate_optical(scene, CAM, _pose(), seed=1)
    b = simulate_optical(scene, CAM, _pose(0.3), seed=2)
    scratch = render._workspace.arrays()
    assert scratch  # the rays of this thread's frames are scratch
    for ka, va in _arrays(a).items():
        for s in scratch:
            assert not np.shares_memory(va, s), ka
        for kb, vb in _arrays(b).items():
            assert not np.shares_memory(va, vb), (ka, kb)


def test_frames_made_at_once_on_several_threads_are_the_serial_frames(scene):
    """Per-thread scratch: frames made on four threads at once (each its own pose, water, seed
    and size) equal the same frames made one after another."""
    jobs = [(CAM, 0.0, None, 21), (CAM_BIG, 0.5, "jerlov-II", 22), (CAM, -0.5, None, 23), (CAM_BIG, 0.2, None, 24)]

    def make(job):
        cam, shift, water, seed = job
        return {k: v.copy() for k, v in _arrays(simulate_optical(scene, cam, _pose(shift), water=water,
                                                                 seed=seed)).items()}

    serial = [make(j) for j in jobs]
    got = [None] * len(jobs)
    errors = []

    def run(i):
        try:
            got[i] = make(jobs[i])
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(len(jobs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for i in range(len(jobs)):
        _same(got[i], serial[i], f"frame {i} made beside others")
