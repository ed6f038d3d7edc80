"""``oas info`` and ``oas view`` on the real samples; errors are one line with exit code 2."""

import cv2
from typer.testing import CliRunner

from optiacoustic.cli import app

runner = CliRunner()


def test_info_aris_and_oculus(aris_sample, oculus_sample):
    r = runner.invoke(app, ["info", str(aris_sample)])
    assert r.exit_code == 0, r.output
    assert "frames: 6" in r.output and "ARIS 1200" in r.output and "Telephoto_48" in r.output
    r = runner.invoke(app, ["info", str(oculus_sample)])
    assert r.exit_code == 0 and "gamma: 127" in r.output and "frames: 1" in r.output


def test_view_writes_polar_fan_and_sheet(tmp_path, aris_sample):
    r = runner.invoke(app, ["view", str(aris_sample), "--frames", "1:4", "--out", str(tmp_path), "--width", "200"])
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["contact_sheet.png", "fan_0001.png", "fan_0002.png", "fan_0003.png",
                     "polar_0001.png", "polar_0002.png", "polar_0003.png"]
    fan = cv2.imread(str(tmp_path / "fan_0002.png"))
    assert fan.shape[1] == 200 and fan[..., 2].max() > 100  # copper-coloured echo present
    assert cv2.imread(str(tmp_path / "polar_0001.png")).shape[0] == 2000


def test_cli_errors_are_one_line(tmp_path, aris_sample):
    bad = tmp_path / "t.aris"
    bad.write_bytes(aris_sample.read_bytes()[:3000])
    r = runner.invoke(app, ["view", str(bad), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "truncated" in r.output and "Traceback" not in r.output
    r = runner.invoke(app, ["view", str(aris_sample), "--frames", "7:9", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "selects no frame" in r.output
    r = runner.invoke(app, ["info", str(aris_sample), "--topic", "/x"])
    assert r.exit_code == 2 and "no topics" in r.output


def test_info_and_view_on_a_bag(tmp_path):
    import numpy as np

    from optiacoustic.io.rosmsg import PROJECTED_SONAR_IMAGE, typestore

    from .bagwriter import projected, write_bag

    ts = typestore(2)
    az = np.linspace(-0.4, 0.4, 32) ** 3 * 6  # uneven
    rng = np.random.default_rng(0)
    msgs = [("/sonar/image", PROJECTED_SONAR_IMAGE, 10.0 + k,
             projected(ts, 2, 10.0 + k, rng.random((50, 32)).astype(np.float32), az, np.linspace(1, 6, 50)))
            for k in range(3)]
    msgs.append(("/chatter", "std_msgs/msg/String", 10.0, ts.types["std_msgs/msg/String"](data="hi")))
    bag = write_bag(tmp_path / "bag", "mcap", msgs)
    r = runner.invoke(app, ["info", str(bag)])
    assert r.exit_code == 0, r.output
    assert "/sonar/image" in r.output and "3 msgs" in r.output and "/chatter" in r.output
    r = runner.invoke(app, ["view", str(bag), "--out", str(tmp_path / "v"), "--frames", "-2:", "--width", "160"])
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == [
        "contact_sheet.png", "fan_0001.png", "fan_0002.png", "polar_0001.png", "polar_0002.png"]
    r = runner.invoke(app, ["view", str(bag), "--topic", "/chatter", "--out", str(tmp_path / "w")])
    assert r.exit_code == 2 and "unsupported message type std_msgs/msg/String" in r.output
