"""``oas view`` refuses bad numbers before it writes anything (exit 2, one line naming the option and the
value, no PNG left behind); the display functions it uses refuse them too."""

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from optiacoustic.cli import app

runner = CliRunner()
DATA = Path(__file__).resolve().parent / "data"
ARIS = DATA / "aris" / "sample.aris"
OCULUS = DATA / "oculus" / "one_ping_8bit.raw"


def _refused(tmp_path, *args, log=ARIS):
    out = tmp_path / "vw"
    r = runner.invoke(app, ["view", str(log), "--out", str(out), *args])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and "RuntimeWarning" not in r.output, r.output
    assert r.output.startswith("error:") and r.output.strip().count("\n") == 0, r.output
    assert not out.exists() or not any(out.iterdir()), sorted(out.iterdir())
    return r.output


@pytest.mark.parametrize("width", ["0", "15", "-5", "100000", "32768"])
def test_width_out_of_bounds_is_refused_before_writing(tmp_path, width):
    # was: polar_0000.png written, then "fan width: ..." (and 100000 tried to allocate 286 GiB first)
    msg = _refused(tmp_path, "--width", width)
    assert f"--width: expected a whole number of pixels from 16 to 32767, got {width}" in msg


def test_width_whose_fan_is_too_tall_is_refused_with_the_largest_that_fits(tmp_path):
    # the ARIS telephoto fan is 15 deg wide: 9000 px across is 34536 px tall, past OpenCV's 32767
    msg = _refused(tmp_path, "--width", "9000")
    assert str(ARIS) in msg and "frame 0" in msg and "--width: 9000 px gives a fan image 34536 px tall" in msg
    assert "at most 8539 px wide" in msg


def test_width_beyond_memory_is_refused_before_writing(tmp_path, monkeypatch):
    from optiacoustic import _validate

    monkeypatch.setattr(_validate, "available_memory", lambda: 100 * 2**20)
    monkeypatch.setattr(_validate, "_LAST_AVAIL", (None, 0.0))
    msg = _refused(tmp_path, "--width", "1000")
    assert "a 1000 x 3838 px fan image (--width 1000) needs about" in msg and "GiB is available" in msg


@pytest.mark.parametrize("value", ["0", "-10", "nan", "inf", "-inf"])
def test_dynamic_range_must_be_finite_and_positive(tmp_path, value):
    # was: 0 -> divide-by-zero warnings and PNGs; -10, nan, inf taken silently (nan: all-black PNGs)
    msg = _refused(tmp_path, "--dynamic-range-db", value)
    assert f"--dynamic-range-db: expected a finite number of dB > 0, got {float(value)!r}" in msg


@pytest.mark.parametrize("frames, needle", [("1.5", "--frames: expected i:j (or i), got '1.5'"),
                                            ("::0", "--frames: expected i:j (or i), got '::0'"),
                                            ("99", "--frames: frame 99 out of range (the log has 6 frames)"),
                                            ("5:2", "--frames 5:2: selects no frame of the 6")])
def test_frames_refused_before_writing(tmp_path, frames, needle):
    assert needle in _refused(tmp_path, "--frames", frames)


@pytest.mark.parametrize("option, value", [("--width", "1.5"), ("--dynamic-range-db", "abc")])
def test_non_numbers_are_usage_errors(tmp_path, option, value):
    r = runner.invoke(app, ["view", str(ARIS), "--out", str(tmp_path / "vw"), option, value])
    assert r.exit_code == 2 and option in r.output and not (tmp_path / "vw").exists()


def test_small_valid_options_still_write(tmp_path):
    r = runner.invoke(app, ["view", str(OCULUS), "--out", str(tmp_path / "vw"), "--width", "16",
                            "--dynamic-range-db", "0.5"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "vw").iterdir()) == ["contact_sheet.png", "fan_0000.png",
                                                                   "polar_0000.png"]


def test_display_functions_refuse_bad_numbers():
    from optiacoustic.io import open_sonar
    from optiacoustic.sonar.display import fan_geometry, fan_shape, polar_to_fan, to_display

    img = np.ones((4, 4))
    for v in (0, -10, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="dynamic_range_db: must be finite and > 0"):
            to_display(img, dynamic_range_db=v)
    with pytest.raises(ValueError, match="gamma: must be finite and > 0"):
        to_display(img, mode="gamma", gamma=0)
    with pytest.raises(ValueError, match="reference: must be finite, got nan"):
        to_display(img, reference=float("nan"))
    with pytest.raises(ValueError, match=r"percentile: expected a number in \[0, 100\], got 150"):
        to_display(img, percentile=150)
    with open_sonar(ARIS) as seq:
        f = seq[0]
    with pytest.raises(ValueError, match="fan width: expected an integer >= 16 pixels, got 0"):
        fan_geometry(f.spec, 0)
    with pytest.raises(ValueError, match="fan width: at most 32767 pixels"):
        fan_shape(f.spec, 100000)
    with pytest.raises(ValueError, match="fan width: 9000 px gives a fan image 34536 px tall"):
        fan_geometry(f.spec, 9000)
    with pytest.raises(ValueError, match="fan width: expected an integer >= 16 pixels, got 600.5"):
        polar_to_fan(f.image, f.spec, width=600.5)
    assert fan_shape(f.spec, 200) == (768, 200)
    assert polar_to_fan(f.image, f.spec, width=200.0).data.shape == (768, 200)


def test_write_previews_refuses_bad_range_before_the_first_file(tmp_path):
    from optiacoustic.io import open_sonar
    from optiacoustic.sonar.preview import write_previews

    with open_sonar(OCULUS) as seq:
        frames = [seq[0]]
    with pytest.raises(ValueError, match="dynamic_range_db"):
        write_previews(frames, tmp_path / "p", dynamic_range_db=float("nan"))
    assert not (tmp_path / "p").exists()
