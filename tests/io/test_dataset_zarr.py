"""Datasets: layout, metadata, config validation, Dask workers and kill -9 / resume."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
import zarr
from typer.testing import CliRunner

from optiacoustic import Pose
from optiacoustic.cli import app
from optiacoustic.io import open_dataset, write_dataset
from optiacoustic.io.dataset import DatasetError
from optiacoustic.simulation.sequence import Sequence

SRC = Path(__file__).resolve().parents[2] / "src"

# small sensors so that a frame costs a few tens of ms
SMALL = {
    "scene": "thesis_scene1",
    "rig": {"sonar": {"preset": "blueview-p900-90", "n_bins": 96, "n_beams": 48, "elevation_samples": 24},
            "camera": {"width_px": 72, "height_px": 48, "sensor_mm": [36, 24], "focal_mm": 50},
            "camera_in_sonar": {"position": [-0.25, 0, 0], "rotation_deg": [0, 0.7543055, -2.2636361]}},
    "water": "jerlov-II",
    "seed": 3,
    "duration": 2.0,
    "rates": {"sonar": 4, "camera": 2},
    "optical": {"slices": 6},
    "trajectory": {"kind": "orbit", "center": [0, 0, 0], "radius": 6.0, "height": 2.0, "period": 60.0},
}


def _write_config(path: Path, cfg: dict) -> Path:
    path.write_text(yaml.safe_dump(cfg))
    return path


def _arrays(path) -> dict:
    root = zarr.open_group(str(path), mode="r")
    return {f"{g}/{n}": root[g][n][:] for g in ("sonar", "camera") for n in root[g].array_keys()}


def _assert_identical(a: dict, b: dict):
    assert a.keys() == b.keys()
    for k in a:
        assert a[k].dtype == b[k].dtype, k
        # frame by frame, so a failure names the frame
        for i in range(len(a[k]) if a[k].ndim > 1 else 1):
            x, y = (a[k][i], b[k][i]) if a[k].ndim > 1 else (a[k], b[k])
            assert np.array_equal(x, y, equal_nan=x.dtype.kind == "f"), f"{k} frame {i}"


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    d = tmp_path_factory.mktemp("ref")
    cfg = _write_config(d / "cfg.yaml", SMALL)
    rep = write_dataset(cfg, d / "ref.zarr", workers=0)
    return cfg, d / "ref.zarr", rep


def test_layout_metadata_and_xarray_view(reference):
    cfg, path, rep = reference
    assert rep.written == {"sonar": 8, "camera": 4} and rep.skipped == {"sonar": 0, "camera": 0}
    root = zarr.open_group(str(path), mode="r")
    assert root["sonar/image"].shape == (8, 96, 48) and root["sonar/image"].chunks == (1, 96, 48)
    assert root["camera/image"].shape == (4, 48, 72, 3) and root["camera/image"].chunks == (1, 48, 72, 3)
    assert root["sonar/image"].compressors  # compressed
    np.testing.assert_allclose(root["sonar/time"][:], np.arange(8) / 4)
    np.testing.assert_allclose(root["camera/time"][:], np.arange(4) / 2)
    meta = root.attrs["optiacoustic"]
    for key in ("config", "sonar_spec", "rig", "water", "scene", "package_version", "seed", "camera", "fingerprint"):
        assert key in meta, key
    assert meta["seed"] == 3 and meta["water"]["name"] == "jerlov-II" and meta["sonar_spec"]["n_beams"] == 48

    # poses: the orbit (analytic) and the rig moving as one body
    T_s, T_c = root["sonar/pose"][:], root["camera/pose"][:]
    t = root["sonar/time"][:]
    a = -np.pi / 2 + 2 * np.pi * t / 60.0
    np.testing.assert_allclose(T_s[:, :3, 3], np.column_stack([6 * np.cos(a), 6 * np.sin(a), np.full_like(a, 2.0)]),
                               atol=1e-12)
    seq = Sequence(cfg)
    for k in range(4):  # camera frame k is at the time of sonar frame 2k
        cam = seq.rig.camera_pose(Pose(T_s[2 * k, :3, :3], T_s[2 * k, :3, 3]))
        np.testing.assert_allclose(T_c[k, :3, :3], cam.R, atol=1e-12)
        np.testing.assert_allclose(T_c[k, :3, 3], cam.t, atol=1e-12)

    tree = open_dataset(path)
    s, c = tree["sonar"], tree["camera"]
    assert s["image"].dims == ("frame", "bin", "beam") and c["image"].dims == ("frame", "row", "col", "channel")
    assert c["depth"].dims == ("frame", "row", "col") and s["shadow"].dims == ("frame", "bin", "beam")
    np.testing.assert_allclose(s["ranges"].values, seq.rig.sonar.ranges)
    np.testing.assert_allclose(s["azimuths"].values, seq.rig.sonar.azimuths)
    assert bool(s["done"].all()) and bool(c["done"].all())
    # arrays are what the simulators give for that frame
    f = seq.render_sonar(5)
    np.testing.assert_array_equal(s["image"][5].values, f.image)
    np.testing.assert_array_equal(s["intensity"][5].values, f.intensity)
    np.testing.assert_array_equal(s["body"][5].values, f.ground_truth.body)
    o = seq.render_camera(2)
    np.testing.assert_array_equal(c["image"][2].values, o.image)
    np.testing.assert_array_equal(c["depth"][2].values, o.depth)
    # physically sensible: noise changes the image, the seabed is in view, depth is finite where a body is hit
    assert not np.array_equal(s["image"][0].values, s["intensity"][0].values)
    assert np.all((c["body"][0].values >= 0) == np.isfinite(c["depth"][0].values))
    # sonar frames differ from frame to frame (the rig moves and the noise is per frame)
    assert not np.array_equal(s["image"][0].values, s["image"][1].values)


def test_global_quiet_hides_the_progress_bar(tmp_path):
    cfg = _write_config(tmp_path / "c.yaml", {**SMALL, "duration": 0.5})
    r = CliRunner().invoke(app, ["-q", "dataset", str(cfg), "--out", str(tmp_path / "q.zarr"), "--workers", "0"])
    assert r.exit_code == 0 and r.output == "", repr(r.output)
    assert open_dataset(tmp_path / "q.zarr")["sonar"]["image"].shape[0] == 2
    r = CliRunner().invoke(app, ["dataset", str(cfg), "--out", str(tmp_path / "v.zarr"), "--workers", "0"])
    assert r.exit_code == 0 and "frames" in r.output and "wrote" in r.output, r.output


def test_rerun_skips_and_other_config_is_refused(reference, tmp_path):
    cfg, path, _ = reference
    rep = write_dataset(cfg, path, workers=0)
    assert rep.frames_written == 0 and rep.skipped == {"sonar": 8, "camera": 4}
    other = _write_config(tmp_path / "other.yaml", {**SMALL, "seed": 4})
    with pytest.raises(DatasetError, match=r"different configuration \(field 'config.seed' was 3, now 4\)"):
        write_dataset(other, path, workers=0)
    r = CliRunner().invoke(app, ["dataset", str(other), "--out", str(path), "--workers", "0", "--quiet"])
    text = " ".join(r.output.split())  # rich wraps long lines
    assert r.exit_code == 2 and "different configuration" in text and "Traceback" not in text
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "file.txt").write_text("x")
    with pytest.raises(DatasetError, match="not a Zarr store"):
        write_dataset(cfg, tmp_path / "junk", workers=0)


@pytest.mark.parametrize("change, field", [
    ({"trajectory": {"kind": "orbit", "radius": -1}}, "trajectory.radius"),
    ({"trajectory": {"kind": "spiral"}}, "trajectory"),
    ({"rates": {"sonar": -5}}, "rates.sonar"),
    ({"rates": {"sonar": 0, "camera": 0}}, "rates"),
    ({"duration": 0}, "duration"),
    ({"duration": float("inf")}, "duration"),
    ({"start": float("nan")}, "start"),
    ({"trajectory": {"kind": "orbit", "height": float("nan")}}, "trajectory.height"),
    ({"start": 1e300}, "start"),  # float64 times 0.5 s apart would all round to one time
    ({"colour": "red"}, "colour"),
    ({"trajectory": {"kind": "waypoints", "points": [{"time": 0, "position": [0, 0, 1]},
                                                     {"time": 1, "position": [1, 0, 1], "target": [0, 0, 0]}]}},
     "trajectory.points.0"),
])
def test_config_errors_name_the_field(tmp_path, change, field):
    cfg = _write_config(tmp_path / "bad.yaml", {**SMALL, **change})
    with pytest.raises(ValueError, match=rf"bad.yaml: field '{field}"):
        Sequence(cfg)
    r = CliRunner().invoke(app, ["dataset", str(cfg), "--out", str(tmp_path / "x.zarr"), "--workers", "0"])
    text = " ".join(r.output.split())
    assert r.exit_code == 2 and f"field '{field}" in text and "Traceback" not in text


def test_unknown_scene_water_and_short_trajectory(tmp_path):
    for change, msg in (({"scene": "atlantis"}, "field 'scene'"), ({"water": "soup"}, "field 'water'"),
                        ({"trajectory": {"kind": "waypoints", "points": [
                            {"time": 0, "position": [0, -6, 2], "target": [0, 0, 0]},
                            {"time": 1, "position": [1, -6, 2], "target": [0, 0, 0]}]}},
                         r"fields 'start' and 'duration': the sonar's frame times 0\.\.[0-9.]+ s lie outside the "
                         r"trajectory's 0\.\.1 s"),
                        ({"duration": 1e7}, r"fields 'duration' and 'rates.sonar': 1e\+07 s at [0-9.]+ Hz is "
                         r"[0-9.e+]+ sonar frames; at most 1e\+07 per sensor"),
                        ({"start": -3.0}, "fields 'start' and 'duration'")):
        with pytest.raises(ValueError, match=msg):
            Sequence({**SMALL, **change})


def _builds():
    import dask

    from optiacoustic import raycast
    from optiacoustic.io import dataset

    # the last: the lean Dask settings reached this worker, also one added by scale()
    return (dataset.BUILDS["sequences"], dataset.BUILDS["scenes"], len(raycast._CASTERS),
            dask.config.get("distributed.worker.profile.enabled"))


def test_one_and_two_workers_give_identical_output(reference, tmp_path):
    """Real Dask: a one-worker cluster, then the same cluster grown to two, via --scheduler's path."""
    from distributed import Client

    from optiacoustic.io import local_cluster

    cfg, ref, _ = reference
    with local_cluster(1) as cluster:
        r1 = write_dataset(cfg, tmp_path / "w1.zarr", scheduler=cluster.scheduler_address)
        cluster.scale(2)
        cluster.wait_for_workers(2)
        r2 = write_dataset(cfg, tmp_path / "w2.zarr", scheduler=cluster.scheduler_address)
        # another configuration of the same scene: a new sequence, the same scene and BVH
        other = _write_config(tmp_path / "other.yaml", {**SMALL, "duration": 0.5})
        r3 = write_dataset(other, tmp_path / "w3.zarr", scheduler=cluster.scheduler_address)
        with Client(cluster) as client:
            builds = client.run(_builds)
    # each worker resolved each configuration once and the scene (and built its BVH) once,
    # the first worker once for both outputs of the first configuration
    assert sorted(builds.values()) == [(2, 1, 1, False), (2, 1, 1, False)], builds
    assert r1.workers == 1 and r2.workers == 2
    assert r1.frames_written == r2.frames_written == 12 and r3.frames_written == 3
    a = _arrays(ref)
    _assert_identical(a, _arrays(tmp_path / "w1.zarr"))
    _assert_identical(a, _arrays(tmp_path / "w2.zarr"))


