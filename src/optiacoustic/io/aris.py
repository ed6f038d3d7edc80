"""Sound Metrics ARIS recordings (``.aris``, DDF_05).

Layout (little-endian, byte-packed; aris-file-sdk ``type_definitions/FileHeader.h`` and
``FrameHeader.h``, ``docs/understanding-aris-data.md``; field by field in
docs/formats/aris.md):

- ``FileHeader``, 1024 bytes at offset 0: ``Version`` (signature 0x05464444),
  ``FrameCount`` (obsolete: the count comes from the file size), ``NumRawBeams``,
  ``SamplesPerChannel``, ``SN``, ``strDate``, ``strHeaderID``, ...
- then frames, each a 1024-byte ``FrameHeader`` followed by ``SamplesPerBeam x BeamCount``
  bytes. Frame ``FI`` starts at ``1024 + FI * (1024 + SamplesPerBeam * BeamCount)``.
- frame header fields used: ``FrameIndex`` (0), ``FrameTime`` (4, uint64 microseconds
  since the epoch, PC clock), ``Version`` (12), ``sonarTimeStamp`` (20), ``WindowStart``
  and ``WindowLength`` (52, 56, float, m; informational), ``ReceiverGain`` (68),
  ``WaterTemp`` (224), ``PingMode`` (436; gives the beam count: 1-2 -> 48, 3-5 -> 96,
  6-8 -> 64, 9-12 -> 128), ``FrequencyHiLow`` (440), ``PulseWidth`` (444),
  ``SamplePeriod`` (452, us), ``SoundSpeed`` (464, float, m/s), ``SamplesPerBeam`` (468),
  ``SampleStartDelay`` (476, us), ``LargeLens`` (480, 1 = telephoto),
  ``TheSystemType`` (484: 0 = ARIS 1800, 1 = ARIS 3000, 2 = ARIS 1200),
  ``SonarSerialNumber`` (488), ``ReorderedSamples`` (516, must be non-zero in files).
- samples: one byte each, 0-255 = 0-80 dB (``units`` ``"aris_db"``), stored
  sample-major (row = range sample, near to far) with beam 0 the right-most beam; we
  reverse the columns so that column 0 is the left-most beam.

Ranges (SDK): ``WindowStart = SampleStartDelay * 1e-6 * SoundSpeed / 2``,
``SampleLength = SamplePeriod * 1e-6 * SoundSpeed / 2``, sample ``i`` at
``WindowStart + i * SampleLength``. Beam angles: the SDK's lens table for the system
type, lens and beam count (``optiacoustic/data/aris_beam_widths``).
"""

from __future__ import annotations

import dataclasses
import functools
import re
from importlib import resources

import numpy as np

from ..sonar.frame import MeasuredSonarFrame
from ..sonar.spec import SonarSpec
from . import units
from ._sequence import FrameSequence, MappedFile
from .errors import ReadError

__all__ = ["open_aris", "ArisReader", "beam_table", "ARIS_SIGNATURE", "FILE_HEADER_SIZE", "FRAME_HEADER_SIZE"]

ARIS_SIGNATURE = 0x05464444
FILE_HEADER_SIZE = 1024
FRAME_HEADER_SIZE = 1024

#: File-header fields read (name, dtype, byte offset).
FILE_FIELDS = [("Version", "<u4", 0), ("FrameCount", "<u4", 4), ("NumRawBeams", "<u4", 16),
               ("SamplesPerChannel", "<u4", 24), ("SN", "<u4", 44), ("strDate", "S32", 48),
               ("strHeaderID", "S256", 80)]
#: Frame-header fields read (name, dtype, byte offset within the frame header).
FRAME_FIELDS = [("FrameIndex", "<u4", 0), ("FrameTime", "<u8", 4), ("Version", "<u4", 12),
                ("sonarTimeStamp", "<u8", 20), ("WindowStart", "<f4", 52), ("WindowLength", "<f4", 56),
                ("ReceiverGain", "<u4", 68), ("WaterTemp", "<f4", 224), ("PingMode", "<u4", 436),
                ("FrequencyHiLow", "<u4", 440), ("PulseWidth", "<u4", 444), ("SamplePeriod", "<u4", 452),
                ("SoundSpeed", "<f4", 464), ("SamplesPerBeam", "<u4", 468), ("SampleStartDelay", "<u4", 476),
                ("LargeLens", "<u4", 480), ("TheSystemType", "<u4", 484), ("SonarSerialNumber", "<u4", 488),
                ("ReorderedSamples", "<u4", 516), ("Salinity", "<u4", 520)]


