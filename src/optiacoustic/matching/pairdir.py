"""Read a rig pair folder (what ``oas render`` writes) without a simulator.

The folder holds ``sonar.npz`` (``image``, ``ranges``, ``azimuths``), ``optical.npz``
(``image``) and ``pair.json`` (the rig's ``R``, ``t``, the camera intrinsics and the sonar's
apertures and resolution). :func:`read_pair` returns the sonar frame (the shared protocol),
the camera image and the rig; ground truth, when the npz files hold it (``depth``), comes
back separately and only the evaluation uses it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import PinholeCamera
from ..rig import Rig

__all__ = ["PairSonarSpec", "PairSonarFrame", "read_pair"]


@dataclass(frozen=True)
class PairSonarSpec:
    """The sonar parameters the matcher needs (from ``pair.json``)."""

    fov_azimuth: float
    fov_elevation: float
    range_min: float
    range_max: float
    range_resolution: float
    beamwidth_azimuth: float
    name: str = ""


@dataclass(frozen=True, eq=False)
class PairSonarFrame:
    """A sonar frame read from a pair folder: ``.image``, ``.ranges``, ``.azimuths``, ``.spec``, ``.time``,
    ``.beam_model`` (``pair.json``'s ``sonar.beam_model``; folders written before it was recorded: ``"thesis"``)."""

    image: np.ndarray
    ranges: np.ndarray
    azimuths: np.ndarray
    spec: PairSonarSpec
    time: float = 0.0
    beam_model: str = "thesis"


def _load_npz(path: Path, keys) -> dict:
    if not path.is_file():
        raise ValueError(f"{path}: missing (a pair folder written by 'oas render' holds it)")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise ValueError(f"{path}: field '{missing[0]}' missing; has {sorted(z.files)}")
            return {k: np.asarray(z[k]) for k in z.files if k in keys or k == "depth"}
    except (OSError, EOFError) as exc:
        raise ValueError(f"{path}: cannot read npz: {exc}") from None


def read_pair(folder, *, range_resolution: float | None = None, beamwidth_azimuth: float | None = None):
    """``(sonar, camera_image, rig, depth)`` from a pair folder; ``depth`` is None when absent.

    ``pair.json`` does not record the sonar's range resolution and azimuth beamwidth: pass
    them (m, rad; the CLI takes them from the named preset), else one bin and one beam
    spacing are assumed.

    Raises
    ------
    ValueError
        Naming the file and field that is missing or malformed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder (expected the output folder of 'oas render')")
    meta_path = folder / "pair.json"
    if not meta_path.is_file():
        raise ValueError(f"{meta_path}: missing (a pair folder written by 'oas render' holds it)")
    try:
        meta = json.loads(meta_path.read_text())
    except (ValueError, OSError) as exc:
        raise ValueError(f"{meta_path}: not JSON: {exc}") from None

    def field(path):
        node = meta
        for part in path.split("."):
            if not isinstance(node, dict) or part not in node:
                raise ValueError(f"{meta_path}: field '{path}' missing")
            node = node[part]
        return node

    def number(path, check=None, what=""):
        v = field(path)
        try:
            x = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"{meta_path}: field '{path}': expected a number, got {v!r}") from None
        if not np.isfinite(x) or (check is not None and not check(x)):
            raise ValueError(f"{meta_path}: field '{path}': expected {what or 'a finite number'}, got {v!r}")
        return x

    try:
        cam_m = field("camera")
        camera = PinholeCamera(fx=number("camera.fx"), fy=number("camera.fy"), cx=number("camera.cx"),
                               cy=number("camera.cy"), width=int(number("camera.width")),
                               height=int(number("camera.height")),
                               dist=tuple(float(v) for v in cam_m.get("dist", [0.0] * 5)))
    except (KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"{meta_path}: field 'camera' malformed: {exc!r}") from None
    except ValueError as exc:
        raise ValueError(exc if str(exc).startswith(str(meta_path)) else f"{meta_path}: field 'camera': {exc}") from None
    s = _load_npz(folder / "sonar.npz", ("image", "ranges", "azimuths"))
    o = _load_npz(folder / "optical.npz", ("image",))
    ranges, az = s["ranges"].astype(float), s["azimuths"].astype(float)
    fov_az = number("sonar.fov_azimuth_deg", lambda x: 0 < x <= 360, "an angle in (0, 360] deg")
    fov_el = number("sonar.fov_elevation_deg", lambda x: 0 < x <= 180, "an angle in (0, 180] deg")
    r_min = number("sonar.range_min", lambda x: x >= 0, "a range >= 0 m")
    r_max = number("sonar.range_max", lambda x: x > r_min, f"a range > sonar.range_min ({r_min:g} m)")
    son_m = field("sonar")
    try:
        spec = PairSonarSpec(
            fov_azimuth=float(np.deg2rad(fov_az)), fov_elevation=float(np.deg2rad(fov_el)),
            range_min=r_min, range_max=r_max,
            range_resolution=float(range_resolution or np.median(np.diff(ranges))),
            beamwidth_azimuth=float(beamwidth_azimuth or np.median(np.diff(az))),
            name=str(son_m.get("preset", "")))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{meta_path}: field 'sonar' malformed: {exc!r}") from None
    beam_model = son_m.get("beam_model", "thesis")
    if beam_model not in ("thesis", "aperture"):
        raise ValueError(f"{meta_path}: field 'sonar.beam_model': expected 'thesis' or 'aperture', got {beam_model!r}")
    sonar = PairSonarFrame(s["image"].astype(np.float32), ranges, az, spec, beam_model=beam_model)
    R_m, t_m = field("rig.R"), field("rig.t")
    try:
        rig = Rig(np.asarray(R_m, float), np.asarray(t_m, float), camera, spec)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{meta_path}: field 'rig': {exc}") from None
    depth = o.get("depth")
    shape = np.shape(o["image"])[:2]
    if depth is not None and np.shape(depth) != shape:
        raise ValueError(f"{folder / 'optical.npz'}: field 'depth' has shape {np.shape(depth)}, the image {shape}")
    return sonar, o["image"], rig, depth
