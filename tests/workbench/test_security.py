"""The workbench serves only what it was started with, to whom it should."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from optiacoustic.workbench import create_app
from optiacoustic.workbench.app import MAX_BODY
from optiacoustic.workbench.server import is_loopback


@pytest.mark.parametrize("path", ["/static/../app.py", "/static/..%2fapp.py", "/static/%2e%2e/%2e%2e/pyproject.toml",
                                  "/static/..%2F..%2F..%2Fetc%2Fpasswd", "/static//etc/passwd", "/../../etc/passwd",
                                  "/static/app.py", "/static/__init__.py", "/api/image/../../session.py"])
def test_path_traversal_is_404(client, path):
    r = client.get(path)
    assert r.status_code == 404
    assert b"import" not in r.content and b"root:" not in r.content


def test_static_files_are_served(client):
    for name, kind in (("app.js", "javascript"), ("style.css", "css"), ("view3d.js", "javascript")):
        r = client.get(f"/static/{name}")
        assert r.status_code == 200 and kind in r.headers["content-type"]
    assert b"<script type=\"module\"" in client.get("/").content


def test_foreign_host_header_is_refused(session):
    with TestClient(create_app(session), base_url="http://evil.example") as c:
        assert c.get("/api/state").status_code == 421


def test_cross_origin_state_change_is_refused(client):
    r = client.post("/api/matches/clear", headers={"Origin": "http://evil.example"})
    assert r.status_code == 403
    assert client.post("/api/matches/clear", headers={"Origin": "http://127.0.0.1:8765"}).status_code == 200


def test_request_bodies_are_bounded(client):
    big = "u,v,range,azimuth_deg\n" + "1,2,3,4\n" * (MAX_BODY // 8 + 10)
    r = client.post("/api/import/matches", json={"text": big})
    assert r.status_code == 413


def test_request_bodies_without_a_length_are_bounded_too(client):
    def chunks():
        yield b'{"text": "'
        for _ in range(MAX_BODY // 4096 + 4):
            yield b"x" * 4096
        yield b'"}'

    r = client.post("/api/import/matches", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_token_is_required_when_set(session):
    app = create_app(session, token="s3cret")
    with TestClient(app, base_url="http://127.0.0.1") as c:
        assert c.get("/api/state").status_code == 403
        assert c.get("/api/state", params={"token": "wrong"}).status_code == 403
        r = c.get("/", params={"token": "s3cret"})
        assert r.status_code == 200 and "oas_workbench_token=s3cret" in r.headers["set-cookie"]
        assert c.get("/api/state").status_code == 200  # the cookie now carries it
    with TestClient(app, base_url="http://127.0.0.1") as c:
        assert c.get("/api/state", headers={"X-Workbench-Token": "s3cret"}).status_code == 200


def test_loopback_detection():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")


def test_cli_refuses_a_remote_host_without_the_flag():
    from optiacoustic.cli import app

    r = CliRunner().invoke(app, ["workbench", "--host", "0.0.0.0", "--no-browser"])
    assert r.exit_code == 2
    assert "--allow-remote" in r.output
