"""Camera info files that are broken, or hold values of the wrong kind, are refused in one line naming the
file, the field and the value: no traceback from OpenCV or the codec, no truncated image size."""

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from optiacoustic.cli import app
from optiacoustic.io import ReadError, read_camera_info
from optiacoustic.io.camera_info import camera_from_matrix

runner = CliRunner()

OPENCV = "%YAML:1.0\n---\n"
K_OPENCV = ("camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
            "   data: [500, 0, 320, 0, 500, 240, 0, 0, 1]\n")
K_ROS = "camera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 500, 240, 0, 0, 1]}\n"


def _refused(tmp_path, text, *needles, name="camera_info.yaml"):
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(ReadError) as exc:
        read_camera_info(p)
    msg = str(exc.value)
    assert msg.startswith(str(p)), msg
    assert "\n" not in msg.strip(), msg
    for n in needles:
        assert n in msg, msg
    return msg


def test_opencv_parse_error_is_a_read_error_not_a_system_error(tmp_path):
    # was: SystemError: <class 'cv2.FileStorage'> returned a result with an exception set
    _refused(tmp_path, OPENCV + "camera_matrix: [1,2\n", "OpenCV FileStorage cannot parse it", "Missing ,")
    _refused(tmp_path, OPENCV + "{{{{\n", "cannot parse it")
    _refused(tmp_path, '<?xml version="1.0"?>\n<opencv_storage>\n<image_width>640</image_width>\n',
             "cannot parse it", name="c.xml")


def test_opencv_scalar_matrix_node_names_the_field(tmp_path):
    # was: cv2.error ... isMap() from node.mat()
    _refused(tmp_path, OPENCV + "camera_matrix: 5\nimage_width: 640\nimage_height: 480\n",
             "camera_matrix: expected a matrix", "got 5")
    _refused(tmp_path, OPENCV + "image_width: 640\nimage_height: 480\n" + K_OPENCV + "D: 3\n",
             "D: expected a matrix", "got 3")
    _refused(tmp_path, OPENCV + "image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3}\n",
             "camera_matrix: expected a matrix", "rows")
    _refused(tmp_path, OPENCV + "image_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n"
                                "   rows: 3\n   cols: 3\n   dt: d\n   data: [1, 2]\n",
             "camera_matrix: rows x cols = 3 x 3 needs 9 values, data has 2")
    _refused(tmp_path, OPENCV + "image_width: 640\nimage_height: 480\n"
                                "camera_matrix: [500, 0, 320, 0, 500, 240, 0, 0, x]\n",
             "camera_matrix: expected numbers", "'x'", "index 8")


@pytest.mark.parametrize("value, shown", [("640.7", "640.7"), ("true", "True (a boolean)"),
                                          ("'640'", "'640' (a string)"), (".inf", "inf"), ("[640]", "[640]"),
                                          ("null", "None")])
def test_ros_image_width_not_a_whole_number_is_refused(tmp_path, value, shown):
    # was: 640.7 -> 640 and true -> 1, silently
    _refused(tmp_path, f"image_width: {value}\nimage_height: 480\n" + K_ROS,
             f"image_width: expected a whole number of pixels, got {shown}")


@pytest.mark.parametrize("value", ["0", "-5", "1000000000"])
def test_ros_image_width_out_of_range_names_field_and_value(tmp_path, value):
    _refused(tmp_path, f"image_width: {value}\nimage_height: 480\n" + K_ROS,
             f"image_width: expected 1 to 32767 pixels, got {int(value)}")


