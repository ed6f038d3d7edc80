"""Results of a sonar simulation: the frame, its ground truth and its per-ray data."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Literal, Mapping, Protocol, runtime_checkable

import numpy as np

from ..frames import Pose
from .display import FanImage, polar_to_fan
from .spec import SonarSpec

__all__ = ["SonarFrame", "SonarGroundTruth", "SonarRays", "FanImage", "MeasuredSonarFrame", "SonarImageLike",
           "load_frame", "spec_to_dict", "spec_from_dict"]

#: Format tag and version written into saved frames.
_FORMAT = "optiacoustic.sonar-frame"
_VERSION = 1


@runtime_checkable
class SonarImageLike(Protocol):
    """What every sonar frame offers, simulated (:class:`SonarFrame`) or measured (:class:`MeasuredSonarFrame`).

    ``image``: ``(n_bins, n_beams)`` float32 linear intensity; ``ranges`` (m, ``(n_bins,)``),
    ``azimuths`` (rad, ``(n_beams,)``, possibly uneven), ``time`` (s since the epoch, NaN when
    unknown), ``spec`` (:class:`SonarSpec`), ``fan(width=...)`` (:class:`FanImage`).
    """

    @property
    def image(self) -> np.ndarray: ...

    @property
    def ranges(self) -> np.ndarray: ...

    @property
    def azimuths(self) -> np.ndarray: ...

    @property
    def time(self) -> float: ...

    @property
    def spec(self) -> SonarSpec: ...

    def fan(self, which: str = "image", *, width: int = 800) -> "FanImage": ...


def spec_to_dict(spec: SonarSpec) -> dict:
    """A JSON-able dict of every field of a spec (radians, metres; tables as lists).

    Field values that are objects with ``to_dict()`` (e.g. beam patterns) are stored as
    ``{"__type__": "module.Class", "data": obj.to_dict()}`` and rebuilt with ``Class.from_dict``.
    """
    out = {}
    for f in dataclasses.fields(SonarSpec):
        v = getattr(spec, f.name)
        if isinstance(v, tuple):
            v = list(v)
        elif hasattr(v, "to_dict"):
            v = {"__type__": f"{type(v).__module__}.{type(v).__qualname__}", "data": v.to_dict()}
        out[f.name] = v
    return out


def spec_from_dict(d: Mapping) -> SonarSpec:
    """Inverse of :func:`spec_to_dict` (exact: floats survive JSON unchanged)."""
    import importlib

    names = {f.name for f in dataclasses.fields(SonarSpec)}
    unknown = set(d) - names
    if unknown:
        raise ValueError(f"spec: unknown fields {sorted(unknown)}")
    kw = {}
    for k, v in d.items():
        if isinstance(v, list):
            v = tuple(v)
        elif isinstance(v, dict) and "__type__" in v:
            mod, _, cls = v["__type__"].rpartition(".")
            if not mod.startswith("optiacoustic."):
                raise ValueError(f"spec: field {k}: refusing to build type {v['__type__']!r}")
            v = getattr(importlib.import_module(mod), cls).from_dict(v["data"])
        kw[k] = v
    return SonarSpec(**kw)


@dataclass(frozen=True, eq=False)
class MeasuredSonarFrame:
    """One sonar frame read from a real log (or emitted in a device's units).

    Shares :class:`SonarImageLike` with :class:`SonarFrame`, so every function that takes
    a sonar image takes either.

    Attributes
    ----------
    raw : ndarray ``(n_bins, n_beams)``
        The values as the device stored them (``uint8`` dB bytes for ARIS, gamma-coded
        ``uint8`` or ``uint16`` for Oculus, any ``ProjectedSonarImage`` type, ...).
        Row = range bin (near to far), column = beam (left to right).
    image : float32 ``(n_bins, n_beams)``
        Linear intensity decoded from ``raw`` with ``encoding`` (``optiacoustic.io.units``).
    spec : SonarSpec
        The device as far as the file says (beam table, range window or table, frequency,
        sound speed); fields the file does not give keep SonarSpec's defaults.
    time : float
        Seconds since the Unix epoch (float64); NaN when the file has no clock.
    encoding : str
        How ``raw`` maps to ``image`` (``"linear"``, ``"aris_db"``, ``"oculus_gamma8"``, ...).
    source : str
        File (and topic) the frame came from.
    index : int
        Frame index within the file or topic.
    meta : mapping
        Device settings as read (read-only; JSON-able values).
    beam_model : {"aperture", "thesis"}
        The elevation beam the image was formed with. ``"aperture"`` (the default): a real
        transducer's beam has no hard edge, its two-way pattern fades in and out
        (``spec.elevation_pattern()``), as in the simulator's ``beam_model="aperture"``. A simulated
        frame emitted in a device's units (``io.units.as_device_frame``) keeps its own; a log read
        back does not record it and reads as ``"aperture"``.
    """

    raw: np.ndarray
    image: np.ndarray
    spec: SonarSpec
    time: float = float("nan")
    encoding: str = "linear"
    source: str = ""
    index: int = 0
    meta: Mapping = field(default_factory=dict)
    beam_model: str = "aperture"

    def __post_init__(self):
        if self.beam_model not in ("thesis", "aperture"):
            raise ValueError(f"MeasuredSonarFrame.beam_model: expected 'thesis' or 'aperture', got {self.beam_model!r}")
        shape = (self.spec.n_bins, self.spec.n_beams)
        for name in ("raw", "image"):
            a = getattr(self, name)
            if np.shape(a) != shape:
                raise ValueError(f"MeasuredSonarFrame.{name}: expected shape (n_bins, n_beams) = {shape}, "
                                 f"got {np.shape(a)}")
        if not isinstance(self.meta, MappingProxyType):
            object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))

    @property
    def ranges(self) -> np.ndarray:
        """Range-bin centres (m), ``(n_bins,)``."""
        return self.spec.ranges

    @property
    def azimuths(self) -> np.ndarray:
        """Beam-centre azimuths (rad), ``(n_beams,)``, possibly uneven."""
        return self.spec.azimuths

    @property
    def intensity(self) -> np.ndarray:
        """Alias of ``image`` (a measured frame has no separate noise-free echo)."""
        return self.image

    def fan(self, which: Literal["image", "intensity"] = "image", *, width: int = 800) -> FanImage:
        """The linear image resampled to the fan (beam and range tables honoured)."""
        from .display import polar_to_fan

        if which not in ("image", "intensity"):
            raise ValueError(f"fan: which must be 'image' or 'intensity', got {which!r}")
        return polar_to_fan(self.image, self.spec, width=width)

    def save(self, path) -> Path:
        """Write raw, image, spec, time, encoding and meta to ``.npz`` (atomically); :meth:`load` reads it back."""
        from .._atomic import save_npz

        header = dict(format=_FORMAT, version=_VERSION, kind="measured", spec=spec_to_dict(self.spec),
                      time=self.time, encoding=self.encoding, source=self.source, index=int(self.index),
                      meta=dict(self.meta), beam_model=self.beam_model)
        return save_npz(path, header=np.array(json.dumps(header, default=_json_default)), raw=self.raw,
                        image=self.image)

    @staticmethod
    def load(path) -> "SonarFrame | MeasuredSonarFrame":
        """Read a frame written by ``save`` (either kind)."""
        return load_frame(path)


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (bytes, bytearray)):
        return o.hex()
    raise TypeError(f"meta value of type {type(o).__name__} is not JSON-able")


def load_frame(path) -> "SonarFrame | MeasuredSonarFrame":
    """Read a frame written by :meth:`SonarFrame.save` or :meth:`MeasuredSonarFrame.save`.

    Raises
    ------
    ValueError
        Not such a file (names the path and what is missing).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        z = np.load(path, allow_pickle=False)
        header = json.loads(str(z["header"]))
    except Exception as exc:  # zip/npz/json errors of every kind: one clear message
        raise ValueError(f"{path}: not a saved sonar frame ({type(exc).__name__}: {exc})") from None
    if header.get("format") != _FORMAT:
        raise ValueError(f"{path}: not a saved sonar frame (format {header.get('format')!r})")
    if header.get("version", 0) > _VERSION:
        raise ValueError(f"{path}: frame format version {header['version']} is newer than this reader ({_VERSION})")
    spec = spec_from_dict(header["spec"])
    if header["kind"] == "measured":
        return MeasuredSonarFrame(raw=z["raw"], image=z["image"], spec=spec, time=float(header["time"]),
                                  encoding=header["encoding"], source=header["source"], index=header["index"],
                                  meta=header["meta"], beam_model=str(header.get("beam_model", "aperture")))
    arrays = {k: z[k] for k in z.files}
    rays = SonarRays(**{f.name: arrays[f"ray_{f.name}"] for f in dataclasses.fields(SonarRays)
                        if f.name != "elevation_step"}, elevation_step=float(header["elevation_step"]))
    maps = (arrays["gt_body"], arrays["gt_elevation_min"], arrays["gt_elevation_max"])
    shadow = arrays["gt_shadow"]
    gt = SonarGroundTruth(arrays["gt_range_map"], lambda: maps, lambda _emin: shadow)
    return SonarFrame(spec=spec, pose=Pose(arrays["pose_R"], arrays["pose_t"]), intensity=arrays["intensity"],
                      image=arrays["image"], ground_truth=gt, rays=rays, body_names=tuple(header["body_names"]),
                      seabed_share={k: arrays[f"share_{k}"] for k in header["seabed_share"]},
                      time=float(header["time"]), beam_model=str(header.get("beam_model", "thesis")))


@dataclass(frozen=True, eq=False)
class SonarRays:
    """Per-ray data of the scan (thesis sec. 2.6.1, the 512 x 750 matrices of Fig. 2.4-2.7).

    Every array is ``(elevation_samples, n_beams)``: row = elevation sample (bottom to
    top of the aperture), column = beam.

    Attributes
    ----------
    range : distance to the hit (m); ``inf`` on a miss.
    energy : the ray's echo energy (reflectivity x cos(incidence) x beam weight x dphi).
    body : id of the body hit; ``-1`` on a miss.
    cos_incidence : cosine of the angle between the ray and the surface normal.
    footprint_lo, footprint_hi : range interval (m) the ray's elevation cell covers on
        its tangent plane; NaN on a miss.
    beam_index, elevation : beam index and elevation (rad) of each ray.
    elevation_lo, elevation_hi : the elevation cell each ray stands for (rad); cells are
        ``elevation_step`` wide except at visibility edges, where they end at the edge.
    elevation_step : nominal angular width of a ray's elevation cell (rad).
    """

    range: np.ndarray
    energy: np.ndarray
    body: np.ndarray
    cos_incidence: np.ndarray
    footprint_lo: np.ndarray
    footprint_hi: np.ndarray
    beam_index: np.ndarray
    elevation: np.ndarray
    elevation_lo: np.ndarray
    elevation_hi: np.ndarray
    elevation_step: float


class SonarGroundTruth:
    """What the sonar image does not say. Maps are ``(n_bins, n_beams)`` like the image.

    The maps are computed on first access and cached (the shadow needs extra rays), so a
    frame costs nothing for truth it is never asked for.

    Attributes
    ----------
    body : int16
        Body id of the strongest single contribution to each cell; ``-1`` where nothing
        echoes. Names are ``SonarFrame.body_names``.
    elevation_min, elevation_max : float32
        Span of elevation angles (rad) of the rays that echo in each cell: the ambiguity
        the sonar cannot resolve and a camera can. NaN where nothing echoes.
    shadow : bool
        Acoustic shadow: cells that a surface would echo into but for an occluder in
        front of it (sec. 2.6.2.2).
    range_map : float32, ``(elevation_samples, n_beams)``
        Range of each ray's first hit (m), ``inf`` on a miss: the scan's depth map.
    """

    def __init__(self, range_map: np.ndarray, compute_maps, compute_shadow):
        self.range_map = range_map
        self._compute_maps = compute_maps
        self._compute_shadow = compute_shadow
        self._maps = None
        self._shadow = None

    def _get_maps(self):
        if self._maps is None:
            self._maps = self._compute_maps()
            for a in self._maps:
                a.setflags(write=False)
        return self._maps

    @property
    def body(self) -> np.ndarray:
        return self._get_maps()[0]

    @property
    def elevation_min(self) -> np.ndarray:
        return self._get_maps()[1]

    @property
    def elevation_max(self) -> np.ndarray:
        return self._get_maps()[2]

    @property
    def shadow(self) -> np.ndarray:
        if self._shadow is None:
            self._shadow = self._compute_shadow(self.elevation_min)
            self._shadow.setflags(write=False)
        return self._shadow


@dataclass(frozen=True, eq=False)
class SonarFrame:
    """One simulated sonar frame.

    Attributes
    ----------
    spec : SonarSpec
    pose : Pose
        Sonar pose in the world.
    intensity : float32 ``(n_bins, n_beams)``
        Noise-free echo: elevation-integrated returns per metre of range in each
        (bin, beam) cell. Row = range bin (near to far), column = beam (left to right).
    image : float32 ``(n_bins, n_beams)``
        ``intensity`` with noise and reverberation, same units.
    ground_truth : SonarGroundTruth
        Per-cell truth, computed on first access.
    rays : SonarRays
        Per-ray data of the scan.
    body_names : tuple of str
        Body ids -> names.
    seabed_share : dict of str -> float32 ``(n_bins, n_beams)``
        For each bottom type present, the share of each cell's echo returned by seabed
        bodies of that type (what the reverberation model acts on); the rest is target.
    time : float
        Seconds (NaN when not set).
    beam_model : {"thesis", "aperture"}
        The elevation beam the image was formed with (``SonarOptions.beam_model``): ``"thesis"``
        a hard cut at ``spec.fov_elevation / 2``, ``"aperture"`` the spec's soft two-way pattern.
        What reads the image's geometry (the matcher's seabed plane) needs to know which.
    """

    spec: SonarSpec
    pose: Pose
    intensity: np.ndarray
    image: np.ndarray
    ground_truth: SonarGroundTruth
    rays: SonarRays
    body_names: tuple[str, ...]
    seabed_share: dict
    time: float = float("nan")
    beam_model: str = "thesis"

    @property
    def ranges(self) -> np.ndarray:
        """Range-bin centres (m), ``(n_bins,)``."""
        return self.spec.ranges

    @property
    def azimuths(self) -> np.ndarray:
        """Beam-centre azimuths (rad), ``(n_beams,)``."""
        return self.spec.azimuths

    def fan(self, which: Literal["image", "intensity"] = "image", *, width: int = 800) -> FanImage:
        """The image resampled to the fan (``cv2.remap`` through a cached map; sec. 2.6.2.4)."""
        if which not in ("image", "intensity"):
            raise ValueError(f"fan: which must be 'image' or 'intensity', got {which!r}")
        return polar_to_fan(getattr(self, which), self.spec, width=width)

    def save(self, path) -> Path:
        """Write the whole frame (spec, pose, images, rays, ground truth) to ``.npz``; read back with :meth:`load`.

        Written atomically; :meth:`load` (or :func:`load_frame`) gives a frame whose arrays
        equal these bit for bit.
        """
        from .._atomic import save_npz

        gt = self.ground_truth
        rays = {f"ray_{f.name}": getattr(self.rays, f.name) for f in dataclasses.fields(SonarRays)
                if f.name != "elevation_step"}
        share = {f"share_{k}": v for k, v in self.seabed_share.items()}
        header = dict(format=_FORMAT, version=_VERSION, kind="simulated", spec=spec_to_dict(self.spec),
                      time=self.time, body_names=list(self.body_names), elevation_step=self.rays.elevation_step,
                      seabed_share=list(self.seabed_share), beam_model=self.beam_model)
        return save_npz(path, header=np.array(json.dumps(header)), intensity=self.intensity, image=self.image,
                        pose_R=self.pose.R, pose_t=self.pose.t, gt_body=gt.body, gt_elevation_min=gt.elevation_min,
                        gt_elevation_max=gt.elevation_max, gt_shadow=gt.shadow, gt_range_map=gt.range_map,
                        **rays, **share)

    @staticmethod
    def load(path) -> "SonarFrame | MeasuredSonarFrame":
        """Read a frame written by :meth:`SonarFrame.save` or :meth:`MeasuredSonarFrame.save`."""
        return load_frame(path)

    def save_npz(self, path) -> Path:
        """Write intensity, image, ranges, azimuths, pose and ground truth to an ``.npz``."""
        path = Path(path)
        data = dict(
            intensity=self.intensity,
            image=self.image,
            ranges=self.ranges,
            azimuths=self.azimuths,
            pose_R=self.pose.R,
            pose_t=self.pose.t,
            body_names=np.array(self.body_names),
            ray_range=self.rays.range,
            ray_energy=self.rays.energy,
            ray_body=self.rays.body,
            ray_elevation=self.rays.elevation[:, 0],
        )
        gt = self.ground_truth
        data.update(
            gt_body=gt.body,
            gt_elevation_min=gt.elevation_min,
            gt_elevation_max=gt.elevation_max,
            gt_shadow=gt.shadow,
            gt_range_map=gt.range_map,
        )
        from .._atomic import save_npz

        return save_npz(path, **data)
