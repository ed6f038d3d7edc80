"""The workbench in a real browser: Playwright driving Debian's chromium (skipped, saying so, without one).

Screenshots of every state go to $OAS_WORKBENCH_SCREENSHOTS (or the test's tmp folder).
"""

from __future__ import annotations

import numpy as np
import pytest

from optiacoustic.frames import polar_from_fan
from optiacoustic.geometry import epipolar as ep

from .conftest import REPO, truth_matches, truth_points


TO_SCREEN = """([id, pts]) => {
  const svg = document.getElementById(id);
  const m = svg.getScreenCTM();
  return pts.map(([x, y]) => { const p = svg.createSVGPoint(); p.x = x; p.y = y; const q = p.matrixTransform(m); return [q.x, q.y]; });
}"""

CURVE_POINTS = """([id, tag, cls]) => [...document.querySelectorAll(`#${id} g[data-curve="${tag}"] polyline.${cls}`)]
  .map((el) => el.getAttribute("points").trim().split(/\\s+/).map((s) => s.split(",").map(Number)))"""


@pytest.fixture
def page(browser, live_server):
    ctx = browser.new_context(viewport={"width": 1500, "height": 1000}, accept_downloads=True)
    pg = ctx.new_page()
    errors = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.goto(live_server + "/")
    pg.wait_for_selector("body[data-ready='1']")
    pg.wait_for_function("document.getElementById('sonar-img').getBBox().width > 0")
    yield pg
    ctx.close()
    assert not errors, errors


def _screen(page, svg_id, pts):
    return page.evaluate(TO_SCREEN, [svg_id, [list(map(float, p)) for p in pts]])


def _click(page, svg_id, pt):
    (x, y), = _screen(page, svg_id, [pt])
    page.mouse.move(x, y)
    page.mouse.click(x, y)


def _rows(page):
    return page.locator("#matches tbody tr").count()


def _wait_rows(page, n):
    page.wait_for_function(f"document.querySelectorAll('#matches tbody tr').length === {n}")


def _zoom(page, svg_id, centre, clicks=3):
    (x, y), = _screen(page, svg_id, [centre])
    page.mouse.move(x, y)
    for _ in range(clicks):
        page.mouse.wheel(0, -300)
    page.wait_for_timeout(100)


def test_default_pair_curve_matches_reconstruction_export_import(page, live_server, session, shots, tmp_path):
    from optiacoustic.geometry.calibrate import load_view

    page.screenshot(path=str(shots / "01_default.png"))
    # sources and the matcher that this installation lacks say so
    st = page.request.get(live_server + "/api/state").json()
    options = page.locator("#source option").all_inner_texts()
    assert "simulated: thesis_scene1" in options
    for kind, label in (("real", "real pair"), ("dataset", "dataset frame")):
        if not st["sources"]["kinds"][kind]["available"]:
            assert f"{label}: not available" in options
            assert "not available" in page.inner_text("#source-note")
    assert page.locator("#suggest").is_disabled() == (not st["matcher"]["available"])
    px, fp, r, th = truth_matches(session)
    # zoom both images onto the points: finer clicks, and zoom works
    _zoom(page, "sonar-svg", fp.mean(0), 4)
    _zoom(page, "camera-svg", px.mean(0), 1)

    # a sonar click draws its conic in the camera image, from the library
    _click(page, "sonar-svg", fp[0])
    page.wait_for_selector('#camera-svg g[data-curve="pending-sonar"] polyline.solid')
    cx, cy = page.evaluate("(() => { const c = document.querySelector('#sonar-svg .mark.pending'); "
                           "return [+c.getAttribute('cx'), +c.getAttribute('cy')]; })()")
    assert np.hypot(cx - fp[0][0], cy - fp[0][1]) < 2.0
    rr, tt = (float(a) for a in polar_from_fan(*session.fan.from_pixel(cx, cy)))
    C = ep.conic(session.rig, rr, tt)
    solid = page.evaluate(CURVE_POINTS, ["camera-svg", "pending-sonar", "solid"])
    dashed = page.evaluate(CURVE_POINTS, ["camera-svg", "pending-sonar", "dashed"])
    assert solid and dashed
    for line in solid + dashed:
        assert len(line) >= 2
        assert np.nanmax(ep.sampson_distance(C, np.asarray(line))) < 0.01
    # the library's own sampled curve, drawn point for point
    lib = ep.sonar_to_optical_curves(session.rig, rr, tt, n_samples=241)[0]
    assert np.allclose(np.concatenate(solid), np.concatenate(lib), atol=2e-3)
    page.screenshot(path=str(shots / "02_curve.png"))

    # six matches: sonar point, then its mate in the camera
    _click(page, "camera-svg", px[0])
    _wait_rows(page, 1)
    for k in range(1, 6):
        _click(page, "sonar-svg", fp[k])
        page.wait_for_selector('#camera-svg g[data-curve="pending-sonar"] polyline')
        _click(page, "camera-svg", px[k])
        _wait_rows(page, k + 1)
    page.wait_for_function("document.getElementById('recon-msg').textContent.includes('all 6 points valid')")
    assert len(session.matches) == 6
    got_px, got_r, got_th = session.arrays()
    assert np.max(np.linalg.norm(got_px - px, axis=1)) < 1.5
    assert np.max(np.abs(got_r - r)) < 0.03 and np.max(np.abs(got_th - th)) < np.deg2rad(0.3)
    rec = page.request.get(live_server + "/api/reconstruction").json()
    P = session.rig.sonar_from_camera(truth_points())
    err = np.linalg.norm(np.array([p["point_sonar"] for p in rec["points"]]) - P, axis=1)
    assert np.all(err < 0.15), err
    # the table shows each match's distances and its CRLB
    cells = page.locator("#matches tbody tr").first.locator("td")
    assert float(cells.nth(4).inner_text()) < 3.0  # px off the curve
    page.locator("#matches tbody tr").nth(2).click()
    page.wait_for_selector('#camera-svg g[data-curve="match-2"] polyline.solid')
    page.screenshot(path=str(shots / "03_matches.png"))

    # the 3D view: orbit it a little
    box = page.locator("#view3d").bounding_box()
    page.mouse.move(box["x"] + 200, box["y"] + 200)
    page.mouse.down()
    page.mouse.move(box["x"] + 330, box["y"] + 170, steps=8)
    page.mouse.up()
    page.locator("#view3d-panel").screenshot(path=str(shots / "04_view3d.png"))

    # export the CSV (the format oas calibrate reads), clear, re-import
    with page.expect_download() as dl:
        page.click("#export-csv")
    csv = tmp_path / "matches.csv"
    dl.value.save_as(csv)
    view = load_view(csv)
    assert np.allclose(view.pixels, got_px, atol=1e-5) and np.allclose(view.ranges, got_r, atol=1e-5)
    page.click("#clear")
    _wait_rows(page, 0)
    page.set_input_files("#import-csv", str(csv))
    _wait_rows(page, 6)
    assert np.allclose(session.arrays()[0], got_px, atol=1e-5)
    with page.expect_download() as dl:
        page.click("#export-png")
    dl.value.save_as(shots / "05_export_view.png")
    with page.expect_download() as dl:
        page.click("#export-ply")
    assert dl.value.path().read_bytes().startswith(b"ply")

    # a path-traversal request from the page's origin gets nothing
    for bad in ("/static/../app.py", "/static/..%2f..%2fpyproject.toml", "/static/%2e%2e/session.py"):
        resp = page.request.get(live_server + bad)
        assert resp.status == 404 and b"import" not in resp.body()


