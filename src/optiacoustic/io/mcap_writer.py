"""ROS 2 out: a dataset as an MCAP file of standard messages, written with rosbags.

Topics (docs/datasets.md has the full table):

- ``/sonar/image``: ``marine_acoustic_msgs/msg/ProjectedSonarImage``, the noisy image;
  ``/sonar/intensity`` the noise-free one; ground truth on ``/sonar/ground_truth/body``
  (int16), ``elevation_min`` / ``elevation_max`` (float32, rad), ``shadow`` (uint8), each
  a ProjectedSonarImage with the same beams and ranges.
- ``/camera/image``: ``sensor_msgs/msg/Image`` (``32FC3`` linear RGB, or ``rgb8`` sRGB),
  ``/camera/camera_info``: ``sensor_msgs/msg/CameraInfo``; ground truth on
  ``/camera/ground_truth/range`` (``32FC1``, m along the ray), ``body`` (``16SC1``) and
  ``normal`` (``32FC3``, world frame).
- ``/tf``: ``world -> sonar`` at every frame time (the rig's body is the sonar);
  ``/tf_static``: ``sonar -> camera`` (OpenCV optical axes) and ``sonar -> sonar_acoustic``.

Sonar frames: ``sonar`` has our axes (X starboard, Y forward, Z up). The
ProjectedSonarImage header names ``sonar_acoustic``, whose Z is forward and whose beams lie
in its Y-Z plane: a beam at our azimuth ``theta`` has direction
``(0, -sin theta, cos theta)`` (DESIGN.md), i.e. its Y points to port, and for a
right-handed frame its X then points down.

Stamps: header stamps and log times are ``start_time + frame time`` (s, as ROS time), each in
[0, 2^31) s (``builtin_interfaces/Time.sec`` is an int32); ``/tf_static`` is stamped at the
first frame.

The dataset is read through :class:`_Source`, which checks it before anything is written and
names the dataset, the array and the frame of whatever is damaged (a lost or undecodable
chunk, a broken ``zarr.json``, a NaN time or pose); a converted log (no rig, no poses) is
exported without the transforms and camera info it cannot give.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from .._atomic import OutputError
from ..frames import are_rotations, is_rotation

__all__ = ["write_mcap", "StartTimeError", "SONAR_TOPICS", "CAMERA_TOPICS", "R_SONAR_FROM_ACOUSTIC", "DEVICE_ENCODINGS"]

SONAR_TOPICS = {"image": "/sonar/image", "intensity": "/sonar/intensity", "body": "/sonar/ground_truth/body",
                "elevation_min": "/sonar/ground_truth/elevation_min",
                "elevation_max": "/sonar/ground_truth/elevation_max", "shadow": "/sonar/ground_truth/shadow"}
CAMERA_TOPICS = {"image": "/camera/image", "depth": "/camera/ground_truth/range", "body": "/camera/ground_truth/body",
                 "normal": "/camera/ground_truth/normal"}
CAMERA_INFO_TOPIC = "/camera/camera_info"

#: columns: the message frame's X (down), Y (port), Z (forward) in our sonar axes.
R_SONAR_FROM_ACOUSTIC = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])

_PSI = "marine_acoustic_msgs/msg/ProjectedSonarImage"
_IMG = "sensor_msgs/msg/Image"
_ENC = {np.dtype("float32"): {1: "32FC1", 3: "32FC3"}, np.dtype("int16"): {1: "16SC1"}, np.dtype("uint8"): {3: "rgb8"}}


def _stamp(ts, seconds: float):
    ns = int(round(seconds * 1e9))
    return ts.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000), ns


def _quat_xyzw(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()


def _transform(ts, stamp, parent: str, child: str, R, t):
    T = ts.types
    q = _quat_xyzw(np.asarray(R, float))
    return T["geometry_msgs/msg/TransformStamped"](
        header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=parent), child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=float(t[0]), y=float(t[1]), z=float(t[2])),
            rotation=T["geometry_msgs/msg/Quaternion"](x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))))


def _sonar_message(ts, stamp, frame_id, data: np.ndarray, ranges, directions, ping_info):
    from .rosmsg import dtype_code

    T = ts.types
    a = np.ascontiguousarray(data)
    if a.dtype == bool:
        a = a.astype(np.uint8)
    return T[_PSI](
        header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id), ping_info=ping_info,
        beam_directions=directions, ranges=np.asarray(ranges, np.float32),
        image=T["marine_acoustic_msgs/msg/SonarImageData"](
            is_bigendian=bool(a.dtype.byteorder == ">"), dtype=dtype_code(a.dtype), beam_count=int(a.shape[1]),
            data=np.frombuffer(a.tobytes(), np.uint8)))


def _image_message(ts, stamp, frame_id, a: np.ndarray):
    T = ts.types
    a = np.ascontiguousarray(a)
    ch = 1 if a.ndim == 2 else a.shape[2]
    enc = _ENC[a.dtype][ch]
    return T[_IMG](header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id), height=int(a.shape[0]),
                   width=int(a.shape[1]), encoding=enc, is_bigendian=0, step=int(a.shape[1] * ch * a.itemsize),
                   data=np.frombuffer(a.tobytes(), np.uint8))


def _camera_info(ts, stamp, frame_id, cam: dict):
    T = ts.types
    K = np.array([[cam["fx"], 0, cam["cx"]], [0, cam["fy"], cam["cy"]], [0, 0, 1]], float)
    P = np.hstack([K, np.zeros((3, 1))])
    return T["sensor_msgs/msg/CameraInfo"](
        header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id), height=int(cam["height"]),
        width=int(cam["width"]), distortion_model="plumb_bob", d=np.asarray(cam["dist"], float), k=K.ravel(),
        r=np.eye(3).ravel(), p=P.ravel(), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))


def _quantise(image: np.ndarray, dtype, full_scale: float) -> np.ndarray:
    top = np.iinfo(dtype).max
    q = np.clip(np.nan_to_num(image, nan=0.0) / full_scale, 0.0, 1.0) * top
    return np.round(q).astype(dtype)


def _static_qos():
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    return Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, QosTime(0, 0),
               QosTime(0, 0), QosLiveliness.AUTOMATIC, QosTime(0, 0), False)


DEVICE_ENCODINGS = ("oculus_gamma8", "aris_db")


def _device_counts(image: np.ndarray, encoding: str, full_scale: float) -> np.ndarray:
    """Intensity in a device's units (:mod:`optiacoustic.io.units`), ``full_scale`` at the top count."""
    from . import units

    img = np.nan_to_num(image, nan=0.0)
    if encoding == "oculus_gamma8":
        return units.encode(img, encoding, full_scale=full_scale)
    # aris_db: 0-255 spans 80 dB; the reference puts full scale at count 255
    return units.encode(img, encoding, reference=full_scale * 10.0 ** -8.0)


