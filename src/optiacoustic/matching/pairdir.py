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
        rig_m, cam_m, son_m = meta["rig"], meta["camera"], meta["sonar"]
        camera = PinholeCamera(fx=float(cam_m["fx"]), fy=float(cam_m["fy"]), cx=float(cam_m["cx"]),
                               cy=float(cam_m["cy"]), width=int(cam_m["width"]), height=int(cam_m["height"]),
                               dist=tuple(float(v) for v in cam_m.get("dist", [0.0] * 5)))
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{meta_path}: malformed: {exc!r}") from None
    s = _load_npz(folder / "sonar.npz", ("image", "ranges", "azimuths"))
    o = _load_npz(folder / "optical.npz", ("image",))
    ranges, az = s["ranges"].astype(float), s["azimuths"].astype(float)
    try:
        spec = PairSonarSpec(
            fov_azimuth=float(np.deg2rad(son_m["fov_azimuth_deg"])),
            fov_elevation=float(np.deg2rad(son_m["fov_elevation_deg"])),
            range_min=float(son_m["range_min"]), range_max=float(son_m["range_max"]),
            range_resolution=float(range_resolution or np.median(np.diff(ranges))),
            beamwidth_azimuth=float(beamwidth_azimuth or np.median(np.diff(az))),
            name=str(son_m.get("preset", "")))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{meta_path}: field 'sonar' malformed: {exc!r}") from None
    beam_model = son_m.get("beam_model", "thesis")
    if beam_model not in ("thesis", "aperture"):
        raise ValueError(f"{meta_path}: field 'sonar.beam_model': expected 'thesis' or 'aperture', got {beam_model!r}")
    sonar = PairSonarFrame(s["image"].astype(np.float32), ranges, az, spec, beam_model=beam_model)
    rig = Rig(np.asarray(rig_m["R"], float), np.asarray(rig_m["t"], float), camera, spec)
    return sonar, o["image"], rig, o.get("depth")
