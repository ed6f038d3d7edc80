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

Files are UTF-8 text. A matrix is ``!!opencv-matrix``, ``{rows, cols, data}`` or a list of
numbers; the image size is a whole number of pixels (``640.0`` is 640; ``640.7``, ``true`` and
``"480"`` are refused, not truncated or coerced). Every refusal is a :class:`ReadError` naming
the file, the field and the value found.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..camera import MAX_IMAGE_SIDE, PinholeCamera
from .errors import ReadError

__all__ = ["read_camera_info", "camera_from_matrix", "camera_from_message"]

_K_NAMES = ("camera_matrix", "K", "cameraMatrix", "intrinsics")
_D_NAMES = ("distortion_coefficients", "D", "dist_coeffs", "distCoeffs", "distortion")


def camera_from_matrix(K, dist, width, height, source="camera info") -> PinholeCamera:
    """A :class:`PinholeCamera` from a 3x3 ``K``, distortion coefficients and the image size.

    ``width`` and ``height`` must be whole numbers of pixels (``640.0`` is taken, ``640.7``
    and ``True`` are refused rather than truncated).
    """
    K = _finite_array(K, "camera matrix", source)
    if K.size != 9:
        raise ValueError(f"{source}: camera matrix: expected 9 values, got {K.size}")
    K = K.reshape(3, 3)
    if not np.allclose(K[2], [0, 0, 1]) or abs(K[1, 0]) > 1e-12:
        raise ValueError(f"{source}: camera matrix: last row must be (0, 0, 1) and K[1,0] = 0, got {K.tolist()}")
    if abs(K[0, 1]) > 1e-9 * max(abs(K[0, 0]), 1.0):
        raise ValueError(f"{source}: camera matrix has skew {K[0, 1]}; PinholeCamera has none")
    d = np.zeros(5) if dist is None else _finite_array(dist, "distortion coefficients", source).ravel()
    if d.size > 5:
        if np.any(d[5:] != 0):
            raise ValueError(f"{source}: distortion has {d.size} coefficients with non-zero terms beyond "
                             f"(k1, k2, p1, p2, k3): {d.tolist()}; only the 5-term model is supported")
        d = d[:5]
    d = np.pad(d, (0, 5 - d.size))
    w = image_side(width, "width", source)
    h = image_side(height, "height", source)
    try:
        return PinholeCamera(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), w, h,
                             tuple(float(x) for x in d))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: {exc}") from None


def image_side(value, name: str, source: str = "camera info") -> int:
    """A whole number of pixels in ``1..MAX_IMAGE_SIDE`` from ``value`` (an int, or a float without a fraction).

    Booleans, strings, fractions and non-finite numbers raise a ``ValueError`` naming ``source``,
    the field ``name`` and the value, instead of being truncated (``640.7`` -> 640, ``True`` -> 1).
    """
    v = value.item() if isinstance(value, np.generic) else value
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not
                                                                  (np.isfinite(v) and v == int(v))):
        raise ValueError(f"{source}: {name}: expected a whole number of pixels, got {_show(value)}")
    v = int(v)
    if not 1 <= v <= MAX_IMAGE_SIDE:
        raise ValueError(f"{source}: {name}: expected 1 to {MAX_IMAGE_SIDE} pixels, got {v}")
    return v


def _finite_array(x, name: str, source: str) -> np.ndarray:
    """Numbers (no booleans, strings or missing values), all finite, as a float array."""
    arr = x if isinstance(x, np.ndarray) and x.dtype.kind in "iuf" else None
    if arr is None:
        items = np.asarray(x, dtype=object)  # nested or ragged lists: their rows are the items
        bad = [v for v in items.ravel() if isinstance(v, (bool, np.bool_))
               or not isinstance(v, (int, float, np.integer, np.floating))]
        if bad or items.size == 0:
            raise ValueError(f"{source}: {name}: expected numbers, got {_show(bad[0] if bad else x)}")
        arr = items
    arr = arr.astype(float)
    if not np.isfinite(arr).all():
        i = int(np.flatnonzero(~np.isfinite(arr.ravel()))[0])
        raise ValueError(f"{source}: {name}: must be finite, got {arr.ravel()[i]} at index {i}")
    return arr


