"""Oculus (Blueprint Subsea) pings as logged by liboculus: ``SimplePingResult`` v1 and v2.

Layout (little-endian, byte-packed; Blueprint's ``Oculus.h`` as shipped in
apl-ocean-engineering/liboculus, ``thirdparty/Oculus/Oculus.h``; field by field in
docs/formats/oculus.md):

- ``OculusMessageHeader`` (16 bytes): ``oculusId`` (0x4f53), source and destination
  ids, ``msgId`` (0x23 = simple ping result), ``msgVersion`` (2 = v2 layout, else
  v1), ``payloadSize`` (bytes after this header), ``partNumber``.
- ``OculusSimpleFireMessage`` (v1, 53 bytes with the header) or ``...2`` (v2, 89):
  ``masterMode`` (1 = low, 2 = high frequency), ``pingRate``, ``networkSpeed``,
  ``gammaCorrection`` (byte), ``flags`` (bit 0 range in metres, bit 1 16-bit data,
  bit 2 gain sent per line, bit 3 simple return, bit 4 gain assistance, bit 6 512
  beams), ``range``, ``gainPercent``, ``speedOfSound``, ``salinity`` (double); v2 adds
  ``extFlags`` and reserved words.
- ``OculusSimplePingResult`` (v1, 122 bytes) / ``...2`` (v2, 202): ``pingId``,
  ``status``, ``frequency`` (Hz), ``temperature``, ``pressure``, (v2: ``heading``,
  ``pitch``, ``roll``), ``speedOfSoundUsed``, ``pingStartTime`` (v1 uint32, v2 double
  seconds since power-up), ``dataSize`` (0/1/2/3 = 8/16/24/32-bit), ``rangeResolution``
  (m per range line), ``nRanges``, ``nBeams``, (v2: four spare words), ``imageOffset``,
  ``imageSize``, ``messageSize``.
- right after the ping struct: ``nBeams`` int16 bearings in 1/100 degree;
- at ``imageOffset``: ``nRanges`` rows, each (when the send-gain flag is set) a 4-byte
  gain followed by ``nBeams`` samples (liboculus reads the gain as a float32).

A ``gammaCorrection`` byte of 0 (not a gamma) is read as 255, no correction: the 8-bit
samples are then amplitudes (exponent 2), whatever ``reading`` says. A ``frequency`` or
``speedOfSoundUsed`` outside a plausible range keeps :class:`SonarSpec`'s default, listed in the
spec's ``unverified``.

A file is a stream of such messages (one ping per message); other message types are
skipped by their ``payloadSize``. Range line ``i`` is centred at
``(i + 0.5) * rangeResolution``. Bearings are taken as positive to starboard and
increasing with the column (the Oculus viewer's convention); they become the spec's
beam table. No wall-clock time is in the ping: ``time`` is NaN unless the caller gives
``times``.
"""

from __future__ import annotations

import functools
import numpy as np

from ..sonar.frame import MeasuredSonarFrame
from ..sonar.spec import SonarSpec
from . import units
from ._sequence import FrameSequence, MappedFile
from .errors import ReadError

__all__ = ["open_oculus", "OculusReader", "OCULUS_ID", "MSG_SIMPLE_PING_RESULT"]

OCULUS_ID = 0x4F53
MSG_SIMPLE_PING_RESULT = 0x23

_HEADER = np.dtype([("oculusId", "<u2"), ("srcDeviceId", "<u2"), ("dstDeviceId", "<u2"), ("msgId", "<u2"),
                    ("msgVersion", "<u2"), ("payloadSize", "<u4"), ("partNumber", "<u2")])
_FIRE = [("masterMode", "u1"), ("pingRate", "u1"), ("networkSpeed", "u1"), ("gammaCorrection", "u1"),
         ("flags", "u1"), ("range", "<f8"), ("gainPercent", "<f8"), ("speedOfSound", "<f8"), ("salinity", "<f8")]
_FIRE2 = _FIRE + [("extFlags", "<u4"), ("reserved0", "<u4", (2,)), ("beaconLocatorFrequency", "<u4"),
                  ("reserved1", "<u4", (5,))]