def _done_count(path: Path) -> int:
    # chunk files c.K (a temporary file of an unfinished write starts with a dot and is not counted)
    return sum(1 for g in ("sonar", "camera") if (path / g / "done").is_dir()
               for _ in (path / g / "done").glob("c.*"))


@pytest.fixture(scope="module")
def reference24(tmp_path_factory):
    """24 frames (16 sonar, 8 camera) rendered in this process, uninterrupted."""
    d = tmp_path_factory.mktemp("ref24")
    cfg = _write_config(d / "cfg.yaml", {**SMALL, "duration": 4.0})
    write_dataset(cfg, d / "ref.zarr", workers=0)
    return cfg, d / "ref.zarr"


def _cli(cfg: Path, out: Path, workers: int) -> list:
    return [sys.executable, "-c", "from optiacoustic.cli import main; main()", "dataset", str(cfg), "--out", str(out),
            "--workers", str(workers), "--quiet"]


_ENV = {**os.environ, "PYTHONPATH": f"{SRC}{os.pathsep}{os.environ.get('PYTHONPATH', '')}", "OAS_THREADS": "1"}


def test_kill_9_at_any_moment_then_resume(reference24, tmp_path):
    """SIGKILL the whole run at several moments, rerun the same command, compare frame by frame."""
    cfg, ref = reference24
    out = tmp_path / "killed.zarr"
    env = _ENV
    cmd = _cli(cfg, out, 0)
    total = 24
    kills = []
    # kill while the store is being created, then after a few frames, then mid-run
    for trigger in (lambda: (out / "zarr.json").exists(), lambda: _done_count(out) >= 3,
                    lambda: _done_count(out) >= 9, lambda: _done_count(out) >= 15):
        before = _done_count(out)
        proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        t0 = time.monotonic()
        while proc.poll() is None and not trigger() and time.monotonic() - t0 < 120:
            time.sleep(0.005)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        kills.append((before, _done_count(out)))
    done_at_kill = _done_count(out)
    assert 0 < done_at_kill < total, kills
    rep = write_dataset(cfg, out, workers=0)
    # finished frames were not recomputed, and every frame is now there exactly once
    assert sum(rep.skipped.values()) == done_at_kill
    assert sum(rep.skipped.values()) + rep.frames_written == total
    assert not list(out.rglob("*.partial")) and not list(out.rglob(".*.tmp-*"))
    _assert_identical(_arrays(ref), _arrays(out))


