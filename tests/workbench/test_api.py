"""The workbench's HTTP API, through Starlette's TestClient: answers checked against the library's
own relations (points on conics, projections of known 3D points, an independent CSV reader)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from optiacoustic.frames import polar_from_fan
from optiacoustic.geometry import epipolar as ep
from optiacoustic.geometry import projection as pr

from .conftest import REPO, truth_matches, truth_points


def _polyline_distance(q, line):
    """Distance from a point to a polyline (independent of how densely it is sampled)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", q - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0, 1)
    return float(np.min(np.linalg.norm(a + t[:, None] * ab - q, axis=1)))


def _add(client, cam, son):
    r = client.post("/api/matches", json={"camera": {"u": cam[0], "v": cam[1]}, "sonar": {"u": son[0], "v": son[1]}})
    assert r.status_code == 200, r.text
    return r.json()["index"]


def _add_truth(client, session, P=None):
    px, fp, r, th = truth_matches(session, P)
    for a, b in zip(px, fp):
        _add(client, a, b)
    return px, fp, r, th


def test_state_and_images(client, session):
    st = client.get("/api/state").json()
    assert st["camera"]["width"] == 600 and st["camera"]["height"] == 400
    assert st["source"]["name"] == "thesis_scene1"
    assert st["matches"] == []
    for name, shape in (("sonar", (st["fan"]["height"], st["fan"]["width"])), ("camera", (400, 600))):
        r = client.get(f"/api/image/{name}.png")
        assert r.headers["content-type"] == "image/png"
        img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape[:2] == shape
        assert img.std() > 5  # not a blank picture


def test_sonar_click_curve_is_the_conic_and_passes_through_the_true_pixel(client, session):
    px, fp, r, th = truth_matches(session)
    for k in range(len(px)):
        c = client.get("/api/curve", params={"side": "sonar", "u": fp[k][0], "v": fp[k][1]}).json()
        solid = np.concatenate([np.asarray(p) for p in c["solid"]])
        dashed = np.concatenate([np.asarray(p) for p in c["dashed"]])
        assert len(solid) > 20 and len(dashed) > 20
        # every drawn point lies on the library's conic of that sonar measurement
        C = ep.conic(session.rig, r[k], th[k])
        assert np.nanmax(ep.sampson_distance(C, solid)) < 0.01
        assert np.nanmax(ep.sampson_distance(C, dashed)) < 0.01
        # and the true point's pixel is on the solid part (inside the elevation aperture)
        assert min(_polyline_distance(px[k], np.asarray(p)) for p in c["solid"]) < 0.05
        assert c["range"] == pytest.approx(r[k], abs=1e-6)


def test_camera_click_curve_holds_the_sonar_measurements_of_the_pixel_ray(client, session):
    px, fp, r, th = truth_matches(session)
    fan = session.fan
    for k in range(len(px)):
        c = client.get("/api/curve", params={"side": "camera", "u": px[k][0], "v": px[k][1]}).json()
        solid = np.concatenate([np.asarray(p) for p in c["solid"]])
        # the true sonar point is on it
        assert min(_polyline_distance(fp[k], np.asarray(p)) for p in c["solid"]) < 0.05
        # each point of the curve is a sonar measurement whose conic passes through the pixel
        rr, tt = polar_from_fan(*fan.from_pixel(solid[:, 0], solid[:, 1]))
        d = ep.sampson_distance(ep.conic(session.rig, rr, tt), np.broadcast_to(px[k], solid.shape))
        assert np.nanmax(d) < 0.05  # fan pixels are sent to 1e-3 px (~3e-5 m)


def test_a_click_outside_the_fan_is_refused_with_a_reason(client):
    r = client.get("/api/curve", params={"side": "sonar", "u": 3.0, "v": 3.0})
    assert r.status_code == 400 and "outside the fan" in r.json()["error"]
    r = client.post("/api/matches", json={"camera": {"u": 10, "v": 10}, "sonar": {"u": 3.0, "v": 3.0}})
    assert r.status_code == 400 and "outside the fan" in r.json()["error"]
    r = client.post("/api/matches", json={"camera": {"u": 900, "v": 10}, "sonar": {"u": 500, "v": 300}})
    assert r.status_code == 400 and "outside the 600 x 400 image" in r.json()["error"]


