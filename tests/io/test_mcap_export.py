"""ROS 2 out: a dataset exported to MCAP and read back with rosbags (an independent reader), field by field."""

from pathlib import Path

import numpy as np
import pytest
import zarr
from rosbags.rosbag2 import Reader
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from optiacoustic.cli import app
from optiacoustic.io import write_dataset, write_mcap
from optiacoustic.io.rosmsg import typestore

CFG = {
    "scene": "thesis_scene1",
    "rig": {"sonar": {"preset": "oculus-m750d-lf", "n_bins": 80, "n_beams": 40, "elevation_samples": 16},
            "camera": {"width_px": 64, "height_px": 40, "sensor_mm": [36, 24], "focal_mm": 50},
            "camera_in_sonar": {"position": [-0.25, 0, 0], "rotation_deg": [0, 0, -2]}},
    "seed": 1,
    "duration": 1.0,
    "rates": {"sonar": 4, "camera": 2},
    "optical": {"slices": 4},
    "trajectory": {"kind": "orbit", "radius": 6.0, "height": 2.0, "period": 40.0},
}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    d = tmp_path_factory.mktemp("mcap")
    write_dataset(CFG, d / "data.zarr", workers=0)
    return d / "data.zarr"


def _read(path: Path):
    ts = typestore(2)
    out = {}
    with Reader(path) as r:
        for conn, t, raw in r.messages():
            out.setdefault(conn.topic, []).append((t, ts.deserialize_cdr(raw, conn.msgtype), conn.msgtype))
    return out


def test_mcap_reads_back_field_by_field(dataset, tmp_path):
    mcap = write_mcap(dataset, tmp_path / "out.mcap", start_time=1_700_000_000.25)
    assert mcap.is_file() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    msgs = _read(mcap)
    root = zarr.open_group(str(dataset), mode="r")
    s, c = root["sonar"], root["camera"]
    az, ranges = s["azimuths"][:], s["ranges"][:]

    sonar = msgs["/sonar/image"]
    assert len(sonar) == 4 and all(m[2] == "marine_acoustic_msgs/msg/ProjectedSonarImage" for m in sonar)
    for k, (t_log, m, _) in enumerate(sonar):
        ns = round((1_700_000_000.25 + s["time"][k]) * 1e9)
        assert t_log == ns and m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == ns
        assert m.header.frame_id == "sonar_acoustic"
        d = np.array([[v.x, v.y, v.z] for v in m.beam_directions])
        np.testing.assert_allclose(d[:, 0], 0.0)
        np.testing.assert_allclose(np.arctan2(-d[:, 1], d[:, 2]), az, atol=1e-12)  # theta = atan2(-y, z)
        np.testing.assert_array_equal(m.ranges, ranges.astype(np.float32))
        assert m.image.dtype == 8 and m.image.beam_count == len(az) and not m.image.is_bigendian
        data = np.frombuffer(m.image.data.tobytes(), "<f4").reshape(len(ranges), len(az))
        np.testing.assert_array_equal(data, s["image"][k])  # bit-exact
        assert m.ping_info.frequency > 0 and len(m.ping_info.rx_beamwidths) == len(az)
    body = msgs["/sonar/ground_truth/body"][2][1]
    assert body.image.dtype == 3
    np.testing.assert_array_equal(np.frombuffer(body.image.data.tobytes(), "<i2").reshape(80, 40), s["body"][2])
    shadow = msgs["/sonar/ground_truth/shadow"][1][1]
    np.testing.assert_array_equal(np.frombuffer(shadow.image.data.tobytes(), np.uint8).reshape(80, 40) > 0,
                                  s["shadow"][1])
    inten = msgs["/sonar/intensity"][3][1]
    np.testing.assert_array_equal(np.frombuffer(inten.image.data.tobytes(), "<f4").reshape(80, 40), s["intensity"][3])

    cams = msgs["/camera/image"]
    assert len(cams) == 2
    for k, (t_log, m, _) in enumerate(cams):
        assert t_log == round((1_700_000_000.25 + c["time"][k]) * 1e9)
        assert (m.encoding, m.height, m.width, m.step) == ("32FC3", 40, 64, 64 * 12)
        np.testing.assert_array_equal(np.frombuffer(m.data.tobytes(), "<f4").reshape(40, 64, 3), c["image"][k])
    info = msgs["/camera/camera_info"][0][1]
    np.testing.assert_allclose(np.reshape(info.k, (3, 3)), c["K"][:])
    rng = msgs["/camera/ground_truth/range"][1][1]
    assert rng.encoding == "32FC1"
    np.testing.assert_array_equal(np.frombuffer(rng.data.tobytes(), "<f4").reshape(40, 64), c["depth"][1])

    # /tf: world -> sonar at every frame time, equal to the stored sonar poses
    tf = [(t, m.transforms[0]) for t, m, _ in msgs["/tf"]]
    assert all(tr.header.frame_id == "world" and tr.child_frame_id == "sonar" for _, tr in tf)
    by_time = {t: tr for t, tr in tf}
    for k in range(4):
        tr = by_time[round((1_700_000_000.25 + s["time"][k]) * 1e9)].transform
        q = [tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w]
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), s["pose"][k][:3, :3], atol=1e-12)
        np.testing.assert_allclose([tr.translation.x, tr.translation.y, tr.translation.z], s["pose"][k][:3, 3])
    # /tf_static: sonar -> camera is the rig; composing gives the stored camera pose
    static = {tr.child_frame_id: tr for tr in msgs["/tf_static"][0][1].transforms}
    tc = static["camera"].transform
    R_sc = Rotation.from_quat([tc.rotation.x, tc.rotation.y, tc.rotation.z, tc.rotation.w]).as_matrix()
    t_sc = np.array([tc.translation.x, tc.translation.y, tc.translation.z])
    for k in range(2):
        tr = by_time[round((1_700_000_000.25 + c["time"][k]) * 1e9)].transform
        R_ws = Rotation.from_quat([tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w]).as_matrix()
        t_ws = np.array([tr.translation.x, tr.translation.y, tr.translation.z])
        np.testing.assert_allclose(R_ws @ R_sc, c["pose"][k][:3, :3], atol=1e-9)
        np.testing.assert_allclose(R_ws @ t_sc + t_ws, c["pose"][k][:3, 3], atol=1e-9)
    # the acoustic frame is right-handed and its Z is the sonar's boresight
    ta = static["sonar_acoustic"].transform
    R_sa = Rotation.from_quat([ta.rotation.x, ta.rotation.y, ta.rotation.z, ta.rotation.w]).as_matrix()
    np.testing.assert_allclose(R_sa[:, 2], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R_sa), 1.0)


