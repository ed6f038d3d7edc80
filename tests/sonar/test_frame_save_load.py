"""SonarFrame / MeasuredSonarFrame save -> load round trips, and the shared protocol."""

import dataclasses

import numpy as np
import pytest

import optiacoustic as oa
from optiacoustic.sonar.frame import MeasuredSonarFrame, SonarFrame, SonarImageLike, SonarRays


def _sim():
    scene = oa.scenes.get("thesis_scene1")
    spec = oa.SonarSpec.preset("blueview-p900-45", n_beams=32, n_bins=64, elevation_samples=16)
    spec = spec.with_beam_table(oa.SonarSpec.equal_sine_azimuths(32, spec.fov_azimuth))
    pose = oa.Pose.look_at(scene.view.eye, scene.view.target, body="sonar")
    return oa.simulate_sonar(scene, spec, pose, noise=oa.sonar.NoiseModel(), seed=1)


def test_simulated_round_trip(tmp_path):
    f = _sim()
    g = SonarFrame.load(f.save(tmp_path / "f.npz"))
    assert isinstance(g, SonarFrame) and g.spec == f.spec
    for k in ("intensity", "image", "ranges", "azimuths"):
        assert np.array_equal(getattr(g, k), getattr(f, k)), k
    for fld in dataclasses.fields(SonarRays):
        assert np.array_equal(getattr(g.rays, fld.name), getattr(f.rays, fld.name)), fld.name
    for k in ("body", "elevation_min", "elevation_max", "shadow", "range_map"):
        assert np.array_equal(getattr(g.ground_truth, k), getattr(f.ground_truth, k), equal_nan=True), k
    assert np.array_equal(g.pose.R, f.pose.R) and np.array_equal(g.pose.t, f.pose.t)
    assert g.body_names == f.body_names and set(g.seabed_share) == set(f.seabed_share)
    assert np.array_equal(g.fan(width=64).data, f.fan(width=64).data)


def test_measured_round_trip_and_protocol(tmp_path):
    rng = np.random.default_rng(0)
    spec = oa.SonarSpec(n_bins=20).with_beam_table(np.sort(rng.uniform(-0.5, 0.5, 7)))
    raw = rng.integers(0, 255, (20, 7), dtype=np.uint8)
    m = MeasuredSonarFrame(raw=raw, image=raw.astype(np.float32) ** 2, spec=spec, time=1.7e9 + 0.25,
                           encoding="test", source="x.bin", index=4, meta={"gain": 3, "mode": "hf"})
    g = MeasuredSonarFrame.load(m.save(tmp_path / "m.npz"))
    assert isinstance(g, MeasuredSonarFrame) and g.spec == spec
    assert np.array_equal(g.raw, raw) and g.raw.dtype == np.uint8 and np.array_equal(g.image, m.image)
    assert g.time == m.time and g.meta == {"gain": 3, "mode": "hf"} and g.index == 4
    assert isinstance(g, SonarImageLike) and isinstance(_sim(), SonarImageLike)


def test_load_rejects_other_files(tmp_path):
    p = tmp_path / "x.npz"
    np.savez(p, a=np.zeros(3))
    with pytest.raises(ValueError, match="not a saved sonar frame"):
        SonarFrame.load(p)
    (tmp_path / "t.npz").write_bytes(b"PK\x03\x04garbage")
    with pytest.raises(ValueError, match="t.npz"):
        SonarFrame.load(tmp_path / "t.npz")


def test_measured_shape_checked():
    with pytest.raises(ValueError, match="expected shape"):
        MeasuredSonarFrame(raw=np.zeros((3, 3)), image=np.zeros((3, 3)), spec=oa.SonarSpec(n_beams=4, n_bins=3))
