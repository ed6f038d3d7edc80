"""Header values of the real ARIS and Oculus samples that describe no sonar: each is a ReadError naming
file, frame and byte offset (so that ``errors="skip"`` and ``oas info`` can deal with it), or a value
kept from the defaults and listed as unverified; never an error from deep inside that names neither."""

import math
import struct
import warnings

import pytest
from typer.testing import CliRunner

from optiacoustic.cli import app
from optiacoustic.io import open_sonar
from optiacoustic.io.errors import ReadError

runner = CliRunner()
ARIS_FRAME0 = 1024  # the file header's size; a frame header follows
ARIS_SSD = 476  # SampleStartDelay (uint32, us) within a frame header


def _patched(src, dst, *edits):
    b = bytearray(src.read_bytes())
    for off, fmt, value in edits:
        struct.pack_into(fmt, b, off, value)
    dst.write_bytes(bytes(b))
    return dst


def _aris_frame_bytes(path):
    seq = open_sonar(path)
    return seq.frame_size, len(seq)


@pytest.mark.parametrize("delay, words", [(0, "SampleStartDelay 0 us"), (30_000_000, "end within 300 m")])
def test_aris_window_that_starts_at_the_ping_or_kilometres_away_is_a_read_error(tmp_path, aris_sample, delay, words):
    # was: 'SonarSpec.range_min: must be ... >= 0, got -0.005' (no file, no frame), and a 21 km window
    # accepted by the reader, then an AttributeError deep in sensor-fit
    p = _patched(aris_sample, tmp_path / "a.aris", (ARIS_FRAME0 + ARIS_SSD, "<I", delay))
    with pytest.raises(ReadError) as e:
        open_sonar(p)[0]
    assert f"{p}, frame 0, byte offset {ARIS_FRAME0 + ARIS_SSD}" in str(e.value) and words in str(e.value)
    info = open_sonar(p).info()
    assert "SampleStartDelay" in info["first_frame_error"]


def test_a_damaged_window_in_a_later_frame_is_skipped(tmp_path, aris_sample):
    size, n = _aris_frame_bytes(aris_sample)
    p = _patched(aris_sample, tmp_path / "a.aris", (ARIS_FRAME0 + 2 * size + ARIS_SSD, "<I", 0))
    seq = open_sonar(p, errors="skip")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = list(seq)
    assert [f.index for f in frames] == [k for k in range(n) if k != 2]
    assert [s.index for s in seq.skipped] == [2] and "SampleStartDelay" in seq.skipped[0].reason


def test_oculus_ping_with_one_beam_names_file_and_frame(tmp_path, oculus_sample):
    # nBeams (v1 offset 108) = 1 with a consistent imageSize (offset 114): 703 rows of one sample.
    # was: 'SonarSpec.beamwidth_azimuth: must be a finite number >= 0, got nan'
    p = _patched(oculus_sample, tmp_path / "o.raw", (108, "<H", 1), (114, "<I", 703))
    with pytest.raises(ReadError) as e:
        open_sonar(p)[0]
    assert str(e.value).startswith(f"{p}, frame 0, byte offset 108") and "nBeams = 1" in str(e.value)


@pytest.mark.parametrize("value", [math.nan, 0.0])
def test_oculus_frequency_that_is_not_plausible_is_listed_as_assumed(tmp_path, oculus_sample, value):
    # frequency: the float64 at offset 61 of a v1 ping; was: silently 900 kHz
    p = _patched(oculus_sample, tmp_path / "o.raw", (61, "<d", value))
    spec = open_sonar(p)[0].spec
    assert spec.frequency == 900e3
    assert any(u.startswith("frequency (the ping's") and "900 kHz assumed" in u for u in spec.unverified)
    assert not any(u.startswith("frequency") for u in open_sonar(oculus_sample)[0].spec.unverified)


@pytest.mark.parametrize("cmd", [["sensor-fit", "{log}", "--out", "{log}"], ["noise-fit", "--input", "{log}", "--out", "{log}"]])
def test_an_output_that_is_the_input_log_is_refused_and_the_log_kept(tmp_path, aris_sample, cmd):
    log = tmp_path / "a.aris"
    log.write_bytes(aris_sample.read_bytes())
    r = runner.invoke(app, [c.format(log=log) for c in cmd])
    assert r.exit_code == 2 and "is the input" in r.output and "Traceback" not in r.output
    assert log.read_bytes() == aris_sample.read_bytes()


def test_paths_with_brackets_are_printed_as_they_are(tmp_path):
    # Rich markup: '[/x]' in a path raised MarkupError after the work, '[red]' vanished from the message
    for name in ("[/x]", "[red]"):
        f = tmp_path / name / "s.yaml"
        r = runner.invoke(app, ["scene", "flat_seabed", "--export", str(f)])
        assert r.exit_code == 0, r.output
        assert f"wrote {f}" in r.output.replace("\n", "") and f.is_file()


def test_convert_skip_damaged_takes_the_geometry_from_the_first_readable_frame(tmp_path, aris_sample):
    # SoundSpeed (float32 at 464 of frame 0's header) NaN: was 'stops at frame 0' even with --skip-damaged
    import zarr

    from optiacoustic.io.convert import convert_log

    p = _patched(aris_sample, tmp_path / "a.aris", (ARIS_FRAME0 + 464, "<f", math.nan))
    with pytest.raises(ReadError, match="frame 0, byte offset 1488: SoundSpeed nan"):
        convert_log(p, tmp_path / "strict.zarr")
    assert not (tmp_path / "strict.zarr").exists()
    res = convert_log(p, tmp_path / "d.zarr", errors="skip")
    n = len(open_sonar(aris_sample))
    assert res["skipped"] == [0] and res["frames"] == n - 1
    g = zarr.open_group(str(tmp_path / "d.zarr"), mode="r")
    done = g["sonar/done"][:]
    assert not done[0] and done[1:].all()
    good = open_sonar(aris_sample)[1]
    assert (g["sonar/raw"][1] == good.raw).all()


def test_a_truncated_last_frame_is_reported_and_times_has_one_value_per_frame(tmp_path, aris_sample, oculus_sample):
    size, n = _aris_frame_bytes(aris_sample)
    cut = tmp_path / "cut.aris"
    cut.write_bytes(aris_sample.read_bytes()[: ARIS_FRAME0 + 2 * size + size // 3])
    seq = open_sonar(cut)
    assert len(seq) == 3 and "damaged_tail" in seq.info()
    t = seq.times()  # was: 2 values for 3 frames
    assert t.shape == (3,) and (t[:2] == open_sonar(aris_sample).times()[:2]).all() and math.isnan(t[2])
    # Oculus: two pings, the second cut short (was: 'frames: 2' and no word of the damage)
    ping = oculus_sample.read_bytes()
    two = tmp_path / "two.raw"
    two.write_bytes(ping + ping[: len(ping) // 2])
    seq = open_sonar(two)
    assert len(seq) == 2 and seq.info()["damaged_tail"] == f"last ping truncated: {len(ping) // 2} of {len(ping)} bytes"
    with pytest.raises(ReadError, match="frame 1"):
        seq[1]
