"""Camera frames from bags (``sensor_msgs/Image`` or ``CompressedImage`` + ``CameraInfo``) or image folders.

A :class:`CameraFrame` has ``.image`` (``(H, W, 3)`` RGB float32 linear: 8-bit data are
sRGB-decoded, 16-bit and float taken as linear and scaled to [0, 1]; DESIGN.md), ``.raw``
(the stored pixels), ``.time`` (s since the epoch; NaN when unknown) and ``.camera`` (a
:class:`PinholeCamera` with distortion).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import PinholeCamera
from ._sequence import FrameSequence
from .camera_info import camera_from_message, read_camera_info
from .errors import ReadError

__all__ = ["CameraFrame", "open_camera", "srgb_to_linear"]

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
_CALIB_NAMES = ("camera_info.yaml", "camera_info.yml", "calibration.yaml", "calibration.yml", "camera.yaml",
                "ost.yaml", "calibration.xml", "camera.xml")
# sensor_msgs/Image encodings -> (numpy dtype, channel order)
_ENCODINGS = {"rgb8": (np.uint8, "rgb"), "bgr8": (np.uint8, "bgr"), "rgba8": (np.uint8, "rgba"),
              "bgra8": (np.uint8, "bgra"), "mono8": (np.uint8, "mono"), "rgb16": (np.uint16, "rgb"),
              "bgr16": (np.uint16, "bgr"), "mono16": (np.uint16, "mono"), "32FC1": (np.float32, "mono"),
              "32FC3": (np.float32, "rgb")}


@dataclass(frozen=True, eq=False)
class CameraFrame:
    """One camera image with its time and intrinsics (see the module docstring)."""

    image: np.ndarray
    raw: np.ndarray
    time: float
    camera: PinholeCamera | None
    index: int = 0
    source: str = ""


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer function inverted: [0, 1] encoded -> [0, 1] linear (float32)."""
    x = np.asarray(x, np.float32)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _to_linear_rgb(raw: np.ndarray, order: str) -> np.ndarray:
    a = raw
    if a.ndim == 2:
        a = a[..., None]
    if order in ("bgr", "bgra"):
        a = a[..., [2, 1, 0]]
    elif order in ("rgba",):
        a = a[..., :3]
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, axis=-1)
    if a.dtype == np.uint8:
        return srgb_to_linear(a / np.float32(255.0))
    if a.dtype == np.uint16:
        return (a / np.float32(65535.0)).astype(np.float32)
    return np.asarray(a, np.float32)


def open_camera(path, *, topic: str | None = None, camera_info=None, errors: str = "raise"):
    """Camera frames from a bag topic or a folder of images (lazy).

    Parameters
    ----------
    path : path-like
        A bag (ROS 1, ROS 2 folder, ``.mcap``) or a folder of images.
    topic : str, optional
        Bag image topic; default the only ``Image``/``CompressedImage`` topic.
    camera_info : path-like or PinholeCamera, optional
        Intrinsics. Default: a bag's ``camera_info`` topic beside the image topic, or a
        calibration file in the folder (``camera_info.yaml``, ``calibration.yaml``, ...).
        Without any, frames have ``camera=None``.
    """
    p = Path(path)
    cam = camera_info if isinstance(camera_info, PinholeCamera) or camera_info is None else read_camera_info(camera_info)
    if p.is_dir() and not (p / "metadata.yaml").exists():
        return ImageFolder(p, cam, errors)
    return BagCamera(p, topic, cam, errors)


class ImageFolder(FrameSequence):
    """Images of a folder in name order; time from a number in the file name (else NaN)."""

    def __init__(self, path, camera, errors):
        super().__init__(errors)
        self.path = Path(path)
        self.files = sorted(f for f in self.path.iterdir() if f.suffix.lower() in _IMAGE_SUFFIXES)
        if not self.files:
            raise ReadError(self.path, f"no images ({', '.join(_IMAGE_SUFFIXES)}) in the folder")
        if camera is None:
            calib = next((self.path / n for n in _CALIB_NAMES if (self.path / n).is_file()), None)
            camera = read_camera_info(calib) if calib is not None else None
        self.camera = camera

    def __len__(self):
        return len(self.files)

    def _read(self, i):
        import cv2

        f = self.files[i]
        raw = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise ReadError(f, "OpenCV cannot decode the image", frame=i)
        order = "mono" if raw.ndim == 2 else ("bgra" if raw.shape[2] == 4 else "bgr")
        m = re.search(r"(\d+(?:\.\d+)?)", f.stem)
        t = float(m.group(1)) if m else float("nan")
        t = t * 1e-9 if t > 1e15 else t  # nanosecond stamps
        return CameraFrame(_to_linear_rgb(raw, order), raw, t, self.camera, i, str(f))