def test_device_counts_and_cli(dataset, tmp_path):
    r = CliRunner().invoke(app, ["export", str(dataset), "--mcap", str(tmp_path / "u16.mcap"), "--sonar-dtype", "uint16",
                                 "--full-scale", "0.5", "--camera-encoding", "rgb8", "--no-ground-truth"])
    assert r.exit_code == 0, r.output
    msgs = _read(tmp_path / "u16.mcap")
    assert "/sonar/ground_truth/body" not in msgs and "/sonar/intensity" in msgs
    s = zarr.open_group(str(dataset), mode="r")["sonar"]
    m = msgs["/sonar/image"][0][1]
    assert m.image.dtype == 2
    counts = np.frombuffer(m.image.data.tobytes(), "<u2").reshape(80, 40)
    np.testing.assert_array_equal(counts, np.round(np.clip(s["image"][0] / 0.5, 0, 1) * 65535).astype(np.uint16))
    img = msgs["/camera/image"][0][1]
    assert img.encoding == "rgb8" and img.step == 64 * 3
    r = CliRunner().invoke(app, ["export", str(dataset), "--mcap", str(tmp_path / "x.mcap"), "--sonar-dtype", "int3"])
    assert r.exit_code == 2 and "sonar_dtype" in r.output
    r = CliRunner().invoke(app, ["export", str(tmp_path), "--mcap", str(tmp_path / "x.mcap")])
    assert r.exit_code == 2 and "not a Zarr store" in " ".join(r.output.split())


