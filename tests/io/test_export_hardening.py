"""``oas export`` on damaged, unusual and measured datasets: one-line errors naming the dataset, the array and
the frame, and no output file left behind; converted logs export what they have (read back with rosbags)."""

import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr
from rosbags.rosbag2 import Reader
from typer.testing import CliRunner

from optiacoustic.cli import app
from optiacoustic.io import write_dataset, write_mcap
from optiacoustic.io.dataset import DatasetError
from optiacoustic.io.mcap_writer import StartTimeError
from optiacoustic.io.rosmsg import typestore

CFG = {
    "scene": "thesis_scene1",
    "rig": {"sonar": {"preset": "oculus-m750d-lf", "n_bins": 24, "n_beams": 16, "elevation_samples": 8},
            "camera": {"width_px": 32, "height_px": 20, "sensor_mm": [36, 24], "focal_mm": 50},
            "camera_in_sonar": {"position": [-0.25, 0, 0], "rotation_deg": [0, 0, -2]}},
    "seed": 3,
    "duration": 1.0,
    "rates": {"sonar": 4, "camera": 2},
    "optical": {"slices": 2},
    "trajectory": {"kind": "orbit", "radius": 6.0, "height": 2.0, "period": 40.0},
}

runner = CliRunner()


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    d = tmp_path_factory.mktemp("hardening")
    write_dataset(CFG, d / "data.zarr", workers=0)
    return d / "data.zarr"


@pytest.fixture
def data(pristine, tmp_path):
    """A copy of the dataset to damage."""
    return Path(shutil.copytree(pristine, tmp_path / "data.zarr"))


def _export(data: Path, out: Path, *extra):
    r = runner.invoke(app, ["export", str(data), "--mcap", str(out), *extra])
    return r.exit_code, r.output.strip()


def _assert_refused(code, output, out: Path, *words):
    """Exit 2, one line starting ``error:``, naming ``words``, no traceback, nothing left where the file would be."""
    assert code == 2, output
    assert len(output.splitlines()) == 1 and output.startswith("error:"), output
    assert "Traceback" not in output
    for w in words:
        assert str(w) in output, (w, output)
    assert not out.exists()
    if out.parent.exists():
        assert not list(out.parent.iterdir()), list(out.parent.iterdir())  # no temporary bag either


def _read(path: Path) -> dict:
    ts = typestore(2)
    msgs = {}
    with Reader(path) as r:
        for conn, t, raw in r.messages():
            msgs.setdefault(conn.topic, []).append((t, ts.deserialize_cdr(raw, conn.msgtype)))
    return msgs


# ----------------------------------------------------------------------------- 1. lost chunks
@pytest.mark.parametrize("array, key, frame", [("sonar/image", "c.2.0.0", 2), ("sonar/intensity", "c.0.0.0", 0),
                                               ("sonar/shadow", "c.3.0.0", 3), ("camera/image", "c.1.0.0.0", 1),
                                               ("camera/depth", "c.0.0.0", 0)])
def test_lost_chunk_of_a_done_frame_is_refused(data, tmp_path, array, key, frame):
    (data / array / key).unlink()
    assert zarr.open_array(str(data / array.split("/")[0] / "done"), mode="r")[frame]
    out = tmp_path / "e" / "x.mcap"
    _assert_refused(*_export(data, out), out, data, f"array {array}, frame {frame}", key, "missing",
                    "marked done")


def test_lost_chunk_of_times_or_poses_is_refused(data, tmp_path):
    """``time`` and ``pose`` read as 0 where their chunk is lost: a silently wrong stamp or /tf."""
    shutil.rmtree(data / "sonar" / "pose" / "c")
    out = tmp_path / "e" / "x.mcap"
    _assert_refused(*_export(data, out), out, data, "array sonar/pose", "chunk c/0/0/0 is missing")


def test_lost_ground_truth_chunk_does_not_matter_without_ground_truth(data, tmp_path):
    (data / "sonar" / "body" / "c.1.0.0").unlink()
    out = tmp_path / "x.mcap"
    code, output = _export(data, out, "--no-ground-truth")
    assert code == 0, output
    assert len(_read(out)["/sonar/image"]) == 4


def test_frames_not_done_are_skipped_not_refused(data, tmp_path):
    """A frame whose flag is not set has no chunks (an interrupted run): it is left out, as before."""
    (data / "sonar" / "done" / "c.3").unlink()
    for name in ("image", "intensity", "body", "elevation_min", "elevation_max", "shadow"):
        (data / "sonar" / name / "c.3.0.0").unlink()
    out = tmp_path / "x.mcap"
    code, output = _export(data, out)
    assert code == 0, output
    assert len(_read(out)["/sonar/image"]) == 3


