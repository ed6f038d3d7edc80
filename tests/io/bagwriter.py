"""Test helper: write bags with rosbags itself (the independent writer the readers are checked against)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from optiacoustic.io.rosmsg import PROJECTED_SONAR_IMAGE, dtype_code, typestore


def header(ts, ros, t, frame_id="sonar"):
    T = ts.types
    sec = int(np.floor(t))
    stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
    return T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame_id) if ros == 1 else \
        T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)


def projected(ts, ros, t, image, azimuths, ranges, *, bigendian=False, frequency=1.2e6, reverse=False):
    """A ProjectedSonarImage of ``image`` ((n_ranges, n_beams), any supported dtype)."""
    T = ts.types
    image = np.asarray(image)
    az = np.asarray(azimuths, float)
    if reverse:
        az, image = az[::-1], image[:, ::-1]
    dt = image.dtype.newbyteorder(">" if bigendian else "<")
    data = np.frombuffer(np.ascontiguousarray(image.astype(dt)).tobytes(), np.uint8)
    V = T["geometry_msgs/msg/Vector3"]
    return T[PROJECTED_SONAR_IMAGE](
        header=header(ts, ros, t),
        ping_info=T["marine_acoustic_msgs/msg/PingInfo"](frequency=frequency, sound_speed=1500.0,
                                                          tx_beamwidths=np.zeros(0, np.float32),
                                                          rx_beamwidths=np.full(az.size, 0.01, np.float32)),
        beam_directions=[V(x=0.0, y=-np.sin(a), z=np.cos(a)) for a in az],
        ranges=np.asarray(ranges, np.float32),
        image=T["marine_acoustic_msgs/msg/SonarImageData"](is_bigendian=bigendian, dtype=dtype_code(image.dtype),
                                                            beam_count=az.size, data=data),
    )


def write_bag(path: Path, kind: str, messages: list[tuple[str, str, float, object]]) -> Path:
    """Write ``(topic, msgtype, time_s, msg)`` to a bag of ``kind``: ros1, sqlite3, mcap. Returns the path to open."""
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        ts = typestore(1)
        with Writer(path) as w:
            conns = {}
            for topic, msgtype, t, msg in messages:
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
                w.write(conns[topic], int(t * 1e9), ts.serialize_ros1(msg, msgtype))
        return path
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = typestore(2)
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns = {}
        for topic, msgtype, t, msg in messages:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(conns[topic], int(t * 1e9), ts.serialize_cdr(msg, msgtype))
    return path
