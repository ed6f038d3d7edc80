"""The workbench's ASGI app (FastAPI): the page, its images, and a small JSON API.

Security (a local tool that must not become a door into the machine):

* it serves only what it was started with: the static files are read once from the package
  into a fixed table (a request's path is a key in that table, never a file name), images are
  rendered from memory, and no request names a file;
* request bodies are bounded (:data:`MAX_BODY` bytes; 413 beyond), counted as they stream;
* nothing changes on GET (state changes are POST, PUT and DELETE), and state-changing requests
  must come from the page's own origin (an ``Origin`` header naming another host is refused);
* the ``Host`` header must name the address the server listens on (DNS rebinding);
* with a ``token`` (another address than loopback), every request must carry it: in the
  URL's ``?token=``, in the ``X-Workbench-Token`` header or in the cookie the page receives.
"""


import hmac
from importlib import resources
from typing import Optional
from urllib.parse import parse_qs, urlsplit

import numpy as np

from . import compute, exports
from .images import fan_rgb8, png, rgba_layer
from .session import Session

__all__ = ["create_app", "MAX_BODY", "STATIC_FILES"]

#: Largest request body accepted (bytes).
MAX_BODY = 1 << 20
#: The static files of the page, by URL name.
STATIC_FILES = {"index.html": "text/html; charset=utf-8", "app.js": "text/javascript; charset=utf-8",
                "view3d.js": "text/javascript; charset=utf-8", "api.js": "text/javascript; charset=utf-8",
                "style.css": "text/css; charset=utf-8"}
_COOKIE = "oas_workbench_token"
_SAFE = ("GET", "HEAD", "OPTIONS")


def _load_static() -> dict:
    base = resources.files("optiacoustic.workbench") / "static"
    return {name: (base / name).read_bytes() for name in STATIC_FILES}


async def _send_plain(send, status: int, text: str):
    body = text.encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"text/plain; charset=utf-8"), (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})


class Guard:
    """ASGI middleware: host check, token, same-origin for state changes, bounded bodies."""

    def __init__(self, app, *, allowed_hosts, token: Optional[str], max_body: int):
        self.app = app
        self.allowed_hosts = {h.lower() for h in allowed_hosts}
        self.token = token
        self.max_body = max_body

    def _host_ok(self, host: str) -> bool:
        if not host:
            return False
        h = host.lower()
        name = h.rsplit(":", 1)[0] if not h.endswith("]") else h
        return h in self.allowed_hosts or name in self.allowed_hosts

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        if not self._host_ok(headers.get("host", "")):
            return await _send_plain(send, 421, "host not served by this workbench")
        method = scope["method"]
        if self.token is not None:
            q = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [""])[0]
            cookie = ""
            for part in headers.get("cookie", "").split(";"):
                k, _, v = part.strip().partition("=")
                if k == _COOKIE:
                    cookie = v
            given = q or headers.get("x-workbench-token", "") or cookie
            if not hmac.compare_digest(given.encode(), self.token.encode()):
                return await _send_plain(send, 403, "this workbench needs its token: open the URL it printed")
        if method not in _SAFE:
            origin = headers.get("origin")
            if origin is not None and not self._host_ok(urlsplit(origin).netloc):
                return await _send_plain(send, 403, f"cross-origin request refused (origin {origin})")
        length = headers.get("content-length")
        if length is not None:
            try:
                if int(length) > self.max_body:
                    return await _send_plain(send, 413, f"request body over {self.max_body} bytes")
            except ValueError:
                return await _send_plain(send, 400, "bad content-length")
        # read the whole body first (it is small), counting as it streams: a request without a
        # content-length cannot slip past the bound, and the app never sees a partial body
        body, more = [], True
        seen = 0
        while more and method not in _SAFE:
            msg = await receive()
            if msg["type"] == "http.disconnect":
                return
            chunk = msg.get("body", b"")
            seen += len(chunk)
            if seen > self.max_body:
                return await _send_plain(send, 413, f"request body over {self.max_body} bytes")
            body.append(chunk)
            more = msg.get("more_body", False)
        replay = [{"type": "http.request", "body": b"".join(body), "more_body": False}]

        async def buffered_receive():
            if replay:
                return replay.pop()
            return await receive()

        set_cookie = self.token is not None and headers.get("cookie", "").find(f"{_COOKIE}={self.token}") < 0

        async def send_with_cookie(msg):
            if set_cookie and msg["type"] == "http.response.start":
                msg = dict(msg)
                msg["headers"] = list(msg.get("headers", [])) + [
                    (b"set-cookie", f"{_COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/".encode())]
            await send(msg)

        await self.app(scope, buffered_receive if method not in _SAFE else receive, send_with_cookie)


