"""The shipped marine_acoustic_msgs definitions serialise and read back through rosbags."""

import numpy as np
import pytest

from optiacoustic.io import rosmsg


@pytest.mark.parametrize("ros", [1, 2])
def test_projected_sonar_image_round_trip(ros):
    ts = rosmsg.typestore(ros)
    T = ts.types
    hdr = T["std_msgs/msg/Header"]
    stamp = T["builtin_interfaces/msg/Time"](sec=1700000000, nanosec=123)
    header = hdr(seq=3, stamp=stamp, frame_id="sonar") if ros == 1 else hdr(stamp=stamp, frame_id="sonar")
    data = np.arange(12, dtype=np.uint8)
    msg = T[rosmsg.PROJECTED_SONAR_IMAGE](
        header=header,
        ping_info=T["marine_acoustic_msgs/msg/PingInfo"](
            frequency=2.1e6, sound_speed=1500.0, tx_beamwidths=np.zeros(3, np.float32),
            rx_beamwidths=np.zeros(3, np.float32)),
        beam_directions=[T["geometry_msgs/msg/Vector3"](x=0.0, y=-np.sin(a), z=np.cos(a)) for a in (-0.1, 0.0, 0.2)],
        ranges=np.array([1.0, 1.5, 2.5, 4.0], np.float32),
        image=T["marine_acoustic_msgs/msg/SonarImageData"](is_bigendian=False, dtype=0, beam_count=3, data=data),
    )
    if ros == 1:
        raw = ts.serialize_ros1(msg, rosmsg.PROJECTED_SONAR_IMAGE)
        back = ts.deserialize_ros1(raw, rosmsg.PROJECTED_SONAR_IMAGE)
    else:
        raw = ts.serialize_cdr(msg, rosmsg.PROJECTED_SONAR_IMAGE)
        back = ts.deserialize_cdr(raw, rosmsg.PROJECTED_SONAR_IMAGE)
    assert np.array_equal(back.image.data, data)
    assert np.array_equal(back.ranges, msg.ranges)
    assert back.beam_directions[2].y == pytest.approx(-np.sin(0.2))
    assert T["marine_acoustic_msgs/msg/SonarImageData"].DTYPE_FLOAT64 == 9


def test_dtype_codes_cover_all_message_types():
    assert [rosmsg.dtype_code(d) for d in rosmsg.SONAR_IMAGE_DTYPES.values()] == list(range(10))
    with pytest.raises(ValueError, match="complex"):
        rosmsg.dtype_code(np.complex64)


@pytest.mark.parametrize("ros", [1, 2])
def test_standard_messages_present(ros):
    ts = rosmsg.typestore(ros)
    for name in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo",
                 "tf2_msgs/msg/TFMessage"):
        assert name in ts.types
