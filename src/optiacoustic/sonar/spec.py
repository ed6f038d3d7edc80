"""Sonar specifications and the presets of real forward-looking imaging sonars."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .._validate import is_number
from .beampattern import BeamPattern

from ..frames import project_to_sonar, SonarProjection

__all__ = ["SonarSpec", "PRESETS", "MAX_COUNTS", "UnknownPresetError"]


class UnknownPresetError(ValueError, KeyError):
    """An unknown preset name: a ValueError (a caller mistake) that is also the KeyError it used to be."""

    __str__ = ValueError.__str__  # the message as is, not KeyError's repr of it


_is_number = is_number  # a real number and not a bool (``range_max=True`` is a mistake, not 1 m)

#: Upper bounds of the count fields (real sonars: up to ~1024 beams and ~4000 bins).
MAX_COUNTS = {"n_beams": 8192, "n_bins": 65536, "elevation_samples": 4096}


@dataclass(frozen=True)
class SonarSpec:
    """What a forward-looking imaging sonar is, and how finely we simulate it.

    Derive variants with ``dataclasses.replace(spec, n_bins=1000)``.

    Attributes
    ----------
    n_beams : int
        Beams across the azimuth aperture, equally spaced in angle.
    n_bins : int
        Range bins between ``range_min`` and ``range_max``, equally spaced.
    fov_azimuth, fov_elevation : float
        Full apertures (rad): the fan spans ``|theta| <= fov_azimuth / 2``, each beam
        integrates over ``|phi| <= fov_elevation / 2``.
    range_min, range_max : float
        Range window (m).
    elevation_samples : int
        Rays per beam across the elevation aperture (simulation fidelity, not a sensor
        property). The echo converges as this grows (docs/physics.md).
    frequency : float
        Carrier frequency (Hz); sets the absorption when spreading loss is simulated.
    beamwidth_azimuth : float
        One-way -3 dB width of a beam in azimuth (rad); used by the optional azimuth
        beam pattern. Zero means ideal (no cross-beam leakage).
    range_resolution : float
        Range resolution of the pulse (m), the width of the anti-aliasing (pulse)
        kernel. Zero means one bin.
    sound_speed : float
        Speed of sound (m/s), for time <-> range conversions.
    name, source : str
        Preset name and where its numbers come from.
    unverified : tuple of str
        Fields whose values could not be checked against a datasheet.
    beam_azimuths : tuple of float or None
        Explicit beam-centre azimuths (rad), strictly increasing, left to right: a real
        device's bearing table (Oculus), lens table (ARIS) or equal-sine spacing. ``None``
        (default) means ``n_beams`` beams equally spaced over ``fov_azimuth``. With a
        table, ``n_beams`` must equal its length and beam ``j`` spans from the midpoint to
        its left neighbour to the midpoint to its right one (the end beams are symmetric
        about their centres); ``fov_azimuth`` must cover those edges (use
        :meth:`with_beam_table`, which sets both).
    bin_ranges : tuple of float or None
        Explicit range-bin centres (m), strictly increasing (a ROS ``ProjectedSonarImage``
        may carry uneven ranges). ``None`` (default): ``n_bins`` equal bins over
        ``[range_min, range_max]``. Measured data only; the simulator needs equal bins.
    elevation_beam, azimuth_beam : BeamPattern, optional
        One-way beam patterns of the array (``sonar.beampattern``), used by the
        ``beam_model="aperture"`` image model. ``None``: the uniform aperture whose -3 dB
        width is ``fov_elevation`` (resp. ``beamwidth_azimuth``) at ``frequency``.
    """

    n_beams: int = 512
    n_bins: int = 750
    fov_azimuth: float = float(np.deg2rad(90.0))
    fov_elevation: float = float(np.deg2rad(20.0))
    range_min: float = 1.0
    range_max: float = 20.0
    elevation_samples: int = 128
    frequency: float = 900e3
    beamwidth_azimuth: float = float(np.deg2rad(1.0))
    range_resolution: float = 0.0
    sound_speed: float = 1500.0
    name: str = "custom"
    source: str = ""
    unverified: tuple[str, ...] = field(default=())
    beam_azimuths: tuple[float, ...] | None = None
    bin_ranges: tuple[float, ...] | None = None
    elevation_beam: Optional["BeamPattern"] = None
    azimuth_beam: Optional["BeamPattern"] = None

    def __post_init__(self):
        def bad(fld, msg):
            raise ValueError(f"SonarSpec.{fld}: {msg}, got {getattr(self, fld)!r}")

        self._check_tables()

        for fld in ("n_beams", "n_bins", "elevation_samples"):
            v = getattr(self, fld)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                bad(fld, "must be a positive integer")
            if v > MAX_COUNTS[fld]:  # no real sonar comes near; beyond, a frame would not fit in memory
                bad(fld, f"must be at most {MAX_COUNTS[fld]}")
        for fld in ("fov_azimuth", "fov_elevation", "range_max", "frequency", "sound_speed"):
            v = getattr(self, fld)
            if not _is_number(v) or not np.isfinite(v) or v <= 0:
                bad(fld, "must be a finite number > 0")
        for fld in ("range_min", "beamwidth_azimuth", "range_resolution"):
            v = getattr(self, fld)
            if not _is_number(v) or not np.isfinite(v) or v < 0:
                bad(fld, "must be a finite number >= 0")
        for fld in ("name", "source"):
            if not isinstance(getattr(self, fld), str):
                bad(fld, "must be a string")
        if not isinstance(self.unverified, (tuple, list)) or not all(isinstance(x, str) for x in self.unverified):
            bad("unverified", "must be a list of field names (strings)")
        object.__setattr__(self, "unverified", tuple(self.unverified))
        for fld in ("elevation_beam", "azimuth_beam"):
            if getattr(self, fld) is not None and not isinstance(getattr(self, fld), BeamPattern):
                bad(fld, "must be a BeamPattern or None")
        if self.fov_azimuth >= np.pi:
            bad("fov_azimuth", "must be < pi (a forward-looking fan)")
        if self.fov_elevation >= np.pi:
            bad("fov_elevation", "must be < pi")
        if self.range_max <= self.range_min:
            raise ValueError(
                f"SonarSpec: range_max ({self.range_max}) must exceed range_min ({self.range_min})"
            )

    def _check_tables(self):
        for fld, count, lim in (("beam_azimuths", "n_beams", np.pi / 2), ("bin_ranges", "n_bins", np.inf)):
            table = getattr(self, fld)
            if table is None:
                continue
            try:
                a = np.asarray(table, float)
            except (TypeError, ValueError):
                raise ValueError(f"SonarSpec.{fld}: expected a 1-D table of >= 2 numbers, got {table!r}") from None
            if a.ndim != 1 or a.size < 2:
                raise ValueError(f"SonarSpec.{fld}: expected a 1-D table of >= 2 values, got shape {a.shape}")
            if not np.all(np.isfinite(a)) or np.any(np.abs(a) >= lim):
                raise ValueError(f"SonarSpec.{fld}: values must be finite (and |azimuth| < pi/2), "
                                 f"got range [{a.min()}, {a.max()}]")
            if np.any(np.diff(a) <= 0):
                i = int(np.flatnonzero(np.diff(a) <= 0)[0])
                raise ValueError(f"SonarSpec.{fld}: must be strictly increasing; entry {i + 1} ({a[i + 1]!r}) "
                                 f"<= entry {i} ({a[i]!r})")
            if a.size != getattr(self, count):
                raise ValueError(f"SonarSpec.{fld}: {a.size} entries but {count} = {getattr(self, count)}; "
                                 f"use SonarSpec.with_beam_table / with_range_table, which set both")
            object.__setattr__(self, fld, tuple(float(x) for x in a))
        tol = 1e-9
        if self.beam_azimuths is not None:
            e = self.beam_edges
            if max(-e[0], e[-1]) > self.fov_azimuth / 2 + tol:
                raise ValueError(f"SonarSpec.fov_azimuth ({self.fov_azimuth!r} rad) does not cover the beam table's "
                                 f"edges [{e[0]!r}, {e[-1]!r}] rad; use SonarSpec.with_beam_table")
        if self.bin_ranges is not None:
            e = self.range_edges
            if e[0] < self.range_min - tol or e[-1] > self.range_max + tol or e[0] < 0:
                raise ValueError(f"SonarSpec: range window [{self.range_min!r}, {self.range_max!r}] m does not "
                                 f"cover the range table's edges [{e[0]!r}, {e[-1]!r}] m; use with_range_table")

    def with_beam_table(self, beam_azimuths) -> "SonarSpec":
        """This spec with an explicit beam-azimuth table (rad), ``n_beams`` and ``fov_azimuth`` set to match.

        ``fov_azimuth`` becomes twice the larger |outer beam edge|, so the fan covers the
        whole table (for an asymmetric table the fan is that wide on both sides; cells
        outside the table's edges are outside the image, see :meth:`contains`).
        """
        a = np.asarray(beam_azimuths, float)
        if a.ndim != 1 or a.size < 2:
            raise ValueError(f"beam_azimuths: expected a 1-D table of >= 2 azimuths (rad), got shape {a.shape}")
        e = _edges_from_centres(a)
        fov = float(2 * max(-e[0], e[-1]))
        return dataclasses.replace(self, beam_azimuths=tuple(a.tolist()), n_beams=int(a.size), fov_azimuth=fov)

    def with_range_table(self, bin_ranges) -> "SonarSpec":
        """This spec with explicit range-bin centres (m); ``n_bins`` and the range window set to match."""
        r = np.asarray(bin_ranges, float)
        if r.ndim != 1 or r.size < 2:
            raise ValueError(f"bin_ranges: expected a 1-D table of >= 2 ranges (m), got shape {r.shape}")
        e = _edges_from_centres(r)
        return dataclasses.replace(self, bin_ranges=tuple(r.tolist()), n_bins=int(r.size),
                                   range_min=float(max(e[0], 0.0)), range_max=float(e[-1]))

    @staticmethod
    def equal_sine_azimuths(n_beams: int, fov_azimuth: float) -> np.ndarray:
        """Beam centres (rad) equally spaced in ``sin(theta)`` across ``fov_azimuth`` (a linear array's beams)."""
        s = np.sin(fov_azimuth / 2)
        return np.arcsin(-s + (np.arange(n_beams) + 0.5) * (2 * s / n_beams))

    @property
    def has_tables(self) -> bool:
        """True when beams or bins come from an explicit table rather than equal spacing."""
        return self.beam_azimuths is not None or self.bin_ranges is not None

    # ------------------------------------------------------------------ presets
    @classmethod
    def preset(cls, name: str, **overrides) -> "SonarSpec":
        """A preset by name (``SonarSpec.preset_names()``), with optional field overrides.

        Raises :class:`UnknownPresetError` (a ValueError, and a KeyError as before) for an unknown
        name, and a ValueError naming an unknown override field.
        """
        if not isinstance(name, str) or name not in PRESETS:
            raise UnknownPresetError(f"unknown sonar preset {name!r}; presets are {cls.preset_names()}")
        spec = PRESETS[name]
        fields = [f.name for f in dataclasses.fields(cls)]
        unknown = [k for k in overrides if k not in fields]
        if unknown:
            raise ValueError(f"SonarSpec.preset({name!r}): unknown field {unknown[0]!r}; fields are {fields}")
        return dataclasses.replace(spec, **overrides) if overrides else spec

    @staticmethod
    def preset_names() -> list[str]:
        return list(PRESETS)

    @classmethod
    def from_dict(cls, data, source: str = "sonar") -> "SonarSpec":
        """A spec from a preset name or a mapping (angles as ``*_deg`` fields).

        ``{preset: blueview-p900-90, n_bins: 1000, fov_elevation_deg: 14}`` starts from
        the preset and overrides fields; without ``preset`` it starts from the defaults.
        """
        if isinstance(data, str):
            try:
                return cls.preset(data)
            except UnknownPresetError as exc:
                raise ValueError(f"{source}: {exc.args[0]}") from None
        if not isinstance(data, dict):
            raise ValueError(f"{source}: expected a preset name or a mapping, got {data!r}")
        data = dict(data)
        base = cls()
        if "preset" in data:
            try:
                base = cls.preset(data.pop("preset"))
            except UnknownPresetError as exc:
                raise ValueError(f"{source}: field 'preset': {exc.args[0]}") from None
        fields = {f.name for f in dataclasses.fields(cls)}
        kw = {}
        for k, v in data.items():
            if k == "beam_azimuths_deg":
                try:
                    kw["beam_azimuths"] = tuple(np.deg2rad(np.asarray(v, float)).tolist())
                except (TypeError, ValueError):
                    raise ValueError(f"{source}: field '{k}': expected a list of numbers, got {v!r}") from None
            elif k.endswith("_deg") and k[:-4] in fields:
                if not _is_number(v):  # `true` is not 1 deg, "30" not 30
                    raise ValueError(f"{source}: field '{k}': expected a number, got {v!r}")
                kw[k[:-4]] = float(np.deg2rad(float(v)))
            elif k in ("elevation_beam", "azimuth_beam"):
                kw[k] = None if v is None else BeamPattern.from_dict(v, f"{source}: field '{k}'")
            elif k == "unverified":
                if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) for x in v):
                    raise ValueError(f"{source}: field '{k}': expected a list of field names, got {v!r}")
                kw[k] = tuple(v)
            elif k == "bin_ranges":
                if not isinstance(v, (list, tuple)) or not all(_is_number(x) for x in v):
                    raise ValueError(f"{source}: field '{k}': expected a list of ranges (m), got {v!r}")
                kw[k] = tuple(v)
            elif k in fields and k not in ("fov_azimuth", "fov_elevation", "beamwidth_azimuth", "beam_azimuths"):
                kw[k] = v
            else:
                raise ValueError(
                    f"{source}: field '{k}': unknown; angles go in *_deg fields "
                    f"(fov_azimuth_deg, fov_elevation_deg, beamwidth_azimuth_deg)"
                )
        if "name" not in kw and base.name != "custom" and kw:
            kw["name"] = base.name + "-custom"
        try:
            table = kw.pop("beam_azimuths", None)
            ranges = kw.pop("bin_ranges", None)
            spec = dataclasses.replace(base, **kw)
            spec = spec.with_beam_table(table) if table is not None else spec
            return spec.with_range_table(ranges) if ranges is not None else spec
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {exc}") from None

    # ------------------------------------------------------------------ beam patterns
    def elevation_pattern(self) -> BeamPattern:
        """One-way elevation pattern: ``elevation_beam`` or the aperture of -3 dB width ``fov_elevation``."""
        if self.elevation_beam is not None:
            return self.elevation_beam
        return BeamPattern.from_beamwidth(self.fov_elevation, self.frequency, self.sound_speed)

    def azimuth_pattern(self) -> BeamPattern:
        """One-way azimuth pattern of one beam: ``azimuth_beam`` or the aperture of -3 dB width
        ``beamwidth_azimuth`` (one beam spacing when that is 0)."""
        if self.azimuth_beam is not None:
            return self.azimuth_beam
        width = self.beamwidth_azimuth if self.beamwidth_azimuth > 0 else self.beam_spacing
        return BeamPattern.from_beamwidth(width, self.frequency, self.sound_speed)

    # ------------------------------------------------------------------ sampling grids
    @property
    def bin_width(self) -> float:
        """Range bin width (m); the mean width with a range table."""
        return (self.range_max - self.range_min) / self.n_bins

    @property
    def beam_spacing(self) -> float:
        """Angle between adjacent beams (rad); the mean spacing with a beam table."""
        if self.beam_azimuths is not None:
            e = self.beam_edges
            return float(e[-1] - e[0]) / self.n_beams
        return self.fov_azimuth / self.n_beams

    @property
    def pulse_width(self) -> float:
        """Effective range resolution (m): ``range_resolution`` or one bin."""
        return self.range_resolution if self.range_resolution > 0 else self.bin_width

    @property
    def ranges(self) -> np.ndarray:
        """Range-bin centres (m), shape ``(n_bins,)``, near to far."""
        if self.bin_ranges is not None:
            return np.array(self.bin_ranges)
        return self.range_min + (np.arange(self.n_bins) + 0.5) * self.bin_width

    @property
    def range_edges(self) -> np.ndarray:
        """Range-bin edges (m), ``(n_bins + 1,)``; with a table, midpoints between centres."""
        if self.bin_ranges is not None:
            e = _edges_from_centres(np.array(self.bin_ranges))
            e[0] = max(e[0], 0.0)
            return e
        return self.range_min + np.arange(self.n_bins + 1) * self.bin_width

    @property
    def azimuths(self) -> np.ndarray:
        """Beam-centre azimuths (rad), shape ``(n_beams,)``, left (negative) to right."""
        if self.beam_azimuths is not None:
            return np.array(self.beam_azimuths)
        return -self.fov_azimuth / 2 + (np.arange(self.n_beams) + 0.5) * self.beam_spacing

    @property
    def beam_edges(self) -> np.ndarray:
        """Beam edges (rad), ``(n_beams + 1,)``; with a table, midpoints between centres."""
        if self.beam_azimuths is not None:
            return _edges_from_centres(np.array(self.beam_azimuths))
        return -self.fov_azimuth / 2 + np.arange(self.n_beams + 1) * (self.fov_azimuth / self.n_beams)

    @property
    def elevation_step(self) -> float:
        return self.fov_elevation / self.elevation_samples

    @property
    def elevations(self) -> np.ndarray:
        """Centres of the elevation cells sampled by rays (rad), shape ``(elevation_samples,)``."""
        return -self.fov_elevation / 2 + (np.arange(self.elevation_samples) + 0.5) * self.elevation_step

    # ------------------------------------------------------------------ geometry
    def project(self, points_sonar) -> SonarProjection:
        """Range, azimuth, elevation of sonar-frame points ``(..., 3)`` and whether they are in the fan."""
        return project_to_sonar(
            points_sonar,
            fov_azimuth=self.fov_azimuth,
            fov_elevation=self.fov_elevation,
            range_min=self.range_min,
            range_max=self.range_max,
        )

    def contains(self, ranges, azimuths, elevations=0.0) -> np.ndarray:
        """True where ``(range, azimuth, elevation)`` lies inside the fan."""
        r, th, ph = np.broadcast_arrays(np.asarray(ranges, float), np.asarray(azimuths, float), np.asarray(elevations, float))
        if self.has_tables:
            with np.errstate(invalid="ignore"):
                b, j = self.bin_index(r), self.beam_index(th)
                return (j >= 0) & (j <= self.n_beams) & (b >= 0) & (b <= self.n_bins) & (np.abs(ph) <= self.fov_elevation / 2)
        with np.errstate(invalid="ignore"):
            return (
                (np.abs(th) <= self.fov_azimuth / 2)
                & (np.abs(ph) <= self.fov_elevation / 2)
                & (r >= self.range_min)
                & (r <= self.range_max)
            )

    def bin_index(self, ranges) -> np.ndarray:
        """Fractional bin coordinate of ranges: bin b spans ``[b, b + 1)``, centre at ``b + 0.5``.

        With a range table the coordinate is piecewise linear through the bin centres
        (``b + 0.5`` at centre ``b``, ``b`` at the edge between ``b - 1`` and ``b``) and
        extends linearly beyond the outer edges (so out-of-window ranges fall outside
        ``[0, n_bins]``).
        """
        if self.bin_ranges is not None:
            return _table_index(np.asarray(ranges, float), np.array(self.bin_ranges))
        return (np.asarray(ranges, float) - self.range_min) / self.bin_width

    def beam_index(self, azimuths) -> np.ndarray:
        """Fractional beam coordinate of azimuths: beam j spans ``[j, j + 1)``, centre ``j + 0.5``.

        With a beam table: piecewise linear through the beam centres, as :meth:`bin_index`.
        """
        if self.beam_azimuths is not None:
            return _table_index(np.asarray(azimuths, float), np.array(self.beam_azimuths))
        return (np.asarray(azimuths, float) + self.fov_azimuth / 2) / self.beam_spacing

    def summary(self) -> str:
        deg = np.rad2deg
        flag = f"  [unverified: {', '.join(self.unverified)}]" if self.unverified else ""
        return (
            f"{self.name}: {self.frequency / 1e3:g} kHz, {self.n_beams} beams, "
            f"{deg(self.fov_azimuth):.4g} x {deg(self.fov_elevation):.4g} deg, "
            f"{self.range_min:g}-{self.range_max:g} m in {self.n_bins} bins ({100 * self.bin_width:.3g} cm), "
            f"beam width {deg(self.beamwidth_azimuth):.3g} deg"
            + (" [beam table]" if self.beam_azimuths is not None else "")
            + (" [range table]" if self.bin_ranges is not None else "")
            + flag
        )