class BagCamera(FrameSequence):
    """Camera frames of one image topic of a bag."""

    def __init__(self, path, topic, camera, errors):
        from .rosbag import COMPRESSED, IMAGE, bag_topics, open_bag

        super().__init__(errors)
        self.path = Path(path)
        self.reader = open_bag(path)
        topics = bag_topics(self.reader)
        images = [t for t, (m, _) in topics.items() if m in (IMAGE, COMPRESSED)]
        if topic is None:
            if len(images) != 1:
                self.reader.close()
                raise ReadError(self.path, f"several image topics: choose one with topic= (--camera-topic on the command line): {sorted(images)}" if images
                                else "no sensor_msgs/Image or CompressedImage topic in the bag")
            topic = images[0]
        if topic not in topics:
            self.reader.close()
            raise ReadError(self.path, f"no topic {topic!r}; topics: {sorted(topics)}")
        if topic not in images:
            self.reader.close()
            raise ReadError(self.path, f"unsupported message type {topics[topic][0]} for a camera "
                                       "(sensor_msgs/Image or CompressedImage)", topic=topic)
        self.topic = topic
        self.msgtype = topics[topic][0]
        self.connections = [c for c in self.reader.connections if c.topic == topic]
        if camera is None:
            info_topic = topic.rsplit("/", 1)[0] + "/camera_info"
            if topic.endswith("/compressed"):
                info_topic = topic.rsplit("/", 2)[0] + "/camera_info"
            conns = [c for c in self.reader.connections if c.topic == info_topic and c.msgtype.endswith("CameraInfo")]
            for c, _, raw in (self.reader.messages(connections=conns) if conns else ()):  # () would mean "all"
                camera = camera_from_message(self.reader.deserialize(raw, c.msgtype), f"{self.path}:{info_topic}")
                break
        self.camera = camera
        self._count = sum(int(c.msgcount) for c in self.connections)
        self._stamps = None

    def __len__(self):
        return self._count

    def _read(self, i):
        from .rosbag import BagSonarReader

        conn, raw = BagSonarReader._raw_message(self, i)  # the same log-time seek as the sonar reader
        return self._decode(self.reader.deserialize(raw, conn.msgtype), i)

    def _stamp_index(self):
        from .rosbag import BagSonarReader

        return BagSonarReader._stamp_index(self)

    def __iter__(self):
        for i, (c, _, raw) in enumerate(self.reader.messages(connections=self.connections)):
            try:
                yield self._decode(self.reader.deserialize(raw, c.msgtype), i)
            except ReadError as exc:
                if self.errors == "raise":
                    raise
                from .errors import SkippedFrame

                self.skipped.append(SkippedFrame(i, str(exc)))

    def _decode(self, msg, i):
        import cv2

        from .rosbag import IMAGE

        t = float(msg.header.stamp.sec) + 1e-9 * float(msg.header.stamp.nanosec)
        if self.msgtype == IMAGE:
            if msg.encoding not in _ENCODINGS:
                raise ReadError(self.path, f"unsupported image encoding {msg.encoding!r}; supported: "
                                           f"{sorted(_ENCODINGS)}", topic=self.topic, frame=i)
            dt, order = _ENCODINGS[msg.encoding]
            dt = np.dtype(dt).newbyteorder(">" if msg.is_bigendian else "<")
            ch = {"mono": 1, "rgb": 3, "bgr": 3, "rgba": 4, "bgra": 4}[order]
            h, w, step = int(msg.height), int(msg.width), int(msg.step)
            data = np.asarray(msg.data, np.uint8)
            if step < w * ch * dt.itemsize or data.size < h * step:
                raise ReadError(self.path, f"image data {data.size} bytes too short for {h} x step {step}",
                                topic=self.topic, frame=i)
            raw = data[:h * step].reshape(h, step)[:, :w * ch * dt.itemsize].copy().view(dt)
            raw = raw.astype(dt.newbyteorder("=")).reshape(h, w, ch) if ch > 1 else raw.astype(dt.newbyteorder("="))
        else:
            raw = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_UNCHANGED)
            if raw is None:
                raise ReadError(self.path, f"CompressedImage format {msg.format!r}: cannot decode",
                                topic=self.topic, frame=i)
            order = "mono" if raw.ndim == 2 else ("bgra" if raw.shape[2] == 4 else "bgr")
        return CameraFrame(_to_linear_rgb(raw, order), raw, t, self.camera, i, f"{self.path}:{self.topic}")

    def close(self):
        self.reader.close()
