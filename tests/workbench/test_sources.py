"""Sources beyond the simulated default: a real pair and a dataset frame, through optiacoustic.io.

Each test skips, saying why, when this installation lacks the reader it needs.
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from optiacoustic.frames import polar_from_fan
from optiacoustic.geometry import epipolar as ep
from optiacoustic.workbench import Session, create_app
from optiacoustic.workbench.sources import THESIS_RIG, source_kinds

from .conftest import REPO


def _client(pair, sources=None):
    from fastapi.testclient import TestClient

    s = Session(pair)
    return s, TestClient(create_app(s, sources=sources), base_url="http://127.0.0.1")


def _check_curve(session, client):
    """A click in the middle of the fan draws the library's conic of that sonar point."""
    h, w = session.fan.data.shape
    vv, uu = np.nonzero(session.fan.mask)
    k = np.argmin((uu - w / 2) ** 2 + (vv - 0.6 * h) ** 2)
    u, v = float(uu[k]), float(vv[k])
    c = client.get("/api/curve", params={"side": "sonar", "u": u, "v": v})
    assert c.status_code == 200, c.text
    r, th = (float(a) for a in polar_from_fan(*session.fan.from_pixel(u, v)))
    C = ep.conic(session.rig, r, th)
    for line in c.json()["dashed"] + c.json()["solid"]:
        assert np.nanmax(ep.sampson_distance(C, np.asarray(line))) < 0.01


def test_the_default_rig_is_the_packaged_thesis_rig():
    from optiacoustic.rig import Rig

    a = Rig.from_dict(THESIS_RIG)
    b = Rig.load(REPO / "src" / "optiacoustic" / "examples" / "rig_thesis.yaml")
    assert np.allclose(a.R, b.R, atol=1e-12) and np.allclose(a.t, b.t, atol=1e-12)
    assert np.allclose(a.camera.K, b.camera.K) and a.sonar.name == b.sonar.name


