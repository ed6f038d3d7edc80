"""Datasets on Dask: frames/s of sonar + camera pairs with ground truth, on 1 and 2 workers.

Also the share of frame time spent writing, bytes per pair on disk, and the workers' memory
over a longer run. Sizes: ``OAS_BENCH_DATASET_PAIRS`` pairs for the speed runs (default 16),
``OAS_BENCH_DATASET_REPEAT`` speed runs per worker count (default 2), and
``OAS_BENCH_DATASET_LONG`` pairs for the memory run (default 24; the issue's long run is
1000: ``python benchmarks/bench_dataset.py --long 1000 --log mem.csv`` runs only that one).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

TITLE = "Datasets (oas dataset on Dask)"
DESCRIPTION = ("Thesis scene, thesis rig (BlueView P900-90 750 x 512, camera 600 x 400, Jerlov II), orbit; "
               "one sonar frame and one camera frame per second of trajectory (a pair), all ground truth. "
               "Local Dask clusters (`optiacoustic.io.local_cluster`: worker processes with one thread each) "
               "started and warmed up before the timing (imports, scene BVH, and every worker renders one frame of "
               "each sensor: the first frame of a simulator in a process costs 0.2-1 s more); 1 and 2 workers "
               "alternate and render the same frames; ratios are to 1 worker in the same run.")


def _config(pairs: int) -> dict:
    return {"scene": "thesis_scene1", "rig": "thesis", "water": "jerlov-II", "seed": 0, "duration": float(pairs),
            "rates": {"sonar": 1, "camera": 1},
            "trajectory": {"kind": "orbit", "center": [0, 0, 0], "radius": 6.0, "height": 2.0, "period": 120.0}}


def _du(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _rss():
    import psutil

    return psutil.Process().memory_info().rss


def _cpu() -> float:
    import psutil

    t = psutil.Process().cpu_times()
    return t.user + t.system


def warm(cluster, out: Path) -> None:
    """Write a one-pair dataset of the same scene, then have every worker render one frame of each sensor.

    The one-pair run alone would leave a worker that got only the sonar frame to pay the
    camera's first-frame cost inside the timing (and the other way round).
    """
    from distributed import Client

    from optiacoustic.io.dataset import warm_worker
    from optiacoustic.simulation.sequence import Sequence

    _run(_config(1), out, cluster)
    seq = Sequence(_config(1))
    with Client(cluster) as c:
        c.run(warm_worker, str(out.resolve()), seq.fingerprint(), seq.config.model_dump(mode="json"),
              str(seq.base_dir), True)


def cpu_split(cfg: dict, out: Path, cluster) -> tuple:
    """``(rep, seconds, worker CPU s, CPU s of this process)`` of one run: this process holds the
    scheduler, the nannies and the client of a local cluster, i.e. everything but the rendering."""
    from distributed import Client

    with Client(cluster) as c:
        w0, m0 = sum(c.run(_cpu).values()), _cpu()
        rep, dt, _ = _run(cfg, out, cluster)
        return rep, dt, sum(c.run(_cpu).values()) - w0, _cpu() - m0


def _run(cfg: dict, out: Path, cluster, sample_memory: bool = False, log=None):
    """One write_dataset on ``cluster``; with ``sample_memory``, each worker's RSS every second."""
    from distributed import Client

    from optiacoustic.io import write_dataset

    samples = []  # (seconds, frames done, {worker: rss bytes})
    state = {"done": 0, "total": 1}
    stop = threading.Event()
    t0 = time.perf_counter()

    def poll():
        with Client(cluster) as c:
            while not stop.is_set():
                row = (time.perf_counter() - t0, state["done"], c.run(_rss))
                samples.append(row)
                if log is not None:
                    log.write(f"{row[0]:.1f},{row[1]},{state['total']}," + ",".join(str(v) for v in row[2].values()) + "\n")
                    log.flush()
                stop.wait(1.0)

    def progress(done, total):
        state["done"], state["total"] = done, total

    th = threading.Thread(target=poll, daemon=True) if sample_memory else None
    if th:
        th.start()
    rep = write_dataset(cfg, out, scheduler=cluster.scheduler_address, progress=progress)
    dt = time.perf_counter() - t0
    if th:
        stop.set()
        th.join()
        samples.append((dt, state["done"], Client(cluster).run(_rss)))
    return rep, dt, samples


def memory_run(pairs: int, tmp: Path, log=None) -> dict:
    """A ``pairs``-pair run on 2 workers: the largest worker RSS at 10 % of the frames and at the end."""
    from optiacoustic.io import local_cluster

    with local_cluster(2) as cluster:
        warm(cluster, tmp / "warm-long.zarr")
        _, dt, samples = _run(_config(pairs), tmp / "long.zarr", cluster, sample_memory=True, log=log)
    total = 2 * pairs
    big = [(d, max(r.values())) for _, d, r in samples]  # the largest worker at each sample
    # RSS moves by a frame's arrays from one sample to the next: average over a tenth of the frames
    near10 = [m for d, m in big if 0.05 * total <= d <= 0.15 * total] or [next(m for d, m in big if d >= 0.1 * total)]
    last = [m for d, m in big if d >= 0.9 * total]
    return {"rss_10": float(np.mean(near10)), "rss_end": float(np.mean(last)), "rss_peak": max(m for _, m in big),
            "seconds": dt, "pairs": pairs}


