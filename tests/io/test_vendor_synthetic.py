"""Oculus pings in every layout, written here with ``struct`` from Blueprint's Oculus.h, read back exactly;
ARIS files made long by repeating frames; corrupt files fuzzed from the real samples."""

import struct

import numpy as np
import pytest

from optiacoustic.io import ReadError, open_sonar
from optiacoustic.io import units


def oculus_ping(*, version=1, bits=8, gain=False, image, bearings_cdeg, gamma=127, res=0.005, ping_id=7,
                freq=1.2e6):
    """One SimplePingResult message (Oculus.h, #pragma pack(1), little-endian)."""
    nr, nb = image.shape
    fire = struct.pack("<5B4d", 2, 0, 0, gamma, 0x01 | (0x04 if gain else 0) | (0x02 if bits > 8 else 0),
                       3.0, 50.0, 1500.0, 0.0)
    if version == 2:
        fire += struct.pack("<I2II5I", 0, 0, 0, 0, 0, 0, 0, 0, 0)
    ds = {8: 0, 16: 1, 32: 3}[bits]
    row = nb * bits // 8 + (4 if gain else 0)
    head_len = 16 + len(fire) + (4 + 4 + 8 * 4 + 4 + 1 + 8 + 2 + 2 + 12 if version == 1 else 4 + 4 + 8 * 8 + 1 + 8 + 2 + 2 + 16 + 12)
    img_off = head_len + 2 * nb + 6  # a little padding, as the device leaves
    size = img_off + nr * row
    if version == 1:
        ping = struct.pack("<II4dIBdHHIII", ping_id, 0, freq, 10.0, 1.0, 1500.0, 12345, ds, res, nr, nb, img_off,
                           nr * row, size)
    else:
        ping = struct.pack("<II8dBdHH4IIII", ping_id, 0, freq, 10.0, 1.0, 0.0, 0.0, 0.0, 1500.0, 12.5, ds, res, nr,
                           nb, 0, 0, 0, 0, img_off, nr * row, size)
    hdr = struct.pack("<5HIH", 0x4F53, 1, 0, 0x23, 2 if version == 2 else 0, size - 16, 0)
    body = hdr + fire + ping
    assert len(body) == head_len
    body += np.asarray(bearings_cdeg, "<i2").tobytes() + b"\0" * 6
    dt = {8: "<u1", 16: "<u2", 32: "<u4"}[bits]
    rows = []
    for i in range(nr):
        rows.append((struct.pack("<f", 1.0 + i) if gain else b"") + image[i].astype(dt).tobytes())
    return body + b"".join(rows)


@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("bits", [8, 16, 32])
@pytest.mark.parametrize("gain", [False, True])
def test_oculus_layouts_round_trip(tmp_path, version, bits, gain):
    rng = np.random.default_rng(bits + version)
    nr, nb = 11, 16
    img = rng.integers(0, 2 ** min(bits, 31), (nr, nb), dtype=np.int64)
    bearings = np.cumsum(rng.integers(20, 60, nb)) - 400
    status = struct.pack("<5HIH", 0x4F53, 1, 0, 0x01, 0, 8, 0) + b"\0" * 8  # a non-ping message, skipped
    p = tmp_path / "pings.bin"
    p.write_bytes(status + oculus_ping(version=version, bits=bits, gain=gain, image=img, bearings_cdeg=bearings)
                  + oculus_ping(version=version, bits=bits, gain=gain, image=img[::-1], bearings_cdeg=bearings))
    r = open_sonar(p)
    assert len(r) == 2 and r.other_messages == 1
    f0, f1 = r
    assert np.array_equal(f0.raw, img) and np.array_equal(f1.raw, img[::-1])
    assert f0.raw.dtype == np.dtype({8: np.uint8, 16: np.uint16, 32: np.uint32}[bits])
    assert np.array_equal(f0.azimuths, np.deg2rad(bearings / 100.0))
    assert np.allclose(f0.ranges, (np.arange(nr) + 0.5) * 0.005)
    assert f0.meta["version"] == version
    if gain:
        assert np.array_equal(f0.meta["gains"], 1.0 + np.arange(nr))
    enc = {8: "oculus_gamma8", 16: "oculus_16", 32: "oculus_32"}[bits]
    assert f0.encoding == enc
    params = dict(gamma=127, reading="gamma") if bits == 8 else {}
    assert np.array_equal(f0.image, units.decode(img.astype(f0.raw.dtype), enc, **params))