def test_matches_move_delete_undo(client, session):
    px, fp, r, th = _add_truth(client, session)
    st = client.get("/api/state").json()
    assert len(st["matches"]) == 6
    assert np.allclose([m["camera"] for m in st["matches"]], px)
    assert np.allclose([m["range"] for m in st["matches"]], r, atol=1e-9)
    client.put("/api/matches/2", json={"camera": {"u": 100.0, "v": 120.0}})
    st = client.get("/api/state").json()
    assert st["matches"][2]["camera"] == [100.0, 120.0]
    assert st["matches"][2]["range"] == pytest.approx(r[2], abs=1e-9)  # the sonar side kept
    assert client.delete("/api/matches/0").status_code == 200
    assert len(client.get("/api/state").json()["matches"]) == 5
    assert client.delete("/api/matches/9").status_code == 404
    # a move to where the match already is (or with nothing to move) changes nothing: no version, no undo step
    v = client.get("/api/state").json()["version"]
    m1 = client.get("/api/state").json()["matches"][1]
    assert client.put("/api/matches/1", json={}).json()["version"] == v
    assert client.put("/api/matches/1", json={"camera": dict(zip("uv", m1["camera"]))}).json()["version"] == v
    client.post("/api/undo")
    client.post("/api/undo")
    st = client.get("/api/state").json()
    assert len(st["matches"]) == 6 and np.allclose(st["matches"][2]["camera"], px[2])
    assert client.post("/api/matches/clear").json()["version"] > st["version"]
    v = client.get("/api/state").json()["version"]
    assert client.post("/api/matches/clear").json()["version"] == v  # clearing no matches: no change
    client.post("/api/undo")
    assert len(client.get("/api/state").json()["matches"]) == 6  # the one undo step is the real clear


def test_reconstruction_of_exact_matches_is_the_truth_and_noise_shows_in_sigmas(client, session):
    P = truth_points()
    _add_truth(client, session, P)
    rec = client.get("/api/reconstruction").json()
    assert rec["n"] == 6 and "all 6 points valid" in rec["message"]
    Ps = session.rig.sonar_from_camera(P)
    for k, p in enumerate(rec["points"]):
        assert np.allclose(p["point_sonar"], Ps[k], atol=1e-4)
        assert p["distance_px"] < 1e-6 and p["distance_sigma"] < 1e-5
        assert all(0 < s < 0.5 for s in p["std_sonar"])  # CRLB: positive, sub-metre at 6 m
    # move one pixel 2 px across its conic: 2 px off (first order), and at most 2 sigma_px
    px, fp, r, th = truth_matches(session, P)
    C = ep.conic(session.rig, r[0], th[0])
    g = (C @ np.r_[px[0], 1.0])[:2]
    n = g / np.linalg.norm(g)
    client.put("/api/matches/0", json={"camera": {"u": px[0][0] + 2 * n[0], "v": px[0][1] + 2 * n[1]}})
    p0 = client.get("/api/reconstruction").json()["points"][0]
    assert p0["distance_px"] == pytest.approx(2.0, rel=0.05)
    assert 0 < p0["distance_sigma"] < 2.0 / session.sigmas.pixel * 1.05


def test_get_never_changes_state(client, session):
    _add_truth(client, session)
    before = client.get("/api/state").json()
    for url in ("/", "/static/app.js", "/api/state", "/api/image/sonar.png", "/api/image/camera.png",
                "/api/curve?side=camera&u=300&v=200", "/api/reconstruction", "/api/scene3d",
                "/api/export/matches.csv", "/api/export/points.ply", "/api/export/view.png",
                "/api/fusion.png?mapping=plane"):
        assert client.get(url).status_code == 200, url
    assert client.get("/api/state").json() == before
    # state-changing routes do not answer GET
    for url in ("/api/undo", "/api/matches/clear", "/api/calibration/run", "/api/source", "/api/settings"):
        assert client.get(url).status_code == 405, url