_PING1 = np.dtype([("head", _HEADER)] + _FIRE + [
    ("pingId", "<u4"), ("status", "<u4"), ("frequency", "<f8"), ("temperature", "<f8"), ("pressure", "<f8"),
    ("speedOfSoundUsed", "<f8"), ("pingStartTime", "<u4"), ("dataSize", "u1"), ("rangeResolution", "<f8"),
    ("nRanges", "<u2"), ("nBeams", "<u2"), ("imageOffset", "<u4"), ("imageSize", "<u4"), ("messageSize", "<u4")])
_PING2 = np.dtype([("head", _HEADER)] + _FIRE2 + [
    ("pingId", "<u4"), ("status", "<u4"), ("frequency", "<f8"), ("temperature", "<f8"), ("pressure", "<f8"),
    ("heading", "<f8"), ("pitch", "<f8"), ("roll", "<f8"), ("speedOfSoundUsed", "<f8"), ("pingStartTime", "<f8"),
    ("dataSize", "u1"), ("rangeResolution", "<f8"), ("nRanges", "<u2"), ("nBeams", "<u2"), ("spare", "<u4", (4,)),
    ("imageOffset", "<u4"), ("imageSize", "<u4"), ("messageSize", "<u4")])
assert _HEADER.itemsize == 16 and _PING1.itemsize == 122 and _PING2.itemsize == 202  # noqa: S101 (layout guard)

_SAMPLE_TYPES = {0: (np.dtype("<u1"), "oculus_gamma8"), 1: (np.dtype("<u2"), "oculus_16"),
                 3: (np.dtype("<u4"), "oculus_32")}
_FLAG_SEND_GAIN = 0x04


def open_oculus(path, *, errors: str = "raise", reading: str = "gamma", times=None) -> "OculusReader":
    """Open an Oculus ping log lazily (see the module docstring for the layout).

    Parameters
    ----------
    path : path-like
    errors : {"raise", "skip"}
        What a damaged ping does while iterating (see :class:`FrameSequence`).
    reading : {"gamma", "amplitude"}
        How 8-bit samples are linearised (:mod:`optiacoustic.io.units`, ``oculus_gamma8``).
    times : sequence of float, optional
        Seconds since the epoch of each ping (from an outer log); default NaN.
    """
    return OculusReader(path, errors=errors, reading=reading, times=times)