def _edges_from_centres(c: np.ndarray) -> np.ndarray:
    """Cell edges of increasing centres: midpoints inside, the end cells symmetric about their centres."""
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[2 * c[0] - mid[0]], mid, [2 * c[-1] - mid[-1]]])


def _table_index(x: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Fractional cell coordinate of ``x`` for cells with these centres (centre k -> k + 0.5).

    Piecewise linear through ``(edge_0, 0), (centre_k, k + 0.5), (edge_n, n)`` and extended
    linearly beyond both ends with the end cells' slopes. NaN stays NaN.
    """
    e = _edges_from_centres(centres)
    n = centres.size
    xp = np.concatenate([[e[0]], centres, [e[-1]]])
    fp = np.concatenate([[0.0], np.arange(n) + 0.5, [float(n)]])
    out = np.interp(x, xp, fp)
    lo, hi = x < e[0], x > e[-1]
    out = np.where(lo, (x - e[0]) / (centres[0] - e[0]) * 0.5, out)
    out = np.where(hi, n + (x - e[-1]) / (e[-1] - centres[-1]) * 0.5, out)
    return np.where(np.isnan(x), np.nan, out)


def _p(name, source, unverified=(), **kw) -> SonarSpec:
    for k in ("fov_azimuth", "fov_elevation", "beamwidth_azimuth"):
        if k in kw:
            kw[k] = float(np.deg2rad(kw[k]))
    return SonarSpec(name=name, source=source, unverified=tuple(unverified), **kw)


_BV = (
    "Teledyne BlueView P900 series datasheet as quoted in the thesis (sec. 2.1, 2.6.1): 900 kHz, "
    "1 x 20 deg beams spaced 0.18 deg, 2.54 cm range resolution"
)
_WINDOW_NOTE = "range window and n_bins are a simulation default, not the sensor's native sampling"

#: Presets by name. Angles in the dataclass are radians; the values below are in degrees.
PRESETS: dict[str, SonarSpec] = {
    p.name: p
    for p in (
        _p("blueview-p900-45", _BV, ("n_beams", "range window: " + _WINDOW_NOTE),
           n_beams=256, n_bins=750, fov_azimuth=45, fov_elevation=20, range_min=1.0, range_max=20.0,
           frequency=900e3, beamwidth_azimuth=1.0, range_resolution=0.0254),
        _p("blueview-p900-90", _BV + "; the thesis's sensor (512 beams x 750 samples)",
           ("range window: " + _WINDOW_NOTE,),
           n_beams=512, n_bins=750, fov_azimuth=90, fov_elevation=20, range_min=1.0, range_max=20.0,
           frequency=900e3, beamwidth_azimuth=1.0, range_resolution=0.0254),
        _p("blueview-p900-130", _BV, ("n_beams", "range window: " + _WINDOW_NOTE),
           n_beams=768, n_bins=750, fov_azimuth=130, fov_elevation=20, range_min=1.0, range_max=20.0,
           frequency=900e3, beamwidth_azimuth=1.0, range_resolution=0.0254),
        _p("oculus-m750d-lf", "Blueprint Subsea Oculus M750d datasheet, low-frequency mode: 750 kHz, "
           "130 x 20 deg, 512 beams, 1 deg angular resolution, 4 mm range resolution, 120 m max range",
           ("range_resolution", "range window: " + _WINDOW_NOTE),
           n_beams=512, n_bins=1000, fov_azimuth=130, fov_elevation=20, range_min=0.5, range_max=40.0,
           frequency=750e3, beamwidth_azimuth=1.0, range_resolution=0.004),
        _p("oculus-m1200d-hf", "Blueprint Subsea Oculus M1200d datasheet, high-frequency mode: 2.1 MHz, "
           "about 60 x 12 deg, 512 beams, 0.4 deg angular resolution, 2.5 mm range resolution, 10 m max range",
           ("fov_azimuth (datasheet says ~60 deg)", "range_resolution", "range window: " + _WINDOW_NOTE),
           n_beams=512, n_bins=1000, fov_azimuth=60, fov_elevation=12, range_min=0.1, range_max=10.0,
           frequency=2.1e6, beamwidth_azimuth=0.4, range_resolution=0.0025),
        _p("didson-300-hf", "Sound Metrics DIDSON 300 datasheet, high-frequency (identification) mode: "
           "1.8 MHz, 96 beams of 0.3 deg over 29 deg, 14 deg elevation, 512 samples per beam",
           ("beam angles (real DIDSON beams are not exactly equiangular)", "range window: " + _WINDOW_NOTE),
           n_beams=96, n_bins=512, fov_azimuth=29, fov_elevation=14, range_min=1.0, range_max=11.0,
           frequency=1.8e6, beamwidth_azimuth=0.3),
        _p("aris-3000-128", "Sound Metrics ARIS Explorer 3000 datasheet, 3 MHz mode: 128 beams, "
           "+-14.83 deg (29.66 deg) x 14 deg, about 3 mm range resolution, 5 m max range",
           ("beam angles (real ARIS beams follow a lens table)", "beamwidth_azimuth",
            "range window: " + _WINDOW_NOTE),
           n_beams=128, n_bins=800, fov_azimuth=29.66, fov_elevation=14, range_min=0.7, range_max=5.0,
           frequency=3.0e6, beamwidth_azimuth=0.25, range_resolution=0.003),
        _p("gemini-720is", "Tritech Gemini 720is datasheet: 720 kHz, 120 x 20 deg, 512 beams at 0.25 deg "
           "spacing, 1 deg angular resolution, 8 mm range resolution, 120 m max range",
           ("n_beams", "range window: " + _WINDOW_NOTE),
           n_beams=512, n_bins=1000, fov_azimuth=120, fov_elevation=20, range_min=0.2, range_max=50.0,
           frequency=720e3, beamwidth_azimuth=1.0, range_resolution=0.008),
    )
}
