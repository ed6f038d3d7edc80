"""Datasets on Dask: frames/s of sonar + camera pairs with ground truth, on 1 and 2 workers.

Also the share of frame time spent writing, bytes per pair on disk, and the workers' memory
over a longer run. Sizes: ``OAS_BENCH_DATASET_PAIRS`` pairs for the speed runs (default 8),
``OAS_BENCH_DATASET_LONG`` pairs for the memory run (default 24; set 1000 for the issue's
long run).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

TITLE = "Datasets (oas dataset on Dask)"
DESCRIPTION = ("Thesis scene, thesis rig (BlueView P900-90 750 x 512, camera 600 x 400, Jerlov II), orbit; "
               "one sonar frame and one camera frame per second of trajectory (a pair), all ground truth. "
               "Local Dask clusters of worker processes with one thread each, started before the timing.")


def _config(pairs: int) -> dict:
    return {"scene": "thesis_scene1", "rig": "thesis", "water": "jerlov-II", "seed": 0, "duration": float(pairs),
            "rates": {"sonar": 1, "camera": 1},
            "trajectory": {"kind": "orbit", "center": [0, 0, 0], "radius": 6.0, "height": 2.0, "period": 120.0}}


def _du(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _cluster(n: int):
    from distributed import LocalCluster

    env = {"OAS_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
    return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None, env=env,
                        silence_logs=40)


def _run(cfg: dict, out: Path, cluster, sample_memory: bool = False):
    from distributed import Client

    from optiacoustic.io import write_dataset

    samples = []
    stop = threading.Event()

    def poll():
        import psutil

        with Client(cluster) as c:
            while not stop.is_set():
                rss = c.run(lambda: psutil.Process().memory_info().rss)
                samples.append((time.perf_counter(), sum(rss.values())))
                stop.wait(1.0)

    th = threading.Thread(target=poll, daemon=True) if sample_memory else None
    if th:
        th.start()
    t0 = time.perf_counter()
    rep = write_dataset(cfg, out, scheduler=cluster.scheduler_address)
    dt = time.perf_counter() - t0
    if th:
        stop.set()
        th.join()
    return rep, dt, samples


def run() -> list[dict]:
    pairs = int(os.environ.get("OAS_BENCH_DATASET_PAIRS", "8"))
    long_pairs = int(os.environ.get("OAS_BENCH_DATASET_LONG", "24"))
    tmp = Path(tempfile.mkdtemp(prefix="oas-bench-dataset-"))
    rows = []
    try:
        cfg = _config(pairs)
        rates = {}
        reps = {}
        for n in (1, 2):
            with _cluster(n) as cluster:
                # warm the workers (imports, BVH) on a one-pair dataset of the same scene
                _run(_config(1), tmp / f"warm{n}.zarr", cluster)
                rep, dt, _ = _run(cfg, tmp / f"w{n}.zarr", cluster)
            rates[n] = pairs / dt
            reps[n] = rep
        rows.append(dict(name="pairs/s, 1 worker", value=rates[1], unit="pairs/s", reference="", ratio=None,
                         note=f"{pairs} pairs, incl. writing"))
        rows.append(dict(name="pairs/s, 2 workers", value=rates[2], unit="pairs/s", reference="1 worker",
                         ratio=rates[2] / rates[1], note="target >= 1.7"))
        r = reps[2]
        rows.append(dict(name="share of frame time writing (2 workers)", value=100 * r.write_s / (r.render_s + r.write_s),
                         unit="%", reference="", ratio=None, note="target <= 10 %; Zarr v3, zstd 3, chunk per frame"))
        size = _du(tmp / "w2.zarr")
        raw = pairs * (750 * 512 * (4 * 4 + 2 + 1) + 400 * 600 * (12 + 4 + 2 + 12))
        rows.append(dict(name="bytes per pair on disk", value=size / pairs, unit="B", reference="uncompressed arrays",
                         ratio=size / raw, note="noisy float32 images compress little"))
        with _cluster(2) as cluster:
            _, dt, samples = _run(_config(long_pairs), tmp / "long.zarr", cluster, sample_memory=True)
        if len(samples) >= 4:
            early = max(m for _, m in samples[: max(2, len(samples) // 5)])
            late = max(m for _, m in samples[-max(2, len(samples) // 5):])
            rows.append(dict(name=f"worker memory, last fifth of a {long_pairs}-pair run", value=late / 2**20,
                             unit="MiB (2 workers)", reference="first fifth", ratio=late / early,
                             note="flat = ratio near 1"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