def test_hover_move_delete_undo(page, live_server, session, shots):
    px, fp, r, th = truth_matches(session)
    # hover over the camera: the pixel's curve appears in the fan
    (x, y), = _screen(page, "camera-svg", [px[1]])
    page.mouse.move(x, y)
    page.wait_for_selector('#sonar-svg g[data-curve="hover"] polyline.solid')
    line = np.concatenate(page.evaluate(CURVE_POINTS, ["sonar-svg", "hover", "solid"]))
    assert np.min(np.linalg.norm(line - fp[1], axis=1)) < 5.0
    for k in range(2):
        page.request.post(live_server + "/api/matches", data={"camera": {"u": px[k][0], "v": px[k][1]},
                                                                 "sonar": {"u": fp[k][0], "v": fp[k][1]}})
    page.reload()
    page.wait_for_selector("body[data-ready='1']")
    _wait_rows(page, 2)
    # drag match 1's camera marker by 20 image px
    (x0, y0), (x1, y1) = _screen(page, "camera-svg", [px[0], px[0] + [20, 0]])
    page.mouse.move(x0, y0)
    page.mouse.down()
    page.mouse.move(x1, y1, steps=6)
    page.mouse.up()
    page.wait_for_function(f"document.querySelector('#matches tbody tr td:nth-child(2)').textContent"
                           f".startsWith('{px[0][0] + 20:.1f}'.slice(0, 3))")
    assert abs(session.matches[0].u - (px[0][0] + 20)) < 1.5
    page.keyboard.press("Control+z")
    page.wait_for_function(f"document.querySelector('#matches tbody tr td:nth-child(2)').textContent"
                           f".startsWith('{px[0][0]:.1f}')")
    assert abs(session.matches[0].u - px[0][0]) < 1e-6
    page.locator("#matches tbody tr").nth(1).click()
    page.keyboard.press("Delete")
    _wait_rows(page, 1)
    assert len(session.matches) == 1


