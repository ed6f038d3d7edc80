"""Camera intrinsics from ROS ``camera_info`` YAML, OpenCV FileStorage (YAML/XML) or a CameraInfo message.

ROS (``camera_calibration`` output, ``camera_info_manager``)::

    image_width: 640
    image_height: 480
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}

OpenCV FileStorage (``cv2.FileStorage``; ``%YAML:1.0`` or XML): a 3x3 matrix node
``camera_matrix`` (or ``K``, ``cameraMatrix``), distortion ``distortion_coefficients``
(or ``D``, ``dist_coeffs``, ``distCoeffs``), size ``image_width``/``image_height`` (or
``width``/``height``).

Distortion: OpenCV's ``(k1, k2, p1, p2, k3)`` (ROS ``plumb_bob``); ``rational_polynomial``
is accepted only when its extra terms are zero.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import PinholeCamera
from .errors import ReadError, read_yaml_mapping

__all__ = ["read_camera_info", "camera_from_matrix", "camera_from_message"]

_K_NAMES = ("camera_matrix", "K", "cameraMatrix", "intrinsics")
_D_NAMES = ("distortion_coefficients", "D", "dist_coeffs", "distCoeffs", "distortion")


def camera_from_matrix(K, dist, width, height, source="camera info") -> PinholeCamera:
    """A :class:`PinholeCamera` from a 3x3 ``K``, distortion coefficients and the image size."""
    K = np.asarray(K, float)
    if K.size != 9:
        raise ValueError(f"{source}: camera matrix: expected 9 values, got {K.size}")
    K = K.reshape(3, 3)
    if not np.allclose(K[2], [0, 0, 1]) or abs(K[1, 0]) > 1e-12:
        raise ValueError(f"{source}: camera matrix: last row must be (0, 0, 1) and K[1,0] = 0, got {K.tolist()}")
    if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0):
        raise ValueError(f"{source}: camera matrix has skew {K[0, 1]}; PinholeCamera has none")
    d = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    if d.size > 5:
        if np.any(d[5:] != 0):
            raise ValueError(f"{source}: distortion has {d.size} coefficients with non-zero terms beyond "
                             f"(k1, k2, p1, p2, k3): {d.tolist()}; only the 5-term model is supported")
        d = d[:5]
    d = np.pad(d, (0, 5 - d.size))
    try:
        return PinholeCamera(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height),
                             tuple(float(x) for x in d))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from None


def camera_from_message(msg, source="CameraInfo") -> PinholeCamera:
    """A :class:`PinholeCamera` from a ``sensor_msgs/CameraInfo`` message (ROS 1 ``K``/``D`` or ROS 2 ``k``/``d``)."""
    K = getattr(msg, "k", None)
    K = msg.K if K is None else K
    D = getattr(msg, "d", None)
    D = msg.D if D is None else D
    model = msg.distortion_model
    if len(D) and model not in ("plumb_bob", "rational_polynomial", ""):
        raise ValueError(f"{source}: unsupported distortion_model {model!r} (plumb_bob or rational_polynomial)")
    return camera_from_matrix(K, D, msg.width, msg.height, source)


def read_camera_info(path) -> PinholeCamera:
    """Read camera intrinsics from a ROS camera_info YAML or an OpenCV FileStorage YAML/XML file.

    Raises
    ------
    ValueError
        Naming the file and the missing or bad field.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such file")
    text = p.read_bytes()[:4096]
    if p.suffix.lower() == ".xml" or text.lstrip().startswith((b"%YAML", b"<?xml")) or b"!!opencv-matrix" in text:
        return _read_opencv(p)
    data = read_yaml_mapping(p, "a mapping of camera_info fields")
    K = _field(p, data, _K_NAMES)
    D = next((data[k] for k in _D_NAMES if k in data), None)
    K = K.get("data") if isinstance(K, dict) else K
    D = D.get("data") if isinstance(D, dict) else D
    w = data.get("image_width", data.get("width"))
    h = data.get("image_height", data.get("height"))
    if w is None or h is None:
        raise ReadError(p, "missing image_width / image_height")
    model = data.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial"):
        raise ReadError(p, f"unsupported distortion_model {model!r} (plumb_bob or rational_polynomial)")
    try:
        return camera_from_matrix(K, D, w, h, str(p))
    except (TypeError, ValueError) as exc:
        raise ReadError(p, str(exc).removeprefix(f"{p}: ")) from None


def _field(p, data, names):
    for k in names:
        if k in data:
            return data[k]
    raise ReadError(p, f"no camera matrix (looked for {', '.join(names)})")


def _read_opencv(p: Path) -> PinholeCamera:
    import cv2

    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise ReadError(p, f"OpenCV FileStorage cannot parse it: {exc.err if hasattr(exc, 'err') else exc}") from None
    if not fs.isOpened():
        raise ReadError(p, "OpenCV FileStorage cannot open it")
    try:
        def node(names):
            for n in names:
                nd = fs.getNode(n)
                if not nd.empty():
                    return nd
            return None

        k = node(_K_NAMES)
        if k is None or k.mat() is None:
            raise ReadError(p, f"no camera matrix node (looked for {', '.join(_K_NAMES)})")
        d = node(_D_NAMES)
        D = None if d is None else d.mat()
        wn, hn = node(("image_width", "width")), node(("image_height", "height"))
        if wn is None or hn is None:
            raise ReadError(p, "missing image_width / image_height nodes")
        try:
            return camera_from_matrix(k.mat(), D, int(wn.real()), int(hn.real()), str(p))
        except ValueError as exc:
            raise ReadError(p, str(exc).removeprefix(f"{p}: ")) from None
    finally:
        fs.release()
