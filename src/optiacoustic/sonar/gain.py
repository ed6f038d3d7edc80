"""Gain and noise as a device applies them: receiver noise, then the device's TVG, then an encoding.

The raw echo power of a cell (after the water's two-way spreading and absorption,
``propagation="spreading"``) is scaled by the source level and receiver gain
(``gain_db``). Two kinds of background add to it *before* the TVG:

* receiver (thermal) noise, flat in range: power ``10^(noise_db / 10)``;
* volume reverberation of the water column: a fixed beam sees a volume ``r^2 dOmega dr``
  whose echo falls as ``r^-4`` two-way, so its power is ``10^(volume_db / 10) r^-2``
  times the absorption.

The device then applies its own time-varying gain

    TVG(r) = (r / r0)^(spreading_db / 10) 10^(2 alpha_dev (r - r0) / 10)

(``spreading_db`` = 20 for "20 log r", 40 for "40 log r"). So after TVG the receiver
noise rises as the TVG and the volume term is flat for a 20 log r TVG: a real device's
background profile is their sum (docs/physics.md, "Gain and noise as devices apply them").
Finally :func:`encode` turns linear intensity into the device's stored values.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["DeviceGain", "encode", "decode", "ENCODINGS"]

#: How a device stores a linear intensity ``I`` (normalised by ``scale``):
#: ``linear`` (I), ``amplitude`` (sqrt I), ``root-amplitude`` (I^(1/4)), ``db`` (10 log10 I).
ENCODINGS = ("linear", "amplitude", "root-amplitude", "db")

#: Bounds of the TVG's coefficients (:class:`DeviceGain`): devices use 20 to 40 log r and the water's
#: absorption (about 1 dB/m at 3 MHz); beyond these the TVG's factor overflows at ordinary ranges.
MAX_SPREADING_DB = 100.0
MAX_ABSORPTION_DB_PER_M = 10.0


@dataclass(frozen=True)
class DeviceGain:
    """A device's gain chain (levels in dB re the simulator's echo units at ``reference_range``).

    Levels (``gain_db``, ``noise_db``, ``volume_db``) lie within +-300 dB (``propagation.MAX_DB``),
    ``spreading_db`` within +-100, ``absorption_db_per_m`` within +-10 dB/m: numbers (not bools or
    strings), checked on construction; a TVG whose factor overflows at a frame's ranges is refused
    when the frame is formed, naming these fields.

    Attributes
    ----------
    gain_db : float
        Source level plus receiver gain applied to the echo.
    noise_db : float or None
        Receiver noise power before the TVG; ``None``: none.
    volume_db : float or None
        Volume reverberation power at ``reference_range`` before the TVG; ``None``: none.
    spreading_db : float
        The TVG's spreading coefficient (``N log10 r``).
    absorption_db_per_m : float
        The TVG's absorption coefficient (one-way, dB/m) as the device assumes it.
    reference_range : float
        ``r0`` (m), where the TVG is 1.
    """

    gain_db: float = 0.0
    noise_db: float | None = -40.0
    volume_db: float | None = None
    spreading_db: float = 20.0
    absorption_db_per_m: float = 0.0
    reference_range: float = 1.0

    def __post_init__(self):
        from .propagation import MAX_DB, check_number

        for name in ("gain_db", "noise_db", "volume_db"):  # None: none (noise and volume)
            check_number(f"DeviceGain.{name}", getattr(self, name), -MAX_DB, MAX_DB, none=name != "gain_db", unit="dB")
        check_number("DeviceGain.spreading_db", self.spreading_db, -MAX_SPREADING_DB, MAX_SPREADING_DB, unit="dB per decade")
        check_number("DeviceGain.absorption_db_per_m", self.absorption_db_per_m, -MAX_ABSORPTION_DB_PER_M,
                     MAX_ABSORPTION_DB_PER_M, unit="dB/m")
        check_number("DeviceGain.reference_range", self.reference_range, 0.0, 1e5, lo_open=True, unit="m")

    def tvg(self, ranges) -> np.ndarray:
        """The device's TVG (linear power factor) at ``ranges`` (m)."""
        r = np.maximum(np.asarray(ranges, float), 1e-3)
        r0 = self.reference_range
        return (r / r0) ** (self.spreading_db / 10.0) * 10.0 ** (2.0 * self.absorption_db_per_m * (r - r0) / 10.0)

    def background_raw(self, ranges, absorption_db_per_m: float = 0.0) -> np.ndarray:
        """Background power before the TVG, ``(n_bins,)``: receiver noise + volume reverberation."""
        r = np.maximum(np.asarray(ranges, float), 1e-3)
        out = np.zeros_like(r)
        if self.noise_db is not None:
            out += 10.0 ** (self.noise_db / 10.0)
        if self.volume_db is not None:
            r0 = self.reference_range
            out += 10.0 ** (self.volume_db / 10.0) * (r0 / r) ** 2 * 10.0 ** (-2 * absorption_db_per_m * (r - r0) / 10.0)
        return out

    def background(self, ranges, absorption_db_per_m: float = 0.0) -> np.ndarray:
        """Mean background power after the TVG, ``(n_bins,)``."""
        return self.background_raw(ranges, absorption_db_per_m) * self.tvg(ranges)

    def to_dict(self) -> dict:
        return asdict(self)


def encode(intensity, encoding: str, scale: float = 1.0, db_range: float = 80.0, full_scale: float = 255.0) -> np.ndarray:
    """Linear intensity -> device values (float, not yet rounded or clipped).

    ``db`` maps ``10 log10(I / scale)`` from 0 .. ``db_range`` dB onto 0 .. ``full_scale``
    (ARIS: 0-255 is 0-80 dB); the others map ``(I / scale)^k`` with k = 1, 1/2, 1/4.
    """
    x = np.maximum(np.asarray(intensity, float), 0.0) / scale
    if encoding == "linear":
        return x
    if encoding == "amplitude":
        return np.sqrt(x)
    if encoding == "root-amplitude":
        return np.sqrt(np.sqrt(x))
    if encoding == "db":
        with np.errstate(divide="ignore"):
            return 10 * np.log10(np.maximum(x, 1e-30)) * full_scale / db_range
    raise ValueError(f"encoding: expected one of {ENCODINGS}, got {encoding!r}")


def decode(values, encoding: str, scale: float = 1.0, db_range: float = 80.0, full_scale: float = 255.0) -> np.ndarray:
    """Device values -> linear intensity; the inverse of :func:`encode`."""
    v = np.asarray(values, float)
    if encoding == "linear":
        return v * scale
    if encoding == "amplitude":
        return v**2 * scale
    if encoding == "root-amplitude":
        return v**4 * scale
    if encoding == "db":
        return 10.0 ** (v * db_range / full_scale / 10.0) * scale
    raise ValueError(f"encoding: expected one of {ENCODINGS}, got {encoding!r}")