def _struct(fields, size):
    return np.dtype({"names": [f[0] for f in fields], "formats": [f[1] for f in fields],
                     "offsets": [f[2] for f in fields], "itemsize": size})


_FILE = _struct(FILE_FIELDS, FILE_HEADER_SIZE)
_FRAME = _struct(FRAME_FIELDS, FRAME_HEADER_SIZE)
_FRAME_OFFSET = {f[0]: f[2] for f in FRAME_FIELDS}

_SYSTEMS = {0: "ARIS 1800", 1: "ARIS 3000", 2: "ARIS 1200"}
#: (system type, telephoto, beams) -> beam-width file; systems 0 and 2 share the 1800/1200 lens.
_TABLE_FILES = {
    (48, False): "BeamWidths_ARIS1800_1200_48.h", (96, False): "BeamWidths_ARIS1800_96.h",
    (64, False): "BeamWidths_ARIS3000_64.h", (128, False): "BeamWidths_ARIS3000_128.h",
    (48, True): "BeamWidths_ARIS_Telephoto_48.h", (96, True): "BeamWidths_ARIS_Telephoto_96.h",
}


def beams_from_ping_mode(ping_mode: int) -> int:
    """Beam count of an ARIS ping mode (aris-file-sdk ``get_beams_from_pingmode``); 0 if unknown."""
    return {1: 48, 2: 48, 3: 96, 4: 96, 5: 96, 6: 64, 7: 64, 8: 64}.get(ping_mode, 128 if 9 <= ping_mode <= 12 else 0)


@functools.lru_cache(maxsize=None)
def beam_table(n_beams: int, telephoto: bool = False) -> tuple[np.ndarray, str]:
    """Beam-centre azimuths (rad, our convention: left to right, positive to starboard) and the table's file name.

    Column ``j`` of a reader's image is SDK beam ``n_beams - 1 - j``; its azimuth is the
    negated SDK centre angle (the SDK's beam 0 is right-most with a negative angle).
    """
    try:
        name = _TABLE_FILES[(int(n_beams), bool(telephoto))]
    except KeyError:
        raise ValueError(f"no ARIS beam table for {n_beams} beams (telephoto={telephoto}); "
                         f"tables exist for {sorted(_TABLE_FILES)}") from None
    text = resources.files("optiacoustic.data").joinpath("aris_beam_widths", name).read_text()
    rows = re.findall(r"DEFINE_BEAMWIDTH3\(\s*(\d+)\s*,\s*([-\d.]+)\s*,\s*([-\d.]+)\s*,\s*([-\d.]+)\s*\)", text)
    beam = np.array([int(r[0]) for r in rows])
    centre = np.array([float(r[1]) for r in rows])
    if not np.array_equal(beam, np.arange(n_beams)):
        raise ValueError(f"{name}: expected beams 0..{n_beams - 1}, found {beam.size} rows")
    az = np.deg2rad(-centre[::-1])
    az.setflags(write=False)
    return az, name


def open_aris(path, *, errors: str = "raise") -> "ArisReader":
    """Open an ARIS recording lazily (memory-mapped; a frame is decoded when asked for)."""
    return ArisReader(path, errors=errors)