_ROS_TIME_END_NS = 2**31 * 10**9  # builtin_interfaces/msg/Time.sec is an int32: stamps in [0, 2^31) s
_GT = {"sonar": ("body", "elevation_min", "elevation_max", "shadow"), "camera": ("depth", "body", "normal")}


class StartTimeError(ValueError):
    """``start_time`` cannot stamp the dataset's frames; ``reason`` says why (the CLI names its option)."""

    def __init__(self, reason: str):
        super().__init__(f"start_time: {reason}")
        self.reason = reason


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


class _Source:
    """A dataset opened for export: every failure is a :class:`DatasetError` naming the path, array and frame.

    Zarr reads a chunk that is not there as the array's fill value, so a done frame whose chunk
    file was lost would come out as NaN or -1 without a word: :meth:`check_chunks` looks for the
    chunk files of the frames to export on the file system (one ``stat`` each, nothing read twice).
    """

    def __init__(self, src: Path):
        import zarr

        from .dataset import DatasetError

        self.src, self._zarr, self._Error = src, zarr, DatasetError
        if not (src / "zarr.json").is_file():
            raise DatasetError(f"{src}: not a Zarr store (no zarr.json)")
        self.root = self._node("zarr.json", lambda: zarr.open_group(str(src), mode="r"), zarr.Group)
        try:
            meta = dict(self.root.attrs).get("optiacoustic")
        except Exception as exc:  # noqa: BLE001 - any unreadable attribute means the same to the user
            raise self.error(f"zarr.json: its attributes cannot be read ({_reason(exc)})") from None
        if not isinstance(meta, dict):
            raise DatasetError(f"{src}: not an optiacoustic dataset (no 'optiacoustic' attribute)")
        self.meta = meta
        self.measured = bool(meta.get("measured", False))

    def error(self, text: str, damaged: bool = True):
        return self._Error(f"{self.src}: {text}" + ("; the dataset is damaged" if damaged else ""))

    def _node(self, where: str, opener, kind):
        try:
            node = opener()
        except MemoryError:
            raise
        except Exception as exc:  # noqa: BLE001 - JSON, codec and Zarr errors all mean a damaged file
            raise self.error(f"{where} cannot be read ({_reason(exc)})") from None
        if not isinstance(node, kind):
            raise self.error(f"{where} is not a Zarr {'group' if kind is self._zarr.Group else 'array'}")
        return node

    def group(self, sensor: str):
        """Group ``sensor``, or None where the dataset has no such folder."""
        folder = self.src / sensor
        if not folder.exists():
            return None
        if not (folder / "zarr.json").is_file():
            raise self.error(f"{sensor}/zarr.json is missing (the folder {sensor} is there)")
        return self._node(f"{sensor}/zarr.json", lambda: self.root[sensor], self._zarr.Group)

    def array(self, group, sensor: str, name: str, required: bool = True):
        """Array ``sensor/name``; None where it is absent and not ``required``."""
        folder = self.src / sensor / name
        if not folder.exists():
            if required:
                raise self.error(f"array {sensor}/{name} is missing")
            return None
        if not (folder / "zarr.json").is_file():
            raise self.error(f"{sensor}/{name}/zarr.json is missing (the folder {sensor}/{name} is there)")
        return self._node(f"{sensor}/{name}/zarr.json", lambda: group[name], self._zarr.Array)

    @staticmethod
    def _grid(arr):
        """The shape of the chunks as stored (shards where the array has them)."""
        return tuple(arr.shards or arr.chunks)

    def chunk_key(self, arr, k: int) -> str:
        grid = self._grid(arr)
        return arr.metadata.encode_chunk_key((k // grid[0],) + (0,) * (len(grid) - 1))

    @staticmethod
    def _blosc_nbytes(arr) -> tuple[int, int] | None:
        """``(decoded bytes, trailer bytes)`` of a chunk where the codecs are ``bytes`` then ``blosc``, then
        optionally ``crc32c`` (its 4-byte trailer; ours since the checksum); else None."""
        from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec

        codecs = tuple(getattr(arr.metadata, "codecs", ()))
        trailer = 4 if len(codecs) == 3 and isinstance(codecs[2], Crc32cCodec) else 0
        if trailer:
            codecs = codecs[:2]
        if len(codecs) == 2 and isinstance(codecs[0], BytesCodec) and isinstance(codecs[1], BloscCodec):
            return int(np.prod(_Source._grid(arr))) * np.dtype(arr.dtype).itemsize, trailer
        return None

    def check_chunks(self, arr, frames=None, missing_ok: bool = False) -> None:
        """Every chunk of ``arr`` (of rows ``frames`` only, when given) is a file in the store.

        With ``missing_ok`` (the ``done`` flags: a flag not yet written reads False) only the
        chunks that are there are checked.

        A Blosc chunk's 16-byte header must also give the file's own size and a whole chunk:
        c-blosc trusts the header, and decoding a truncated chunk reads past its end (it
        crashed the process, found by fuzzing chunks of a dataset); with the sizes checked,
        fuzzed chunks fail with an error instead.
        """
        import itertools

        grid = self._grid(arr)
        counts = [range(-(-s // c)) for s, c in zip(arr.shape, grid)]
        rows = counts[0] if frames is None or not counts else sorted({int(k) // grid[0] for k in frames})
        folder = self.src / arr.path
        blosc = self._blosc_nbytes(arr)
        nbytes, trailer = blosc if blosc is not None else (None, 0)
        for idx in itertools.product(rows, *counts[1:]) if counts else [()]:
            key = arr.metadata.encode_chunk_key(idx)
            path = folder / key
            frame = "" if frames is None else f", frame {idx[0] * grid[0]}"
            if not path.is_file():
                if missing_ok:
                    continue
                done = "" if frames is None else " although the frame is marked done"
                raise self.error(f"array {arr.path}{frame}: chunk {key} is missing{done}")
            if nbytes is not None:
                with open(path, "rb") as f:
                    head = f.read(16)
                    size = f.seek(0, 2) - trailer  # the Blosc chunk's bytes, less the CRC after them
                problem = None
                if len(head) < 16 or size < 16:
                    problem = f"{size + trailer} bytes, too short for a Blosc chunk" + (" and its CRC" if trailer else "")
                elif int.from_bytes(head[12:16], "little") != size:
                    problem = (f"its Blosc header says {int.from_bytes(head[12:16], 'little')} bytes, the file has {size}"
                               + (" before its CRC" if trailer else ""))
                elif int.from_bytes(head[4:8], "little") != nbytes:
                    problem = (f"its Blosc header says {int.from_bytes(head[4:8], 'little')} bytes decoded, "
                               f"a chunk holds {nbytes}")
                if problem:
                    raise self.error(f"array {arr.path}{frame}: chunk {key} is damaged ({problem})")

    def read(self, arr, k: int | None = None) -> np.ndarray:
        """All of ``arr``, or its frame ``k``; a chunk that cannot be decoded is named."""
        try:
            return np.asarray(arr[:] if k is None else arr[int(k)])
        except MemoryError:
            raise
        except Exception as exc:  # noqa: BLE001 - codec, JSON and shape errors all mean a damaged chunk
            if k is None and arr.shape and self._grid(arr)[0] < arr.shape[0]:
                for j in range(0, arr.shape[0], self._grid(arr)[0]):  # name the frame: read chunk by chunk
                    self.read(arr, j)
            where = f"array {arr.path}" if k is None else f"array {arr.path}, frame {k} (chunk {self.chunk_key(arr, k)})"
            if "checksum do not match" in str(exc):  # Zarr's crc32c codec: the bytes changed after writing
                raise self.error(f"{where} is damaged (its CRC-32C checksum does not match its bytes)") from None
            raise self.error(f"{where} cannot be read ({_reason(exc)})") from None

    def meta_field(self, dotted: str, number: bool = False):
        v, parts = self.meta, dotted.split(".")
        for i, part in enumerate(parts):
            if not isinstance(v, dict) or part not in v:
                raise self.error(f"metadata field '{'.'.join(parts[:i + 1])}' is missing")
            v = v[part]
        if number:
            try:
                return float(v)
            except (TypeError, ValueError):
                raise self.error(f"metadata field '{dotted}' is not a number: {v!r}") from None
        return v


def _rig(ds: _Source):
    """``(R_sonar_from_camera, t_camera_in_sonar)`` of the metadata; None for a measured dataset without one."""
    if "rig" not in ds.meta and ds.measured:
        return None  # a converted log has no rig: no sonar -> camera transform
    R = np.asarray(ds.meta_field("rig.R_sonar_from_camera"), dtype=object)
    t = np.asarray(ds.meta_field("rig.t_camera_in_sonar"), dtype=object)
    try:
        R, t = R.astype(float), t.astype(float)
    except (TypeError, ValueError):
        raise ds.error("metadata field 'rig' holds something other than numbers") from None
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise ds.error(f"metadata field 'rig': expected a finite 3 x 3 R_sonar_from_camera and a 3-vector "
                       f"t_camera_in_sonar, got shapes {R.shape} and {t.shape}")
    if not is_rotation(R):
        raise ds.error("metadata field 'rig.R_sonar_from_camera' is not a rotation matrix")
    return R, t


def _camera_meta(ds: _Source, image_shape) -> dict | None:
    """The camera's intrinsics for CameraInfo; None for a measured dataset without them."""
    if "camera" not in ds.meta and ds.measured:
        return None  # a converted log keeps only K, not the distortion: no half-known CameraInfo
    cam = {k: ds.meta_field(f"camera.{k}", number=True) for k in ("fx", "fy", "cx", "cy", "width", "height")}
    try:
        cam["dist"] = [float(v) for v in ds.meta_field("camera.dist")]
    except (TypeError, ValueError):
        raise ds.error("metadata field 'camera.dist' is not a list of numbers") from None
    if not all(np.isfinite(v) for v in list(cam.values())[:6] + cam["dist"]):
        raise ds.error("metadata field 'camera' holds a value that is not finite")
    if (cam["height"], cam["width"]) != tuple(image_shape[1:3]):
        raise ds.error(f"metadata field 'camera' says {cam['width']:g} x {cam['height']:g} px, array camera/image "
                       f"holds {image_shape[2]} x {image_shape[1]} px frames")
    return cam


def _poses_known(ds: _Source, sensor: str, poses: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Mask over ``frames``: the frame's pose is known (checked rigid); all-NaN poses of a measured log are unknown."""
    P = poses[frames]
    known = np.isfinite(P).all(axis=(1, 2))
    unknown = np.isnan(P).all(axis=(1, 2)) if ds.measured else np.zeros(len(frames), bool)
    bad = ~(known | unknown)
    rigid = are_rotations(P[known, :3, :3]) & np.all(np.abs(P[known, 3] - [0, 0, 0, 1]) < 1e-9, axis=1)
    bad[np.flatnonzero(known)[~rigid]] = True
    if bad.any():
        k = int(frames[np.flatnonzero(bad)[0]])
        what = "is not a rigid transform" if np.isfinite(poses[k]).all() else \
            "is partly NaN" if ds.measured else "is not finite"
        raise ds.error(f"array {sensor}/pose, frame {k}: the pose {what}")
    return known


def _sensor_plan(ds: _Source, sensor: str, ground_truth: bool):
    """What the export reads of one sensor, checked before anything is written; None without the group."""
    g = ds.group(sensor)
    if g is None:
        return None
    done_arr = ds.array(g, sensor, "done")
    ds.check_chunks(done_arr, missing_ok=True)  # a missing flag chunk reads False: the frame is not done
    done = ds.read(done_arr)
    if done.ndim != 1:
        raise ds.error(f"array {sensor}/done has shape {done.shape}, expected (frames,)")
    n = len(done)
    frames = np.flatnonzero(done)
    small = {}
    for name, shape in (("time", (n,)), ("pose", (n, 4, 4))):
        a = ds.array(g, sensor, name)
        if a.shape != shape:
            raise ds.error(f"array {sensor}/{name} has shape {a.shape}, expected {shape} ({n} frames in {sensor}/done)")
        ds.check_chunks(a)  # a lost chunk would read as 0 s or a zero pose
        small[name] = ds.read(a).astype(float)
    times = small["time"]
    bad = frames[~np.isfinite(times[frames])]
    if bad.size:
        k = int(bad[0])
        if ds.measured and np.isnan(times[k]):
            raise ds.error(f"array {sensor}/time, frame {k}: no time (nan); a ROS message needs a stamp and a log "
                           "without a clock (a raw Oculus stream) has none, so it cannot be exported", damaged=False)
        raise ds.error(f"array {sensor}/time, frame {k}: not a finite time ({times[k]})")
    plan = {"group": g, "frames": frames, "times": times, "poses": small["pose"],
            "known": _poses_known(ds, sensor, small["pose"], frames), "arrays": {}}
    names = ("image", "intensity") if sensor == "sonar" else ("image",)
    for name in names + (_GT[sensor] if ground_truth else ()):
        a = ds.array(g, sensor, name, required=name == "image")
        if a is None:
            continue
        if not a.shape or a.shape[0] != n:
            raise ds.error(f"array {sensor}/{name} has shape {a.shape}, expected {n} frames as in {sensor}/done")
        plan["arrays"][name] = a
    if sensor == "sonar":
        from .rosmsg import dtype_code

        for name in ("ranges", "azimuths"):
            a = ds.array(g, sensor, name)
            ds.check_chunks(a)
            plan[name] = ds.read(a).astype(float)
            if plan[name].ndim != 1 or not np.isfinite(plan[name]).all():
                raise ds.error(f"array sonar/{name}: expected finite values, one per "
                               f"{'bin' if name == 'ranges' else 'beam'}")
        want = (len(plan["ranges"]), len(plan["azimuths"]))
        for name, a in plan["arrays"].items():
            if tuple(a.shape[1:]) != want:
                raise ds.error(f"array sonar/{name} holds {a.shape[1:]} frames, expected (bins, beams) = {want} "
                               "from sonar/ranges and sonar/azimuths")
            try:
                dtype_code(np.uint8 if a.dtype == bool else a.dtype)
            except ValueError as exc:
                raise ds.error(f"array sonar/{name}: {exc}", damaged=False) from None
    else:
        for name, a in plan["arrays"].items():
            ch = 1 if len(a.shape) == 3 else a.shape[-1]
            if len(a.shape) not in (3, 4) or ch not in _ENC.get(a.dtype, {}):
                raise ds.error(f"array camera/{name}: a {a.dtype} array of shape {a.shape} is no image an "
                               "Image message can carry", damaged=False)
    for a in plan["arrays"].values():
        if len(frames):
            ds.check_chunks(a, frames)
    return plan


def _check_start_time(start_time, events: list) -> float:
    """``start_time`` as a float, such that every stamp is a ROS time in [0, 2^31) s."""
    rule = "must be finite and give ROS times in [0, 2^31) s"
    try:
        st = float(start_time)
    except (TypeError, ValueError):
        raise StartTimeError(f"{rule}, got {start_time!r}") from None
    if not np.isfinite(st):
        raise StartTimeError(f"{rule}, got {st:g}")
    t0, t1 = events[0][0], events[-1][0]
    lo, hi = round((st + t0) * 1e9), round((st + t1) * 1e9)
    if lo < 0 or hi >= _ROS_TIME_END_NS:
        raise StartTimeError(f"{rule}, got {st:.12g} (the dataset's frames are at {t0:.12g} to {t1:.12g} s: "
                             f"start time in [{0.0 - t0 + 0.0:.12g}, {2**31 - t1:.12g}) s)")
    return st


def write_mcap(dataset, out, *, sonar_dtype: str = "float32", full_scale: float | None = None,
               sonar_encoding: str | None = None, camera_encoding: str = "32FC3", start_time: float = 0.0,
               ground_truth: bool = True) -> Path:
    """Write a dataset's done frames as ROS 2 messages into one MCAP file.

    The dataset is checked before anything is written: its metadata, every array's
    ``zarr.json``, the times and poses, and that every chunk of every frame marked done is
    on disk (Zarr would read a lost chunk as fill values). A chunk that cannot be decoded
    stops the export. Each is a :class:`~optiacoustic.io.dataset.DatasetError` naming the
    dataset, the array and the frame, and no ``out`` file is left behind.

    A converted log (``oas convert``, metadata ``measured: true``) has no rig and no
    ground-truth poses: its sonar (and camera) images are exported with their own ranges,
    azimuths and times, ``/tf_static`` holds only ``sonar -> sonar_acoustic``, ``/tf`` only
    frames whose pose is known, and ``/camera/camera_info`` is left out (the dataset keeps
    K but not the distortion). A done frame without a time (NaN, a log without a clock) is
    an error naming it.

    Parameters
    ----------
    dataset : path of a dataset (``.zarr``)
    out : path
        The ``.mcap`` file, written atomically (a temporary bag beside it, then renamed).
    sonar_dtype : {"float32", "uint8", "uint16"}
        ``/sonar/image`` data: the linear intensity as float32, or a device's counts
        ``round(clip(I / full_scale, 0, 1) * max)``.
    full_scale : float, optional
        Linear intensity of the top count (default: the 99.9th percentile of the
        dataset's sonar images); ignored for float32 without ``sonar_encoding``.
    sonar_encoding : {"oculus_gamma8", "aris_db"}, optional
        ``/sonar/image`` in a device's own units (:mod:`optiacoustic.io.units`, uint8):
        Oculus gamma-coded bytes (gamma byte 127) or ARIS 80 dB bytes, with
        ``full_scale`` at count 255; overrides ``sonar_dtype``.
    camera_encoding : {"32FC3", "rgb8"}
        ``/camera/image``: linear float RGB as stored, or sRGB 8-bit.
    start_time : float
        ROS time (s) of dataset time 0; every stamp ``start_time + frame time`` must lie in
        [0, 2^31) s (:class:`StartTimeError` otherwise). A converted log's times are
        already s since the Unix epoch: leave it at 0 there.
    ground_truth : bool
        Also write the ground-truth topics.

    Returns
    -------
    Path of the MCAP file.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    from .dataset import DatasetError
    from .rosmsg import typestore

    if sonar_dtype not in ("float32", "uint8", "uint16"):
        raise ValueError(f"sonar_dtype: expected 'float32', 'uint8' or 'uint16', got {sonar_dtype!r}")
    if sonar_encoding is not None and sonar_encoding not in DEVICE_ENCODINGS:
        raise ValueError(f"sonar_encoding: expected one of {list(DEVICE_ENCODINGS)}, got {sonar_encoding!r}")
    if full_scale is not None and not (np.isfinite(full_scale) and full_scale > 0):
        raise ValueError(f"full_scale: expected a finite intensity > 0, got {full_scale!r}")
    if camera_encoding not in ("32FC3", "rgb8"):
        raise ValueError(f"camera_encoding: expected '32FC3' or 'rgb8', got {camera_encoding!r}")
    src = Path(dataset)
    ds = _Source(src)
    out = Path(out)
    if out.suffix != ".mcap":
        raise OutputError(f"cannot write {out}: expected a .mcap file name")
    if out.is_dir():
        raise OutputError(f"cannot write {out}: it is a folder, a file was expected")
    # everything the export needs is read and checked before anything is written
    plans = {s: p for s in ("sonar", "camera") if (p := _sensor_plan(ds, s, ground_truth)) is not None}
    events = sorted((float(p["times"][k]), s, int(k)) for s, p in plans.items() for k in p["frames"])
    if not events:
        raise DatasetError(f"{src}: has no finished frame to export")
    start_time = _check_start_time(start_time, events)
    rig = _rig(ds)
    cam_meta = _camera_meta(ds, plans["camera"]["arrays"]["image"].shape) if "camera" in plans else None
    ts = typestore(2)
    T = ts.types
    if "sonar" in plans:
        sp = plans["sonar"]
        az, ranges = sp["azimuths"], sp["ranges"]
        directions = [T["geometry_msgs/msg/Vector3"](x=0.0, y=float(-np.sin(a)), z=float(np.cos(a))) for a in az]
        spec = {k: ds.meta_field(f"sonar_spec.{k}", number=True)
                for k in ("frequency", "sound_speed", "fov_elevation", "beamwidth_azimuth")}
        n_beams = len(az)
        ping = T["marine_acoustic_msgs/msg/PingInfo"](
            frequency=spec["frequency"], sound_speed=spec["sound_speed"],
            tx_beamwidths=np.full(n_beams, spec["fov_elevation"], np.float32),
            rx_beamwidths=np.full(n_beams, spec["beamwidth_azimuth"], np.float32))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.stem}.tmp-", dir=out.parent))
    bag = tmp / "bag"
    try:
        if "sonar" in plans and (sonar_dtype != "float32" or sonar_encoding) and full_scale is None:
            simg = plans["sonar"]["arrays"]["image"]
            vals = np.concatenate([ds.read(simg, k).ravel() for k in plans["sonar"]["frames"]])
            vals = vals[np.isfinite(vals) & (vals > 0)]
            full_scale = float(np.percentile(vals, 99.9)) if vals.size else 1.0
        if "camera" in plans and camera_encoding == "rgb8":
            from ..optical.frame import auto_exposure, to_srgb8

            # one exposure for the whole sequence, so that brightness does not flicker
            cimg, idx = plans["camera"]["arrays"]["image"], plans["camera"]["frames"]
            exposure = float(np.median([auto_exposure(ds.read(cimg, k))
                                        for k in idx[np.linspace(0, len(idx) - 1, min(len(idx), 9)).astype(int)]]))
        with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
            conns = {}

            def conn(topic, msgtype, **kw):
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, msgtype, typestore=ts, **kw)
                return conns[topic]

            def put(topic, msg, ns):
                w.write(conn(topic, msg.__msgtype__), ns, ts.serialize_cdr(msg, msg.__msgtype__))

            # static transforms at the first frame's stamp (a converted log's stamps are epoch times)
            stamp0, ns0 = _stamp(ts, start_time + events[0][0])
            tf_static = [_transform(ts, stamp0, "sonar", "sonar_acoustic", R_SONAR_FROM_ACOUSTIC, np.zeros(3))]
            if rig is not None:
                tf_static.insert(0, _transform(ts, stamp0, "sonar", "camera", *rig))
            w.write(conn("/tf_static", "tf2_msgs/msg/TFMessage", offered_qos_profiles=[_static_qos()]), ns0,
                    ts.serialize_cdr(T["tf2_msgs/msg/TFMessage"](transforms=tf_static), "tf2_msgs/msg/TFMessage"))
            known = {s: dict(zip(p["frames"].tolist(), p["known"].tolist())) for s, p in plans.items()}
            for t, s, k in events:
                stamp, ns = _stamp(ts, start_time + t)
                arrays = plans[s]["arrays"]
                pose = plans[s]["poses"][k] if known[s][k] else None
                if s == "sonar":
                    if pose is not None:
                        put("/tf", T["tf2_msgs/msg/TFMessage"](
                            transforms=[_transform(ts, stamp, "world", "sonar", pose[:3, :3], pose[:3, 3])]), ns)
                    img = ds.read(arrays["image"], k)
                    if sonar_encoding:
                        data = _device_counts(img, sonar_encoding, full_scale)
                    elif sonar_dtype == "float32":
                        data = img
                    else:
                        data = _quantise(img, np.dtype(sonar_dtype), full_scale)
                    put(SONAR_TOPICS["image"], _sonar_message(ts, stamp, "sonar_acoustic", data, ranges, directions,
                                                              ping), ns)
                    for name in ("intensity",) + _GT["sonar"]:
                        if name in arrays:
                            put(SONAR_TOPICS[name], _sonar_message(ts, stamp, "sonar_acoustic", ds.read(arrays[name], k),
                                                                   ranges, directions, ping), ns)
                else:
                    if pose is not None:
                        # the camera's world pose follows from /tf (world -> sonar at the sonar's rate) only at
                        # shared times; publish world -> sonar at the camera's times as well (without a rig,
                        # world -> camera itself)
                        child, T_pub = ("sonar", pose @ np.linalg.inv(_rig_matrix(*rig))) if rig is not None \
                            else ("camera", pose)
                        put("/tf", T["tf2_msgs/msg/TFMessage"](
                            transforms=[_transform(ts, stamp, "world", child, T_pub[:3, :3], T_pub[:3, 3])]), ns)
                    img = ds.read(arrays["image"], k)
                    if camera_encoding == "rgb8":
                        img = to_srgb8(img, exposure)
                    put(CAMERA_TOPICS["image"], _image_message(ts, stamp, "camera", img), ns)
                    if cam_meta is not None:
                        put(CAMERA_INFO_TOPIC, _camera_info(ts, stamp, "camera", cam_meta), ns)
                    for name in _GT["camera"]:
                        if name in arrays:
                            put(CAMERA_TOPICS[name], _image_message(ts, stamp, "camera", ds.read(arrays[name], k)), ns)
        files = list(bag.glob("*.mcap"))
        if len(files) != 1:  # pragma: no cover - rosbags writes one file
            raise OutputError(f"cannot write {out}: rosbags wrote {len(files)} MCAP files")
        files[0].replace(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def _rig_matrix(R, t) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = t
    return M