class OculusReader(FrameSequence):
    """Lazy sequence of :class:`MeasuredSonarFrame` from an Oculus message stream."""

    def __init__(self, path, *, errors="raise", reading="gamma", times=None):
        super().__init__(errors)
        units._gamma_exponent(127, reading)  # validates ``reading``
        self.reading = reading
        self.file = MappedFile(path)
        self.path = self.file.path
        self._offsets, self.other_messages, self.index_error = self._scan()
        if not self._offsets and self.index_error is None:
            raise ReadError(self.path, "no Oculus SimplePingResult (msgId 0x23) message in the file")
        if not self._offsets:
            raise self.index_error
        self._times = None if times is None else np.asarray(times, float)
        if self._times is not None and self._times.shape != (len(self._offsets),):
            raise ValueError(f"times: expected {len(self._offsets)} values (one per ping), got {self._times.shape}")

    def _scan(self):
        """Offsets of the ping messages: read 16 bytes per message, jump by ``payloadSize``."""
        f, pos, pings, other = self.file, 0, [], 0
        while pos < f.size:
            if pos + _HEADER.itemsize > f.size:
                return pings, other, ReadError(self.path, f"truncated message header ({f.size - pos} of 16 bytes)",
                                               frame=len(pings), offset=pos)
            h = np.frombuffer(f.view(pos, _HEADER.itemsize, "message header"), _HEADER)[0]
            if h["oculusId"] != OCULUS_ID:
                return pings, other, ReadError(
                    self.path, f"not an Oculus message: oculusId 0x{int(h['oculusId']):04x}, expected 0x4f53",
                    frame=len(pings), offset=pos)
            end = pos + _HEADER.itemsize + int(h["payloadSize"])
            if h["msgId"] == MSG_SIMPLE_PING_RESULT:
                pings.append((pos, min(end, f.size) - pos))
            else:
                other += 1
            pos = end
        return pings, other, None

    def __len__(self):
        # a damaged tail (bad or truncated message header) counts as one more frame, which raises when read
        return len(self._offsets) + (1 if self.index_error is not None else 0)

    def header(self, i: int) -> np.void:
        """The parsed ``SimplePingResult`` struct of ping ``i`` (v1 or v2 dtype)."""
        pos, length = self._offsets[i]
        h = np.frombuffer(self.file.view(pos, 16, "message header", i), _HEADER)[0]
        dt = _PING2 if h["msgVersion"] == 2 else _PING1
        if length < dt.itemsize:
            raise ReadError(self.path, f"truncated ping: {length} bytes, the v{2 if dt is _PING2 else 1} ping "
                                       f"header alone is {dt.itemsize}", frame=i, offset=pos)
        return np.frombuffer(self.file.view(pos, dt.itemsize, "ping header", i), dt)[0]

    def _read(self, i: int) -> MeasuredSonarFrame:
        if i >= len(self._offsets):
            raise self.index_error
        pos, length = self._offsets[i]
        p = self.header(i)
        fail = functools.partial(ReadError, self.path, frame=i)
        h = p["head"]
        if int(h["payloadSize"]) + 16 > length:
            raise fail(f"truncated ping: payloadSize says {int(h['payloadSize']) + 16} bytes, the file holds "
                       f"{length}", offset=pos)
        nb, nr = int(p["nBeams"]), int(p["nRanges"])
        off = lambda name: pos + p.dtype.fields[name][1]  # noqa: E731
        if nr < 1:
            raise fail(f"nRanges = {nr}: must be >= 1", offset=off("nRanges"))
        if nb < 2:  # a fan's beam spacing needs two bearings
            raise fail(f"nBeams = {nb}: an imaging sonar's ping has at least 2 beams", offset=off("nBeams"))
        ds = int(p["dataSize"])
        if ds not in _SAMPLE_TYPES:
            raise fail(f"unsupported dataSize {ds} ({(ds + 1) * 8}-bit samples); supported: 8, 16, 32-bit",
                       offset=off("dataSize"))
        dtype, encoding = _SAMPLE_TYPES[ds]
        res = float(p["rangeResolution"])
        if not (np.isfinite(res) and 0 < res < 10):
            raise fail(f"rangeResolution {res!r} m is not a plausible value", offset=off("rangeResolution"))
        gain = bool(int(p["flags"]) & _FLAG_SEND_GAIN)
        stride = nb * dtype.itemsize + (4 if gain else 0)
        img_off, img_size = int(p["imageOffset"]), int(p["imageSize"])
        if img_size != nr * stride:
            raise fail(f"imageSize {img_size} != nRanges x row size = {nr} x {stride}", offset=off("imageSize"))
        bearing_off = p.dtype.itemsize
        if img_off < bearing_off + 2 * nb or img_off + img_size > length:
            raise fail(f"imageOffset {img_off} + imageSize {img_size} do not fit the {length}-byte message after "
                       f"{nb} bearings", offset=off("imageOffset"))
        bearings = np.frombuffer(self.file.view(pos + bearing_off, 2 * nb, "bearing table", i), "<i2")
        if np.any(np.diff(bearings) <= 0):
            k = int(np.flatnonzero(np.diff(bearings) <= 0)[0])
            raise fail(f"bearing table not strictly increasing at beam {k + 1} ({bearings[k]} then "
                       f"{bearings[k + 1]} x 0.01 deg)", offset=pos + bearing_off + 2 * k)
        rows = np.frombuffer(self.file.view(pos + img_off, img_size, "image", i), np.uint8).reshape(nr, stride)
        raw = np.ascontiguousarray(rows[:, (4 if gain else 0):]).view(dtype.newbyteorder("<")).astype(dtype.newbyteorder("="))
        gains = rows[:, :4].copy().view("<f4")[:, 0].astype(np.float32) if gain else None
        spec = _spec(tuple(bearings.tolist()), nr, res, float(p["frequency"]), float(p["speedOfSoundUsed"]))
        gamma = int(p["gammaCorrection"])
        params = dict(gamma=gamma if gamma > 0 else 255, reading=self.reading) if ds == 0 else {}
        image = units.decode(raw, encoding, **params)
        meta = dict(format="oculus", version=2 if h["msgVersion"] == 2 else 1, ping_id=int(p["pingId"]),
                    master_mode=int(p["masterMode"]), gamma=gamma, flags=int(p["flags"]), range=float(p["range"]),
                    gain_percent=float(p["gainPercent"]), frequency=float(p["frequency"]),
                    sound_speed=float(p["speedOfSoundUsed"]), range_resolution=res, data_bits=dtype.itemsize * 8,
                    ping_start_time=float(p["pingStartTime"]), part_number=int(h["partNumber"]),
                    encoding_params=params, byte_offset=pos)
        if gains is not None:
            meta["gains"] = gains.tolist()
        t = float(self._times[i]) if self._times is not None else float("nan")
        return MeasuredSonarFrame(raw=raw, image=image, spec=spec, time=t, encoding=encoding, source=str(self.path),
                                  index=i, meta=meta)

    def times(self) -> np.ndarray:
        """The ``times`` given when opening, else NaN for every ping (pings carry no wall clock)."""
        out = np.full(len(self), np.nan)
        if self._times is not None:
            out[:self._times.size] = self._times
        return out

    def info(self) -> dict:
        d = super().info()
        d.update(other_messages=self.other_messages)
        if self.index_error is not None:
            d["damaged_tail"] = str(self.index_error)
        else:  # a last ping cut short (its header says more bytes than the file holds), as ARIS reports
            pos, n = self._offsets[-1]
            h = np.frombuffer(self.file.view(pos, _HEADER.itemsize, "message header"), _HEADER)[0]
            want = _HEADER.itemsize + int(h["payloadSize"])
            if n < want:
                d["damaged_tail"] = f"last ping truncated: {n} of {want} bytes"
        try:
            f = self._frame(0)
            d.update({k: v for k, v in f.meta.items() if k not in ("gains", "encoding_params", "format")})
            d["format"] = f"Oculus SimplePingResult v{f.meta['version']} stream"
            d["spec"] = f.spec.summary()
        except ReadError as exc:
            d["first_frame_error"] = str(exc)
        return d

    def close(self):
        self.file.close()