def create_app(session: Session, *, token: Optional[str] = None,
               allowed_hosts=("127.0.0.1", "localhost", "[::1]"), max_body: int = MAX_BODY,
               sources: Optional[dict] = None):
    """The workbench app for a session.

    Parameters
    ----------
    session : Session
    token : str, optional
        Required on every request when given (serving beyond loopback).
    allowed_hosts : iterable of str
        Host names (optionally ``name:port``) the ``Host`` header may name.
    max_body : int
        Largest request body (bytes).
    sources : dict, optional
        ``{name: callable(frame=None) -> Pair}`` the page may switch to (besides the built-in
        scenes); ``frame`` picks a frame of a source that has several.
    """
    from fastapi import FastAPI, HTTPException, Query, Request
    from fastapi.responses import JSONResponse, Response
    from pydantic import BaseModel, Field, confloat

    from .. import scenes
    from .sources import matcher_available, simulated_pair, source_kinds

    static = _load_static()
    extra_sources = dict(sources or {})
    current = {"key": next(iter(extra_sources), session.pair.name)}
    api = FastAPI(title="optiacoustic workbench", docs_url=None, redoc_url=None, openapi_url=None)
    S = session
    cache: dict = {}
    api.state.cache = cache  # results by state version (read by tests: it must stay bounded)

    Coord = confloat(ge=-1e6, le=1e6, allow_inf_nan=False, strict=True)  # no true or "300" taken as numbers

    class Point(BaseModel):
        u: Coord
        v: Coord

    class MatchIn(BaseModel):
        camera: Point
        sonar: Point

    class MoveIn(BaseModel):
        camera: Optional[Point] = None
        sonar: Optional[Point] = None

    class SigmasIn(BaseModel):
        # lower bounds: 1e-300 passed gt=0 and made every reconstruction divide by zero (a 500)
        pixel: confloat(ge=1e-4, le=1e3, allow_inf_nan=False, strict=True)
        range: confloat(ge=1e-6, le=10, allow_inf_nan=False, strict=True)
        azimuth_deg: confloat(ge=1e-4, le=45, allow_inf_nan=False, strict=True)

    class SourceIn(BaseModel):
        name: str = Field(max_length=200)
        frame: Optional[int] = Field(default=None, ge=0, le=10_000_000)

    class CsvIn(BaseModel):
        text: str = Field(max_length=MAX_BODY)
        name: str = Field(default="upload.csv", max_length=200)

    @api.exception_handler(ValueError)
    async def _value_error(request: Request, exc: ValueError):
        return JSONResponse({"error": str(exc)}, status_code=400)

    from fastapi.exceptions import RequestValidationError

    @api.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError):
        # one message naming each field and the value sent (FastAPI's own 422 echoes the input, and
        # a NaN or Infinity in it cannot be rendered as JSON: it became a 400 naming nothing)
        parts = []
        for e in exc.errors():
            loc = ".".join(str(x) for x in e.get("loc", ())[1:]) or "body"
            got = e.get("input")
            shown = repr(got) if isinstance(got, (int, float, str, bool)) or got is None else type(got).__name__
            parts.append(f"{loc}: {e.get('msg', 'invalid')} (got {shown})")
        return JSONResponse({"error": "; ".join(parts) or "invalid request"}, status_code=422)

    from starlette.exceptions import HTTPException as StarletteHTTPException

    @api.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException):
        # unknown routes (404), wrong methods (405) and our own HTTPExceptions: the one {"error": ...}
        # body every other failure has (FastAPI's default is {"detail": ...})
        return JSONResponse({"error": str(exc.detail)}, status_code=exc.status_code, headers=exc.headers)

    @api.exception_handler(KeyError)
    async def _key_error(request: Request, exc: KeyError):
        return JSONResponse({"error": str(exc.args[0] if exc.args else exc)}, status_code=404)

    from ..matching.ranking import RankModelError

    @api.exception_handler(RankModelError)
    async def _rank_model_error(request: Request, exc: RankModelError):
        # the matcher's candidate trees do not load (a broken install, no libgomp1): the page shows why
        return JSONResponse({"error": f"{exc.filename}: {exc.strerror}"}, status_code=500)

    def no_store(resp):
        resp.headers["cache-control"] = "no-store"
        resp.headers["x-content-type-options"] = "nosniff"
        return resp

    # ------------------------------------------------------------------ page
    @api.get("/")
    def index():
        return no_store(Response(static["index.html"], media_type=STATIC_FILES["index.html"]))

    @api.get("/static/{name}")
    def static_file(name: str):
        if name not in static:
            raise HTTPException(404, "no such file")
        return no_store(Response(static[name], media_type=STATIC_FILES[name]))

    # ------------------------------------------------------------------ state and images
    @api.get("/api/state")
    def state():
        st = S.state()
        kinds = source_kinds()
        st["sources"] = {"scenes": scenes.names(), "extra": list(extra_sources), "current": current["key"],
                         "kinds": {k: {"available": a, "message": m} for k, (a, m) in kinds.items()}}
        st["mappings"] = list(compute.MAPPINGS)
        ok, msg = matcher_available()
        st["matcher"] = {"available": ok, "message": msg}
        return st

    def _image(key, make):
        with S.lock:
            k = (key, S.version if key == "view" else id(S.pair))
            if k not in cache:
                cache.clear() if len(cache) > 16 else None
                cache[k] = make()
            data = cache[k]
        return no_store(Response(data, media_type="image/png"))

    @api.get("/api/image/sonar.png")
    def sonar_png():
        return _image("sonar", lambda: png(fan_rgb8(S.fan)))

    @api.get("/api/image/camera.png")
    def camera_png():
        return _image("camera", lambda: png(S.pair.camera_rgb8))

    # ------------------------------------------------------------------ curves (no state change)
    @api.get("/api/curve")
    def curve(side: str = Query(..., pattern="^(sonar|camera)$"), u: float = Query(..., ge=-1e6, le=1e6),
              v: float = Query(..., ge=-1e6, le=1e6)):
        with S.lock:
            rig, fan, spec = S.rig, S.fan, S.pair.spec
        if side == "sonar":
            r, th = compute.sonar_measurement(fan, spec, u, v)
            return {"side": side, "target": "camera", **compute.camera_curves(rig, r, th)}
        return {"side": side, "target": "sonar", **compute.sonar_curves(rig, fan, u, v)}

    # ------------------------------------------------------------------ matches
    def _xy(p):
        return None if p is None else (p.u, p.v)

    @api.post("/api/matches")
    def add_match(m: MatchIn):
        i = S.add(S.match_from_display(_xy(m.camera), _xy(m.sonar)))
        return {"index": i, "version": S.version}

    @api.put("/api/matches/{i}")
    def move_match(i: int, m: MoveIn):
        S.move(i, _xy(m.camera), _xy(m.sonar))
        return {"index": i, "version": S.version}

    @api.delete("/api/matches/{i}")
    def delete_match(i: int):
        S.delete(i)
        return {"version": S.version}

    @api.post("/api/matches/clear")
    def clear_matches():
        S.replace_all([])
        return {"version": S.version}

    @api.post("/api/matches/suggest")
    def suggest_matches():
        from .session import Match

        with S.lock:
            rows, msg = compute.suggest(S.pair, S.rig, seabed=S.seabed)
            S.replace_all(S.matches + [Match(*row) for row in rows])
        return {"added": len(rows), "message": msg, "version": S.version}

    @api.post("/api/undo")
    def undo():
        return {"undone": S.undo(), "version": S.version}

    @api.post("/api/settings")
    def settings(s: SigmasIn):
        S.set_sigmas(compute.Sigmas(s.pixel, s.range, float(np.deg2rad(s.azimuth_deg))))
        return {"version": S.version}

    # ------------------------------------------------------------------ reconstruction, 3D
    def _drop_old(kind):
        """Forget ``kind``'s results of earlier versions (each edit made one: 2.3 MB per edit, never freed)."""
        for k in list(cache):
            if k[0] == kind and k[-1] != S.version:
                cache.pop(k, None)

    def _recon():
        with S.lock:
            key = ("recon", S.version)
            arrays = S.arrays()
            if key not in cache:
                _drop_old("recon")
                cache[key] = compute.reconstruct(S.rig, *arrays, S.sigmas)
            return cache[key], S.rig, arrays

    @api.get("/api/reconstruction")
    def reconstruction():
        return _recon()[0]

    @api.get("/api/scene3d")
    def scene3d():
        rec, rig, arrays = _recon()
        return compute.scene3d(rig, rec, *arrays)

    # ------------------------------------------------------------------ calibration
    @api.post("/api/calibration/views")
    def add_view_from_matches():
        from ..geometry.calibrate import CalibrationView

        with S.lock:
            if len(S.matches) < 4:
                raise ValueError(f"a calibration view needs at least 4 grid corners matched, there are {len(S.matches)}")
            px, r, th = S.arrays()
            i = S.add_view(CalibrationView(px, r, th))
            S.replace_all([])
        return {"index": i, "version": S.version}

    def _checked(c):
        """A CSV of corners or matches, checked as clicks are: inside the image, the fan and its ranges."""
        from ..geometry.calibrate import check_view

        view = exports.parse_view_csv(c.text, c.name)
        with S.lock:
            check_view(view, S.rig.camera, S.pair.spec, name=c.name or "the CSV")
        return view

    @api.post("/api/calibration/import")
    def import_view(c: CsvIn):
        i = S.add_view(_checked(c))
        return {"index": i, "n": int(S.views[i].n), "version": S.version}

    @api.delete("/api/calibration/views/{i}")
    def delete_view(i: int):
        S.delete_view(i)
        return {"version": S.version}

    @api.post("/api/calibration/run")
    def run_calibration():
        return S.run_calibration()

    @api.post("/api/calibration/apply")
    def apply_calibration():
        S.apply_calibration()
        return {"version": S.version, "rig": S.state()["rig"]}

    @api.post("/api/rig/reset")
    def reset_rig():
        S.set_rig(S.pair.rig)
        return {"version": S.version}

    # ------------------------------------------------------------------ fusion
    @api.get("/api/fusion.png")
    def fusion(mapping: str = Query("rbf", pattern="^(rbf|rbf-smoothed|plane|piecewise)$")):
        with S.lock:
            key = ("fusion", mapping, S.version)
            hit = cache.get(key)
            rig, fan_small, (px, r, th) = S.rig, S.fan_small, S.arrays()
        if hit is None:  # seconds of work: outside the lock, so that curves keep coming
            echo, msg = compute.fusion_layer(mapping, rig, fan_small, r, th, px)
            _drop_old("fusion")
            hit = cache[key] = (png(rgba_layer(echo)), msg)
        data, msg = hit
        resp = Response(data, media_type="image/png")
        resp.headers["x-mapping"] = msg
        return no_store(resp)

    # ------------------------------------------------------------------ export / import
    @api.get("/api/export/matches.csv")
    def export_csv():
        with S.lock:
            text = exports.matches_csv(S.matches, header=f"optiacoustic workbench matches: {S.pair.name}\n"
                                       f"u, v: camera pixels; range (m) and azimuth (deg) in the sonar")
        return no_store(Response(text, media_type="text/csv",
                                 headers={"content-disposition": 'attachment; filename="matches.csv"'}))

    @api.post("/api/import/matches")
    def import_csv(c: CsvIn):
        from .session import Match

        view = _checked(c)
        S.replace_all([Match(float(u), float(v), float(r), float(a))
                       for (u, v), r, a in zip(view.pixels, view.ranges, view.azimuths)])
        return {"n": int(view.n), "version": S.version}

    @api.get("/api/export/points.ply")
    def export_ply():
        rec = _recon()[0]
        pts = [p["point_sonar"] for p in rec["points"] if p["valid"]]
        return no_store(Response(exports.points_ply(np.array(pts, float)), media_type="application/octet-stream",
                                 headers={"content-disposition": 'attachment; filename="points.ply"'}))

    @api.get("/api/export/view.png")
    def export_view():
        def make():
            px, r, th = S.arrays()
            cam_curves = [compute.camera_curves(S.rig, a, b, n_samples=121) for a, b in zip(r, th)]
            fan_curves = [compute.sonar_curves(S.rig, S.fan, *p, n_samples=120) for p in px]
            fp = compute.fan_pixels(S.fan, r, th) if len(r) else np.zeros((0, 2))
            return exports.view_png(fan_rgb8(S.fan), S.pair.camera_rgb8, fp, px, cam_curves, fan_curves)

        resp = _image("view", make)
        resp.headers["content-disposition"] = 'attachment; filename="workbench_view.png"'
        return resp

    # ------------------------------------------------------------------ sources
    @api.post("/api/source")
    def set_source(s: SourceIn):
        if s.name in extra_sources:
            pair = extra_sources[s.name](s.frame) if s.frame is not None else extra_sources[s.name]()
        elif s.frame is not None:
            raise ValueError(f"source {s.name!r} has one frame")
        elif s.name in scenes.names():
            pair = simulated_pair(scenes.get(s.name), S.pair.rig)
        else:
            raise ValueError(f"source {s.name!r}: expected one of {sorted(extra_sources) + scenes.names()}")
        if s.frame is not None and not 0 <= s.frame < pair.n_frames:  # (a source that ignores the frame asked)
            raise ValueError(f"source {s.name!r} has {pair.n_frames} frame(s); there is no frame {s.frame}")
        S.set_pair(pair, same_source=s.name == current["key"] and s.frame is not None)
        current["key"] = s.name
        cache.clear()
        return {"version": S.version}

    return Guard(api, allowed_hosts=allowed_hosts, token=token, max_body=max_body)
