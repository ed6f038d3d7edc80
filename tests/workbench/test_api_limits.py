"""The workbench API refuses what would break it later: imported matches and calibration corners that
no click could make, views too large for the calibration to fit in memory, sigmas that divide by zero;
and its result cache does not grow with every edit (a tester's findings, 2026-11-24)."""

from __future__ import annotations

from .conftest import REPO, truth_matches


def _rows(lines):
    return "u,v,range,azimuth_deg\n" + "".join(f"{u},{v},{r},{a}\n" for u, v, r, a in lines)


def test_imported_matches_are_checked_as_clicks_are(client):
    before = client.get("/api/state").json()["matches"]
    for row, words in (((100000, -5000, 10, 0), "outside the 600 x 400 image"), ((300, 200, 500, 0), "range 500"),
                       ((300, 200, 10, 80), "azimuth 80")):
        r = client.post("/api/import/matches", json={"text": _rows([(290, 210, 9, 1), row]), "name": "m.csv"})
        assert r.status_code == 400 and "m.csv: corner 1" in r.json()["error"] and words in r.json()["error"], r.json()
    assert client.get("/api/state").json()["matches"] == before


def test_calibration_views_need_four_corners_and_a_bounded_total(client):
    from optiacoustic.workbench.session import MAX_CORNERS

    r = client.post("/api/calibration/import", json={"text": _rows([(300, 200, 9, 1)]), "name": "one.csv"})
    assert r.status_code == 400 and "at least 4 grid corners" in r.json()["error"]
    view = (REPO / "examples" / "calibration" / "view_01.csv").read_text().splitlines()
    header, body = [ln for ln in view if not ln.startswith("#")][0], [ln for ln in view if ln and not ln.startswith("#")][1:]
    big = "\n".join([header] + body * (MAX_CORNERS // len(body) + 1)) + "\n"
    r = client.post("/api/calibration/import", json={"text": big, "name": "big.csv"})
    assert r.status_code == 400 and f"at most {MAX_CORNERS} grid corners" in r.json()["error"]
    assert client.get("/api/state").json()["views"] == []


def test_sigmas_too_small_to_divide_by_are_refused(client, session):
    cams, sons = truth_matches(session)[:2]
    for cam, son in zip(cams[:6], sons[:6]):
        client.post("/api/matches", json={"camera": {"u": cam[0], "v": cam[1]}, "sonar": {"u": son[0], "v": son[1]}})
    r = client.post("/api/settings", json={"pixel": 1e-300, "range": 1e-300, "azimuth_deg": 1e-300})
    assert r.status_code == 422
    assert client.get("/api/reconstruction").status_code == 200


def test_the_reconstruction_cache_keeps_one_version(client, session):
    cams, sons = truth_matches(session)[:2]
    for cam, son in zip(cams[:6], sons[:6]):
        client.post("/api/matches", json={"camera": {"u": cam[0], "v": cam[1]}, "sonar": {"u": son[0], "v": son[1]}})
    cache = client.app.app.state.cache
    for k in range(12):
        assert client.put("/api/matches/0", json={"camera": {"u": 300 + k, "v": 200}}).status_code == 200
        assert client.get("/api/reconstruction").status_code == 200
    assert sum(1 for key in cache if key[0] == "recon") == 1


def test_non_numbers_and_non_finite_numbers_are_named_not_coerced(client):
    import json

    before = client.get("/api/state").json()
    for raw, field in ((b'{"camera":{"u":NaN,"v":200},"sonar":{"u":512,"v":362}}', "camera.u"),
                       (json.dumps({"camera": {"u": True, "v": 200}, "sonar": {"u": 512, "v": 362}}).encode(), "camera.u"),
                       (json.dumps({"camera": {"u": 300, "v": "200"}, "sonar": {"u": 512, "v": 362}}).encode(), "camera.v")):
        r = client.post("/api/matches", content=raw, headers={"content-type": "application/json"})
        assert r.status_code == 422 and r.json()["error"].startswith(field), r.json()
    r = client.post("/api/settings", json={"pixel": "1", "range": 0.1, "azimuth_deg": True})
    assert r.status_code == 422 and "pixel" in r.json()["error"] and "azimuth_deg" in r.json()["error"]
    assert client.get("/api/state").json() == before


def test_a_frame_the_source_does_not_have_is_refused(session):
    # the CLI's "as started" source of a one-frame pair took any frame (it was 200, frame 0)
    from fastapi.testclient import TestClient

    from optiacoustic.workbench import create_app

    pair = session.pair
    name = f"simulated: {pair.name} (as started)"
    with TestClient(create_app(session, sources={name: lambda *frame: pair}), base_url="http://127.0.0.1") as c:
        r = c.post("/api/source", json={"name": name, "frame": 999999})
        assert r.status_code == 400 and "has 1 frame(s); there is no frame 999999" in r.json()["error"]
        assert c.post("/api/source", json={"name": name, "frame": 0}).status_code == 200