def test_whole_float_size_is_taken(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("image_width: 640.0\nimage_height: 480\n" + K_ROS)
    cam = read_camera_info(p)
    assert (cam.width, cam.height) == (640, 480)


@pytest.mark.parametrize("value, shown", [('"480"', "'480' (a string)"), ("480.5", "480.5"), (".nan", "nan"),
                                          ("{a: 1}", "a mapping")])
def test_opencv_image_height_names_the_actual_value(tmp_path, value, shown):
    # was: "height: at most 32767 px, got 1.797...e308" for a string node (FileNode.real() of a string)
    msg = _refused(tmp_path, OPENCV + f"image_width: 640\nimage_height: {value}\n" + K_OPENCV,
                   f"image_height: expected a whole number of pixels, got {shown}")
    assert "e+308" not in msg and "1797" not in msg


def test_opencv_xml_string_size(tmp_path):
    xml = ('<?xml version="1.0"?>\n<opencv_storage>\n<image_width>abc</image_width><image_height>480</image_height>'
           '<camera_matrix type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>'
           '<data>500 0 320 0 500 240 0 0 1</data></camera_matrix></opencv_storage>\n')
    _refused(tmp_path, xml, "image_width: expected a whole number of pixels, got 'abc' (a string)", name="c.xml")


@pytest.mark.parametrize("opencv", [False, True])
def test_non_utf8_file_names_the_file(tmp_path, opencv):
    # was: 'utf-8' codec can't decode byte 0xff ... (no file name)
    head = OPENCV if opencv else ""
    body = "image_width: 640\nimage_height: 480\n" + (K_OPENCV if opencv else K_ROS)
    _refused(tmp_path, head.encode() + b"# \xff\xfe\n" + body.encode(), "not UTF-8 text (byte 0xff)", "byte offset")


@pytest.mark.parametrize("text, needles", [
    ("image_width: 640\nimage_height: 480\ncamera_matrix: {data: [500, 0, 320, 0, 500, 240, 0, 0, a]}\n",
     ["camera_matrix.data: expected numbers", "'a'"]),
    ("image_width: 640\nimage_height: 480\ncamera_matrix: {data: [.nan, 0, 320, 0, 500, 240, 0, 0, 1]}\n",
     ["camera_matrix.data: must be finite", "nan"]),
    ("image_width: 640\nimage_height: 480\ncamera_matrix: [true, 0, 320, 0, 500, 240, 0, 0, 1]\n",
     ["camera_matrix: expected numbers", "True"]),
    ("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3}\n", ["camera_matrix: expected a 'data' list"]),
    ("image_width: 640\nimage_height: 480\n" + K_ROS + "distortion_coefficients: {data: [0.1, x]}\n",
     ["distortion_coefficients.data: expected numbers", "'x'"]),
    ("image_width: 640\nimage_height: 480\n" + K_ROS + "distortion_model: fisheye\n",
     ["distortion_model: unsupported 'fisheye'"]),
    ("- 1\n- 2\n", ["expected a mapping of camera_info fields"]),
])
def test_ros_fields_of_the_wrong_kind(tmp_path, text, needles):
    _refused(tmp_path, text, *needles)


def test_a_folder_is_not_a_camera_info_file(tmp_path):
    (tmp_path / "camera_info.yaml").mkdir()
    with pytest.raises(ReadError, match="camera_info.yaml: not a file"):
        read_camera_info(tmp_path / "camera_info.yaml")


def test_camera_from_matrix_refuses_truncation():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    with pytest.raises(ValueError, match=r"cam: width: expected a whole number of pixels, got 640.7"):
        camera_from_matrix(K, None, 640.7, 480, "cam")
    with pytest.raises(ValueError, match=r"cam: height: expected a whole number of pixels, got True"):
        camera_from_matrix(K, None, 640, True, "cam")
    with pytest.raises(ValueError, match=r"cam: camera matrix: expected numbers, got 'a'"):
        camera_from_matrix([500, 0, 320, 0, 500, 240, 0, 0, "a"], None, 640, 480, "cam")
    assert camera_from_matrix(K, None, np.int64(640), 480.0, "cam").width == 640


@pytest.mark.parametrize("text, needle", [
    (OPENCV + "camera_matrix: [1,2\n", "OpenCV FileStorage cannot parse it"),
    (OPENCV + "camera_matrix: 5\nimage_width: 640\nimage_height: 480\n", "camera_matrix: expected a matrix"),
    ("image_width: 640.7\nimage_height: 480\n" + K_ROS, "image_width: expected a whole number of pixels, got 640.7"),
    (OPENCV + 'image_width: 640\nimage_height: "480"\n' + K_OPENCV, "image_height: expected a whole number of pixels, "
                                                                    "got '480' (a string)"),
    (b"image_width: 640\nimage_height: 480\n# \xff\n" + K_ROS.encode(), "not UTF-8 text"),
])
def test_convert_with_a_bad_camera_folder_is_one_line_and_writes_nothing(tmp_path, text, needle):
    import cv2

    from optiacoustic.io import open_camera

    cam = tmp_path / "cam"
    cam.mkdir()
    cv2.imwrite(str(cam / "000001.png"), np.zeros((48, 64, 3), np.uint8))
    (cam / "camera_info.yaml").write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(ReadError, match="camera_info.yaml"):
        open_camera(cam)
    aris = Path(__file__).resolve().parents[1] / "data" / "aris" / "sample.aris"
    out = tmp_path / "out.zarr"
    r = runner.invoke(app, ["convert", str(aris), "--out", str(out), "--camera", str(cam)])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and str(cam / "camera_info.yaml") in r.output and needle in r.output
    assert r.output.strip().count("\n") == 0, r.output
    assert not out.exists()
