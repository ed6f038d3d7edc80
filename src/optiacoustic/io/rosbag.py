"""Sonar frames from ROS 1 bags, ROS 2 bags (MCAP or SQLite storage) and bare ``.mcap`` files.

Read through ``rosbags`` (pure Python, no ROS install). Message types:

``marine_acoustic_msgs/ProjectedSonarImage``
    Geometry from the message: beam ``j``'s direction ``(x, y, z)`` in the message's
    frame (Z forward, X up) gives our azimuth ``theta = atan2(-y, z)`` (positive to
    starboard; DESIGN.md); ``ranges`` are the bin centres (kept exactly, uneven allowed,
    as the spec's range table). ``image.data`` is a ``(n_ranges, beam_count)`` row-major
    array of ``image.dtype`` (UINT8..FLOAT64) in the byte order of ``is_bigendian``.
    Beams stored right to left are reversed so columns run left to right. Values are
    taken as linear intensity unless ``encoding=`` names a device encoding
    (:mod:`optiacoustic.io.units`).
``sensor_msgs/Image``, ``sensor_msgs/CompressedImage``
    Polar images some drivers publish (row = range bin, column = beam). They carry no
    geometry: pass ``spec=`` (a :class:`SonarSpec` with the device's beams and ranges).
    Encodings ``mono8``, ``8UC1``, ``mono16``, ``16UC1``, ``32FC1``, ``64FC1``; compressed
    PNG/JPEG/TIFF single-channel images (decoded with OpenCV).

Frames are fetched lazily: ``len`` comes from the bag's index, iteration streams
messages, random access seeks by the message's log time (the first random access makes one
pass over the topic to list the log times; 8 bytes per message are kept).
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from ..sonar.frame import MeasuredSonarFrame
from ..sonar.spec import SonarSpec
from . import units
from ._sequence import FrameSequence
from .errors import ReadError
from .rosmsg import PROJECTED_SONAR_IMAGE, SONAR_IMAGE_DTYPES, typestore

__all__ = ["open_bag_sonar", "open_bag", "BagSonarReader", "IMAGE_ENCODINGS", "bag_topics"]

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
SONAR_TYPES = (PROJECTED_SONAR_IMAGE, IMAGE, COMPRESSED)

#: sensor_msgs/Image encodings a polar sonar image may use -> numpy dtype.
IMAGE_ENCODINGS = {"mono8": np.uint8, "8UC1": np.uint8, "mono16": np.uint16, "16UC1": np.uint16,
                   "32FC1": np.float32, "64FC1": np.float64}


def _norm(msgtype: str) -> str:
    # ROS 1 bags name types "pkg/Type"; rosbags normalises to "pkg/msg/Type"
    return msgtype if "/msg/" in msgtype else msgtype.replace("/", "/msg/", 1)


def open_bag(path):
    """An open ``rosbags.highlevel.AnyReader`` on a ROS 1 bag, ROS 2 bag folder, ``.db3`` or ``.mcap``.

    Errors from rosbags (corrupt index, unknown storage, missing metadata) come back as
    :class:`ReadError` naming the path.
    """
    from rosbags.highlevel import AnyReader

    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file or folder")
    ros = 1 if p.suffix == ".bag" else 2
    try:
        reader = AnyReader([p], default_typestore=typestore(ros))
        reader.open()
    except FileNotFoundError:
        raise
    except Exception as exc:  # rosbags raises many types for damaged bags; one clear message
        raise ReadError(p, f"cannot open as a ROS {ros} bag: {type(exc).__name__}: {exc}") from None
    return reader


def bag_topics(reader) -> dict[str, tuple[str, int]]:
    """Topic -> (message type, message count) of an open bag."""
    out: dict[str, tuple[str, int]] = {}
    for c in reader.connections:
        t, n = out.get(c.topic, (_norm(c.msgtype), 0))
        out[c.topic] = (t, n + int(c.msgcount))
    return out


def open_bag_sonar(path, *, topic=None, errors="raise", spec: SonarSpec | None = None,
                   encoding: str | None = None, **encoding_params) -> "BagSonarReader":
    """Sonar frames of one topic of a bag (see the module docstring); lazy."""
    return BagSonarReader(path, topic=topic, errors=errors, spec=spec, encoding=encoding, **encoding_params)


class BagSonarReader(FrameSequence):
    """Lazy sequence of :class:`MeasuredSonarFrame` from one sonar topic of a bag."""

    def __init__(self, path, *, topic=None, errors="raise", spec=None, encoding=None, **encoding_params):
        super().__init__(errors)
        self.path = Path(path)
        self.reader = open_bag(path)
        topics = bag_topics(self.reader)
        self.topic = self._pick_topic(topics, topic)
        self.msgtype = topics[self.topic][0]
        if self.msgtype in (IMAGE, COMPRESSED) and spec is None:
            self.close()
            raise ReadError(self.path, f"{self.msgtype} polar images carry no beam or range geometry: pass "
                                       "spec=SonarSpec(...) with the device's beams and ranges (Python API; the "
                                       "command line reads ProjectedSonarImage topics)", topic=self.topic)
        if encoding is not None:
            units._get(encoding)
        self.spec, self.encoding, self.encoding_params = spec, encoding, encoding_params
        self.connections = [c for c in self.reader.connections if c.topic == self.topic]
        self._count = sum(int(c.msgcount) for c in self.connections)
        if self._count == 0:
            self.close()
            raise ReadError(self.path, "no messages on the topic (empty bag or topic)", topic=self.topic)
        self._stamps = None  # log times (ns) of every message, built on the first random access

    def _pick_topic(self, topics, topic):
        if not topics:
            self.close()
            raise ReadError(self.path, "the bag has no topics (empty bag)")
        listing = ", ".join(f"{t} ({m}, {n} msgs)" for t, (m, n) in sorted(topics.items()))
        if topic is not None:
            if topic not in topics:
                self.close()
                raise ReadError(self.path, f"no topic {topic!r}; topics: {listing}")
            if topics[topic][0] not in SONAR_TYPES:
                self.close()
                raise ReadError(self.path, f"unsupported message type {topics[topic][0]} for a sonar; readable: "
                                           f"{', '.join(SONAR_TYPES)}", topic=topic)
            return topic
        psi = [t for t, (m, _) in topics.items() if m == PROJECTED_SONAR_IMAGE]
        if len(psi) == 1:
            return psi[0]
        self.close()
        if not psi:
            raise ReadError(self.path, f"no {PROJECTED_SONAR_IMAGE} topic; pass topic= (--topic) for a polar Image topic. "
                                       f"Topics: {listing}")
        raise ReadError(self.path, f"several sonar topics: choose one with topic= (--topic on the command line): "
                                   f"{sorted(psi)}")

    def __len__(self):
        return self._count

    # -------------------------------------------------------------- access
    def _stamp_index(self):
        if self._stamps is None:
            try:
                self._stamps = np.fromiter((t for _, t, _ in self.reader.messages(connections=self.connections)),
                                           np.int64, count=self._count)
            except Exception as exc:  # a damaged bag fails in rosbags' own code: name the file and topic
                raise ReadError(self.path, f"cannot index the topic's messages: {type(exc).__name__}: {exc}",
                                topic=self.topic) from None
        return self._stamps

    def _raw_message(self, i):
        stamps = self._stamp_index()
        t = int(stamps[i])
        k = i - int(np.searchsorted(stamps, t, side="left"))  # several messages may share a log time
        try:
            for j, (conn, _, raw) in enumerate(self.reader.messages(connections=self.connections, start=t,
                                                                    stop=t + 1)):
                if j == k:
                    return conn, raw
        except Exception as exc:
            raise ReadError(self.path, f"cannot read message: {type(exc).__name__}: {exc}", topic=self.topic,
                            frame=i) from None
        raise ReadError(self.path, "message not found at its indexed log time", topic=self.topic, frame=i)

    def _read(self, i):
        conn, raw = self._raw_message(i)
        return self._decode(conn, raw, i)

    def __iter__(self):
        stream = self.reader.messages(connections=self.connections)
        for i in range(self._count):
            try:
                conn, _, raw = next(stream)
            except StopIteration:
                return
            except Exception as exc:
                err = ReadError(self.path, f"cannot read message: {type(exc).__name__}: {exc}", topic=self.topic,
                                frame=i)
                if self.errors == "raise":
                    raise err from None
                self._skip(i, err)
                return
            try:
                yield self._decode(conn, raw, i)
            except ReadError as exc:
                if self.errors == "raise":
                    raise
                self._skip(i, exc)

    def _skip(self, i, exc):
        import warnings

        from .errors import SkippedFrame

        self.skipped.append(SkippedFrame(i, str(exc)))
        warnings.warn(f"skipped damaged frame: {exc}", stacklevel=3)

    # -------------------------------------------------------------- decoding
    def _fail(self, i, reason):
        return ReadError(self.path, reason, topic=self.topic, frame=i)

    def _decode(self, conn, raw, i) -> MeasuredSonarFrame:
        try:
            msg = self.reader.deserialize(raw, conn.msgtype)
        except Exception as exc:
            raise self._fail(i, f"cannot deserialise {conn.msgtype}: {type(exc).__name__}: {exc}") from None
        stamp = msg.header.stamp
        t = float(stamp.sec) + 1e-9 * float(stamp.nanosec)
        if self.msgtype == PROJECTED_SONAR_IMAGE:
            return self._projected(msg, t, i)
        return self._polar_image(msg, t, i)

    def _projected(self, msg, t, i) -> MeasuredSonarFrame:
        img = msg.image
        code = int(img.dtype)
        if code not in SONAR_IMAGE_DTYPES:
            raise self._fail(i, f"unsupported SonarImageData.dtype {code} (known: 0..9 = UINT8..FLOAT64)")
        dt = SONAR_IMAGE_DTYPES[code].newbyteorder(">" if img.is_bigendian else "<")
        data = np.asarray(img.data, np.uint8)
        nb = int(img.beam_count)
        ranges = np.asarray(msg.ranges, np.float32)
        dirs = msg.beam_directions
        if nb < 1 or len(dirs) != nb:
            raise self._fail(i, f"beam_count {nb} but {len(dirs)} beam_directions")
        nr = ranges.size
        if data.size != nr * nb * dt.itemsize:
            raise self._fail(i, f"image.data has {data.size} bytes; {nr} ranges x {nb} beams x {dt.itemsize} "
                                f"bytes ({dt.name}) = {nr * nb * dt.itemsize}")
        y = np.array([d.y for d in dirs], float)
        z = np.array([d.z for d in dirs], float)
        theta = np.arctan2(-y, z)
        raw = data.view(dt).reshape(nr, nb).astype(dt.newbyteorder("="))
        if nb > 1 and np.all(np.diff(theta) < 0):  # stored right to left
            theta, raw = theta[::-1], raw[:, ::-1]
        raw = np.ascontiguousarray(raw)
        if nb < 2 or not np.all(np.diff(theta) > 0):
            raise self._fail(i, "beam_directions are not monotonic in azimuth (need >= 2 beams)")
        if nr < 2 or not np.all(np.isfinite(ranges)) or np.any(np.diff(ranges) <= 0) or ranges[0] < 0:
            raise self._fail(i, "ranges must be >= 2 finite, non-negative, strictly increasing values")
        info = msg.ping_info
        bw = np.asarray(info.rx_beamwidths, float)
        spec = _projected_spec(theta.tobytes(), ranges.astype(float).tobytes(), float(info.frequency),
                               float(info.sound_speed), float(bw.mean()) if bw.size else 0.0)
        enc = self.encoding or "linear"
        meta = dict(format="ros", msgtype=self.msgtype, topic=self.topic, frame_id=msg.header.frame_id,
                    dtype=str(SONAR_IMAGE_DTYPES[code]), frequency=float(info.frequency),
                    sound_speed=float(info.sound_speed), encoding_params=self.encoding_params)
        return MeasuredSonarFrame(raw=raw, image=units.decode(raw, enc, **self.encoding_params), spec=spec, time=t,
                                  encoding=enc, source=f"{self.path}:{self.topic}", index=i, meta=meta)

    def _polar_image(self, msg, t, i) -> MeasuredSonarFrame:
        if self.msgtype == IMAGE:
            enc = msg.encoding
            if enc not in IMAGE_ENCODINGS:
                raise self._fail(i, f"unsupported image encoding {enc!r} for a polar sonar image; "
                                    f"supported: {sorted(IMAGE_ENCODINGS)}")
            dt = np.dtype(IMAGE_ENCODINGS[enc]).newbyteorder(">" if msg.is_bigendian else "<")
            h, w, step = int(msg.height), int(msg.width), int(msg.step)
            data = np.asarray(msg.data, np.uint8)
            if step < w * dt.itemsize or data.size < h * step:
                raise self._fail(i, f"image data: {data.size} bytes for {h} rows of step {step} "
                                    f"(width {w} x {dt.itemsize} bytes)")
            raw = data[:h * step].reshape(h, step)[:, :w * dt.itemsize].copy().view(dt).astype(dt.newbyteorder("="))
        else:
            import cv2

            raw = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_UNCHANGED)
            if raw is None:
                raise self._fail(i, f"CompressedImage format {msg.format!r}: OpenCV cannot decode the data")
            if raw.ndim != 2:
                raise self._fail(i, f"CompressedImage has {raw.shape[2]} channels; a polar sonar image has one")
        spec = self.spec
        if raw.shape != (spec.n_bins, spec.n_beams):
            raise self._fail(i, f"image is {raw.shape[0]} x {raw.shape[1]} (rows x cols) but spec says "
                                f"n_bins x n_beams = {spec.n_bins} x {spec.n_beams}")
        enc = self.encoding or "linear"
        meta = dict(format="ros", msgtype=self.msgtype, topic=self.topic, frame_id=msg.header.frame_id,
                    encoding_params=self.encoding_params)
        return MeasuredSonarFrame(raw=raw, image=units.decode(raw, enc, **self.encoding_params), spec=spec, time=t,
                                  encoding=enc, source=f"{self.path}:{self.topic}", index=i, meta=meta)

    def info(self) -> dict:
        d = super().info()
        d.update(format="ROS bag", topic=self.topic, msgtype=self.msgtype,
                 topics={t: {"type": m, "messages": n} for t, (m, n) in bag_topics(self.reader).items()})
        return d

    def close(self):
        try:
            self.reader.close()
        except Exception:  # noqa: BLE001 - closing a half-opened reader must not mask the real error
            pass


@functools.lru_cache(maxsize=32)
def _projected_spec(theta_bytes, range_bytes, frequency, sound_speed, beamwidth) -> SonarSpec:
    theta = np.frombuffer(theta_bytes, float)
    ranges = np.frombuffer(range_bytes, float)
    kw = dict(name="ros-projected-sonar-image", source="marine_acoustic_msgs/ProjectedSonarImage",
              unverified=("fov_elevation (not in the message)",))
    if np.isfinite(frequency) and frequency > 0:
        kw["frequency"] = frequency
    if np.isfinite(sound_speed) and sound_speed > 0:
        kw["sound_speed"] = sound_speed
    if np.isfinite(beamwidth) and beamwidth > 0:
        kw["beamwidth_azimuth"] = beamwidth
    return SonarSpec(**kw).with_beam_table(theta).with_range_table(ranges)