class ArisReader(FrameSequence):
    """Lazy sequence of :class:`MeasuredSonarFrame` from an ``.aris`` file."""

    def __init__(self, path, *, errors="raise"):
        super().__init__(errors)
        self.file = MappedFile(path)
        self.path = self.file.path
        fh = np.frombuffer(self.file.view(0, FILE_HEADER_SIZE, "ARIS file header"), _FILE)[0]
        if fh["Version"] != ARIS_SIGNATURE:
            raise ReadError(self.path, f"not an ARIS file: signature 0x{int(fh['Version']):08x}, expected "
                                       f"0x{ARIS_SIGNATURE:08x}", offset=0)
        self.file_header = fh
        h0 = self._frame_header(0, FILE_HEADER_SIZE)
        self.n_beams = beams_from_ping_mode(int(h0["PingMode"]))
        if self.n_beams == 0:
            raise ReadError(self.path, f"PingMode {int(h0['PingMode'])} is not an ARIS ping mode (1..12)", frame=0,
                            offset=FILE_HEADER_SIZE + _FRAME_OFFSET["PingMode"])
        self.n_samples = int(h0["SamplesPerBeam"])
        if not 1 <= self.n_samples <= 1 << 16:
            raise ReadError(self.path, f"SamplesPerBeam {self.n_samples} is not plausible", frame=0,
                            offset=FILE_HEADER_SIZE + _FRAME_OFFSET["SamplesPerBeam"])
        self.frame_size = FRAME_HEADER_SIZE + self.n_beams * self.n_samples
        body = self.file.size - FILE_HEADER_SIZE
        self._n_full, self._tail = divmod(body, self.frame_size)

    def __len__(self):
        return self._n_full + (1 if self._tail else 0)

    def _frame_header(self, i: int, pos: int) -> np.void:
        h = np.frombuffer(self.file.view(pos, FRAME_HEADER_SIZE, "frame header", i), _FRAME)[0]
        if h["Version"] != ARIS_SIGNATURE:
            raise ReadError(self.path, f"bad frame signature 0x{int(h['Version']):08x} (expected "
                                       f"0x{ARIS_SIGNATURE:08x}): corrupt frame header", frame=i, offset=pos + 12)
        return h

    def frame_offset(self, i: int) -> int:
        """Byte offset of frame ``i``'s header."""
        return FILE_HEADER_SIZE + i * self.frame_size

    def _read(self, i: int) -> MeasuredSonarFrame:
        pos = self.frame_offset(i)
        h = self._frame_header(i, pos)
        fail = lambda msg, field: ReadError(self.path, msg, frame=i, offset=pos + _FRAME_OFFSET[field])  # noqa: E731
        if beams_from_ping_mode(int(h["PingMode"])) != self.n_beams or int(h["SamplesPerBeam"]) != self.n_samples:
            raise fail(f"frame size changed: PingMode {int(h['PingMode'])}, SamplesPerBeam "
                       f"{int(h['SamplesPerBeam'])} (the file's first frame: {self.n_beams} beams x "
                       f"{self.n_samples} samples)", "PingMode")
        c = float(h["SoundSpeed"])
        if not (np.isfinite(c) and 1300.0 <= c <= 1700.0):
            raise fail(f"SoundSpeed {c!r} m/s is outside 1300-1700", "SoundSpeed")
        period = int(h["SamplePeriod"])
        if not 1 <= period <= 1000:
            raise fail(f"SamplePeriod {period} us is outside 1-1000", "SamplePeriod")
        delay = int(h["SampleStartDelay"])
        start, end = delay * 1e-6 * c / 2, (delay + period * (self.n_samples - 0.5)) * 1e-6 * c / 2
        if not (period / 2 <= delay and end <= _MAX_RANGE_M):
            raise fail(f"SampleStartDelay {delay} us puts the window at {start:.3g}-{end:.3g} m: it must start at least "
                       f"half a sample period ({period / 2:g} us) after the ping and end within {_MAX_RANGE_M:g} m",
                       "SampleStartDelay")
        if h["ReorderedSamples"] == 0:
            raise fail("ReorderedSamples is 0: samples in device order (a live stream, not a file); "
                       "reordering is not supported", "ReorderedSamples")
        data = self.file.view(pos + FRAME_HEADER_SIZE, self.n_beams * self.n_samples, "frame samples", i)
        raw = np.frombuffer(data, np.uint8).reshape(self.n_samples, self.n_beams)[:, ::-1].copy()
        spec = _spec(self.n_beams, bool(h["LargeLens"]), int(h["SampleStartDelay"]), period, c, self.n_samples,
                     int(h["FrequencyHiLow"]), int(h["TheSystemType"]))
        t_us = int(h["FrameTime"])
        meta = dict(format="aris", system=_SYSTEMS.get(int(h["TheSystemType"]), f"type {int(h['TheSystemType'])}"),
                    telephoto=bool(h["LargeLens"]), ping_mode=int(h["PingMode"]), beams=self.n_beams,
                    samples_per_beam=self.n_samples, sample_period_us=period, sample_start_delay_us=int(h["SampleStartDelay"]),
                    sound_speed=c, window_start_header=float(h["WindowStart"]),
                    window_length_header=float(h["WindowLength"]), receiver_gain_db=int(h["ReceiverGain"]),
                    frequency="high" if h["FrequencyHiLow"] else "low", pulse_width_us=int(h["PulseWidth"]),
                    water_temp_c=float(h["WaterTemp"]), serial=int(h["SonarSerialNumber"]),
                    frame_index_header=int(h["FrameIndex"]), sonar_time_us=int(h["sonarTimeStamp"]),
                    beam_table=beam_table(self.n_beams, bool(h["LargeLens"]) and self.n_beams in (48, 96))[1],
                    byte_offset=pos)
        return MeasuredSonarFrame(raw=raw, image=units.decode(raw, "aris_db"), spec=spec,
                                  time=t_us * 1e-6 if t_us else float("nan"), encoding="aris_db",
                                  source=str(self.path), index=i, meta=meta)

    def times(self) -> np.ndarray:
        """``FrameTime`` of every frame (s), from the frame headers only (NaN where zero, and for a
        truncated last frame: one time per frame, as ``len``)."""
        out = np.full(len(self), np.nan)
        for i in range(self._n_full):
            t = int(np.frombuffer(self.file.view(self.frame_offset(i) + 4, 8, "FrameTime", i), "<u8")[0])
            out[i] = t * 1e-6 if t else np.nan
        return out

    def info(self) -> dict:
        d = super().info()
        d.update(format="ARIS (DDF_05)", beams=self.n_beams, samples_per_beam=self.n_samples,
                 frame_bytes=self.frame_size, serial=int(self.file_header["SN"]))
        if self._tail:
            d["damaged_tail"] = f"last frame truncated: {self._tail} of {self.frame_size} bytes"
        try:
            f = self._frame(0)
            d.update({k: v for k, v in f.meta.items() if k not in ("byte_offset", "format")})
            d["range_window_m"] = (float(f.ranges[0]), float(f.ranges[-1]))
            d["spec"] = f.spec.summary()
        except ReadError as exc:
            d["first_frame_error"] = str(exc)
        return d

    def close(self):
        self.file.close()


