"""Datasets: synchronised sonar + camera sequences with ground truth, in Zarr v3, on Dask.

Layout (docs/datasets.md): groups ``sonar`` and ``camera``, one chunk per frame,
compressed (Blosc LZ4, byte shuffle), each array with named dimensions (Zarr v3
``dimension_names``), so that plain ``zarr`` and ``xarray`` both read it. Times and poses
are known before any frame is rendered and are written when the store is created; a
frame's arrays are written by the worker that rendered it, straight into the store (one
chunk per frame, so workers never write the same file), then its flag in ``done``
(written last); only a few numbers per task travel back to the client. A rerun of the same
command renders only the frames whose flag is not set, so a run killed at any moment
(SIGKILL included) resumes without a missing, duplicated or half-written frame: every
chunk is written to a temporary file and renamed (by :mod:`._chunks` in the worker's own
thread, the same bytes as Zarr's writer, or by Zarr's local store).

A frame's noise depends only on ``(seed, sensor, frame index)``: the output is the same
whatever the number of workers and the order they finish in.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._atomic import jsonable as _jsonable

__all__ = ["write_dataset", "open_dataset", "local_cluster", "DatasetReport", "DatasetError", "FORMAT",
           "FORMAT_VERSION"]

FORMAT = "optiacoustic-dataset"
FORMAT_VERSION = 1
_ATTR = "optiacoustic"


class DatasetError(ValueError):
    """A dataset cannot be written or read (names the path and the reason)."""


# --------------------------------------------------------------------------- layout
def _layout(seq, ground_truth: bool) -> dict:
    """``{group: {array: (frame shape, dims, dtype, fill)}}`` of the per-frame arrays."""
    out = {}
    if len(seq.sonar):
        s = seq.rig.sonar
        img = (s.n_bins, s.n_beams)
        dims = ("bin", "beam")
        out["sonar"] = {"image": (img, dims, "float32", np.nan), "intensity": (img, dims, "float32", np.nan)}
        if ground_truth:
            out["sonar"].update(body=(img, dims, "int16", -1), elevation_min=(img, dims, "float32", np.nan),
                                elevation_max=(img, dims, "float32", np.nan), shadow=(img, dims, "bool", False))
    if len(seq.camera):
        c = seq.rig.camera
        hw, dims = (c.height, c.width), ("row", "col")
        out["camera"] = {"image": (hw + (3,), dims + ("channel",), "float32", np.nan)}
        if ground_truth:
            out["camera"].update(depth=(hw, dims, "float32", np.nan), body=(hw, dims, "int16", -1),
                                 normal=(hw + (3,), dims + ("xyz",), "float32", np.nan))
    return out


def _frame_arrays(seq, sensor: str, k: int, ground_truth: bool) -> dict:
    if sensor == "sonar":
        f = seq.render_sonar(k)
        a = {"image": f.image, "intensity": f.intensity}
        if ground_truth:
            gt = f.ground_truth
            a.update(body=gt.body, elevation_min=gt.elevation_min, elevation_max=gt.elevation_max, shadow=gt.shadow)
    else:
        f = seq.render_camera(k)
        a = {"image": f.image}
        if ground_truth:
            a.update(depth=f.depth, body=f.body, normal=f.normal)
    return a


def _metadata(seq) -> dict:
    from .. import __version__
    from ..sonar.frame import spec_to_dict

    rig, cam, w = seq.rig, seq.rig.camera, seq.water
    canonical = seq.canonical()
    return _jsonable({
        "format": FORMAT, "format_version": FORMAT_VERSION, "package_version": __version__,
        "fingerprint": seq.fingerprint(), "seed": seq.config.seed,
        "config": canonical["config"], "scene": canonical["scene"], "body_names": list(seq.scene.body_names()),
        "sonar_spec": spec_to_dict(rig.sonar) if rig.sonar is not None else None,
        "camera": {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width, "height": cam.height,
                   "dist": list(cam.dist), "K": cam.K},
        "rig": {"R_sonar_from_camera": rig.R, "t_camera_in_sonar": rig.t},
        "water": {"name": w.name, "a": list(w.a), "b": list(w.b), "c": w.c, "source": w.source},
        "conventions": "metres, radians, seconds; poses map sensor to world (P_world = R P_sensor + t) as 4x4; "
                       "sonar axes X right, Y forward, Z up; camera axes OpenCV (X right, Y down, Z forward); "
                       "rig P_sonar = R P_camera + t; sonar images (n_bins, n_beams), near to far, left to right",
    })


def _compressors(shuffle: str = "shuffle"):
    """Blosc LZ4 with byte shuffle, then a CRC-32C of the compressed chunk (Zarr v3's ``crc32c`` codec).

    Blosc LZ4: per pair as small as zstd level 3 and the fastest to write, chosen from
    benchmarks/bench_dataset_codecs.py on the real frame arrays (docs/benchmarks.md). Blosc keeps
    no checksum of its own: a flipped bit in a chunk decoded silently to wrong numbers, and a
    damaged header could make c-blosc read past the chunk. With the CRC (4 bytes a chunk, checked
    by Zarr, xarray and our exporter before Blosc sees the bytes) any damage is an error naming the
    chunk. Stores written before it (no ``crc32c`` in their codecs) read as before.
    """
    from zarr.codecs import BloscCodec, Crc32cCodec

    return [BloscCodec(cname="lz4", clevel=5, shuffle=shuffle), Crc32cCodec()]


# Ground-truth arrays made of runs of equal values (body ids, elevation spans that are NaN
# wherever nothing echoes, the shadow mask) compress better and twice as fast without the
# byte shuffle (measured on the thesis pair, bench_dataset_codecs.py: elevation_min 8 % of
# raw in 0.7 ms against 15 % in 1.2 ms with it); images, intensity, depth and normals
# compress better with it.
_NO_SHUFFLE = {("sonar", "body"), ("sonar", "elevation_min"), ("sonar", "elevation_max"), ("sonar", "shadow"),
               ("camera", "body")}


def _checksum():
    """The CRC-32C alone (arrays of one byte a frame, the ``done`` flags: nothing to compress)."""
    from zarr.codecs import Crc32cCodec

    return [Crc32cCodec()]


def _frame_compressors(sensor: str, name: str):
    """The compressor of per-frame array ``name`` of ``sensor`` (Blosc LZ4, shuffle or not)."""
    return _compressors("noshuffle" if (sensor, name) in _NO_SHUFFLE else "shuffle")


# Chunk files of the per-frame arrays are named ``c.K.0.0`` in the array's folder (Zarr v3's
# default chunk key encoding with the "." separator) rather than ``c/K/0/0``: with "/" every
# frame made two or three new folders per array, which cost as much as the compression.
_CHUNK_KEYS = {"name": "default", "separator": "."}


def _create(path: Path, seq, ground_truth: bool):
    import zarr

    root = zarr.open_group(str(path), mode="w", zarr_format=3)
    for sensor, arrays in _layout(seq, ground_truth).items():
        g = root.create_group(sensor)
        sched = seq.schedule(sensor)
        n = len(sched)
        for name, (shape, dims, dtype, fill) in arrays.items():
            g.create_array(name, shape=(n,) + shape, chunks=(1,) + shape, dtype=dtype, fill_value=fill,
                           compressors=_frame_compressors(sensor, name), dimension_names=("frame",) + dims,
                           chunk_key_encoding=_CHUNK_KEYS)
        g.create_array("time", data=sched.times.astype("float64"), chunks=(max(n, 1),), compressors=_compressors(),
                       dimension_names=("frame",), attributes={"units": "s"})
        g.create_array("pose", data=sched.poses.astype("float64"), chunks=(max(n, 1), 4, 4), compressors=_compressors(),
                       dimension_names=("frame", "pose_row", "pose_col"),
                       attributes={"description": f"{sensor} to world, P_world = T[:3,:3] P_{sensor} + T[:3,3]"})
        g.create_array("done", shape=(n,), chunks=(1,), dtype="bool", fill_value=False, dimension_names=("frame",),
                       compressors=_checksum(), chunk_key_encoding=_CHUNK_KEYS,  # one byte a frame: its CRC alone
                       attributes={"description": "frame k is complete (written after all its arrays)"})
        if sensor == "sonar":
            g.create_array("ranges", data=seq.rig.sonar.ranges.astype("float64"), dimension_names=("bin",),
                           compressors=_compressors(),
                           attributes={"units": "m", "description": "range-bin centres"})
            g.create_array("azimuths", data=seq.rig.sonar.azimuths.astype("float64"), dimension_names=("beam",),
                           compressors=_compressors(),
                           attributes={"units": "rad", "description": "beam centres, positive to starboard"})
        else:
            g.create_array("K", data=seq.rig.camera.K.astype("float64"), dimension_names=("k_row", "k_col"),
                           compressors=_compressors())
    meta = _metadata(seq)
    meta["layout_complete"] = True
    root.attrs[_ATTR] = meta  # last: a store without it is an interrupted creation
    return root


def _config_difference(old: dict, new: dict, prefix: str = "") -> str:
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k, "<absent>"), new.get(k, "<absent>")
        if isinstance(a, dict) and isinstance(b, dict):
            d = _config_difference(a, b, f"{prefix}{k}.")
            if d:
                return d
        elif a != b:
            return f"field '{prefix}{k}' was {a!r}, now {b!r}"
    return ""


def _open_or_create(path: Path, seq, ground_truth: bool):
    import zarr

    if path.exists() and not path.is_dir():
        raise DatasetError(f"{path}: exists and is not a folder")
    if not path.exists() or not any(path.iterdir()):
        return _create(path, seq, ground_truth), False
    if not (path / "zarr.json").is_file():
        raise DatasetError(f"{path}: exists and is not a Zarr store; refusing to write into it")
    try:
        root = zarr.open_group(str(path), mode="r+")
        meta = dict(root.attrs).get(_ATTR)
    except Exception as exc:  # noqa: BLE001 - any unreadable root means the same to the user
        raise DatasetError(f"{path}: cannot open as a Zarr group: {exc}") from None
    if meta is None:
        if any(root.group_keys()) or any(root.array_keys()):
            # our creation writes the attribute last: groups without it were an interrupted creation
            if set(root.group_keys()) <= {"sonar", "camera"} and not any(root.array_keys()):
                return _create(path, seq, ground_truth), False
            raise DatasetError(f"{path}: is a Zarr store but not an optiacoustic dataset; refusing to write into it")
        return _create(path, seq, ground_truth), False
    if meta.get("fingerprint") != seq.fingerprint():
        new = _jsonable(seq.canonical())
        diff = _config_difference({"config": meta.get("config", {}), "scene": meta.get("scene", {})}, new)
        raise DatasetError(f"{path}: was written from a different configuration ({diff or 'scene differs'}); "
                           "use a new output path or delete it")
    return root, True


def _remove_partials(path: Path) -> int:
    """Delete temporary chunk files left by a killed writer, never read.

    Zarr's own (``*.partial``) and those of :mod:`optiacoustic._atomic` (``.NAME.tmp-*``).
    """
    n = 0
    for pattern in ("*.partial", ".*.tmp-*"):
        for p in path.rglob(pattern):
            try:
                p.unlink()
                n += 1
            except OSError:
                pass
    return n


# --------------------------------------------------------------------------- frames (run on a worker)
_SEQUENCES: dict = {}  # fingerprint -> Sequence, per worker process
_SCENES: dict = {}  # SHA-256 of the canonical scene -> Scene (and so its BVH), per worker process
_STORES: dict = {}  # (output path, fingerprint) -> {sensor: {array name: zarr.Array}}, per worker process
BUILDS = {"sequences": 0, "scenes": 0}  # how many times this process resolved a config / a scene (tests read it)
_CONTEXT_LOCK = threading.Lock()  # workers of an external cluster may run several threads


def _context(path: str, fingerprint: str, config: dict, base_dir: str):
    """This process's Sequence (keyed by the configuration's fingerprint) and open arrays.

    The scene is shared by every configuration of the same scene (keyed by its canonical
    content), so the scene's ray caster (its BVH) is built once per worker and reused
    for every later frame, of this output or of another output of the same scene.
    """
    with _CONTEXT_LOCK:
        return _context_locked(path, fingerprint, config, base_dir)


def _keep_latest(cache: dict, n: int) -> None:
    while len(cache) >= n:  # a worker keeps the latest few: memory stays flat over many outputs
        cache.pop(next(iter(cache)))


def _context_locked(path: str, fingerprint: str, config: dict, base_dir: str):
    import hashlib
    import json

    import zarr

    from ..simulation.sequence import SENSORS, Sequence

    seq = _SEQUENCES.get(fingerprint)
    if seq is None:
        seq = Sequence(config, base_dir=base_dir)
        canonical = seq.canonical()
        if hashlib.sha256(json.dumps(canonical, sort_keys=True).encode()).hexdigest() != fingerprint:
            raise DatasetError(f"{path}: the worker resolved a different scene or config than the client "
                               "(a relative path that differs between machines?)")
        scene_key = hashlib.sha256(json.dumps(canonical["scene"], sort_keys=True).encode()).hexdigest()
        if scene_key in _SCENES:
            seq.scene = _SCENES[scene_key]  # the same content: reuse its ray caster
        else:
            _keep_latest(_SCENES, 2)
            _SCENES[scene_key] = seq.scene
            BUILDS["scenes"] += 1
        _keep_latest(_SEQUENCES, 2)
        _SEQUENCES[fingerprint] = seq
        BUILDS["sequences"] += 1
    arrays = _STORES.get((path, fingerprint))
    if arrays is None:
        root = zarr.open_group(path, mode="r+")
        # every chunk is written, even one equal to the fill value: no scan of each frame for
        # "empty", and a done frame always has all its chunk files
        arrays = {s: {n: _FrameArray(a.with_config({"write_empty_chunks": True})) for n, a in root[s].arrays()}
                  for s in SENSORS if s in root}
        _keep_latest(_STORES, 4)
        _STORES[(path, fingerprint)] = arrays
    return seq, arrays


class _FrameArray:
    """One per-frame array of the store: ``fa[k] = frame`` writes chunk ``k``.

    Through a :class:`~optiacoustic.io._chunks.ChunkWriter` (the same bytes as Zarr, in
    this thread, without Zarr's per-call thread hand-offs) where the array allows it,
    otherwise through Zarr.
    """

    def __init__(self, arr):
        from ._chunks import ChunkWriter

        self.array = arr
        self.writer = ChunkWriter.for_array(arr) if len(arr.shape) and arr.chunks[0] == 1 else None

    def __setitem__(self, k: int, value) -> None:
        if self.writer is not None:
            self.writer.write(k, value)
        else:
            self.array[k] = value


def warm_worker(path: str, fingerprint: str, config: dict, base_dir: str, render: bool = False) -> int:
    """Resolve the configuration, open the store and build the scene's ray caster on this process.

    Called on every worker before the first frame, so that workers warm up in parallel
    and the first frames are not delayed by it. With ``render``, also render (not write)
    the first frame of each sensor, so that the one-time costs of each simulator (loading
    compiled kernels, first-call caches: a few tenths of a second) are paid too; benchmarks
    use it to time every worker count in the same state. Returns this process's id.
    """
    seq, _ = _context(path, fingerprint, config, base_dir)
    seq.prepare()
    if render:
        for sensor in ("sonar", "camera"):
            if len(seq.schedule(sensor)):
                _frame_arrays(seq, sensor, 0, True)
    return os.getpid()


def write_frames(path: str, fingerprint: str, config: dict, base_dir: str, sensor: str, ks: list,
                 ground_truth: bool) -> tuple:
    """Render frames ``ks`` of ``sensor`` and write each where the worker runs; its ``done`` flag last.

    Only this small record travels back to the client: ``(sensor, frames, render_s,
    write_s, render_cpu_s, write_cpu_s)``: wall and CPU seconds (CPU of this thread, where
    both happen) spent rendering and writing.
    """
    seq, arrays = _context(path, fingerprint, config, base_dir)
    g = arrays[sensor]
    render_s = write_s = render_cpu = write_cpu = 0.0
    for k in ks:
        t0, c0 = time.perf_counter(), time.thread_time()
        frame = _frame_arrays(seq, sensor, int(k), ground_truth)
        t1, c1 = time.perf_counter(), time.thread_time()
        for name, a in frame.items():
            g[name][int(k)] = a
        g["done"][int(k)] = True  # last: the frame is complete
        render_s += t1 - t0
        write_s += time.perf_counter() - t1
        render_cpu += c1 - c0
        write_cpu += time.thread_time() - c1
    return sensor, len(ks), render_s, write_s, render_cpu, write_cpu


def write_frame(path: str, fingerprint: str, config: dict, base_dir: str, sensor: str, k: int,
                ground_truth: bool) -> tuple:
    """Render frame ``k`` of ``sensor`` and write it; the ``done`` flag last (see :func:`write_frames`)."""
    return write_frames(path, fingerprint, config, base_dir, sensor, [k], ground_truth)


def _batches(seq, todo: list, n_workers: int) -> list:
    """Group the frames to do into tasks: small frames in batches, big frames one per task.

    A task holds at most :data:`TASK_PIXELS` pixels (at least one frame), fewer as the
    frames of a sensor run out (guided self-scheduling): a task holds at most the frames
    left of its sensor divided by ``4 * n_workers``, so the first tasks are big (few
    scheduler round trips) and the last ones single frames, which the workers finish
    together. ``todo`` is ``[(time, sensor, k)]``; returns ``[(sensor, [k, ...])]`` in time order.
    """
    rig = seq.rig
    pixels = {"sonar": rig.sonar.n_bins * rig.sonar.n_beams if rig.sonar is not None else 1,
              "camera": rig.camera.width * rig.camera.height}
    out = []
    for sensor in ("sonar", "camera"):
        items = [(t, k) for t, s, k in todo if s == sensor]
        cap = max(1, TASK_PIXELS // max(pixels[sensor], 1))
        i = 0
        while i < len(items):
            size = max(1, min(cap, (len(items) - i) // (4 * max(n_workers, 1))))
            out.append((items[i][0], sensor, [k for _, k in items[i:i + size]]))
            i += size
    out.sort(key=lambda b: (b[0], b[1]))
    return [(s, ks) for _, s, ks in out]


TASK_PIXELS = 1_000_000  # pixels of frames per Dask task at most (2 frames of a 750 x 512 sonar, 4 of a 600 x 400 camera)


# --------------------------------------------------------------------------- the run
@dataclass(frozen=True)
class DatasetReport:
    """What a run of :func:`write_dataset` did.

    ``written`` frames rendered now per sensor, ``skipped`` frames found done,
    ``elapsed`` wall time (s), ``render_s`` / ``write_s`` wall time summed over frames (s),
    ``workers`` the number of Dask workers (0: in this process), ``render_cpu_s`` /
    ``write_cpu_s`` CPU time of the rendering / writing thread summed over frames (s).
    """

    path: Path
    written: dict
    skipped: dict
    elapsed: float
    render_s: float
    write_s: float
    workers: int
    render_cpu_s: float = 0.0
    write_cpu_s: float = 0.0

    @property
    def frames_written(self) -> int:
        return sum(self.written.values())


# Dask's background work that a local rendering cluster does not need: each worker's
# statistical profiler samples its stack every 10 ms, the memory monitors poll every 100 ms,
# every event loop (scheduler, nannies, client, each worker) checks its own health every
# 20 ms (measured: 25 ms CPU per second in the scheduler's process and 13 ms per second in
# each idle worker; 7 and 4 with a 1 s tick). On a machine with as many workers as cores
# that CPU comes out of the rendering. One task per worker thread at a time
# (worker-saturation 1.0, Dask's default is 1.1, i.e. 2 for a one-thread worker): a
# worker never holds a queued task while another one is idle at the end of a run.
#
# Dask's nannies also start their workers with MALLOC_TRIM_THRESHOLD_=65536, which makes
# glibc hand every freed block over 64 KiB back to the system and switches off its
# adaptive mmap threshold: every large temporary of a render is then a fresh mmap whose
# pages the kernel zeroes on first touch. Measured on the thesis pair in one thread: sonar
# 43 -> 76 ms, camera 120 -> 170 ms CPU per frame with it. Our workers run without it
# (glibc's defaults; a user's own MALLOC_TRIM_THRESHOLD_ in the environment still applies);
# their memory stays flat without it (docs/benchmarks.md, worker RSS over a long run).
_LEAN_DASK = {"distributed.worker.profile.enabled": False, "distributed.worker.memory.monitor-interval": "1s",
              "distributed.admin.system-monitor.interval": "2s", "distributed.admin.tick.interval": "1s",
              "distributed.scheduler.worker-saturation": 1.0,
              "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


def local_cluster(n: int):
    """A local Dask cluster for datasets: ``n`` worker processes of one thread each, lean settings."""
    import dask
    from distributed import LocalCluster

    env = {"OAS_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    with dask.config.set(_LEAN_DASK):  # for the scheduler, made here; each nanny passes `config` to its worker
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                            env=env, silence_logs=40, config=dict(_LEAN_DASK))


def _default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def write_dataset(config, out, *, workers: int | None = None, scheduler: str | None = None, progress=None,
                  base_dir=None) -> DatasetReport:
    """Render a configured sequence into a Zarr v3 dataset, resuming an interrupted one.

    Parameters
    ----------
    config : path of a YAML/JSON config, mapping, or SequenceConfig
        See docs/datasets.md.
    out : path
        The ``.zarr`` folder. If it holds a dataset of the same configuration, only the
        frames not yet done are rendered; of another configuration, a
        :class:`DatasetError` is raised and nothing is written.
    workers : int, optional
        Processes of a local Dask cluster (default: all usable cores); 0 renders in
        this process without Dask.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``); ``workers`` is then
        ignored. Its workers must see ``out`` and any scene or rig files at the same paths.
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame; the CLI draws a bar with it.
    base_dir : path, optional
        Folder for relative paths of a mapping config.

    Returns
    -------
    DatasetReport
    """
    from ..simulation.sequence import SENSORS, Sequence

    t_start = time.perf_counter()
    seq = Sequence(config, base_dir=base_dir)
    path = Path(out).resolve()
    gt = seq.config.ground_truth
    root, resumed = _open_or_create(path, seq, gt)
    if resumed:
        _remove_partials(path)
    todo, skipped = [], {}
    for sensor in SENSORS:
        n = len(seq.schedule(sensor))
        if not n:
            continue
        try:
            done = root[sensor]["done"][:] if resumed else np.zeros(n, bool)
        except ValueError as exc:  # a damaged flag chunk (its CRC, or its bytes): name it, do not guess
            raise DatasetError(f"{path}: array {sensor}/done cannot be read ({' '.join(str(exc).split())[:200]}); "
                               "the dataset is damaged: remove it or the damaged flag's chunk to render that "
                               "frame again") from None
        skipped[sensor] = int(done.sum())
        todo += [(float(seq.schedule(sensor).times[k]), sensor, int(k)) for k in np.flatnonzero(~done)]
    todo.sort()  # in time order, sensors interleaved
    total = len(todo)
    written = {s: 0 for s in skipped}
    args = (str(path), seq.fingerprint(), seq.config.model_dump(mode="json"), str(seq.base_dir))
    times = np.zeros(4)  # render_s, write_s, render_cpu_s, write_cpu_s summed over frames
    n_workers = 0
    n_done = 0

    def _count(sensor, n):
        nonlocal n_done
        written[sensor] += n
        n_done += n
        if progress is not None:
            progress(n_done, total)

    if progress is not None:
        progress(0, total)
    if total and workers == 0 and scheduler is None:
        for _, sensor, k in todo:
            res = write_frames(*args, sensor, [k], gt)
            times += res[2:]
            _count(sensor, 1)
    elif total:
        from distributed import Client, as_completed

        cluster = None
        if scheduler is None:
            cluster = local_cluster(workers or _default_workers())
        try:
            with Client(scheduler if scheduler else cluster) as client:
                n_workers = len(client.scheduler_info().get("workers", {})) or (workers or 0)
                client.run(warm_worker, *args)  # every worker resolves the scene and builds its BVH, in parallel
                tasks = {}
                for sensor, ks in _batches(seq, todo, n_workers):
                    fut = client.submit(write_frames, *args, sensor, ks, gt, pure=False,
                                        key=f"oas-{sensor}-{ks[0]}-{ks[-1]}-{args[1][:12]}")
                    tasks[fut.key] = (fut, sensor, len(ks))
                # the frames are in the store when a task finishes: count them from what the client
                # knows, and fetch the tasks' few numbers once at the end (one round trip, not one a task)
                for fut in as_completed([f for f, _, _ in tasks.values()]):
                    if fut.status != "finished":
                        fut.result()  # raises the worker's error
                    _count(*tasks[fut.key][1:])
                for res in client.gather([f for f, _, _ in tasks.values()]):
                    times += res[2:]
                del tasks
        finally:
            if cluster is not None:
                cluster.close()
    render_s, write_s, render_cpu, write_cpu = (float(x) for x in times)
    return DatasetReport(path, written, skipped, time.perf_counter() - t_start, render_s, write_s, n_workers,
                         render_cpu, write_cpu)


# --------------------------------------------------------------------------- reading
def open_dataset(path):
    """A dataset as an :class:`xarray.DataTree` with named dimensions (lazy, nothing loaded).

    Children ``sonar`` (dims ``frame``, ``bin``, ``beam``; coordinates ``time``,
    ``ranges``, ``azimuths``) and ``camera`` (dims ``frame``, ``row``, ``col``,
    ``channel``; coordinate ``time``); the metadata is in ``tree.attrs["optiacoustic"]``.
    Frames whose ``done`` flag is False hold fill values (NaN, -1).
    """
    import xarray as xr
    import zarr

    p = Path(path)
    if not (p / "zarr.json").is_file():
        raise DatasetError(f"{p}: not a Zarr store (no zarr.json)")
    root = zarr.open_group(str(p), mode="r")
    if _ATTR not in root.attrs:
        raise DatasetError(f"{p}: not an optiacoustic dataset (no '{_ATTR}' attribute)")
    tree = xr.open_datatree(str(p), engine="zarr", consolidated=False, mask_and_scale=False, decode_times=False,
                            chunks={})
    for name in ("sonar", "camera"):
        if name in tree.children:
            ds = tree[name].to_dataset()
            coords = [c for c in ("time", "ranges", "azimuths") if c in ds]
            tree[name] = xr.DataTree(ds.set_coords(coords))
    return tree