@functools.lru_cache(maxsize=64)
def _spec(bearings_cdeg: tuple, n_ranges: int, res: float, frequency: float, sound_speed: float) -> SonarSpec:
    az = np.deg2rad(np.asarray(bearings_cdeg, float) / 100.0)
    kw = dict(n_bins=n_ranges, range_min=0.0, range_max=n_ranges * res, range_resolution=res,
              name="oculus", source="Oculus SimplePingResult",
              beamwidth_azimuth=float(np.mean(np.diff(az))),
              unverified=("beamwidth_azimuth (mean bearing spacing)", "fov_elevation (not in the ping)"))
    # a value the ping does not give plausibly keeps SonarSpec's default, and says so
    if np.isfinite(frequency) and 1e3 < frequency < 1e8:
        kw["frequency"] = frequency
    else:
        kw["unverified"] += (f"frequency (the ping's {frequency!r} Hz is not plausible: "
                             f"{SonarSpec.frequency / 1e3:g} kHz assumed)",)
    if np.isfinite(sound_speed) and 1000 < sound_speed < 2000:
        kw["sound_speed"] = sound_speed
    else:
        kw["unverified"] += (f"sound_speed (the ping's speedOfSoundUsed {sound_speed!r} m/s is not plausible: "
                             f"{SonarSpec.sound_speed:g} m/s assumed)",)
    spec = SonarSpec(**kw).with_beam_table(az)
    # the beam width: the mean bearing spacing is what the table says; the physical width is not in the ping
    return spec