def _group(pgid: int) -> list:
    """Processes of process group ``pgid`` still alive (zombies excluded), as (pid, command line)."""
    import psutil

    alive = []
    for p in psutil.process_iter(["pid", "status", "cmdline"]):
        try:
            if os.getpgid(p.pid) == pgid and p.info["status"] != psutil.STATUS_ZOMBIE:
                alive.append((p.pid, " ".join(p.info["cmdline"] or [])[:100]))
        except (ProcessLookupError, psutil.Error):
            pass
    return alive


def _wait_group_gone(pgid: int, seconds: float = 60.0) -> list:
    t0 = time.monotonic()
    while _group(pgid) and time.monotonic() - t0 < seconds:
        time.sleep(0.1)
    return _group(pgid)


def test_kill_9_a_two_worker_dask_run_then_resume(reference24, tmp_path):
    """A real `oas dataset --workers 2` (local Dask cluster of 2 processes) SIGKILLed mid-way, then rerun.

    Only the command's own process is killed (scheduler, nannies and client live there): its
    worker processes must exit by themselves, the rerun must render exactly the frames that
    were not done, and the result must equal an uninterrupted run frame by frame.
    """
    cfg, ref = reference24
    out = tmp_path / "dask.zarr"
    total = 24
    proc = subprocess.Popen(_cli(cfg, out, 2), env=_ENV, start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        t0 = time.monotonic()
        while proc.poll() is None and _done_count(out) < 4 and time.monotonic() - t0 < 180:
            time.sleep(0.005)
        assert proc.poll() is None, f"the run ended before it could be killed: {proc.stderr.read().decode()[-2000:]}"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        # no stray Dask worker outlives the command that started it
        stray = _wait_group_gone(proc.pid)
        assert not stray, f"processes left after SIGKILL of the run: {stray}"
    finally:
        if _group(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
    done_at_kill = _done_count(out)  # counted once every writer is gone
    assert 0 < done_at_kill < total, done_at_kill
    finished = _chunk_stamps(out)  # every chunk file of the frames done at the kill
    rerun = subprocess.Popen(_cli(cfg, out, 2), env=_ENV, start_new_session=True, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        _, err = rerun.communicate(timeout=300)
    finally:
        stray = _wait_group_gone(rerun.pid, 10.0)
        if stray:
            os.killpg(rerun.pid, signal.SIGKILL)
    assert rerun.returncode == 0, err[-2000:]
    assert not stray, f"processes left after the run ended: {stray}"
    # finished frames were not recomputed (their files untouched); every frame is there once
    assert {k: v for k, v in _chunk_stamps(out).items() if k in finished} == finished
    assert _done_count(out) == total
    assert not list(out.rglob("*.partial")) and not list(out.rglob(".*.tmp-*"))
    _assert_identical(_arrays(ref), _arrays(out))


def _chunk_stamps(path: Path) -> dict:
    """(inode, mtime) of every chunk file of every frame whose done flag is set, by relative path.

    Chunk files are named ``c.K`` or ``c.K.0.0...`` (Zarr v3 default keys, "." separator).
    """
    root = zarr.open_group(str(path), mode="r")
    stamps = {}
    for sensor in ("sonar", "camera"):
        per_frame = [n for n, a in root[sensor].arrays() if n not in ("time", "pose") and a.chunks[0] == 1
                     and a.shape[0] == root[sensor]["time"].shape[0]]
        for k in np.flatnonzero(root[sensor]["done"][:]):
            files = [f for f in (path / sensor).glob(f"*/c.{k}") if f.is_file()] + \
                    [f for f in (path / sensor).glob(f"*/c.{k}.*") if f.is_file()]
            assert sorted(f.parent.name for f in files) == sorted(per_frame), (sensor, k, files)
            for f in files:
                st = f.stat()
                stamps[str(f.relative_to(path))] = (st.st_ino, st.st_mtime_ns)
    return stamps


def test_tasks_batch_small_frames_and_cover_every_frame_once(tmp_path):
    """Dask tasks: small frames batched (at most TASK_PIXELS a task), big ones alone, each frame once."""
    from optiacoustic.io.dataset import TASK_PIXELS, _batches

    seq = Sequence({**SMALL, "duration": 40.0}, base_dir=tmp_path)  # 160 sonar, 80 camera frames
    todo = sorted((float(seq.schedule(s).times[k]), s, k) for s in ("sonar", "camera") for k in range(len(seq.schedule(s))))
    tasks = _batches(seq, todo, n_workers=2)
    got = sorted((s, k) for s, ks in tasks for k in ks)
    assert got == sorted((s, k) for _, s, k in todo)  # every frame exactly once
    n = {"sonar": 160, "camera": 80}
    px = {"sonar": 96 * 48, "camera": 72 * 48}
    for sensor in ("sonar", "camera"):
        sizes = [len(ks) for t, ks in tasks if t == sensor]
        # the first task as big as allowed, sizes shrinking as frames run out, the last ones single frames
        assert sizes[0] == min(TASK_PIXELS // px[sensor], n[sensor] // 8), (sensor, sizes)
        assert sizes == sorted(sizes, reverse=True) and sizes[-8:] == [1] * 8, (sensor, sizes)
        assert max(sizes) * px[sensor] <= TASK_PIXELS
    firsts = [float(seq.schedule(s).times[ks[0]]) for s, ks in tasks]
    assert firsts == sorted(firsts)  # in time order
    # thesis-size frames (750 x 512 sonar, 600 x 400 camera): a few per task, never over TASK_PIXELS
    big = Sequence({**SMALL, "rig": "thesis", "duration": 40.0}, base_dir=tmp_path)
    todo = [(float(big.schedule(s).times[k]), s, k) for s in ("sonar", "camera") for k in range(len(big.schedule(s)))]
    tasks = _batches(big, todo, n_workers=1)
    assert sorted((s, k) for s, ks in tasks for k in ks) == sorted((s, k) for _, s, k in todo)
    assert max(len(ks) for s, ks in tasks if s == "sonar") == TASK_PIXELS // (750 * 512)
    assert max(len(ks) for s, ks in tasks if s == "camera") == TASK_PIXELS // (600 * 400)
