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

Stamps: header stamps and log times are ``start_time + frame time`` (s, as ROS time).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

from .._atomic import OutputError

__all__ = ["write_mcap", "SONAR_TOPICS", "CAMERA_TOPICS", "R_SONAR_FROM_ACOUSTIC", "DEVICE_ENCODINGS"]

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


def write_mcap(dataset, out, *, sonar_dtype: str = "float32", full_scale: float | None = None,
               sonar_encoding: str | None = None, camera_encoding: str = "32FC3", start_time: float = 0.0,
               ground_truth: bool = True) -> Path:
    """Write a dataset's done frames as ROS 2 messages into one MCAP file.

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
        ROS time (s) of dataset time 0.
    ground_truth : bool
        Also write the ground-truth topics.

    Returns
    -------
    Path of the MCAP file.
    """
    import zarr
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
    if not (src / "zarr.json").is_file():
        raise DatasetError(f"{src}: not a Zarr store (no zarr.json)")
    root = zarr.open_group(str(src), mode="r")
    meta = dict(root.attrs).get("optiacoustic")
    if meta is None:
        raise DatasetError(f"{src}: not an optiacoustic dataset")
    out = Path(out)
    if out.suffix != ".mcap":
        raise OutputError(f"cannot write {out}: expected a .mcap file name")
    if out.is_dir():
        raise OutputError(f"cannot write {out}: it is a folder, a file was expected")
    out.parent.mkdir(parents=True, exist_ok=True)
    ts = typestore(2)
    T = ts.types
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.stem}.tmp-", dir=out.parent))
    bag = tmp / "bag"
    try:
        with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
            conns = {}

            def conn(topic, msgtype, **kw):
                if topic not in conns:
                    conns[topic] = w.add_connection(topic, msgtype, typestore=ts, **kw)
                return conns[topic]

            def put(topic, msg, ns):
                w.write(conn(topic, msg.__msgtype__), ns, ts.serialize_cdr(msg, msg.__msgtype__))

            stamp0, ns0 = _stamp(ts, start_time)
            rig = meta["rig"]
            tf_static = [_transform(ts, stamp0, "sonar", "camera", np.array(rig["R_sonar_from_camera"]),
                                    rig["t_camera_in_sonar"]),
                         _transform(ts, stamp0, "sonar", "sonar_acoustic", R_SONAR_FROM_ACOUSTIC, np.zeros(3))]
            w.write(conn("/tf_static", "tf2_msgs/msg/TFMessage", offered_qos_profiles=[_static_qos()]), ns0,
                    ts.serialize_cdr(T["tf2_msgs/msg/TFMessage"](transforms=tf_static), "tf2_msgs/msg/TFMessage"))
            events = []
            sensors = [s for s in ("sonar", "camera") if s in root]
            for s in sensors:
                g = root[s]
                done = g["done"][:]
                for k in np.flatnonzero(done):
                    events.append((float(g["time"][k]), s, int(k)))
            events.sort()
            if not events:
                raise DatasetError(f"{src}: has no finished frame to export")
            if "sonar" in sensors:
                sg = root["sonar"]
                az = sg["azimuths"][:]
                directions = [T["geometry_msgs/msg/Vector3"](x=0.0, y=float(-np.sin(a)), z=float(np.cos(a))) for a in az]
                ranges = sg["ranges"][:]
                spec = meta["sonar_spec"]
                n_beams = len(az)
                ping = T["marine_acoustic_msgs/msg/PingInfo"](
                    frequency=float(spec["frequency"]), sound_speed=float(spec["sound_speed"]),
                    tx_beamwidths=np.full(n_beams, spec["fov_elevation"], np.float32),
                    rx_beamwidths=np.full(n_beams, spec["beamwidth_azimuth"], np.float32))
                if (sonar_dtype != "float32" or sonar_encoding) and full_scale is None:
                    done_idx = np.flatnonzero(sg["done"][:])
                    vals = np.concatenate([sg["image"][int(k)].ravel() for k in done_idx])
                    vals = vals[np.isfinite(vals) & (vals > 0)]
                    full_scale = float(np.percentile(vals, 99.9)) if vals.size else 1.0
            if "camera" in sensors and camera_encoding == "rgb8":
                from ..optical.frame import auto_exposure, to_srgb8

                # one exposure for the whole sequence, so that brightness does not flicker
                cg = root["camera"]
                idx = np.flatnonzero(cg["done"][:])
                exposure = float(np.median([auto_exposure(cg["image"][int(k)])
                                            for k in idx[np.linspace(0, len(idx) - 1, min(len(idx), 9)).astype(int)]]))
            for t, s, k in events:
                stamp, ns = _stamp(ts, start_time + t)
                g = root[s]
                pose = g["pose"][k]
                if s == "sonar":
                    put("/tf", T["tf2_msgs/msg/TFMessage"](
                        transforms=[_transform(ts, stamp, "world", "sonar", pose[:3, :3], pose[:3, 3])]), ns)
                    img = g["image"][k]
                    if sonar_encoding:
                        data = _device_counts(img, sonar_encoding, full_scale)
                    elif sonar_dtype == "float32":
                        data = img
                    else:
                        data = _quantise(img, np.dtype(sonar_dtype), full_scale)
                    put(SONAR_TOPICS["image"], _sonar_message(ts, stamp, "sonar_acoustic", data, ranges, directions,
                                                              ping), ns)
                    for name in ("intensity", "body", "elevation_min", "elevation_max", "shadow"):
                        if (name == "intensity" or ground_truth) and name in g:
                            put(SONAR_TOPICS[name], _sonar_message(ts, stamp, "sonar_acoustic", g[name][k], ranges,
                                                                   directions, ping), ns)
                else:
                    # the camera's world pose follows from /tf (world -> sonar at the sonar's rate) only at
                    # shared times; publish world -> sonar at the camera's times as well
                    sonar_pose = pose @ np.linalg.inv(_rig_matrix(rig))
                    put("/tf", T["tf2_msgs/msg/TFMessage"](
                        transforms=[_transform(ts, stamp, "world", "sonar", sonar_pose[:3, :3], sonar_pose[:3, 3])]),
                        ns)
                    img = g["image"][k]
                    if camera_encoding == "rgb8":
                        img = to_srgb8(img, exposure)
                    put(CAMERA_TOPICS["image"], _image_message(ts, stamp, "camera", img), ns)
                    put(CAMERA_INFO_TOPIC, _camera_info(ts, stamp, "camera", meta["camera"]), ns)
                    for name in ("depth", "body", "normal"):
                        if ground_truth and name in g:
                            put(CAMERA_TOPICS[name], _image_message(ts, stamp, "camera", g[name][k]), ns)
        files = list(bag.glob("*.mcap"))
        if len(files) != 1:  # pragma: no cover - rosbags writes one file
            raise OutputError(f"cannot write {out}: rosbags wrote {len(files)} MCAP files")
        files[0].replace(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def _rig_matrix(rig: dict) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = np.asarray(rig["R_sonar_from_camera"], float)
    M[:3, 3] = np.asarray(rig["t_camera_in_sonar"], float)
    return M
