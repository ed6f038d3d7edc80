"""Camera intrinsics, camera frames, rigs and time pairing from files written by independent writers."""

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from optiacoustic import PinholeCamera
from optiacoustic.io import ReadError, open_camera, pair_frames, read_camera_info, read_rig
from optiacoustic.io.rosmsg import typestore

from .bagwriter import header, write_bag

K = np.array([[800.0, 0, 320.5], [0, 810.0, 240.25], [0, 0, 1]])
D = np.array([-0.1, 0.01, 0.001, -0.002, 0.0005])
CAM = PinholeCamera(800.0, 810.0, 320.5, 240.25, 640, 480, tuple(D))
# a camera looking where a REP-103 sonar looks (its X), 0.25 m to the sonar's left (+Y)
R_REP_FROM_OPTICAL = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
Q = Rotation.from_matrix(R_REP_FROM_OPTICAL).as_quat()


def test_ros_camera_info_yaml(tmp_path):
    p = tmp_path / "ost.yaml"
    p.write_text(yaml.safe_dump({"image_width": 640, "image_height": 480, "camera_name": "c",
                                 "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
                                 "distortion_model": "plumb_bob",
                                 "distortion_coefficients": {"rows": 1, "cols": 5, "data": D.tolist()}}))
    assert read_camera_info(p) == CAM


@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_opencv_filestorage(tmp_path, suffix):
    p = tmp_path / f"calib{suffix}"
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D.reshape(1, 5))
    fs.release()
    assert read_camera_info(p) == CAM