def test_calibration_mode_applies_the_new_rig(page, live_server, session, shots):
    page.click("#modes button[data-mode='calibrate']")
    page.fill("#sig-px", "0.5")
    page.fill("#sig-r", "0.005")
    page.fill("#sig-a", "0.1")
    page.locator("#sig-a").dispatch_event("change")
    page.wait_for_function("document.getElementById('sig-a').value === '0.1'")
    views = sorted((REPO / "examples" / "calibration").glob("view_*.csv"))
    page.set_input_files("#import-views", [str(p) for p in views])
    page.wait_for_function(f"document.querySelectorAll('#views li').length === {len(views)}")
    page.click("#run-calib")
    page.wait_for_selector("#calib-report table")
    assert "weak" in page.locator("#calib-report").inner_text()
    page.click("#apply-calib")
    page.wait_for_function("document.getElementById('rig-info').textContent.includes('calibrated')")
    assert session.rig is not session.pair.rig
    # a click now draws the curve of the calibrated rig
    px, fp, r, th = truth_matches(session)
    _click(page, "sonar-svg", fp[0])
    page.wait_for_selector('#camera-svg g[data-curve="pending-sonar"] polyline')
    cx, cy = page.evaluate("(() => { const c = document.querySelector('#sonar-svg .mark.pending'); "
                           "return [+c.getAttribute('cx'), +c.getAttribute('cy')]; })()")
    rr, tt = (float(a) for a in polar_from_fan(*session.fan.from_pixel(cx, cy)))
    drawn = np.concatenate(page.evaluate(CURVE_POINTS, ["camera-svg", "pending-sonar", "dashed"]))
    assert np.nanmax(ep.sampson_distance(ep.conic(session.rig, rr, tt), drawn)) < 0.01
    assert np.nanmedian(ep.sampson_distance(ep.conic(session.pair.rig, rr, tt), drawn)) > 0.5
    page.screenshot(path=str(shots / "06_calibration.png"), full_page=True)


def test_fusion_overlay_with_opacity(page, live_server, session, shots):
    pose_R = np.asarray(session.pair.truth["sonar_pose_R"])
    pose_t = np.asarray(session.pair.truth["sonar_pose_t"])
    xs = np.array([[-1.0, -1.0, 0], [1.0, -0.8, 0], [-1.5, 0.5, 0], [1.5, 0.8, 0], [0.3, 1.4, 0], [-0.2, 0.0, 0],
                   [0.9, 0.3, 0]])
    P = session.rig.camera_from_sonar((xs - pose_t) @ pose_R)
    px, fp, r, th = truth_matches(session, P)
    for a, b in zip(px, fp):
        page.request.post(live_server + "/api/matches", data={"camera": {"u": a[0], "v": a[1]}, "sonar": {"u": b[0], "v": b[1]}})
    page.reload()
    page.wait_for_selector("body[data-ready='1']")
    page.click("#modes button[data-mode='fusion']")
    page.select_option("#mapping", "plane")
    page.click("#fusion-update")
    page.wait_for_function("document.getElementById('fusion-img').getAttribute('visibility') === 'visible'", timeout=60000)
    page.locator("#opacity").fill("0.8")
    assert page.get_attribute("#fusion-img", "opacity") == "0.8"
    assert "plane" in page.inner_text("#fusion-msg")
    page.screenshot(path=str(shots / "07_fusion.png"))


def test_suggest_matches_says_why_when_the_trees_do_not_load(page, live_server, session, shots, tmp_path,
                                                             monkeypatch):
    """A broken install (the matcher's candidate trees truncated): the button's click shows the reason in the
    status line, as an error, and adds nothing."""
    st = page.request.get(live_server + "/api/state").json()
    if not st["matcher"]["available"]:
        pytest.skip(f"suggest matches: {st['matcher']['message']}")
    from optiacoustic.matching import ranking

    bad = tmp_path / "match_candidate_trees.txt.gz"
    bad.write_bytes(ranking.MODEL_FILE.read_bytes()[:1000])
    monkeypatch.setattr(ranking, "MODEL_FILE", bad)
    ranking._booster.cache_clear()
    try:
        page.click("#suggest")
        page.wait_for_function("document.getElementById('status').textContent.includes('cannot read the ranking "
                               "model')", timeout=120000)
        assert "error" in page.locator("#status").get_attribute("class")
        assert session.matches == []
        page.screenshot(path=str(shots / "08b_suggest_trees_broken.png"))
    finally:
        monkeypatch.undo()
        ranking._booster.cache_clear()


def test_suggest_matches_button(page, live_server, session, shots):
    st = page.request.get(live_server + "/api/state").json()
    if not st["matcher"]["available"]:
        assert page.locator("#suggest").is_disabled()
        pytest.skip(f"suggest matches: {st['matcher']['message']}")
    page.click("#suggest")
    page.wait_for_function("document.getElementById('status').textContent.includes('suggested matches added')",
                           timeout=120000)
    n = len(session.matches)
    _wait_rows(page, n)
    # every suggestion is a match the workbench can use: the ML reconstruction takes them all
    rec = page.request.get(live_server + "/api/reconstruction").json()
    assert rec["n"] == n
    page.screenshot(path=str(shots / "08_suggested.png"))
    page.click("#undo")
    _wait_rows(page, 0)
