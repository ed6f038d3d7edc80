"""TEMPORARY test helper: minimal readers of the two shared real samples (until i9's io readers land).

Only what the realism tests need: the stored values, the bearing/lens table, the range
window. Builds ``MeasuredSonarFrame`` (sonar/frame.py) so that the tests switch to
``optiacoustic.io.open_sonar`` without other changes.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np

from optiacoustic.sonar import SonarSpec
from optiacoustic.sonar.frame import MeasuredSonarFrame

REAL = Path("/work/shared/realdata")
OCULUS = REAL / "oculus" / "one_ping_8bit.raw"
ARIS = REAL / "aris" / "sample.aris"


def available() -> bool:
    return OCULUS.exists() and ARIS.exists()


def oculus_frames():
    d = OCULUS.read_bytes()
    o = 16 + 5
    _range, _gain, sos, _sal = struct.unpack_from("<4d", d, o)
    o += 32
    fmt = "<IIddddIBdHHIII"
    (_pid, _st, freq, _t, _p, _sosu, _pst, _ds, rres, n_r, n_b, img_off, img_size, _ms) = struct.unpack_from(fmt, d, o)
    o += struct.calcsize(fmt)
    bearings = np.deg2rad(np.frombuffer(d, "<i2", n_b, o) / 100.0)
    raw = np.frombuffer(d, np.uint8, n_r * n_b, img_off).reshape(n_r, n_b)
    base = SonarSpec.preset("oculus-m1200d-hf")
    spec = SonarSpec(n_beams=int(n_b), n_bins=int(n_r), fov_azimuth=base.fov_azimuth, fov_elevation=base.fov_elevation,
                     range_min=0.0, range_max=float(n_r * rres), frequency=float(freq), sound_speed=float(sos),
                     beamwidth_azimuth=base.beamwidth_azimuth, range_resolution=float(rres), name="oculus-m1200d-hf",
                     ).with_beam_table(tuple(bearings.tolist()))
    return [MeasuredSonarFrame(raw=raw, image=raw.astype(np.float32) ** 2, spec=spec, encoding="oculus_gamma8",
                               source=str(OCULUS), index=0)]


def _aris_table():
    txt = (REAL / "aris" / "beam-widths" / "BeamWidths_ARIS_Telephoto_48.h").read_text()
    c = [float(m.group(1)) for m in re.finditer(r"DEFINE_BEAMWIDTH3\(\s*\d+\s*,\s*([-\d.]+)", txt)]
    return np.deg2rad(np.array(c))


def aris_frames():
    d = ARIS.read_bytes()
    n_beams, n_samples = 48, 2000
    frame_size = 1024 + n_beams * n_samples
    n = (len(d) - 1024) // frame_size
    out = []
    for k in range(n):
        h = 1024 + k * frame_size
        w0, wl = struct.unpack_from("<ff", d, h + 52)
        raw = np.frombuffer(d, np.uint8, n_beams * n_samples, h + 1024).reshape(n_samples, n_beams)
        spec = SonarSpec(n_beams=n_beams, n_bins=n_samples, fov_azimuth=np.deg2rad(15.0), fov_elevation=np.deg2rad(14.0),
                         range_min=float(w0), range_max=float(w0 + wl), frequency=1.2e6, sound_speed=1500.0,
                         beamwidth_azimuth=np.deg2rad(0.3), range_resolution=0.009, name="aris-1200-telephoto",
                         ).with_beam_table(tuple(_aris_table().tolist()))
        img = (10.0 ** (raw.astype(np.float64) * 80.0 / 255.0 / 10.0)).astype(np.float32)
        out.append(MeasuredSonarFrame(raw=raw, image=img, spec=spec, encoding="aris_db", source=str(ARIS), index=k))
    return out
