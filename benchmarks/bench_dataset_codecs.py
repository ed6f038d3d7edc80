"""Dataset codecs: bytes and write time of one sonar + camera pair under each candidate codec.

The real arrays of a pair (thesis scene and rig, all ground truth, as ``oas dataset``
writes them: float32 images, intensity, depth, elevations and normals, int16 body ids,
bool shadow) are written as one Zarr v3 chunk each, the way a worker writes a frame
(``array[k] = frame``), through each codec. Time: median over repeated frames after a
warm-up, one thread; bytes: the chunk files on disk.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

TITLE = "Dataset codecs (bytes and write time per pair)"
DESCRIPTION = ("One sonar frame (750 x 512) and one camera frame (600 x 400) of the thesis scene with all ground "
               "truth, written as Zarr v3 chunks through each codec in one thread; ratio = bytes on disk / "
               "uncompressed bytes; the note gives the CPU time of the write per pair (process time, all threads: less "
               "disturbed by a busy machine than wall time), its ratio to zstd level 3, and the wall time.")

CODECS = {
    "none": lambda c: [],
    "zstd level 1": lambda c: [c.ZstdCodec(level=1)],
    "zstd level 2": lambda c: [c.ZstdCodec(level=2)],
    "zstd level 3": lambda c: [c.ZstdCodec(level=3)],
    "blosc lz4, byte shuffle": lambda c: [c.BloscCodec(cname="lz4", clevel=5, shuffle="shuffle")],
    "blosc lz4, bit shuffle": lambda c: [c.BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle")],
    "blosc zstd 1, byte shuffle": lambda c: [c.BloscCodec(cname="zstd", clevel=1, shuffle="shuffle")],
    "blosc zstd 1, bit shuffle": lambda c: [c.BloscCodec(cname="zstd", clevel=1, shuffle="bitshuffle")],
    "blosc zstd 3, byte shuffle": lambda c: [c.BloscCodec(cname="zstd", clevel=3, shuffle="shuffle")],
}
DATASET = "dataset's choice: blosc lz4, byte shuffle except ground-truth ids, elevations, shadow"


def _dataset_codec(name: str):
    """The compressor ``oas dataset`` gives array ``name`` (``sensor_array``)."""
    from optiacoustic.io.dataset import _frame_compressors

    sensor, array = name.split("_", 1)
    return _frame_compressors(sensor, array)


def _pair() -> dict:
    from optiacoustic.io.dataset import _frame_arrays, _layout
    from optiacoustic.simulation.sequence import Sequence

    seq = Sequence({"scene": "thesis_scene1", "rig": "thesis", "water": "jerlov-II", "seed": 0, "duration": 4.0,
                    "rates": {"sonar": 1, "camera": 1},
                    "trajectory": {"kind": "orbit", "radius": 6.0, "height": 2.0, "period": 120.0}})
    layout = _layout(seq, True)
    out = {}
    for sensor in ("sonar", "camera"):
        for name, a in _frame_arrays(seq, sensor, 2, True).items():
            out[f"{sensor}_{name}"] = np.asarray(a, dtype=layout[sensor][name][2])  # as stored
    return out


def measure(arrays: dict, repeat: int = 9) -> list[dict]:
    import zarr
    import zarr.codecs as codecs

    tmp = Path(tempfile.mkdtemp(prefix="oas-bench-codecs-"))
    res = []
    try:
        raw = sum(a.nbytes for a in arrays.values())
        stores = {}
        labels = list(CODECS) + [DATASET]
        for i, label in enumerate(labels):
            root = zarr.open_group(str(tmp / f"codec{i}"), mode="w", zarr_format=3)
            stores[label] = (Path(root.store.root), {
                n: root.create_array(n, shape=(repeat + 1,) + a.shape, chunks=(1,) + a.shape, dtype=a.dtype,
                                     compressors=_dataset_codec(n) if label == DATASET else CODECS[label](codecs)
                                     ).with_config({"write_empty_chunks": True})
                for n, a in arrays.items()})  # as the dataset's workers write: every chunk, no emptiness scan
        times = {label: [] for label in labels}
        cpu = {label: [] for label in labels}
        for k in range(repeat + 1):  # codecs interleaved, so that a busy moment of the machine hits them all
            for label, (_, z) in stores.items():
                t0, c0 = time.perf_counter(), time.process_time()
                for n, a in arrays.items():
                    z[n][k] = a
                times[label].append(time.perf_counter() - t0)
                cpu[label].append(time.process_time() - c0)  # all threads: zarr compresses in a pool
        for label, (folder, _) in stores.items():
            size = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file() and p.name != "zarr.json")
            res.append({"codec": label, "ms": 1e3 * float(np.median(times[label][1:])),
                        "cpu_ms": 1e3 * float(np.median(cpu[label][1:])), "bytes": size / (repeat + 1), "raw": raw})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return res


def write_paths(arrays: dict, repeat: int = 15) -> dict:
    """CPU and wall time per pair of the dataset's write path against Zarr's ``array[k] = frame``.

    Both write the pair's arrays (the dataset's codecs) and a ``done`` flag: through
    ``zarr.Array.__setitem__`` with Zarr's default chunk keys ``c/K/0/0`` (how the workers
    wrote before) and through :class:`optiacoustic.io._chunks.ChunkWriter` with keys
    ``c.K.0.0`` (how they write now; the same chunk bytes). Interleaved frame by frame, in a
    thread that is not the main one, as in a Dask worker (numcodecs' Blosc then runs in one thread).
    """
    import threading

    import zarr

    from optiacoustic.io._chunks import ChunkWriter

    tmp = Path(tempfile.mkdtemp(prefix="oas-bench-writepath-"))
    out = {}

    def work():
        arrs = {"zarr": {}, "writer": {}}
        for label, sep in (("zarr", "/"), ("writer", ".")):
            root = zarr.open_group(str(tmp / label), mode="w", zarr_format=3)
            keys = {"name": "default", "separator": sep}
            for n, a in list(arrays.items()) + [("done", np.bool_(True))]:
                z = root.create_array(n, shape=(repeat + 2,) + np.shape(a), chunks=(1,) + np.shape(a), dtype=a.dtype,
                                      compressors=_dataset_codec(n) if n != "done" else None,
                                      chunk_key_encoding=keys).with_config({"write_empty_chunks": True})
                arrs[label][n] = z if label == "zarr" else ChunkWriter.for_array(z)
        frames = list(arrays.items()) + [("done", True)]
        times = {label: ([], []) for label in arrs}
        for k in range(repeat + 2):
            for label, z in arrs.items():
                t0, c0 = time.perf_counter(), time.process_time()
                for n, a in frames:
                    if label == "zarr":
                        z[n][k] = a
                    else:
                        z[n].write(k, a)
                times[label][0].append(time.perf_counter() - t0)
                times[label][1].append(time.process_time() - c0)
        for label, (w, c) in times.items():
            out[label] = (1e3 * float(np.median(w[2:])), 1e3 * float(np.median(c[2:])))

    try:
        th = threading.Thread(target=work)
        th.start()
        th.join()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def run() -> list[dict]:
    pair = _pair()
    res = measure(pair)
    ref = next(r for r in res if r["codec"] == "zstd level 3")
    rows = [dict(name=r["codec"], value=r["bytes"] / 1e6, unit="MB/pair", reference="uncompressed",
                 ratio=r["bytes"] / r["raw"],
                 note=f"write {r['cpu_ms']:.0f} ms CPU/pair ({r['cpu_ms'] / ref['cpu_ms']:.2f} x zstd 3), "
                      f"{r['ms']:.0f} ms wall")
            for r in res]
    wp = write_paths(pair)
    (zw, zc), (ww, wc) = wp["zarr"], wp["writer"]
    rows.append(dict(name="dataset write path (ChunkWriter, c.K.0.0 keys), CPU per pair", value=wc, unit="ms",
                     reference="zarr array[k] = frame, c/K/0/0 keys", ratio=wc / zc,
                     note=f"the dataset's codecs, 10 arrays + done flag; Zarr {zc:.0f} ms CPU; "
                          f"wall {ww:.0f} ms vs {zw:.0f} ms; interleaved, one worker-like thread"))
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
