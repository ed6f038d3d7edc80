"""Device units both ways: linear intensity <-> what a sonar stores.

Linear *intensity* here is power (``|amplitude|^2``), the unit of ``SonarFrame.image``
(the simulator's noise model squares a complex amplitude; docs/physics.md). Each
encoding has a ``decode`` (device values -> float32 intensity) and an ``encode``
(intensity -> device values, clipped and rounded to the device's type), so a simulated
frame can be written like a real one and a real one compared with a simulation.

Encodings (``name``: device value ``v`` <-> intensity ``I``):

``"linear"``
    ``I = v`` (float or integer data already linear in power).
``"amplitude"``
    ``I = v^2`` (linear amplitude, any numeric type).
``"aris_db"``
    ARIS bytes: 0-255 span 0-80 dB (Sound Metrics, *Understanding ARIS data*), read as
    power decibels over ``reference``: ``I = reference * 10^(v * 80/255 / 10)``.
``"oculus_gamma8"``
    Oculus 8-bit samples with the gamma byte ``g`` of the fire message. The ping does
    not say how the gamma is applied; ``reading`` picks the assumption:
    ``"gamma"`` (default): ``v/255 = (A/A_full)^(g/255)``, so ``I = (v/255)^(2*255/g)``;
    ``"amplitude"``: the gamma is display-only and ``v`` is linear amplitude,
    ``I = (v/255)^2``. Both give ``I`` in units of the full-scale power.
``"oculus_16"``, ``"oculus_32"``
    Oculus 16- and 32-bit samples, taken as linear amplitude counts: ``I = v^2``
    (liboculus does not apply the gamma to wide data; the firmware's exact scaling is
    not documented).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["ENCODINGS", "decode", "encode", "describe", "as_device_frame"]

_ARIS_DB_PER_COUNT = 80.0 / 255.0


@dataclass(frozen=True)
class Encoding:
    name: str
    dtype: np.dtype | None  # the device's storage type; None: keep the caller's
    decode: Callable
    encode: Callable
    doc: str


def _f32(x):
    return np.asarray(x, np.float32)


def _dec_linear(v, **_):
    return _f32(v)


def _enc_linear(i, dtype=np.float32, **_):
    return _to_dtype(np.asarray(i, np.float64), dtype)


def _dec_amplitude(v, **_):
    a = np.asarray(v, np.float32)
    return a * a


def _enc_amplitude(i, dtype=np.float32, **_):
    return _to_dtype(np.sqrt(np.maximum(np.asarray(i, np.float64), 0.0)), dtype)


def _dec_aris(v, reference=1.0, **_):
    db = np.asarray(v, np.float32) * np.float32(_ARIS_DB_PER_COUNT)
    return (np.float32(reference) * np.power(np.float32(10.0), db / np.float32(10.0))).astype(np.float32)


def _enc_aris(i, reference=1.0, **_):
    with np.errstate(divide="ignore", invalid="ignore"):
        db = 10.0 * np.log10(np.maximum(np.asarray(i, np.float64), 0.0) / reference)
    return _to_dtype(np.nan_to_num(db, nan=0.0, neginf=0.0) / _ARIS_DB_PER_COUNT, np.uint8)


def _gamma_exponent(gamma, reading):
    if reading == "amplitude":
        return 2.0
    if reading != "gamma":
        raise ValueError(f"oculus_gamma8: reading must be 'gamma' or 'amplitude', got {reading!r}")
    g = float(gamma)
    if not 0 < g <= 255:
        raise ValueError(f"oculus_gamma8: gamma byte must be in 1..255, got {gamma!r}")
    return 2.0 * 255.0 / g


def _dec_gamma8(v, gamma=127, reading="gamma", **_):
    p = _gamma_exponent(gamma, reading)
    return np.power(np.asarray(v, np.float32) / np.float32(255.0), np.float32(p)).astype(np.float32)


def _enc_gamma8(i, gamma=127, reading="gamma", full_scale=1.0, **_):
    p = _gamma_exponent(gamma, reading)
    x = np.maximum(np.asarray(i, np.float64), 0.0) / float(full_scale)
    return _to_dtype(255.0 * np.power(x, 1.0 / p), np.uint8)


def _to_dtype(x, dtype):
    dt = np.dtype(dtype)
    if dt.kind in "ui":
        info = np.iinfo(dt)
        return np.clip(np.rint(x), info.min, info.max).astype(dt)
    return np.asarray(x, dt)


ENCODINGS: dict[str, Encoding] = {
    e.name: e
    for e in (
        Encoding("linear", None, _dec_linear, _enc_linear, "I = v"),
        Encoding("amplitude", None, _dec_amplitude, _enc_amplitude, "I = v^2"),
        Encoding("aris_db", np.dtype(np.uint8), _dec_aris, _enc_aris, "I = 10^(v * 80/255 / 10) (ARIS dB bytes)"),
        Encoding("oculus_gamma8", np.dtype(np.uint8), _dec_gamma8, _enc_gamma8,
                 "I = (v/255)^(2*255/gamma) ('gamma' reading) or (v/255)^2 ('amplitude')"),
        Encoding("oculus_16", np.dtype(np.uint16), _dec_amplitude,
                 lambda i, **kw: _enc_amplitude(i, np.uint16), "I = v^2 (16-bit amplitude counts)"),
        Encoding("oculus_32", np.dtype(np.uint32), _dec_amplitude,
                 lambda i, **kw: _enc_amplitude(i, np.uint32), "I = v^2 (32-bit amplitude counts)"),
    )
}


def _get(encoding: str) -> Encoding:
    try:
        return ENCODINGS[encoding]
    except KeyError:
        raise ValueError(f"unknown device encoding {encoding!r}; known: {sorted(ENCODINGS)}") from None


def decode(raw, encoding: str, **params) -> np.ndarray:
    """Device values -> linear intensity (float32, same shape).

    Parameters
    ----------
    raw : array_like
        Values as stored (any shape).
    encoding : str
        A key of :data:`ENCODINGS`.
    **params
        Encoding parameters: ``reference`` (aris_db), ``gamma`` and ``reading``
        (oculus_gamma8).
    """
    enc = _get(encoding)
    a = np.asarray(raw)
    if a.dtype == np.uint8 and a.size > 256:  # a 256-entry table: one gather instead of a pow per sample
        return _lut(encoding, tuple(sorted(params.items())))[a]
    return enc.decode(a, **params)


@functools.lru_cache(maxsize=64)
def _lut(encoding: str, params: tuple) -> np.ndarray:
    table = np.asarray(_get(encoding).decode(np.arange(256, dtype=np.uint8), **dict(params)), np.float32)
    table.setflags(write=False)
    return table


def encode(intensity, encoding: str, **params) -> np.ndarray:
    """Linear intensity -> device values (clipped and rounded to the device's type).

    ``decode(encode(I))`` equals ``I`` to within the device's quantisation; values
    beyond the device's range saturate. ``dtype=`` picks the type for ``linear`` and
    ``amplitude``; ``full_scale`` is the intensity that maps to 255 for ``oculus_gamma8``.
    """
    return _get(encoding).encode(intensity, **params)


def describe(encoding: str, **params) -> str:
    """One line saying how an encoding's values were linearised (for reports)."""
    e = _get(encoding)
    extra = ", ".join(f"{k}={v}" for k, v in sorted(params.items()))
    return f"{e.name}: {e.doc}" + (f" [{extra}]" if extra else "")


def as_device_frame(frame, encoding: str, **params):
    """A frame (simulated or measured) emitted in a device's units: a ``MeasuredSonarFrame``.

    ``raw = encode(frame.image, encoding, **params)`` and ``image = decode(raw)``, so the
    result carries the device's quantisation and saturation and can be compared with, or
    written like, a real frame of that device.
    """
    from ..sonar.frame import MeasuredSonarFrame

    raw = encode(frame.image, encoding, **params)
    return MeasuredSonarFrame(raw=raw, image=decode(raw, encoding, **params), spec=frame.spec,
                              time=float(getattr(frame, "time", float("nan"))), encoding=encoding,
                              source=getattr(frame, "source", "simulated"), index=int(getattr(frame, "index", 0)),
                              meta={"encoding_params": dict(params)},
                              beam_model=getattr(frame, "beam_model", "aperture"))
