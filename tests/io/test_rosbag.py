"""Bags written by rosbags itself (ROS 1, rosbag2 SQLite and MCAP, bare .mcap) read back bit-exact."""

import numpy as np
import pytest

from optiacoustic.io import open_sonar, ReadError
from optiacoustic.io.rosmsg import PROJECTED_SONAR_IMAGE, SONAR_IMAGE_DTYPES, typestore

from .bagwriter import header, projected, write_bag

RNG = np.random.default_rng(7)
AZ = np.sort(RNG.uniform(-0.5, 0.5, 9))          # non-uniform beams
RANGES = np.cumsum(RNG.uniform(0.01, 0.05, 13)) + 0.5  # non-uniform ranges
T0 = 1_700_000_000.25


def _image(dtype, k):
    dt = np.dtype(dtype)
    if dt.kind == "f":
        return RNG.standard_normal((RANGES.size, AZ.size)).astype(dt) * (10 ** k)
    info = np.iinfo(dt)
    return RNG.integers(info.min, info.max, (RANGES.size, AZ.size), dtype=dt, endpoint=True)


def _ros(kind):
    return 1 if kind == "ros1" else 2


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_every_dtype_round_trips_bit_exact(tmp_path, kind):
    ros = _ros(kind)
    ts = typestore(ros)
    msgs, images = [], {}
    for k, dt in enumerate(SONAR_IMAGE_DTYPES.values()):
        img = _image(dt, k % 3)
        topic = f"/sonar/{dt.name}"
        images[topic] = img
        for j in range(2):
            big = bool((k + j) % 2)
            msgs.append((topic, PROJECTED_SONAR_IMAGE, T0 + k + 0.5 * j,
                         projected(ts, ros, T0 + k + 0.5 * j, img + np.asarray(j, img.dtype), AZ, RANGES,
                                   bigendian=big, reverse=bool(j))))
    path = write_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), kind, msgs)
    for topic, img in images.items():
        r = open_sonar(path, topic=topic)
        assert len(r) == 2
        frames = list(r)
        for j, f in enumerate(frames):
            expect = img + np.asarray(j, img.dtype)
            assert f.raw.dtype == img.dtype and np.array_equal(f.raw, expect), topic
            assert np.array_equal(f.image, expect.astype(np.float32))
            assert np.allclose(f.azimuths, AZ, atol=1e-12, rtol=0)
            assert np.array_equal(f.ranges, RANGES.astype(np.float32).astype(float))
            assert f.time == pytest.approx(T0 + list(images).index(topic) + 0.5 * j, abs=1e-6)
        # random access agrees with iteration
        assert np.array_equal(r[1].raw, frames[1].raw) and np.array_equal(r[-2].raw, frames[0].raw)
        r.close()