def test_units_round_trip_and_values():
    rng = np.random.default_rng(0)
    b = np.arange(256, dtype=np.uint8)
    # ARIS: byte 255 is 80 dB, byte 0 is 0 dB
    I = units.decode(b, "aris_db")
    assert I[0] == 1.0 and I[-1] == pytest.approx(1e8, rel=1e-5)
    assert np.array_equal(units.encode(I, "aris_db"), b)
    for reading in ("gamma", "amplitude"):
        I = units.decode(b, "oculus_gamma8", gamma=127, reading=reading)
        assert np.array_equal(units.encode(I, "oculus_gamma8", gamma=127, reading=reading), b)
    # gamma 127 reading: the byte is about amplitude^0.5, so intensity ~ (b/255)^4
    assert units.decode(np.uint8(128), "oculus_gamma8", gamma=127)[()] == pytest.approx((128 / 255) ** (510 / 127), rel=1e-5)
    w = rng.integers(0, 65536, 100).astype(np.uint16)
    assert np.array_equal(units.encode(units.decode(w, "oculus_16"), "oculus_16"), w)
    x = rng.random(50).astype(np.float32)
    assert np.array_equal(units.decode(units.encode(x, "linear"), "linear"), x)
    # saturation, not wrap-around
    assert units.encode(np.array([1e12]), "aris_db")[0] == 255
    with pytest.raises(ValueError, match="unknown device encoding"):
        units.decode(b, "nope")


def test_aris_long_file_made_by_repeating_frames(tmp_path, aris_sample):
    data = aris_sample.read_bytes()
    frame = 1024 + 48 * 2000
    body = data[1024:]
    p = tmp_path / "long.aris"
    p.write_bytes(data[:1024] + body * 4)
    r = open_sonar(p)
    assert len(r) == 24
    assert np.array_equal(r[23].raw, r[5].raw) and np.array_equal(r[6].raw, r[0].raw)
    assert len(body) == 6 * frame


# ------------------------------------------------------------------ fuzzing the real samples
def _offsets(n, k, rng):
    return sorted(set([0, 1, 15, 16, 17, 121, 122, 1023, 1024, 1025, n - 1] + rng.integers(0, n, k).tolist()))


def test_truncated_aris_named_and_skippable(tmp_path, aris_sample):
    data = aris_sample.read_bytes()
    rng = np.random.default_rng(0)
    frame = 1024 + 48 * 2000
    for cut in _offsets(len(data), 25, rng):
        p = tmp_path / "t.aris"
        p.write_bytes(data[:cut])
        try:
            r = open_sonar(p)
        except ReadError as exc:
            assert "t.aris" in str(exc) and ("byte offset" in str(exc) or cut == 0)
            assert cut < 2048, cut  # only a file without one whole frame header fails to open
            continue
        n_whole = (cut - 1024) // frame
        if (cut - 1024) % frame:
            with pytest.raises(ReadError, match=rf"frame {n_whole}, byte offset \d+: truncated"):
                r[n_whole]
            r2 = open_sonar(p, errors="skip")
            with pytest.warns(UserWarning):
                got = list(r2)
            assert len(got) == n_whole and [s.index for s in r2.skipped] == [n_whole]
        r = open_sonar(p)
        assert [r[k].index for k in range(n_whole)] == list(range(n_whole))


def test_corrupt_aris_headers(tmp_path, aris_sample):
    data = bytearray(aris_sample.read_bytes())
    frame = 1024 + 48 * 2000
    cases = [(0, b"\xff\xff\xff\xff", "not an ARIS file"),
             (1024 + 2 * frame + 12, b"\0\0\0\0", r"frame 2, byte offset \d+: bad frame signature"),
             (1024 + 3 * frame + 464, struct.pack("<f", float("nan")), r"frame 3, byte offset \d+: SoundSpeed nan"),
             (1024 + 1 * frame + 452, struct.pack("<I", 0), r"frame 1, byte offset \d+: SamplePeriod 0"),
             (1024 + 4 * frame + 436, struct.pack("<I", 9), r"frame 4, byte offset \d+: frame size changed"),
             (1024 + 436, struct.pack("<I", 77), r"frame 0, byte offset 1460: PingMode 77")]
    for off, patch, msg in cases:
        bad = bytearray(data)
        bad[off:off + len(patch)] = patch
        p = tmp_path / "c.aris"
        p.write_bytes(bytes(bad))
        with pytest.raises(ReadError, match=msg):
            list(open_sonar(p))
    # random byte flips in headers never crash with anything but ReadError
    rng = np.random.default_rng(3)
    for _ in range(40):
        bad = bytearray(data)
        fr = int(rng.integers(0, 6))
        off = 1024 + fr * frame + int(rng.integers(0, 1024)) if rng.random() < 0.8 else int(rng.integers(0, 1024))
        bad[off] ^= int(rng.integers(1, 256))
        p.write_bytes(bytes(bad))
        try:
            for f in open_sonar(p):
                assert f.raw.shape == (2000, 48) and np.all(np.isfinite(f.ranges))
        except ReadError as exc:
            assert "c.aris" in str(exc)