def test_csv_export_reads_back_with_the_calibration_reader_and_imports(client, session, tmp_path):
    from optiacoustic.geometry.calibrate import load_view

    px, fp, r, th = _add_truth(client, session)
    text = client.get("/api/export/matches.csv").text
    (tmp_path / "m.csv").write_text(text)
    view = load_view(tmp_path / "m.csv")
    assert np.allclose(view.pixels, px, atol=1e-5)
    assert np.allclose(view.ranges, r, atol=1e-5)
    assert np.allclose(view.azimuths, th, atol=1e-7)
    client.post("/api/matches/clear")
    assert client.get("/api/state").json()["matches"] == []
    assert client.post("/api/import/matches", json={"text": text, "name": "m.csv"}).json()["n"] == 6
    st = client.get("/api/state").json()
    assert np.allclose([m["camera"] for m in st["matches"]], px, atol=1e-5)
    bad = client.post("/api/import/matches", json={"text": "u,v,range\n1,2,3\n", "name": "bad.csv"})
    assert bad.status_code == 400 and "bad.csv" in bad.json()["error"] and "azimuth" in bad.json()["error"]
    assert "/tmp" not in bad.json()["error"]


def test_ply_export_holds_the_reconstructed_points(client, session, tmp_path):
    import trimesh

    _add_truth(client, session)
    (tmp_path / "p.ply").write_bytes(client.get("/api/export/points.ply").content)
    cloud = trimesh.load(tmp_path / "p.ply")
    assert np.allclose(np.asarray(cloud.vertices), session.rig.sonar_from_camera(truth_points()), atol=1e-4)


def test_view_png(client, session):
    _add_truth(client, session)
    r = client.get("/api/export/view.png")
    img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape[0] == 400 and img.shape[1] > 600


def test_scene3d_has_fan_frustum_and_points(client, session):
    _add_truth(client, session)
    s = client.get("/api/scene3d").json()
    assert len(s["points"]) == 6 and len(s["fan"]) > 4 and len(s["frustum"]) == 5
    assert np.allclose(s["camera_centre"], session.rig.t, atol=1e-3)
    # the frustum's edges leave the camera centre along the image corners' rays
    e = np.asarray(s["frustum"][0])
    assert np.allclose(e[0], session.rig.t, atol=1e-3)
    uv = pr.project(session.rig, session.rig.camera_from_sonar(e[1])).pixels
    assert np.allclose(uv, [-0.5, -0.5], atol=0.1)  # 3D points are sent to 1 mm
    # each match's sonar arc and camera ray both pass through its (true) point
    P = session.rig.sonar_from_camera(truth_points())
    for m in s["matches"]:
        arc, ray = np.asarray(m["arc"]), np.asarray(m["ray"])
        assert np.allclose(np.linalg.norm(arc, axis=1), np.linalg.norm(P[m["index"]]), atol=1e-3)
        d = (ray[1] - ray[0]) / np.linalg.norm(ray[1] - ray[0])
        off = P[m["index"]] - ray[0]
        assert np.linalg.norm(off - (off @ d) * d) < 2e-3


def _calibration_views():
    return sorted((REPO / "examples" / "calibration").glob("view_*.csv"))


def test_calibration_from_imported_views_applies_to_the_curves(client, session):
    import yaml

    from optiacoustic.frames import R_SONAR_FROM_CAMERA_FORWARD, rotation_from_euler_xyz

    views = _calibration_views()
    assert len(views) >= 4
    client.post("/api/settings", json={"pixel": 0.5, "range": 0.005, "azimuth_deg": 0.1})
    for p in views:
        assert client.post("/api/calibration/import", json={"text": p.read_text(), "name": p.name}).status_code == 200
    rep = client.post("/api/calibration/run").json()
    assert rep["success"], rep["message"]
    truth = yaml.safe_load((REPO / "examples" / "calibration" / "truth.yaml").read_text())["camera_in_sonar"]
    assert np.allclose(rep["t"][:2], truth["position"][:2], atol=0.03)
    R_true = rotation_from_euler_xyz(np.deg2rad(truth["rotation_deg"])) @ R_SONAR_FROM_CAMERA_FORWARD
    ang = np.rad2deg(np.arccos(np.clip((np.trace(np.asarray(rep["R"]).T @ R_true) - 1) / 2, -1, 1)))
    assert 0 < ang < 3.0
    assert "pitch" in rep["weak"] or "t_z" in rep["weak"]  # the elevation ambiguity shows
    before = client.get("/api/curve", params={"side": "camera", "u": 300, "v": 200}).json()
    client.post("/api/calibration/apply")
    st = client.get("/api/state").json()
    assert st["rig"]["calibrated"] and np.allclose(st["rig"]["t"], rep["t"], atol=1e-6)
    after = client.get("/api/curve", params={"side": "camera", "u": 300, "v": 200}).json()
    assert after["solid"] != before["solid"]
    client.post("/api/rig/reset")
    assert client.get("/api/curve", params={"side": "camera", "u": 300, "v": 200}).json()["solid"] == before["solid"]


