"""Sonar specifications and the presets of real forward-looking imaging sonars."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .beampattern import BeamPattern

from ..frames import project_to_sonar, SonarProjection

__all__ = ["SonarSpec", "PRESETS"]


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
    elevation_beam: Optional["BeamPattern"] = None
    azimuth_beam: Optional["BeamPattern"] = None

    def __post_init__(self):
        def bad(fld, msg):
            raise ValueError(f"SonarSpec.{fld}: {msg}, got {getattr(self, fld)!r}")

        for fld in ("n_beams", "n_bins", "elevation_samples"):
            v = getattr(self, fld)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                bad(fld, "must be a positive integer")
        for fld in ("fov_azimuth", "fov_elevation", "range_max", "frequency", "sound_speed"):
            v = getattr(self, fld)
            if not isinstance(v, (int, float, np.floating)) or not np.isfinite(v) or v <= 0:
                bad(fld, "must be a finite number > 0")
        for fld in ("range_min", "beamwidth_azimuth", "range_resolution"):
            v = getattr(self, fld)
            if not isinstance(v, (int, float, np.floating)) or not np.isfinite(v) or v < 0:
                bad(fld, "must be a finite number >= 0")
        if self.fov_azimuth >= np.pi:
            bad("fov_azimuth", "must be < pi (a forward-looking fan)")
        if self.fov_elevation >= np.pi:
            bad("fov_elevation", "must be < pi")
        if self.range_max <= self.range_min:
            raise ValueError(
                f"SonarSpec: range_max ({self.range_max}) must exceed range_min ({self.range_min})"
            )

    # ------------------------------------------------------------------ presets
    @classmethod
    def preset(cls, name: str, **overrides) -> "SonarSpec":
        """A preset by name (``SonarSpec.preset_names()``), with optional field overrides."""
        try:
            spec = PRESETS[name]
        except KeyError:
            raise KeyError(f"unknown sonar preset {name!r}; presets are {cls.preset_names()}") from None
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
            except KeyError as exc:
                raise ValueError(f"{source}: {exc.args[0]}") from None
        if not isinstance(data, dict):
            raise ValueError(f"{source}: expected a preset name or a mapping, got {data!r}")
        data = dict(data)
        base = cls()
        if "preset" in data:
            try:
                base = cls.preset(data.pop("preset"))
            except KeyError as exc:
                raise ValueError(f"{source}: {exc.args[0]}") from None
        fields = {f.name for f in dataclasses.fields(cls)}
        kw = {}
        for k, v in data.items():
            if k.endswith("_deg") and k[:-4] in fields:
                try:
                    kw[k[:-4]] = float(np.deg2rad(float(v)))
                except (TypeError, ValueError):
                    raise ValueError(f"{source}: field '{k}': expected a number, got {v!r}") from None
            elif k in ("elevation_beam", "azimuth_beam"):
                kw[k] = None if v is None else BeamPattern.from_dict(v, f"{source}: field '{k}'")
            elif k in fields and k not in ("fov_azimuth", "fov_elevation", "beamwidth_azimuth"):
                kw[k] = tuple(v) if k == "unverified" else v
            else:
                raise ValueError(
                    f"{source}: field '{k}': unknown; angles go in *_deg fields "
                    f"(fov_azimuth_deg, fov_elevation_deg, beamwidth_azimuth_deg)"
                )
        if "name" not in kw and base.name != "custom" and kw:
            kw["name"] = base.name + "-custom"
        try:
            return dataclasses.replace(base, **kw)
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
        """Range bin width (m)."""
        return (self.range_max - self.range_min) / self.n_bins

    @property
    def beam_spacing(self) -> float:
        """Angle between adjacent beams (rad)."""
        return self.fov_azimuth / self.n_beams

    @property
    def pulse_width(self) -> float:
        """Effective range resolution (m): ``range_resolution`` or one bin."""
        return self.range_resolution if self.range_resolution > 0 else self.bin_width

    @property
    def ranges(self) -> np.ndarray:
        """Range-bin centres (m), shape ``(n_bins,)``, near to far."""
        return self.range_min + (np.arange(self.n_bins) + 0.5) * self.bin_width

    @property
    def range_edges(self) -> np.ndarray:
        return self.range_min + np.arange(self.n_bins + 1) * self.bin_width

    @property
    def azimuths(self) -> np.ndarray:
        """Beam-centre azimuths (rad), shape ``(n_beams,)``, left (negative) to right."""
        return -self.fov_azimuth / 2 + (np.arange(self.n_beams) + 0.5) * self.beam_spacing

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
        with np.errstate(invalid="ignore"):
            return (
                (np.abs(th) <= self.fov_azimuth / 2)
                & (np.abs(ph) <= self.fov_elevation / 2)
                & (r >= self.range_min)
                & (r <= self.range_max)
            )

    def bin_index(self, ranges) -> np.ndarray:
        """Fractional bin coordinate of ranges: bin b spans ``[b, b + 1)``, centre at ``b + 0.5``."""
        return (np.asarray(ranges, float) - self.range_min) / self.bin_width

    def beam_index(self, azimuths) -> np.ndarray:
        """Fractional beam coordinate of azimuths: beam j spans ``[j, j + 1)``."""
        return (np.asarray(azimuths, float) + self.fov_azimuth / 2) / self.beam_spacing

    def summary(self) -> str:
        deg = np.rad2deg
        flag = f"  [unverified: {', '.join(self.unverified)}]" if self.unverified else ""
        return (
            f"{self.name}: {self.frequency / 1e3:g} kHz, {self.n_beams} beams, "
            f"{deg(self.fov_azimuth):.4g} x {deg(self.fov_elevation):.4g} deg, "
            f"{self.range_min:g}-{self.range_max:g} m in {self.n_bins} bins ({100 * self.bin_width:.3g} cm), "
            f"beam width {deg(self.beamwidth_azimuth):.3g} deg{flag}"
        )


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