def test_project_reader_reads_the_export_bit_exact(dataset, tmp_path):
    """optiacoustic.io.open_sonar (i9's reader) on our MCAP: images, azimuths, ranges, stamps."""
    from optiacoustic.io import open_sonar

    for dtype in ("float32", "uint8"):
        mcap = write_mcap(dataset, tmp_path / f"{dtype}.mcap", sonar_dtype=dtype, full_scale=0.3, start_time=100.0)
        frames = open_sonar(mcap, topic="/sonar/image")
        s = zarr.open_group(str(dataset), mode="r")["sonar"]
        assert len(frames) == 4
        for k, f in enumerate(frames):
            want = s["image"][k] if dtype == "float32" else \
                np.round(np.clip(s["image"][k] / 0.3, 0, 1) * 255).astype(np.uint8)
            np.testing.assert_array_equal(f.raw, want)
            if dtype == "float32":
                np.testing.assert_array_equal(f.image, s["image"][k])
            np.testing.assert_allclose(f.spec.azimuths, s["azimuths"][:], atol=1e-12)
            np.testing.assert_array_equal(f.spec.ranges, s["ranges"][:].astype(np.float32))
            assert abs(f.time - (100.0 + s["time"][k])) < 1e-9


def test_convert_real_logs_into_the_layout(dataset, tmp_path):
    from optiacoustic.io import open_dataset, open_sonar

    aris = Path(__file__).resolve().parents[1] / "data" / "aris" / "sample.aris"
    r = CliRunner().invoke(app, ["convert", str(aris), "--out", str(tmp_path / "aris.zarr")])
    assert r.exit_code == 0, r.output
    tree = open_dataset(tmp_path / "aris.zarr")
    frames = open_sonar(aris)
    s = tree["sonar"]
    assert s["image"].dims == ("frame", "bin", "beam") and s["image"].shape[0] == len(frames)
    for k, f in enumerate(frames):
        np.testing.assert_array_equal(s["raw"][k].values, f.raw)
        np.testing.assert_array_equal(s["image"][k].values, f.image)
    np.testing.assert_allclose(s["azimuths"].values, frames[0].spec.azimuths)
    assert bool(s["done"].all())
    # our own export converts back to the same images
    mcap = write_mcap(dataset, tmp_path / "x.mcap")
    r = CliRunner().invoke(app, ["convert", str(mcap), "--topic", "/sonar/image", "--camera-topic", "/camera/image",
                                 "--out", str(tmp_path / "back.zarr")])
    assert r.exit_code == 0, r.output
    back = zarr.open_group(str(tmp_path / "back.zarr"), mode="r")
    orig = zarr.open_group(str(dataset), mode="r")
    np.testing.assert_array_equal(back["sonar/image"][:], orig["sonar/image"][:])
    np.testing.assert_array_equal(back["camera/image"][:], orig["camera/image"][:])
    np.testing.assert_allclose(back["camera/K"][:], orig["camera/K"][:])
    np.testing.assert_allclose(back["camera/time"][:], orig["camera/time"][:])
    r = CliRunner().invoke(app, ["convert", str(mcap), "--out", str(tmp_path / "back.zarr")])
    assert r.exit_code == 2 and "already exists" in " ".join(r.output.split())


def test_device_encodings_decode_back(dataset, tmp_path):
    """Oculus gamma bytes and ARIS dB bytes: the project's units.decode gives the image back to quantisation."""
    from optiacoustic.io import units

    s = zarr.open_group(str(dataset), mode="r")["sonar"]
    img = s["image"][1]
    fs = float(np.percentile(img, 99))
    # decode: Oculus bytes give intensity in units of the full-scale power, ARIS bytes over the reference
    for enc, params, unit in (("oculus_gamma8", {}, fs), ("aris_db", {"reference": fs * 1e-8}, 1.0)):
        mcap = write_mcap(dataset, tmp_path / f"{enc}.mcap", sonar_encoding=enc, full_scale=fs, ground_truth=False)
        m = _read(mcap)["/sonar/image"][1][1]
        assert m.image.dtype == 0  # uint8
        counts = np.frombuffer(m.image.data.tobytes(), np.uint8).reshape(80, 40)
        assert counts.max() == 255 and np.mean(counts == 255) < 0.03  # full scale at the top count
        back = units.decode(counts, enc, **params) * unit
        ok = (img > fs * 1e-6) & (img < fs)
        # the top count is full scale; below it decoding returns the intensity to within one count
        if enc == "aris_db":
            np.testing.assert_allclose(10 * np.log10(back[ok]), 10 * np.log10(img[ok]), atol=80 / 255 / 2 + 1e-4)
        else:
            np.testing.assert_allclose(255 * (back[ok] / fs) ** (127 / 510), 255 * (img[ok] / fs) ** (127 / 510),
                                       atol=0.5 + 1e-3)