def run() -> list[dict]:
    from optiacoustic.io import local_cluster

    pairs = int(os.environ.get("OAS_BENCH_DATASET_PAIRS", "16"))
    repeat = int(os.environ.get("OAS_BENCH_DATASET_REPEAT", "2"))
    long_pairs = int(os.environ.get("OAS_BENCH_DATASET_LONG", "24"))
    tmp = Path(tempfile.mkdtemp(prefix="oas-bench-dataset-"))
    rows = []
    try:
        cfg = _config(pairs)
        rates = {1: [], 2: []}
        reps_all = {1: [], 2: []}
        cpu = {1: [], 2: []}
        for i in range(repeat):
            for n in (1, 2):
                with local_cluster(n) as cluster:
                    warm(cluster, tmp / f"warm{n}-{i}.zarr")
                    rep, dt, cw, cm = cpu_split(cfg, tmp / f"w{n}-{i}.zarr", cluster)
                rates[n].append(pairs / dt)
                reps_all[n].append(rep)
                cpu[n].append((cw / pairs, cm / pairs))
        r1, r2 = float(np.median(rates[1])), float(np.median(rates[2]))
        ratios = ", ".join(f"{b / a:.2f}" for a, b in zip(rates[1], rates[2]))
        rows.append(dict(name="pairs/s, 1 worker", value=r1, unit="pairs/s", reference="", ratio=None,
                         note=f"{pairs} pairs, incl. writing; median of {repeat}"))
        rows.append(dict(name="pairs/s, 2 workers", value=r2, unit="pairs/s", reference="1 worker",
                         ratio=r2 / r1, note=f"target >= 1.7; each run's ratio: {ratios}"))
        cw2, cm2 = (float(np.median([c[j] for c in cpu[2]])) for j in (0, 1))
        rows.append(dict(name="CPU outside the workers per pair (2 workers)", value=1e3 * cm2, unit="ms",
                         reference="workers' CPU per pair", ratio=cm2 / cw2,
                         note=f"scheduler, nannies, client; workers {1e3 * cw2:.0f} ms CPU/pair; "
                              "with W workers on W cores, W x speed is reached only while this stays small"))
        cw1 = float(np.median([c[0] for c in cpu[1]]))
        rows.append(dict(name="workers' CPU per pair, 2 workers", value=1e3 * cw2, unit="ms", reference="1 worker",
                         ratio=cw2 / cw1, note=f"1 worker {1e3 * cw1:.0f} ms; above 1: the two workers slow each other "
                                               "down (shared caches and memory bandwidth), which no scheduling removes"))
        shares = {n: [100 * r.write_s / (r.render_s + r.write_s) for r in reps_all[n]] for n in (1, 2)}
        cpu_shares = [100 * r.write_cpu_s / (r.render_cpu_s + r.write_cpu_s) for r in reps_all[2]]
        rows.append(dict(name="share of frame time writing (2 workers)", value=float(np.median(shares[2])),
                         unit="%", reference="", ratio=None,
                         note="target <= 10 %; worker wall time in write / (render + write), each run: "
                              + ", ".join(f"{x:.1f}" for x in shares[2])
                              + "; 1 worker: " + ", ".join(f"{x:.1f}" for x in shares[1])
                              + "; CPU share (thread CPU time): " + ", ".join(f"{x:.1f}" for x in cpu_shares)
                              + "; the writes run in the worker's own thread after each render (no writer thread), "
                                "Zarr v3, Blosc LZ4 (shuffle except ground-truth runs), one chunk file per frame and array"))
        size = _du(tmp / f"w2-{repeat - 1}.zarr")
        raw = pairs * (750 * 512 * (4 * 4 + 2 + 1) + 400 * 600 * (12 + 4 + 2 + 12))
        rows.append(dict(name="bytes per pair on disk", value=size / pairs, unit="B", reference="uncompressed arrays",
                         ratio=size / raw, note="noisy float32 images compress little"))
        m = memory_run(long_pairs, tmp)
        rows.append(dict(name=f"worker RSS over the last 10 % of a {long_pairs}-pair run", value=m["rss_end"] / 2**20,
                         unit="MiB (largest worker)", reference="same over 5-15 % of the frames",
                         ratio=m["rss_end"] / m["rss_10"],
                         note=f"flat = ratio near 1; peak {m['rss_peak'] / 2**20:.0f} MiB"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rows


if __name__ == "__main__":
    if "--long" in sys.argv:
        n = int(sys.argv[sys.argv.index("--long") + 1])
        log_path = sys.argv[sys.argv.index("--log") + 1] if "--log" in sys.argv else None
        tmp = Path(tempfile.mkdtemp(prefix="oas-bench-dataset-long-"))
        try:
            with open(log_path, "w") if log_path else open(os.devnull, "w") as log:
                log.write("seconds,frames_done,frames_total,rss_worker_bytes...\n")
                m = memory_run(n, tmp, log=log)
            print({k: (v / 2**20 if k.startswith("rss") else v) for k, v in m.items()}, "(rss in MiB)")
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    else:
        for row in run():
            print(row)
