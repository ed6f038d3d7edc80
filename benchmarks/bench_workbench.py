"""Speed of the workbench's answers: a click's epipolar curve over HTTP against the library call alone.

The server is the real one (uvicorn on a loopback port, in a thread of this process) and the
client a keep-alive ``httpx.Client``, so a round trip includes HTTP parsing, validation, the
library calls, JSON encoding and the socket. The reference, timed in the same run, is the
library call the server makes for that click: ``sonar_to_optical_curves`` (inside the
elevation aperture and the whole arc) for a sonar click, ``optical_to_sonar_curves`` (both)
for a camera click. The issue's target is a curve in at most 100 ms.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from _timing import median_ms

TITLE = "Workbench (issue 12)"
DESCRIPTION = ("A click's epipolar curve from the workbench server (HTTP round trip on loopback) against the "
               "library calls behind it, timed in the same run; the target is 100 ms per curve.")


def run() -> list[dict]:
    import httpx
    import uvicorn

    from optiacoustic.geometry import epipolar as ep
    from optiacoustic.workbench import Session, compute, create_app, default_pair
    from optiacoustic.workbench.server import allowed_hosts, free_port

    session = Session(default_pair())
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_app(session, allowed_hosts=allowed_hosts("127.0.0.1", port)),
                                           host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=server.run, daemon=True)
    th.start()
    while not server.started:
        time.sleep(0.02)
    rig, fan = session.rig, session.fan
    r, az = 6.0, np.deg2rad(3.0)
    su, sv = compute.fan_pixels(fan, r, az)
    rows = []
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}") as c:
            def sonar_click():
                resp = c.get("/api/curve", params={"side": "sonar", "u": su, "v": sv})
                resp.raise_for_status()
                return resp.json()

            def camera_click():
                resp = c.get("/api/curve", params={"side": "camera", "u": 310.0, "v": 210.0})
                resp.raise_for_status()
                return resp.json()

            def lib_sonar():
                ep.sonar_to_optical_curves(rig, r, az, n_samples=241)
                ep.sonar_to_optical_curves(rig, r, az, n_samples=4 * 241, clip_elevation=False)

            def lib_camera():
                ep.optical_to_sonar_curves(rig, [310.0, 210.0], n_samples=240, coords="fan")
                ep.optical_to_sonar_curves(rig, [310.0, 210.0], n_samples=240, coords="fan", clip_elevation=False)

            for name, http, lib in (("sonar click -> conic in the camera", sonar_click, lib_sonar),
                                    ("camera click -> curve in the fan", camera_click, lib_camera)):
                t_lib = median_ms(lib, repeat=30, warmup=3)
                t_http = median_ms(http, repeat=30, warmup=3)
                rows.append(dict(name=f"{name}: library calls alone", value=t_lib, unit="ms", reference="itself",
                                 ratio=1.0, note="the epipolar functions the server calls for one click"))
                rows.append(dict(name=f"{name}: HTTP round trip", value=t_http, unit="ms",
                                 reference="library calls alone", ratio=t_http / t_lib,
                                 note=f"target <= 100 ms: {'met' if t_http <= 100 else 'NOT met'}"))
    finally:
        server.should_exit = True
        th.join(10)
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