def test_real_pair_from_a_real_sonar_log_and_an_image_folder(tmp_path):
    ok, msg = source_kinds()["real"]
    if not ok:
        pytest.skip(f"real-pair source: {msg}")
    import cv2

    from optiacoustic import io
    from optiacoustic.workbench.sources import real_pair

    log = REPO / "tests" / "data" / "oculus" / "one_ping_8bit.raw"
    if not log.is_file():
        log = REPO.parent.parent / "shared" / "realdata" / "oculus" / "one_ping_8bit.raw"
    if not log.is_file():
        pytest.skip("no real Oculus sample (tests/data/oculus/one_ping_8bit.raw)")
    folder = tmp_path / "images"
    folder.mkdir()
    yy, xx = np.mgrid[0:400, 0:600]
    img = np.stack([xx * 255 // 599, yy * 255 // 399, np.full_like(xx, 90)], -1).astype(np.uint8)
    cv2.imwrite(str(folder / "frame_000.png"), img[..., ::-1])
    rig_file = tmp_path / "rig.yaml"
    rig_file.write_text(yaml.safe_dump(THESIS_RIG))
    pair = real_pair(log, folder, rig_file)
    frame = io.open_sonar(log)[0]
    assert np.array_equal(pair.sonar_image, np.asarray(frame.image, np.float32))
    assert pair.spec is frame.spec or pair.spec == frame.spec
    assert np.array_equal(pair.camera_rgb8, img)  # 8-bit sRGB shown as stored
    assert pair.rig.sonar == frame.spec and pair.kind == "real"
    # a real sonar's beam is soft: the automatic matcher declines it with a message, not with wrong matches
    from optiacoustic.workbench.compute import suggest

    assert pair.beam_model == "aperture" and pair.sonar_frame().beam_model == "aperture"
    rows, message = suggest(pair, pair.rig)
    assert rows == [] and "soft elevation beam" in message
    # with the seabed from the navigation (oas workbench --seabed-altitude), the matcher runs on it: the page's
    # button adds what it returns (no real pair here has depth truth to judge them by)
    from optiacoustic.matching import SeabedPlane

    nav = SeabedPlane.from_attitude(1.5, 20.0, sigma_height=0.01, sigma_tilt=np.deg2rad(0.05))
    rows, message = suggest(pair, pair.rig, seabed=nav)
    assert "soft elevation beam" not in message and message
    session, client = _client(pair)
    session.seabed = nav
    with client:
        r = client.post("/api/matches/suggest")
        assert r.status_code == 200 and r.json()["added"] == len(rows) == len(session.matches)
        client.post("/api/undo")
    session, client = _client(pair)
    with client:
        st = client.get("/api/state").json()
        assert st["source"]["kind"] == "real" and st["sonar"]["n_beams"] == frame.spec.n_beams
        _check_curve(session, client)


SMALL_DATASET = {
    "scene": "thesis_scene1",
    "rig": {"sonar": {"preset": "blueview-p900-90", "n_bins": 96, "n_beams": 48, "elevation_samples": 24},
            "camera": {"width_px": 72, "height_px": 48, "sensor_mm": [36, 24], "focal_mm": 50},
            "camera_in_sonar": {"position": [-0.25, 0, 0], "rotation_deg": [0, 0.7543055, -2.2636361]}},
    "water": "jerlov-II",
    "seed": 3,
    "duration": 1.0,
    "rates": {"sonar": 2, "camera": 2},
    "optical": {"slices": 6},
    "trajectory": {"kind": "orbit", "center": [0, 0, 0], "radius": 6.0, "height": 2.0, "period": 60.0},
}


def test_dataset_frame(tmp_path):
    ok, msg = source_kinds()["dataset"]
    if not ok:
        pytest.skip(f"dataset source: {msg}")
    import zarr

    from optiacoustic.io import write_dataset
    from optiacoustic.rig import Rig
    from optiacoustic.workbench.sources import dataset_pair

    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(yaml.safe_dump(SMALL_DATASET))
    path = tmp_path / "d.zarr"
    write_dataset(cfg, path, workers=0)
    root = zarr.open_group(str(path), mode="r")  # an independent reader of the same store
    n = root["sonar"]["image"].shape[0]
    assert n >= 2
    pair = dataset_pair(path, index=1)
    assert np.array_equal(pair.sonar_image, root["sonar"]["image"][1], equal_nan=True)
    ts, tc = root["sonar"]["time"][1], root["camera"]["time"][:]
    j = int(np.argmin(np.abs(tc - ts)))
    assert np.array_equal(pair.camera_linear, root["camera"]["image"][j], equal_nan=True)
    ref = Rig.from_dict(SMALL_DATASET["rig"])
    assert np.allclose(pair.rig.R, ref.R, atol=1e-9) and np.allclose(pair.rig.t, ref.t, atol=1e-12)
    assert pair.rig.camera.width == 72 and pair.spec.n_beams == 48
    with pytest.raises(ValueError, match="sonar frames"):
        dataset_pair(path, index=n)
    make = lambda k=None: dataset_pair(path, index=1 if k is None else k)  # noqa: E731
    session, client = _client(pair, {"ds": make})
    with client:
        st = client.get("/api/state").json()
        assert st["source"]["kind"] == "dataset" and (st["source"]["frame"], st["source"]["n_frames"]) == (1, n)
        _check_curve(session, client)
        # grid views collected over frames: another frame keeps the views, the matches start afresh
        from optiacoustic.geometry.calibrate import CalibrationView

        session.add_view(CalibrationView(np.array([[1.0, 2], [30, 4], [5, 20], [40, 30]]), np.full(4, 3.0),
                                         np.zeros(4)))
        session.add(session.match_from_display((10, 10), session.fan.to_pixel(0.0, 5.0)))
        r = client.post("/api/source", json={"name": "ds", "frame": 0})
        assert r.status_code == 200, r.text
        st = client.get("/api/state").json()
        assert st["source"]["frame"] == 0 and len(st["views"]) == 1 and st["matches"] == []
        assert np.array_equal(session.pair.sonar_image, root["sonar"]["image"][0], equal_nan=True)
        assert client.post("/api/source", json={"name": "ds", "frame": n}).status_code == 400