# ----------------------------------------------------------------------------- 2. corrupt chunks and metadata
@pytest.mark.parametrize("array, key, frame", [("sonar/image", "c.2.0.0", 2), ("sonar/elevation_max", "c.1.0.0", 1),
                                               ("camera/normal", "c.1.0.0.0", 1)])
@pytest.mark.parametrize("damage", ["random", "truncated", "extended", "version", "bit"])
def test_corrupt_chunk_is_refused_naming_array_and_frame(data, tmp_path, array, key, frame, damage):
    chunk = data / array / key
    raw = chunk.read_bytes()
    if damage == "random":
        chunk.write_bytes(np.random.default_rng(0).bytes(100))
    elif damage == "truncated":
        chunk.write_bytes(raw[:len(raw) // 2])
    elif damage == "extended":
        chunk.write_bytes(raw + b"\0" * 8)
    elif damage == "version":  # the header's sizes are right, its format version is not
        chunk.write_bytes(b"\x7f" + raw[1:])
    else:  # one bit of the compressed data: Blosc alone decoded it to other numbers without a word
        a = bytearray(raw)
        a[len(a) // 2] ^= 0x10
        chunk.write_bytes(bytes(a))
    out = tmp_path / "e" / "x.mcap"
    words = ("is damaged (its CRC-32C checksum does not match its bytes)",) if damage in ("version", "bit") \
        else ("is damaged",)
    _assert_refused(*_export(data, out), out, data, f"array {array}, frame {frame}", key, *words)


def test_chunks_of_a_dataset_carry_a_crc32c_that_zarr_and_xarray_check(data):
    """Every per-frame array is Blosc then CRC-32C; one flipped bit is an error for Zarr and xarray too."""
    import zarr

    from optiacoustic.io import open_dataset

    root = zarr.open_group(str(data), mode="r")
    for sensor in ("sonar", "camera"):  # every array: frames, flags, times, poses, coordinates
        for name, arr in root[sensor].arrays():
            codecs = [type(c).__name__ for c in arr.metadata.codecs]
            assert codecs[-1] == "Crc32cCodec", (sensor, name, codecs)
    before = np.asarray(root["sonar/image"][1])
    chunk = data / "sonar" / "image" / "c.1.0.0"
    a = bytearray(chunk.read_bytes())
    a[len(a) // 2] ^= 0x01
    chunk.write_bytes(bytes(a))
    with pytest.raises(ValueError, match="checksum"):
        root["sonar/image"][1]
    with pytest.raises(ValueError, match="checksum"):
        open_dataset(data)["sonar"]["image"][1].values
    assert np.isfinite(before).any()


_FUZZ = """
import sys, numpy as np
from pathlib import Path
from optiacoustic.io import write_mcap
from optiacoustic.io.dataset import DatasetError
data, out = Path(sys.argv[1]), Path(sys.argv[2])
chunk = data / "sonar" / "image" / "c.1.0.0"
raw = chunk.read_bytes()
rng = np.random.default_rng(0)
cases = [raw[:n] for n in (0, 8, 15, 16, 17, 20, len(raw) // 3, len(raw) // 2, len(raw) - 1)]
for _ in range(12):
    a = bytearray(raw)
    for i in rng.integers(0, len(raw), rng.integers(1, 6)):
        a[i] = int(rng.integers(256))
    cases.append(bytes(a))
for i, case in enumerate(cases):
    chunk.write_bytes(case)
    try:
        write_mcap(data, out, ground_truth=False)
        print(i, "ok")
    except DatasetError as exc:
        assert "array sonar/image, frame 1" in str(exc), exc
        print(i, "refused")
"""


def test_fuzzed_chunks_never_crash_the_export(data, tmp_path):
    """Truncated and byte-flipped chunks: an error naming the frame (truncations always), never a crash.

    c-blosc trusts a chunk's header: decoding a truncated chunk read past its end and killed the process.
    Run in a child process, so that a crash fails this test instead of the test run.
    """
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _FUZZ, str(data), str(tmp_path / "f.mcap")], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    outcomes = dict(line.split() for line in r.stdout.splitlines())
    assert len(outcomes) == 21
    assert all(outcomes[str(i)] == "refused" for i in range(9))  # every truncation


def test_corrupt_flag_chunk_names_the_frame(data, tmp_path):
    (data / "sonar" / "done" / "c.1").write_bytes(b"xyz")
    out = tmp_path / "e" / "x.mcap"
    _assert_refused(*_export(data, out), out, data, "array sonar/done, frame 1", "is damaged (its CRC-32C checksum")


def test_damaged_flag_chunk_stops_a_resume_naming_the_array(data, tmp_path):
    """Resuming a dataset whose done flag is damaged: an error naming the array, not a guess at the frame."""
    from optiacoustic.io.dataset import DatasetError

    (data / "sonar" / "done" / "c.1").write_bytes(b"\x01\0\0\0\0")
    with pytest.raises(DatasetError, match=r"array sonar/done cannot be read \(Stored and computed checksum"):
        write_dataset(CFG, data, workers=0)


@pytest.mark.parametrize("where", ["zarr.json", "sonar/zarr.json", "sonar/image/zarr.json", "camera/time/zarr.json"])
def test_corrupt_zarr_json_is_refused_naming_the_file(data, tmp_path, where):
    (data / where).write_text('{"bad json\n')
    out = tmp_path / "e" / "x.mcap"
    _assert_refused(*_export(data, out), out, data, f"{where} cannot be read")


@pytest.mark.parametrize("where", ["sonar/zarr.json", "sonar/intensity/zarr.json"])
def test_lost_zarr_json_is_refused_not_skipped(data, tmp_path, where):
    """Without it Zarr no longer sees the group or array: the export would silently drop a topic."""
    (data / where).unlink()
    out = tmp_path / "e" / "x.mcap"
    _assert_refused(*_export(data, out), out, data, f"{where} is missing")


def test_damage_found_while_writing_keeps_an_existing_file(data, tmp_path):
    """A chunk that fails to decode mid-export: the previous file is untouched and no temporary bag remains."""
    (data / "camera" / "image" / "c.1.0.0.0").write_bytes(b"\0" * 64)
    out = tmp_path / "x.mcap"
    out.write_bytes(b"previous export")
    code, output = _export(data, out)
    assert code == 2 and "array camera/image, frame 1" in output, output
    assert out.read_bytes() == b"previous export"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data.zarr", "x.mcap"]


def test_nan_pose_or_time_of_a_simulated_dataset_is_refused(data, tmp_path):
    pose = zarr.open_array(str(data / "sonar" / "pose"), mode="r+")
    good = pose[:]
    p = good.copy()
    p[2, 0, 1] = np.nan
    pose[:] = p
    out = tmp_path / "e" / "x.mcap"
    _assert_refused(*_export(data, out), out, data, "array sonar/pose, frame 2", "not finite")
    p[2, 0, 1] = 5.0  # finite, but no rotation: scipy would silently make one of it
    pose[:] = p
    _assert_refused(*_export(data, out), out, data, "array sonar/pose, frame 2", "not a rigid transform")
    pose[:] = good
    time = zarr.open_array(str(data / "camera" / "time"), mode="r+")
    t = time[:]
    t[1] = np.inf
    time[:] = t
    _assert_refused(*_export(data, out), out, data, "array camera/time, frame 1", "not a finite time (inf)")


# ----------------------------------------------------------------------------- 3. --start-time
@pytest.mark.parametrize("value, shown", [("-10", "got -10 "), ("1e12", "got 1e+12 "), ("inf", "got inf"),
                                          ("nan", "got nan"), ("-inf", "got -inf"),
                                          (str(2**31 - 0.5), "got 2147483647.5 ")])
def test_start_time_out_of_ros_time_is_refused_before_writing(pristine, tmp_path, value, shown):
    out = tmp_path / "e" / "x.mcap"
    code, output = _export(pristine, out, f"--start-time={value}")
    _assert_refused(code, output, out, "--start-time: must be finite and give ROS times in [0, 2^31) s", shown)
    assert not out.parent.exists()  # checked before anything was made


def test_start_time_bounds_follow_the_dataset_times(pristine, tmp_path):
    """The last sonar frame is at 0.75 s: 2^31 - 1 s still stamps it below 2^31 s."""
    last = float(zarr.open_array(str(pristine / "sonar" / "time"), mode="r")[-1])
    assert last == 0.75
    out = write_mcap(pristine, tmp_path / "x.mcap", start_time=2**31 - 1, ground_truth=False)
    t_log, m = _read(out)["/sonar/image"][-1]
    assert t_log == round((2**31 - 1 + 0.75) * 1e9) < 2**31 * 10**9
    assert m.header.stamp.sec == 2**31 - 1 and abs(m.header.stamp.nanosec - 750_000_000) < 1000
    with pytest.raises(StartTimeError, match=r"^start_time: .*got 2147483647.3 .*\[0, 2147483647.25\) s"):
        write_mcap(pristine, tmp_path / "y.mcap", start_time=2**31 - 0.7)
    with pytest.raises(StartTimeError, match=r"got 'soon'"):
        write_mcap(pristine, tmp_path / "y.mcap", start_time="soon")
    assert not (tmp_path / "y.mcap").exists()


# ----------------------------------------------------------------------------- 4. converted (measured) logs
def test_converted_aris_log_exports_its_images_times_and_geometry(tmp_path, aris_sample):
    from optiacoustic.io.convert import convert_log

    convert_log(aris_sample, tmp_path / "a.zarr")
    out = tmp_path / "e" / "a.mcap"
    code, output = _export(tmp_path / "a.zarr", out)
    assert code == 0, output
    s = zarr.open_group(str(tmp_path / "a.zarr"), mode="r")["sonar"]
    msgs = _read(out)
    assert set(msgs) == {"/sonar/image", "/tf_static"}  # no rig, no pose: no sonar -> camera, no /tf
    static = msgs["/tf_static"][0]
    assert [tr.child_frame_id for tr in static[1].transforms] == ["sonar_acoustic"]
    times = s["time"][:]
    assert static[0] == round(times[0] * 1e9)  # at the first frame (epoch times), not at 1970
    az, ranges = s["azimuths"][:], s["ranges"][:]
    assert len(msgs["/sonar/image"]) == 6
    for k, (t, m) in enumerate(msgs["/sonar/image"]):
        assert t == round(times[k] * 1e9) == m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        assert 1.3e9 < times[k] < 1.4e9  # the log's own clock (2013)
        d = np.array([[v.x, v.y, v.z] for v in m.beam_directions])
        np.testing.assert_allclose(np.arctan2(-d[:, 1], d[:, 2]), az, atol=1e-12)  # the real, uneven lens table
        np.testing.assert_array_equal(m.ranges, ranges.astype(np.float32))
        data = np.frombuffer(m.image.data.tobytes(), "<f4").reshape(len(ranges), len(az))
        np.testing.assert_array_equal(data, s["image"][k])
        assert m.ping_info.frequency == pytest.approx(1.2e6)


def test_converted_log_with_camera_exports_images_without_rig_or_camera_info(pristine, tmp_path):
    from optiacoustic.io.convert import convert_log

    convert_log(write_mcap(pristine, tmp_path / "sim.mcap", ground_truth=False), tmp_path / "m.zarr",
                topic="/sonar/image", camera_topic="/camera/image")
    out = write_mcap(tmp_path / "m.zarr", tmp_path / "m.mcap", camera_encoding="rgb8")
    msgs = _read(out)
    assert set(msgs) == {"/sonar/image", "/camera/image", "/tf_static"}
    assert len(msgs["/camera/image"]) == 2 and msgs["/camera/image"][0][1].encoding == "rgb8"
    orig = zarr.open_group(str(pristine), mode="r")
    assert [t for t, _ in msgs["/camera/image"]] == [round(t * 1e9) for t in orig["camera/time"][:]]


def test_converted_log_without_clock_is_refused_naming_the_frame(tmp_path, oculus_sample):
    from optiacoustic.io.convert import convert_log

    convert_log(oculus_sample, tmp_path / "o.zarr")
    out = tmp_path / "e" / "o.mcap"
    _assert_refused(*_export(tmp_path / "o.zarr", out), out, tmp_path / "o.zarr", "array sonar/time, frame 0",
                    "no time (nan)", "needs a stamp")


def test_converted_log_with_a_partly_nan_pose_is_refused(tmp_path, aris_sample):
    from optiacoustic.io.convert import convert_log

    convert_log(aris_sample, tmp_path / "a.zarr")
    pose = zarr.open_array(str(tmp_path / "a.zarr" / "sonar" / "pose"), mode="r+")
    p = pose[:]
    p[4] = np.eye(4)
    p[4, 0, 3] = np.nan
    pose[:] = p
    with pytest.raises(DatasetError, match=r"array sonar/pose, frame 4: the pose is partly NaN"):
        write_mcap(tmp_path / "a.zarr", tmp_path / "a.mcap")
    p[4] = np.eye(4)  # a known pose of a measured frame is published
    pose[:] = p
    msgs = _read(write_mcap(tmp_path / "a.zarr", tmp_path / "a.mcap"))
    assert len(msgs["/tf"]) == 1 and msgs["/tf"][0][1].transforms[0].child_frame_id == "sonar"


def test_simulated_dataset_without_rig_metadata_is_refused(data, tmp_path):
    g = zarr.open_group(str(data), mode="r+")
    meta = dict(g.attrs)["optiacoustic"]
    del meta["rig"]
    g.attrs["optiacoustic"] = meta
    out = tmp_path / "e" / "x.mcap"
    _assert_refused(*_export(data, out), out, data, "metadata field 'rig' is missing")