def test_camera_info_errors(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("image_width: 640\nimage_height: 480\n")
    with pytest.raises(ReadError, match=r"c.yaml: no camera matrix"):
        read_camera_info(p)
    p.write_text(yaml.safe_dump({"image_width": 640, "image_height": 480, "camera_matrix": {"data": [1, 2, 3]}}))
    with pytest.raises(ReadError, match="expected 9 values"):
        read_camera_info(p)


def test_rig_yaml_matches_design_convention(tmp_path):
    (tmp_path / "cam.yaml").write_text(yaml.safe_dump({"image_width": 640, "image_height": 480,
                                                        "camera_matrix": {"data": K.ravel().tolist()},
                                                        "distortion_coefficients": {"data": D.tolist()}}))
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump({"parent": "sonar", "child": "camera", "translation": [0.0, 0.25, 0.0],
                                 "rotation": Q.tolist(), "camera_info": "cam.yaml"}))
    rig = read_rig(p)
    # DESIGN.md: a camera looking the same way as the sonar has R = [[1,0,0],[0,0,1],[0,-1,0]]
    assert np.allclose(rig.R, [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)
    assert np.allclose(rig.t, [-0.25, 0, 0], atol=1e-12)
    assert rig.camera == CAM
    # the same transform given camera -> sonar is inverted to the same rig
    Rinv = R_REP_FROM_OPTICAL.T
    p.write_text(yaml.safe_dump({"parent": "camera", "translation": (-Rinv @ [0, 0.25, 0]).tolist(),
                                 "rotation": Rotation.from_matrix(Rinv).as_quat().tolist(), "camera_info": "cam.yaml"}))
    rig2 = read_rig(p)
    assert np.allclose(rig2.R, rig.R, atol=1e-12) and np.allclose(rig2.t, rig.t, atol=1e-12)
    p.write_text(yaml.safe_dump({"translation": [0, 0, 0], "rotation": [0, 0, 0, 2.0], "camera_info": "cam.yaml"}))
    with pytest.raises(ReadError, match="unit quaternion"):
        read_rig(p)


def _camera_info_msg(ts, ros, t):
    T = ts.types
    kw = dict(header=header(ts, ros, t, "cam_optical"), height=480, width=640, distortion_model="plumb_bob",
              binning_x=0, binning_y=0,
              roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
    if ros == 1:
        kw.update(D=D, K=K.ravel(), R=np.eye(3).ravel(), P=np.zeros(12))
    else:
        kw.update(d=D, k=K.ravel(), r=np.eye(3).ravel(), p=np.zeros(12))
    return T["sensor_msgs/msg/CameraInfo"](**kw)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_bag_camera_and_tf_static(tmp_path, kind):
    ros = 1 if kind == "ros1" else 2
    ts = typestore(ros)
    T = ts.types
    rgb = np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    tr = T["geometry_msgs/msg/TransformStamped"](
        header=header(ts, ros, 0.0, "sonar_link"), child_frame_id="cam_optical",
        transform=T["geometry_msgs/msg/Transform"](translation=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.25, z=0.0),
                                                    rotation=T["geometry_msgs/msg/Quaternion"](x=Q[0], y=Q[1], z=Q[2], w=Q[3])))
    msgs = [("/tf_static", "tf2_msgs/msg/TFMessage", 1.0, T["tf2_msgs/msg/TFMessage"](transforms=[tr])),
            ("/cam/camera_info", "sensor_msgs/msg/CameraInfo", 1.0, _camera_info_msg(ts, ros, 1.0))]
    for k in range(3):
        msgs.append(("/cam/image_raw", "sensor_msgs/msg/Image", 1.0 + k, T["sensor_msgs/msg/Image"](
            header=header(ts, ros, 1.0 + k, "cam_optical"), height=480, width=640, encoding="bgr8", is_bigendian=0,
            step=640 * 3, data=np.ascontiguousarray(rgb[..., ::-1] // (k + 1)).ravel())))
    path = write_bag(tmp_path / ("c.bag" if kind == "ros1" else "c"), kind, msgs)
    cams = open_camera(path)
    assert len(cams) == 3
    frames = list(cams)
    assert frames[0].camera == CAM and frames[2].time == pytest.approx(3.0)
    assert np.array_equal(frames[0].raw[..., ::-1], rgb)  # bgr stored, raw as stored
    lin = frames[0].image
    assert lin.shape == (480, 640, 3) and lin.dtype == np.float32
    # sRGB decode: 255 -> 1, 0 -> 0, monotone, mid-grey 128 -> about 0.216
    x = np.array([0, 128, 255], np.uint8)
    from optiacoustic.io.camera import srgb_to_linear

    assert np.allclose(srgb_to_linear(x / 255.0), [0, 0.2158605, 1], atol=1e-6)
    rig = read_rig(path)
    assert np.allclose(rig.R, [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-9) and np.allclose(rig.t, [-0.25, 0, 0])
    with pytest.raises(ReadError, match="unsupported message type"):
        open_camera(path, topic="/tf_static")


def test_image_folder(tmp_path):
    rng = np.random.default_rng(1)
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"frame_{1700000000 + k}.png"), rng.integers(0, 256, (48, 64, 3), dtype=np.uint8))
    (tmp_path / "camera_info.yaml").write_text(yaml.safe_dump({"image_width": 640, "image_height": 480,
                                                                "camera_matrix": {"data": K.ravel().tolist()},
                                                                "distortion_coefficients": {"data": D.tolist()}}))
    cams = open_camera(tmp_path)
    assert len(cams) == 3 and cams[1].time == 1700000001.0 and cams[1].camera == CAM


def test_pair_frames_nearest_within_tolerance():
    ts = np.array([0.0, 1.0, 2.0, 3.0, np.nan])
    tc = np.array([2.96, 0.04, 1.6, 1.02])
    p = pair_frames(ts, tc, max_dt=0.05)
    assert p.sonar.tolist() == [0, 1, 3] and p.camera.tolist() == [1, 3, 0]
    assert np.allclose(p.dt, [0.04, 0.02, -0.04])
    assert len(pair_frames(ts, tc, max_dt=0.0)) == 0
    with pytest.raises(ValueError, match="max_dt"):
        pair_frames(ts, tc, max_dt=-1)


def test_bag_camera_random_access(tmp_path):
    ts = typestore(2)
    T = ts.types
    msgs = [("/c/image", "sensor_msgs/msg/Image", 5.0 + k, T["sensor_msgs/msg/Image"](
        header=header(ts, 2, 5.0 + k), height=2, width=3, encoding="mono8", is_bigendian=0, step=3,
        data=np.full(6, 10 * k, np.uint8))) for k in range(4)]
    cams = open_camera(write_bag(tmp_path / "r", "mcap", msgs))
    assert [int(cams[k].raw[0, 0]) for k in (3, 0, 2)] == [30, 0, 20] and cams[-1].time == 8.0


def test_pair_frames_with_readers(tmp_path, aris_sample):
    from optiacoustic.io import open_sonar

    sonar = open_sonar(aris_sample)
    t = sonar.times()
    assert np.array_equal(t, [f.time for f in sonar])
    cam_t = t[[0, 2, 4]] + 0.01
    p = pair_frames(sonar, cam_t, max_dt=0.02)
    assert p.sonar.tolist() == [0, 2, 4] and p.camera.tolist() == [0, 1, 2]


def test_every_axis_convention_is_a_proper_rotation():
    """A reflection among the axis tables would turn every rig read with it into a mirror image."""
    from optiacoustic.io.rig import AXES, CAMERA_AXES

    for name, R in {**AXES, **{f"camera {k}": v for k, v in CAMERA_AXES.items()}}.items():
        assert np.allclose(R @ R.T, np.eye(3)), name
        assert np.isclose(np.linalg.det(R), 1.0), name
    # the ProjectedSonarImage frame: a beam at our azimuth theta points along (0, -sin theta, cos theta)
    theta = 0.3
    d_ours = AXES["marine_acoustic"] @ np.array([0.0, -np.sin(theta), np.cos(theta)])
    assert np.allclose(d_ours, [np.sin(theta), np.cos(theta), 0.0])