def test_truncated_and_corrupt_oculus(tmp_path, oculus_sample):
    data = oculus_sample.read_bytes()
    rng = np.random.default_rng(1)
    p = tmp_path / "o.raw"
    for cut in _offsets(len(data), 20, rng):
        if cut == 0:
            continue
        p.write_bytes(data[:cut])
        with pytest.raises(ReadError, match=r"o.raw.*(truncated|frame 0|unknown sonar log format)"):
            list(open_sonar(p))
    # header fields
    def patched(off, fmt, value):
        b = bytearray(data)
        struct.pack_into(fmt, b, off, value)
        p.write_bytes(bytes(b))
        return p

    with pytest.raises(ReadError, match="unsupported dataSize 2"):
        open_sonar(patched(53 + 4 + 4 + 32 + 4, "<B", 2))[0]
    # nRanges (v1 offset 106) no longer agrees with imageSize (offset 114)
    with pytest.raises(ReadError, match=r"frame 0, byte offset 114: imageSize 179968 != nRanges x row size = 700 x 256"):
        open_sonar(patched(106, "<H", 700))[0]
    with pytest.raises(ReadError, match="bearing table not strictly increasing"):
        open_sonar(patched(122 + 2 * 10, "<h", 3000))[0]
    with pytest.raises(ReadError, match="rangeResolution"):
        open_sonar(patched(53 + 4 + 4 + 32 + 4 + 1, "<d", -1.0))[0]
    # a second, truncated ping after a good one: skip mode keeps the first and reports the second
    p.write_bytes(data + data[:5000])
    r = open_sonar(p, errors="skip")
    with pytest.warns(UserWarning, match="skipped damaged frame"):
        frames = list(r)
    assert len(frames) == 1 and r.skipped and r.skipped[0].index == 1
    with pytest.raises(ReadError, match=r"frame 1, byte offset 182016: truncated"):
        list(open_sonar(p))
    # garbage after a good ping (not an Oculus header) is reported, not dropped
    p.write_bytes(data + b"\x00" * 40)
    r = open_sonar(p)
    assert len(r) == 2 and r[0].raw.shape == (703, 256)
    with pytest.raises(ReadError, match=r"frame 1, byte offset 182016: not an Oculus message"):
        list(r)
    # random flips never produce anything but a frame or a ReadError
    for _ in range(40):
        b = bytearray(data)
        off = int(rng.integers(0, 2048))
        b[off] ^= int(rng.integers(1, 256))
        p.write_bytes(bytes(b))
        try:
            for f in open_sonar(p):
                assert f.raw.ndim == 2
        except ReadError as exc:
            assert "o.raw" in str(exc)


def test_not_a_sonar_file(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_bytes(b"hello world, not a sonar log")
    with pytest.raises(ReadError, match=r"x.mcap, byte offset 0: named .mcap but its first bytes"):
        open_sonar(p)
    (tmp_path / "e.bin").write_bytes(b"")
    with pytest.raises(ReadError, match="empty file"):
        open_sonar(tmp_path / "e.bin")
    with pytest.raises(FileNotFoundError):
        open_sonar(tmp_path / "missing.aris")


def test_simulated_frame_in_device_units(aris_sample):
    """A simulated frame emitted as ARIS bytes: quantised to 80/255 dB steps, saturating, same geometry."""
    import optiacoustic as oa

    real = open_sonar(aris_sample)[0]
    scene = oa.scenes.get("flat_seabed")
    spec = oa.SonarSpec(n_bins=200, elevation_samples=32, range_min=3.0, range_max=23.0, fov_elevation=np.deg2rad(14))
    spec = spec.with_beam_table(real.azimuths)
    sim = oa.simulate_sonar(scene, spec, oa.Pose.look_at((0, 0, 3.0), (0, 15.0, 0)))
    ref = np.percentile(sim.image[sim.image > 0], 1)
    dev = units.as_device_frame(sim, "aris_db", reference=ref)
    assert dev.raw.dtype == np.uint8 and dev.spec is sim.spec
    inside = (sim.image >= ref) & (sim.image <= ref * 1e8)  # within the device's 80 dB
    assert inside.sum() > 100
    db_err = 10 * np.log10(dev.image[inside] / sim.image[inside])
    assert np.all(np.abs(db_err) <= 80 / 255 / 2 + 1e-3)
    assert np.all(dev.raw[sim.image < ref] == 0) and np.all(dev.raw[sim.image > ref * 1e8] == 255)