def _show(v) -> str:
    """A value for a message, saying when it is text or a boolean (``'480'`` is not 480)."""
    if isinstance(v, str):
        return f"{v!r} (a string)"
    if isinstance(v, (bool, np.bool_)):
        return f"{v!r} (a boolean)"
    return repr(v)


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
        A :class:`ReadError` naming the file, the missing or bad field and its value.
    """
    p = Path(path)
    if not p.is_file():
        if p.exists():
            raise ReadError(p, "not a file (a camera_info YAML or OpenCV FileStorage YAML/XML file is expected)")
        raise FileNotFoundError(f"{p}: no such file")
    text = _read_text(p)
    head = text[:4096].lstrip("\ufeff").lstrip()
    if p.suffix.lower() == ".xml" or head.startswith(("%YAML", "<?xml")) or "!!opencv-matrix" in head:
        return _read_opencv(p)
    data = _yaml_mapping(p, text)
    kname = _key(p, data, _K_NAMES, required=f"no camera matrix (looked for {', '.join(_K_NAMES)})")
    dname = _key(p, data, _D_NAMES)
    K = _numbers(p, data[kname], kname)
    D = None if dname is None else _numbers(p, data[dname], dname)
    wname = _key(p, data, ("image_width", "width"), required="missing image_width / image_height")
    hname = _key(p, data, ("image_height", "height"), required="missing image_width / image_height")
    w, h = (_side(p, data[n], n) for n in (wname, hname))
    model = data.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial"):
        raise ReadError(p, f"distortion_model: unsupported {model!r} (plumb_bob or rational_polynomial)")
    try:
        return camera_from_matrix(K, D, w, h, str(p))
    except (TypeError, ValueError) as exc:
        raise ReadError(p, str(exc).removeprefix(f"{p}: ")) from None


def _read_text(p: Path) -> str:
    """The file as UTF-8 text, with the size limit of the project's config files; errors name the file."""
    from .._config import MAX_BYTES

    try:
        n = p.stat().st_size
        if n > MAX_BYTES:
            raise ReadError(p, f"camera info file is {n:,} bytes, over the limit of {MAX_BYTES:,} bytes")
        raw = p.read_bytes()
    except OSError as exc:
        raise ReadError(p, f"cannot read the camera info file: {exc.strerror or exc}") from None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ReadError(p, f"not UTF-8 text (byte 0x{raw[exc.start]:02x})", offset=exc.start) from None


def _yaml_mapping(p: Path, text: str) -> dict:
    """The ROS camera_info YAML through the project's one config parser (duplicate keys, alias bombs refused)."""
    import yaml

    from .._config import ConfigError, parse_config

    try:
        data = parse_config(text)
    except (ConfigError, yaml.YAMLError) as exc:
        raise ReadError(p, str(exc)) from None
    if not isinstance(data, dict):
        raise ReadError(p, f"expected a mapping of camera_info fields, got {type(data).__name__}")
    return data


def _key(p, data, names, required=None):
    """The first of ``names`` that is a key of ``data``; None (or a ReadError ``required``) if none is."""
    for k in names:
        if k in data:
            return k
    if required is not None:
        raise ReadError(p, required)
    return None


def _numbers(p, value, name) -> np.ndarray:
    """A ROS matrix field (``{rows, cols, data}`` or a plain list) as finite floats."""
    if isinstance(value, dict):
        if "data" not in value:
            raise ReadError(p, f"{name}: expected a 'data' list, got the keys {sorted(map(str, value))}")
        value, name = value["data"], f"{name}.data"
    try:
        return _finite_array(value, name, str(p))
    except ValueError as exc:
        raise ReadError(p, str(exc).removeprefix(f"{p}: ")) from None


def _side(p, value, name) -> int:
    try:
        return image_side(value, name, str(p))
    except ValueError as exc:
        raise ReadError(p, str(exc).removeprefix(f"{p}: ")) from None


def _read_opencv(p: Path) -> PinholeCamera:
    import cv2

    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        # a parse error can surface as SystemError ("returned a result with an exception set") wrapping cv2.error
        raise ReadError(p, f"OpenCV FileStorage cannot parse it: {_cv_reason(exc)}") from None
    if not fs.isOpened():
        raise ReadError(p, "OpenCV FileStorage cannot open it")
    try:
        def node(names):
            for n in names:
                nd = fs.getNode(n)
                if not nd.empty() and not nd.isNone():
                    return n, nd
            return None, None

        kname, k = node(_K_NAMES)
        if k is None:
            raise ReadError(p, f"no camera matrix node (looked for {', '.join(_K_NAMES)})")
        K = _cv_matrix(p, k, kname)
        dname, d = node(_D_NAMES)
        D = None if d is None else _cv_matrix(p, d, dname)
        (wname, wn), (hname, hn) = node(("image_width", "width")), node(("image_height", "height"))
        if wn is None or hn is None:
            raise ReadError(p, "missing image_width / image_height nodes")
        w, h = _cv_side(p, wn, wname), _cv_side(p, hn, hname)
        try:
            return camera_from_matrix(K, D, w, h, str(p))
        except ValueError as exc:
            raise ReadError(p, str(exc).removeprefix(f"{p}: ")) from None
    except (cv2.error, SystemError) as exc:  # anything OpenCV refuses that the checks above let through
        raise ReadError(p, f"OpenCV FileStorage cannot read it: {_cv_reason(exc)}") from None
    finally:
        fs.release()


