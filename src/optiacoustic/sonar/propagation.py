"""Acoustic propagation: absorption in sea water and two-way spreading loss.

The default image model is the thesis's: an ideal time-varying gain (TVG) removes the
range dependence entirely (sec. 2.5). :func:`two_way_gain` gives the alternative, raw
echo level of a surface patch seen through a fixed angular cell:
``G(r) = (r0 / r)^2 * 10^(-2 alpha r / 10)`` (docs/physics.md derives the ``r^-2``: the
``r^-4`` of two-way spherical spreading times the ``r^2`` growth of the patch).
"""

from __future__ import annotations

import functools

from dataclasses import dataclass

import numpy as np

from .._validate import check_number  # noqa: F401 (the sonar models import it from here)

__all__ = ["Seawater", "absorption_db_per_m", "two_way_gain"]

#: Bound of every level in dB of the sonar models (``NoiseModel``, ``DeviceGain``): +-300 dB is a factor
#: of 1e+-30, beyond any physical source level, gain or noise (a typo such as 1e6 dB would overflow).
MAX_DB = 300.0


@dataclass(frozen=True)
class Seawater:
    """Water properties for absorption: temperature (deg C), salinity (PSU), depth (m), pH."""

    temperature: float = 10.0
    salinity: float = 35.0
    depth: float = 10.0
    ph: float = 8.0

    def __post_init__(self):
        for name, lo, hi in (("temperature", -2, 40), ("salinity", 0, 45), ("depth", 0, 11000), ("ph", 6, 9)):
            check_number(f"Seawater.{name}", getattr(self, name), lo, hi)


def absorption_db_per_m(frequency_hz, water: Seawater = Seawater()) -> np.ndarray:
    """Sound absorption in sea water (dB/m), Ainslie & McColm (1998), JASA 103(3):1671-1672.

    Sum of the boric acid, magnesium sulphate and pure-water relaxation terms; valid
    from 100 Hz to 1 MHz (and used beyond, where the pure-water f^2 term dominates).
    At 900 kHz, 10 deg C, 35 PSU it gives about 0.32 dB/m.
    """
    f = np.asarray(frequency_hz, float) / 1e3  # kHz
    T, S, z, pH = water.temperature, water.salinity, water.depth / 1e3, water.ph
    f1 = 0.78 * np.sqrt(S / 35.0) * np.exp(T / 26.0)
    f2 = 42.0 * np.exp(T / 17.0)
    boric = 0.106 * f1 * f**2 / (f1**2 + f**2) * np.exp((pH - 8.0) / 0.56)
    mgso4 = 0.52 * (1 + T / 43.0) * (S / 35.0) * f2 * f**2 / (f2**2 + f**2) * np.exp(-z / 6.0)
    pure = 0.00049 * f**2 * np.exp(-(T / 27.0 + z / 17.0))
    return (boric + mgso4 + pure) / 1e3


@functools.lru_cache(maxsize=64)
def absorption_scalar(frequency_hz: float, water: Seawater) -> float:
    """``float(absorption_db_per_m(frequency_hz, water))`` for one frequency, remembered (a frame asks for
    it two or three times; each evaluation costs ~30 us of numpy calls on the frame's serial path)."""
    return float(absorption_db_per_m(float(frequency_hz), water))


def two_way_gain(ranges, frequency_hz, water: Seawater = Seawater(), reference_range: float = 1.0) -> np.ndarray:
    """Echo level factor of a surface patch at ``ranges`` (m) relative to ``reference_range``.

    ``(r0 / r)^2 * 10^(-2 alpha (r - r0) / 10)``; the inverse is the ideal TVG.
    """
    r = np.asarray(ranges, float)
    a = absorption_db_per_m(frequency_hz, water)
    with np.errstate(divide="ignore"):
        return (reference_range / r) ** 2 * 10.0 ** (-2.0 * a * (r - reference_range) / 10.0)