# a sanity bound on the window's far end, well beyond any ARIS model's longest window (tens of metres)
_MAX_RANGE_M = 300.0
# nominal frequencies (Hz) of (system type, high-frequency flag), from Sound Metrics datasheets
_FREQ = {(0, 1): 1.8e6, (0, 0): 1.1e6, (1, 1): 3.0e6, (1, 0): 1.8e6, (2, 1): 1.2e6, (2, 0): 0.7e6}


@functools.lru_cache(maxsize=64)
def _spec(n_beams, telephoto, start_delay_us, period_us, c, n_samples, hf, system) -> SonarSpec:
    az, name = beam_table(n_beams, telephoto and n_beams in (48, 96))
    start = start_delay_us * 1e-6 * c / 2
    step = period_us * 1e-6 * c / 2
    ranges = start + np.arange(n_samples) * step
    spec = SonarSpec(name=_SYSTEMS.get(system, f"aris-type{system}").lower().replace(" ", "-"),
                     source=f"ARIS frame header; beam table {name}", fov_elevation=float(np.deg2rad(14.0)),
                     frequency=_FREQ.get((system, int(bool(hf))), 1.8e6), sound_speed=float(c),
                     range_resolution=step,
                     beamwidth_azimuth=float(np.mean(np.diff(az))),
                     unverified=("fov_elevation (14 deg nominal)", "frequency (nominal)",
                                 "beamwidth_azimuth (mean beam spacing)"))
    # equal bins: the window as a uniform range grid (bin centres at the sample ranges)
    spec = spec.with_beam_table(az)
    return dataclasses.replace(spec, n_bins=n_samples, range_min=float(ranges[0] - step / 2),
                               range_max=float(ranges[-1] + step / 2))