def test_calibration_errors_are_reported(client):
    assert client.post("/api/calibration/run").status_code == 400
    assert client.post("/api/calibration/apply").status_code == 400
    r = client.post("/api/calibration/views")
    assert r.status_code == 400 and "at least 4" in r.json()["error"]


def test_fusion_overlay_maps_the_fan_into_the_camera(client, session):
    # seabed points (z = 0 in the world): a plane, where the plane mapping is exact
    pose_R = np.asarray(session.pair.truth["sonar_pose_R"])
    pose_t = np.asarray(session.pair.truth["sonar_pose_t"])
    xs = np.array([[-1.0, -1.0, 0], [1.0, -0.8, 0], [-1.5, 0.5, 0], [1.5, 0.8, 0], [0.3, 1.4, 0], [-0.2, 0.0, 0]])
    P_sonar = (xs - pose_t) @ pose_R
    P = session.rig.camera_from_sonar(P_sonar)
    _add_truth(client, session, P)
    for m in ("plane", "rbf"):
        r = client.get("/api/fusion.png", params={"mapping": m})
        assert r.status_code == 200, r.text
        img = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_UNCHANGED)
        assert img.shape == (400, 600, 4)
        assert (img[..., 3] > 0).mean() > 0.05
    assert client.get("/api/fusion.png", params={"mapping": "nope"}).status_code == 422


def test_fusion_needs_matches(client):
    r = client.get("/api/fusion.png", params={"mapping": "plane"})
    assert r.status_code == 400 and "at least 3" in r.json()["error"]


def test_source_switch_only_to_known_names(client):
    r = client.post("/api/source", json={"name": "../../etc/passwd"})
    assert r.status_code == 400 and "expected one of" in r.json()["error"]
    assert client.post("/api/source", json={"name": "flat_seabed"}).status_code == 200
    st = client.get("/api/state").json()
    assert st["source"]["name"] == "flat_seabed" and st["matches"] == []
    kinds = st["sources"]["kinds"]
    for k in ("real", "dataset"):
        assert kinds[k]["available"] or "not available" in kinds[k]["message"]


def test_suggest_matches_is_either_the_matcher_or_says_not_available(client, session):
    from optiacoustic.workbench.sources import matcher_available

    ok, msg = matcher_available()
    st = client.get("/api/state").json()
    assert st["matcher"] == {"available": ok, "message": msg}
    r = client.post("/api/matches/suggest")
    if not ok:
        assert r.status_code == 400 and "not available" in r.json()["error"]
        return
    assert r.status_code == 200, r.text
    n = r.json()["added"]
    assert len(session.matches) == n
    if n:
        rec = client.get("/api/reconstruction").json()
        assert all(p["distance_sigma"] is None or p["distance_sigma"] >= 0 for p in rec["points"])
        client.post("/api/undo")
        assert session.matches == []


def test_suggest_matches_reports_unloadable_trees(client, session, monkeypatch):
    """When the matcher's candidate trees cannot be loaded (a broken install, no libgomp1) the suggest call answers
    with the reason as JSON (the page shows its ``error``), not a bare server error; nothing is added."""
    from optiacoustic.matching.ranking import RankModelError
    from optiacoustic.workbench import compute

    def broken(*a, **k):
        raise RankModelError(0, "cannot read the ranking model: truncated", "/x/match_candidate_trees.txt.gz")

    monkeypatch.setattr(compute, "suggest", broken)
    r = client.post("/api/matches/suggest")
    assert r.status_code == 500
    assert r.json()["error"] == "/x/match_candidate_trees.txt.gz: cannot read the ranking model: truncated"
    assert session.matches == []


def test_every_error_has_the_one_error_body(client):
    """Unknown routes, wrong methods and missing static files answer {"error": ...} as every other failure."""
    for r, code in ((client.get("/api/nothing-here"), 404), (client.delete("/api/state"), 405),
                    (client.get("/static/nothing.js"), 404), (client.delete("/api/matches/99"), 404),
                    (client.put("/api/matches/0", json={"camera": {"u": "x", "v": 1}}), 422)):
        assert r.status_code == code and set(r.json()) == {"error"} and r.json()["error"], (code, r.text)
    assert "allow" in {k.lower() for k in client.delete("/api/state").headers}  # 405 keeps its Allow header