def test_bare_mcap_file_and_default_topic(tmp_path):
    ts = typestore(2)
    img = _image(np.uint16, 0)
    path = write_bag(tmp_path / "bag", "mcap", [("/oculus/sonar_image", PROJECTED_SONAR_IMAGE, T0,
                                                  projected(ts, 2, T0, img, AZ, RANGES))])
    mcap = next(path.glob("*.mcap"))
    r = open_sonar(mcap)  # the bare file, no metadata.yaml beside it needed
    assert r.topic == "/oculus/sonar_image" and np.array_equal(r[0].raw, img)
    f = r[0]
    assert f.spec.beam_azimuths is not None and f.spec.bin_ranges is not None
    assert f.fan(width=64).data.shape[1] == 64


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_polar_image_topics(tmp_path, kind):
    import cv2

    import optiacoustic as oa

    ros = _ros(kind)
    ts = typestore(ros)
    T = ts.types
    spec = oa.SonarSpec(n_beams=AZ.size, n_bins=RANGES.size)
    img16 = _image(np.uint16, 0)
    img32 = RNG.random((RANGES.size, AZ.size)).astype(np.float32)
    png = np.frombuffer(cv2.imencode(".png", img16)[1].tobytes(), np.uint8)
    msgs = [
        ("/polar16", "sensor_msgs/msg/Image", T0, T["sensor_msgs/msg/Image"](
            header=header(ts, ros, T0), height=RANGES.size, width=AZ.size, encoding="mono16", is_bigendian=1,
            step=AZ.size * 2, data=np.frombuffer(img16.astype(">u2").tobytes(), np.uint8))),
        ("/polar32", "sensor_msgs/msg/Image", T0, T["sensor_msgs/msg/Image"](
            header=header(ts, ros, T0), height=RANGES.size, width=AZ.size, encoding="32FC1", is_bigendian=0,
            step=AZ.size * 4 + 8, data=np.frombuffer(np.pad(img32, ((0, 0), (0, 2))).tobytes(), np.uint8))),
        ("/polarpng", "sensor_msgs/msg/CompressedImage", T0, T["sensor_msgs/msg/CompressedImage"](
            header=header(ts, ros, T0), format="png", data=png)),
        ("/rgb", "sensor_msgs/msg/Image", T0, T["sensor_msgs/msg/Image"](
            header=header(ts, ros, T0), height=2, width=2, encoding="rgb8", is_bigendian=0, step=6,
            data=np.zeros(12, np.uint8))),
    ]
    path = write_bag(tmp_path / ("p.bag" if kind == "ros1" else "p"), kind, msgs)
    assert np.array_equal(open_sonar(path, topic="/polar16", spec=spec)[0].raw, img16)
    assert np.array_equal(open_sonar(path, topic="/polar32", spec=spec)[0].raw, img32)
    assert np.array_equal(open_sonar(path, topic="/polarpng", spec=spec)[0].raw, img16)
    with pytest.raises(ReadError, match="carry no beam or range geometry"):
        open_sonar(path, topic="/polar16")
    with pytest.raises(ReadError, match=r"no ProjectedSonarImage|no marine_acoustic_msgs"):
        open_sonar(path)
    r = open_sonar(path, topic="/rgb", spec=spec)
    with pytest.raises(ReadError, match=r"topic /rgb, frame 0: unsupported image encoding 'rgb8'"):
        r[0]
    with pytest.raises(ReadError, match="no topic '/nope'"):
        open_sonar(path, topic="/nope", spec=spec)


def test_wrong_type_and_empty_bag(tmp_path):
    ts = typestore(2)
    T = ts.types
    path = write_bag(tmp_path / "w", "mcap", [("/info", "std_msgs/msg/String", T0, T["std_msgs/msg/String"](data="x"))])
    with pytest.raises(ReadError, match="unsupported message type std_msgs/msg/String"):
        open_sonar(path, topic="/info")
    empty = write_bag(tmp_path / "e", "mcap", [])
    with pytest.raises(ReadError, match="empty bag"):
        open_sonar(empty)


def test_bad_message_named(tmp_path):
    ts = typestore(2)
    good = projected(ts, 2, T0, _image(np.uint8, 0), AZ, RANGES)
    bad = projected(ts, 2, T0 + 1, _image(np.uint8, 0), AZ, RANGES[:-1])  # one range short for the data
    path = write_bag(tmp_path / "x", "sqlite3", [("/s", PROJECTED_SONAR_IMAGE, T0, good),
                                                 ("/s", PROJECTED_SONAR_IMAGE, T0 + 1, bad)])
    r = open_sonar(path)
    with pytest.raises(ReadError, match=r"topic /s, frame 1: image.data has 117 bytes; 12 ranges x 9 beams"):
        list(r)
    r = open_sonar(path, errors="skip")
    with pytest.warns(UserWarning, match="skipped damaged frame"):
        frames = list(r)
    assert len(frames) == 1 and [s.index for s in r.skipped] == [1]


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_truncated_bags_raise_read_errors(tmp_path, kind):
    ros = _ros(kind)
    ts = typestore(ros)
    msgs = [("/s", PROJECTED_SONAR_IMAGE, T0 + k, projected(ts, ros, T0 + k, _image(np.uint8, 0), AZ, RANGES))
            for k in range(4)]
    path = write_bag(tmp_path / ("b.bag" if kind == "ros1" else "b"), kind, msgs)
    f = path if kind == "ros1" else next(path.glob("*.mcap"))
    data = f.read_bytes()
    for cut in np.linspace(1, len(data) - 1, 12).astype(int):
        g = tmp_path / f"t{f.suffix}"
        g.write_bytes(data[:cut])
        with pytest.raises(ReadError, match=r"t\.(bag|mcap)"):
            r = open_sonar(g)
            list(r)
            r[len(r) - 1]