def _cv_reason(exc) -> str:
    """The useful part of a cv2.error (possibly the context of a SystemError)."""
    import cv2

    err = exc if isinstance(exc, cv2.error) else exc.__context__ or exc.__cause__
    if isinstance(err, cv2.error):
        func, what = getattr(err, "func", "") or "", getattr(err, "err", "") or ""
        if getattr(err, "code", None) == -212 and func:  # parse errors: .func holds "calib.yaml(3): Missing ':'"
            text = func
        elif what:
            text = f"OpenCV check {what!r} failed" + (f" in {func}" if func else "")
        else:
            text = str(err)
        return " ".join(str(text).split())
    return " ".join(str(exc).split())


def _cv_describe(nd) -> str:
    """A FileNode's value or kind, for messages."""
    if nd.isInt():
        return f"{int(nd.real())}"
    if nd.isReal():
        return f"{nd.real()!r}"
    if nd.isString():
        return f"{nd.string()!r} (a string)"
    if nd.isSeq():
        return f"a sequence of {nd.size()}"
    if nd.isMap():
        return f"a mapping with keys {list(nd.keys())}"
    return "an empty value"


def _cv_matrix(p, nd, name) -> np.ndarray:
    """A matrix node: ``!!opencv-matrix``, a ``{rows, cols, data}`` mapping or a sequence of numbers."""
    import cv2

    if nd.isMap():
        keys = set(nd.keys())
        if "dt" in keys:
            _cv_check_count(p, nd, name)
            try:
                m = nd.mat()
            except cv2.error as exc:
                raise ReadError(p, f"{name}: not a valid !!opencv-matrix ({_cv_reason(exc)})") from None
            if m is None:
                raise ReadError(p, f"{name}: not a valid !!opencv-matrix (no data)")
            try:
                return _finite_array(np.asarray(m), name, str(p))
            except ValueError as exc:
                raise ReadError(p, str(exc).removeprefix(f"{p}: ")) from None
        if "data" not in keys:
            raise ReadError(p, f"{name}: expected a matrix (!!opencv-matrix or a list of numbers), "
                               f"got {_cv_describe(nd)}")
        nd, name = nd.getNode("data"), f"{name}.data"
    if not nd.isSeq():
        raise ReadError(p, f"{name}: expected a matrix (!!opencv-matrix or a list of numbers), got {_cv_describe(nd)}")
    vals = []
    for i in range(nd.size()):
        e = nd.at(i)
        if not (e.isInt() or e.isReal()):
            raise ReadError(p, f"{name}: expected numbers, got {_cv_describe(e)} at index {i}")
        vals.append(e.real())
    try:
        return _finite_array(np.asarray(vals, float), name, str(p))
    except ValueError as exc:
        raise ReadError(p, str(exc).removeprefix(f"{p}: ")) from None


def _cv_check_count(p, nd, name) -> None:
    """An ``!!opencv-matrix`` whose data do not fill rows x cols, refused with the counts (OpenCV only asserts)."""
    rows, cols, data, dt = (nd.getNode(k) for k in ("rows", "cols", "data", "dt"))
    for key, v in (("rows", rows), ("cols", cols)):
        if not v.isInt() or v.real() < 1:
            raise ReadError(p, f"{name}.{key}: expected a whole number >= 1, got {_cv_describe(v)}")
    if not data.isSeq():
        raise ReadError(p, f"{name}.data: expected a list of numbers, got {_cv_describe(data)}")
    single = dt.isString() and len(dt.string()) == 1  # "d", "f", "i", ...: one channel
    need = int(rows.real()) * int(cols.real())
    if single and data.size() != need:
        raise ReadError(p, f"{name}: rows x cols = {int(rows.real())} x {int(cols.real())} needs {need} values, "
                           f"data has {data.size()}")


def _cv_side(p, nd, name) -> int:
    """An image size node: a number (an integer, or a real without a fraction); strings and the rest refused."""
    if not (nd.isInt() or nd.isReal()):
        raise ReadError(p, f"{name}: expected a whole number of pixels, got {_cv_describe(nd)}")
    return _side(p, nd.real(), name)
