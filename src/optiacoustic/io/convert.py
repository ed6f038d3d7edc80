"""A real sonar log (ARIS, Oculus, ROS 1/2 bag, MCAP) into the dataset layout (docs/datasets.md).

The ``sonar`` group gets what a simulated dataset has that a log can give: ``image``
(linear intensity decoded by the reader), ``raw`` (the device's values as stored),
``time`` (s since the Unix epoch, NaN without a clock), ``pose`` (NaN: a log has no
ground-truth pose), ``ranges``, ``azimuths`` and ``done``. The store is written beside the
output under a temporary name and renamed when complete, so a killed conversion leaves
nothing at the output path.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["convert_log"]


def convert_log(path, out, *, topic: str | None = None, camera=None, camera_topic: str | None = None,
                errors: str = "raise") -> dict:
    """Convert the sonar frames of a log into a Zarr v3 dataset.

    Parameters
    ----------
    path : path-like
        A log :func:`optiacoustic.io.open_sonar` reads.
    out : path-like
        The ``.zarr`` folder to create; must not exist.
    topic : str, optional
        Sonar topic of a bag (default: its only sonar topic).
    camera : path-like, optional
        Camera images to add as the ``camera`` group: a bag or a folder of images
        (:func:`optiacoustic.io.open_camera`). Default: ``path`` itself when
        ``camera_topic`` is given, else no camera.
    camera_topic : str, optional
        Image topic of the camera bag.
    errors : {"raise", "skip"}
        A damaged frame stops the conversion (default) or is left not done
        (``done[k] = False``, fill values) and listed in the result.

    Returns
    -------
    dict with ``frames`` (sonar frames written), ``camera_frames``, ``skipped`` (sonar
    frame indices) and ``path``.
    """
    import zarr

    from .. import __version__
    from ..sonar.frame import spec_to_dict
    from .dataset import FORMAT, FORMAT_VERSION, DatasetError, _checksum, _compressors, _jsonable
    from .sonar import open_sonar

    out = Path(out)
    if out.exists():
        raise DatasetError(f"{out}: already exists; convert writes a new dataset")
    frames = open_sonar(path, topic=topic)
    n = len(frames)
    if n == 0:
        raise DatasetError(f"{path}: has no sonar frame")
    k0, first = _first_readable(frames, errors)
    spec = first.spec
    shape = (spec.n_bins, spec.n_beams)
    ranges, azimuths = np.asarray(spec.ranges, float), np.asarray(spec.azimuths, float)
    from .._atomic import ensure_dir

    ensure_dir(out.parent)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.stem}.tmp-", dir=out.parent)) / out.name
    try:
        root = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        g = root.create_group("sonar")
        dims = ("frame", "bin", "beam")
        img = g.create_array("image", shape=(n,) + shape, chunks=(1,) + shape, dtype="float32", fill_value=np.nan,
                             compressors=_compressors(), dimension_names=dims)
        raw = g.create_array("raw", shape=(n,) + shape, chunks=(1,) + shape, dtype=first.raw.dtype.newbyteorder("<"),
                             fill_value=0, compressors=_compressors(), dimension_names=dims)
        done = g.create_array("done", shape=(n,), chunks=(1,), dtype="bool", fill_value=False,
                              compressors=_checksum(), dimension_names=("frame",))
        times = np.full(n, np.nan)
        skipped = []
        for k, f in _readable_frames(frames, first, k0, errors, skipped):
            if f.image.shape != shape:
                raise DatasetError(f"{path}: frame {k} is {f.image.shape[0]} bins x {f.image.shape[1]} beams, "
                                   f"frame {k0} is {shape[0]} x {shape[1]}; one dataset holds one sonar geometry")
            if not (np.allclose(f.spec.ranges, ranges) and np.allclose(f.spec.azimuths, azimuths)):
                raise DatasetError(f"{path}: frame {k} has other ranges or beam azimuths than frame {k0} "
                                   "(the range window changed); one dataset holds one sonar geometry")
            img[k] = f.image
            raw[k] = f.raw
            done[k] = True
            times[k] = f.time
        g.create_array("time", data=times, dimension_names=("frame",), attributes={"units": "s since the Unix epoch"},
                       compressors=_compressors())
        g.create_array("pose", data=np.full((n, 4, 4), np.nan), dimension_names=("frame", "pose_row", "pose_col"),
                       attributes={"description": "unknown for a measured log (NaN)"}, compressors=_compressors())
        g.create_array("ranges", data=ranges, dimension_names=("bin",), attributes={"units": "m"},
                       compressors=_compressors())
        g.create_array("azimuths", data=azimuths, dimension_names=("beam",), attributes={"units": "rad"},
                       compressors=_compressors())
        n_cam = 0
        if camera is not None or camera_topic is not None:
            n_cam = _convert_camera(root, camera if camera is not None else path, camera_topic, errors)
        root.attrs["optiacoustic"] = _jsonable({
            "format": FORMAT, "format_version": FORMAT_VERSION, "package_version": __version__, "measured": True,
            "source": str(path), "topic": topic, "encoding": first.encoding,
            "sonar_spec": spec_to_dict(spec), "skipped_frames": skipped, "layout_complete": True,
        })
        tmp.replace(out)
    finally:
        shutil.rmtree(tmp.parent, ignore_errors=True)
    return {"path": out, "frames": n - len(skipped), "camera_frames": n_cam, "skipped": skipped}


def _convert_camera(root, path, topic, errors: str) -> int:
    """The ``camera`` group from a camera log: image (linear RGB float32), time, pose (NaN), K, done."""
    from .camera import open_camera
    from .dataset import DatasetError, _checksum, _compressors

    frames = open_camera(path, topic=topic)
    n = len(frames)
    if n == 0:
        raise DatasetError(f"{path}: has no camera frame")
    k0, first = _first_readable(frames, errors)
    shape = first.image.shape
    g = root.create_group("camera")
    img = g.create_array("image", shape=(n,) + shape, chunks=(1,) + shape, dtype="float32", fill_value=np.nan,
                         compressors=_compressors(), dimension_names=("frame", "row", "col", "channel"))
    done = g.create_array("done", shape=(n,), chunks=(1,), dtype="bool", fill_value=False, compressors=_checksum(),
                          dimension_names=("frame",))
    times = np.full(n, np.nan)
    written = 0
    skipped = []
    for k, f in _readable_frames(frames, first, k0, errors, skipped):
        if f.image.shape != shape:
            raise DatasetError(f"{path}: camera frame {k} is {f.image.shape}, frame {k0} is {shape}")
        img[k] = f.image
        done[k] = True
        times[k] = f.time
        written += 1
    g.create_array("time", data=times, dimension_names=("frame",), attributes={"units": "s since the Unix epoch"},
                   compressors=_compressors())
    g.create_array("pose", data=np.full((n, 4, 4), np.nan), dimension_names=("frame", "pose_row", "pose_col"),
                   attributes={"description": "unknown for a measured log (NaN)"}, compressors=_compressors())
    if first.camera is not None:
        g.create_array("K", data=np.asarray(first.camera.K, float), dimension_names=("k_row", "k_col"),
                       compressors=_compressors())
    g.attrs["skipped_frames"] = skipped  # damaged camera frames are reported, never dropped silently
    return written


def _first_readable(frames, errors: str):
    """``(k, frame)``: frame 0, or with ``errors="skip"`` the first frame that reads (it sets the
    dataset's geometry); raises the first frame's error when none does."""
    from .errors import ReadError

    first_error = None
    for k in range(len(frames) if errors == "skip" else 1):
        try:
            return k, frames[k]
        except ReadError as exc:
            first_error = first_error or exc
    raise first_error


def _readable_frames(frames, first, k0: int, errors: str, skipped: list):
    """Yield ``(k, frame)`` for every frame of a log (``first`` is frame ``k0``, already read); a
    damaged one raises, or is appended to ``skipped``."""
    from .errors import ReadError

    for k in range(len(frames)):
        try:
            f = first if k == k0 else frames[k]
        except ReadError:
            if errors == "raise":
                raise
            skipped.append(k)
            continue
        yield k, f
