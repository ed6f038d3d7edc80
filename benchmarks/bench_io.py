"""Reader throughput against a raw read() of the same bytes, and memory while iterating a long log."""

from __future__ import annotations

import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

TITLE = "Readers (ARIS, Oculus, ROS 2 MCAP bag)"
DESCRIPTION = (
    "Long logs made by repeating the real samples (tests/data): an ARIS file of 300 frames (48 x 2000), "
    "an Oculus stream of 200 pings (256 x 703, 8-bit) and a rosbag2 MCAP bag of 200 ProjectedSonarImage "
    "messages written by rosbags (uint8 256 x 703). Each reader iterates every frame to linear float32 "
    "intensity (MeasuredSonarFrame with raw, image, spec). Reference: `read()` of the same file in chunks "
    "of one frame, in the same run (ratio = reader time / raw read time; the OS cache is warm for both). "
    "Memory: tracemalloc peak of Python allocations while iterating the whole log, against the same for "
    "a tenth of it (flat means the reader does not hold frames)."
)

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"


def _make_logs(tmp: Path) -> dict:
    aris = (DATA / "aris" / "sample.aris").read_bytes()
    (tmp / "long.aris").write_bytes(aris[:1024] + aris[1024:] * 50)
    (tmp / "short.aris").write_bytes(aris[:1024] + aris[1024:] * 5)
    ping = (DATA / "oculus" / "one_ping_8bit.raw").read_bytes()
    (tmp / "long.oculus").write_bytes(ping * 200)

    from optiacoustic.io import open_sonar
    from optiacoustic.io.rosmsg import PROJECTED_SONAR_IMAGE, dtype_code, typestore
    from rosbags.rosbag2 import StoragePlugin, Writer

    f = open_sonar(DATA / "oculus" / "one_ping_8bit.raw")[0]
    ts = typestore(2)
    T = ts.types
    V = T["geometry_msgs/msg/Vector3"]
    msg = T[PROJECTED_SONAR_IMAGE](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="s"),
        ping_info=T["marine_acoustic_msgs/msg/PingInfo"](frequency=2.1e6, sound_speed=1500.0,
                                                          tx_beamwidths=np.zeros(0, np.float32),
                                                          rx_beamwidths=np.zeros(0, np.float32)),
        beam_directions=[V(x=0.0, y=-np.sin(a), z=np.cos(a)) for a in f.azimuths],
        ranges=f.ranges.astype(np.float32),
        image=T["marine_acoustic_msgs/msg/SonarImageData"](is_bigendian=False, dtype=dtype_code(np.uint8),
                                                            beam_count=f.raw.shape[1], data=f.raw.ravel()))
    raw = ts.serialize_cdr(msg, PROJECTED_SONAR_IMAGE)
    with Writer(tmp / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/sonar", PROJECTED_SONAR_IMAGE, typestore=ts)
        for k in range(200):
            w.write(c, int(1.7e18) + k * 100_000_000, raw)
    mcap = next((tmp / "bag").glob("*.mcap"))
    return {"ARIS": (tmp / "long.aris", 1024 + 48 * 2000), "Oculus": (tmp / "long.oculus", len(ping)),
            "MCAP bag": (mcap, len(raw))}


def _raw_read(path: Path, chunk: int) -> float:
    t0 = time.perf_counter()
    with open(path, "rb") as fh:
        while fh.read(chunk):
            pass
    return time.perf_counter() - t0


def _iterate(path: Path) -> tuple[float, int]:
    from optiacoustic.io import open_sonar

    t0 = time.perf_counter()
    n = 0
    with open_sonar(path) as seq:
        for f in seq:
            n += 1
    return time.perf_counter() - t0, n


def _peak_mb(path: Path) -> float:
    from optiacoustic.io import open_sonar

    tracemalloc.start()
    with open_sonar(path) as seq:
        for f in seq:
            pass
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / 1e6


def run() -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as d:
        logs = _make_logs(Path(d))
        for name, (path, chunk) in logs.items():
            size = path.stat().st_size
            _iterate(path)  # warm the OS cache and the imports
            reader = min(_iterate(path)[0] for _ in range(3))
            n = _iterate(path)[1]
            ref = min(_raw_read(path, chunk) for _ in range(3))
            rows.append(dict(name=f"{name}: frames per second", value=n / reader, unit="frames/s",
                             reference="raw read() of the same bytes", ratio=reader / ref,
                             note=f"{n} frames, {size / 1e6:.1f} MB; ratio = reader time / read time"))
            rows.append(dict(name=f"{name}: throughput", value=size / reader / 1e6, unit="MB/s",
                             reference="raw read()", ratio=(size / reader) / (size / ref),
                             note=f"raw read() {size / ref / 1e6:.0f} MB/s"))
        long_peak = _peak_mb(logs["ARIS"][0])
        short_peak = _peak_mb(Path(d) / "short.aris")
        rows.append(dict(name="ARIS 300 frames: peak Python memory while iterating", value=long_peak, unit="MB",
                         reference="same reader over 30 frames", ratio=long_peak / short_peak,
                         note=f"30 frames: {short_peak:.2f} MB; one decoded frame is "
                              f"{48 * 2000 * 5 / 1e6:.2f} MB (raw + float32)"))
        bag_peak = _peak_mb(logs["MCAP bag"][0])
        rows.append(dict(name="MCAP bag 200 frames: peak Python memory while iterating", value=bag_peak, unit="MB",
                         reference="", ratio=None, note=f"bag {logs['MCAP bag'][0].stat().st_size / 1e6:.1f} MB"))
    return rows
