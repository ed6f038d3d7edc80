"""Beam patterns of a line aperture (or a measured table), one-way and two-way.

A transducer of length ``L`` with a real, symmetric aperture weighting ``a(x)``
(``|x| <= L / 2``) radiates, in the far field at angle ``theta`` from its broadside, the
normalised amplitude

    F(v) = (1 / (L mean(a))) integral a(x) exp(-2 pi i x sin(theta) / lambda) dx,
    v = L sin(theta) / lambda,

with ``F(0) = 1`` (docs/physics.md, "Beam patterns from the aperture"). We use the
*cosine-on-a-pedestal* weighting ``a(x) = p + (1 - p) cos(pi x / L)``: ``p = 1`` is the
uniform aperture (``F = sinc v``, first sidelobe -13.26 dB one-way), smaller ``p`` trades
width for lower sidelobes (``p = 0``: -23 dB). Closed form:

    F(v) = [p sinc(v) + (1 - p) (sinc(v - 1/2) + sinc(v + 1/2)) / 2] / [p + (1 - p) 2 / pi]

One-way power is ``F^2``; transmit and receive through the same aperture give the
two-way power ``F^4``. Parseval gives the integrals the tests check:

    integral F^2 du = (lambda / L) mean(a^2) / mean(a)^2
    integral F^4 du = (lambda / L) integral (a * a)^2 dx / (L^3 mean(a)^4)

(``u = sin theta``; ``a * a`` the autocorrelation of the weighting). For ``p = 1``:
``lambda / L`` and ``2 lambda / (3 L)``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

__all__ = ["BeamPattern"]


def _pedestal_f(v, p: float) -> np.ndarray:
    v = np.asarray(v, float)
    num = p * np.sinc(v) + (1.0 - p) * 0.5 * (np.sinc(v - 0.5) + np.sinc(v + 0.5))
    return num / (p + (1.0 - p) * 2.0 / np.pi)


@dataclass(frozen=True)
class BeamPattern:
    """The one-way pattern of one axis (elevation or azimuth) of a sonar's array.

    Build it with :meth:`aperture`, :meth:`from_beamwidth` or :meth:`table`.

    Attributes
    ----------
    length : float
        Aperture length ``L`` (m); 0 for a tabulated pattern.
    wavelength : float
        ``c / f`` (m).
    pedestal : float
        Weighting pedestal ``p`` in ``[0, 1]`` (1: uniform aperture).
    table_angles : tuple of float
        Angles (rad, increasing) of a tabulated one-way power pattern.
    table_db : tuple of float
        One-way power (dB re the peak) at ``table_angles``; outside the table the
        pattern holds its end values.
    """

    length: float = 0.0
    wavelength: float = 0.0
    pedestal: float = 1.0
    table_angles: tuple = field(default=())
    table_db: tuple = field(default=())

    def __post_init__(self):
        if self.table_angles:
            a = np.asarray(self.table_angles, float)
            g = np.asarray(self.table_db, float)
            if a.ndim != 1 or a.shape != g.shape or a.size < 3:
                raise ValueError(f"BeamPattern.table: angles and gains must be 1-D of equal length >= 3, "
                                 f"got {a.shape} and {g.shape}")
            if not (np.all(np.isfinite(a)) and np.all(np.isfinite(g)) and np.all(np.diff(a) > 0)):
                raise ValueError("BeamPattern.table: angles must be finite and strictly increasing, gains finite")
            return
        if not (np.isfinite(self.length) and self.length > 0):
            raise ValueError(f"BeamPattern.length: must be > 0 m, got {self.length!r}")
        if not (np.isfinite(self.wavelength) and self.wavelength > 0):
            raise ValueError(f"BeamPattern.wavelength: must be > 0 m, got {self.wavelength!r}")
        if not 0.0 <= self.pedestal <= 1.0:
            raise ValueError(f"BeamPattern.pedestal: must lie in [0, 1], got {self.pedestal!r}")

    # ------------------------------------------------------------------ constructors
    @classmethod
    def aperture(cls, length: float, frequency: float, sound_speed: float = 1500.0, pedestal: float = 1.0) -> "BeamPattern":
        """A line aperture of ``length`` (m) at ``frequency`` (Hz)."""
        return cls(length=float(length), wavelength=float(sound_speed) / float(frequency), pedestal=float(pedestal))

    @classmethod
    def from_beamwidth(cls, width: float, frequency: float, sound_speed: float = 1500.0,
                       pedestal: float = 1.0) -> "BeamPattern":
        """The aperture whose one-way -3 dB full width is ``width`` (rad)."""
        if not (np.isfinite(width) and 0 < width < np.pi):
            raise ValueError(f"beam width: must lie in (0, pi) rad, got {width!r}")
        v3 = _half_power_v(float(pedestal))
        lam = float(sound_speed) / float(frequency)
        return cls(length=v3 * lam / np.sin(width / 2), wavelength=lam, pedestal=float(pedestal))

    @classmethod
    def table(cls, angles, gain_db) -> "BeamPattern":
        """A tabulated one-way power pattern: ``angles`` (rad), ``gain_db`` (dB re peak)."""
        return cls(table_angles=tuple(float(x) for x in np.ravel(angles)),
                   table_db=tuple(float(x) for x in np.ravel(gain_db)))

    @property
    def is_table(self) -> bool:
        return bool(self.table_angles)

    # ------------------------------------------------------------------ evaluation
    def amplitude(self, angles) -> np.ndarray:
        """One-way amplitude ``F`` (signed for an aperture: sidelobes alternate), peak 1."""
        th = np.asarray(angles, float)
        if self.is_table:
            return np.sqrt(self.one_way(th))
        return _pedestal_f(self.length * np.sin(th) / self.wavelength, self.pedestal)

    def one_way(self, angles) -> np.ndarray:
        """One-way power pattern ``F^2`` at ``angles`` (rad), peak 1."""
        th = np.asarray(angles, float)
        if self.is_table:
            db = np.interp(th, self.table_angles, self.table_db)
            return 10.0 ** (db / 10.0)
        return self.amplitude(th) ** 2

    def two_way(self, angles) -> np.ndarray:
        """Two-way power pattern ``F^4`` (transmit and receive), peak 1."""
        return self.one_way(angles) ** 2

    def cell_average_two_way(self, centres, width: float, n_sub: int = 16) -> np.ndarray:
        """``F^4`` averaged over cells of ``width`` (rad) around ``centres``."""
        off = ((np.arange(n_sub) + 0.5) / n_sub - 0.5) * width
        return self.two_way(np.asarray(centres, float)[..., None] + off).mean(-1)

    # ------------------------------------------------------------------ derived numbers
    def beamwidth(self) -> float:
        """One-way -3 dB full width (rad)."""
        if self.is_table:
            a = np.asarray(self.table_angles)
            g = np.asarray(self.table_db)
            i = int(np.argmax(g))
            peak = g[i]
            left = np.interp(peak - 3.0, g[: i + 1], a[: i + 1])
            right = np.interp(-(peak - 3.0), -g[i:], a[i:])
            return float(right - left)
        v3 = _half_power_v(self.pedestal)
        return float(2 * np.arcsin(min(1.0, v3 * self.wavelength / self.length)))

    def null_angle(self, k: int = 1) -> float:
        """Angle (rad) of the ``k``-th null of an aperture pattern (pi/2 when beyond end-fire)."""
        if self.is_table:
            return float(max(abs(self.table_angles[0]), abs(self.table_angles[-1])))
        v = _null_v(self.pedestal, k)
        s = v * self.wavelength / self.length
        return float(np.arcsin(s)) if s < 1 else float(np.pi / 2)

    def sidelobe_db(self) -> float:
        """Level of the first sidelobe, one-way power, dB re the peak."""
        if self.is_table:
            g = np.asarray(self.table_db)
            i = int(np.argmax(g))
            from scipy.signal import argrelmax

            peaks = [j for j in argrelmax(g)[0] if j != i]
            return float(max(g[peaks]) - g[i]) if peaks else float("-inf")
        v1, v2 = _null_v(self.pedestal, 1), _null_v(self.pedestal, 2)
        vv = np.linspace(v1, v2, 2001)
        return float(10 * np.log10(np.max(_pedestal_f(vv, self.pedestal) ** 2)))

    def integral_one_way_u(self) -> float:
        """Closed form of ``integral F^2 du`` over all ``u = sin theta`` (aperture only)."""
        p = self.pedestal
        mean_a = p + (1 - p) * 2 / np.pi
        mean_a2 = p * p + 2 * p * (1 - p) * 2 / np.pi + (1 - p) ** 2 / 2
        return float(self.wavelength / self.length * mean_a2 / mean_a**2)

    def to_dict(self) -> dict:
        if self.is_table:
            return {"table_angles_deg": [float(np.rad2deg(a)) for a in self.table_angles],
                    "table_db": list(self.table_db)}
        return {"length": float(self.length), "wavelength": float(self.wavelength), "pedestal": float(self.pedestal)}

    @classmethod
    def from_dict(cls, d: dict, source: str = "beam pattern") -> "BeamPattern":
        try:
            if "table_angles_deg" in d:
                return cls.table(np.deg2rad(np.asarray(d["table_angles_deg"], float)), d["table_db"])
            return cls(length=float(d["length"]), wavelength=float(d["wavelength"]), pedestal=float(d.get("pedestal", 1.0)))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{source}: expected length/wavelength/pedestal or table_angles_deg/table_db, got {d!r}") from exc


@functools.lru_cache(maxsize=256)
def _half_power_v(p: float) -> float:
    return brentq(lambda v: _pedestal_f(v, p) ** 2 - 0.5, 1e-6, _null_v(p, 1))


@functools.lru_cache(maxsize=256)
def _null_v(p: float, k: int) -> float:
    """``k``-th zero of ``F(v)`` for v > 0 (uniform: v = k; cosine: v = k + 1/2)."""
    # zeros lie in (k, k + 1/2]; bracket on a fine grid to be safe
    vv = np.linspace(k - 0.01, k + 0.51, 2001)
    f = _pedestal_f(vv, p)
    idx = np.flatnonzero(np.sign(f[:-1]) != np.sign(f[1:]))
    if idx.size == 0:
        return float(vv[np.argmin(np.abs(f))])
    i = idx[0]
    return brentq(lambda v: _pedestal_f(v, p), vv[i], vv[i + 1])
