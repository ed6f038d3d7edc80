"""What leaves and enters the workbench as files: matches CSV, points PLY, the view PNG.

* Matches: the CSV :func:`optiacoustic.geometry.calibrate.load_view` reads (and so
  ``oas calibrate``): ``u,v,range,azimuth_deg``, ``#`` comment lines. Imports go through
  that same reader.
* Points: PLY (binary, via trimesh) of the maximum-likelihood points in the sonar frame (m).
* View: a PNG of the fan and the camera image side by side with the matches and their curves.

Nothing here opens a path that came from a request: an import is written to a fresh
temporary folder under a fixed name and read back with the library's reader.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

__all__ = ["matches_csv", "parse_view_csv", "points_ply", "view_png"]


def matches_csv(matches, *, header: str = "") -> str:
    """Matches as the calibration-view CSV (azimuth in degrees)."""
    lines = [f"# {h}" for h in header.splitlines()] if header else []
    lines.append("u,v,range,azimuth_deg")
    lines += [f"{m.u:.6f},{m.v:.6f},{m.range:.6f},{np.rad2deg(m.azimuth):.6f}" for m in matches]
    return "\n".join(lines) + "\n"


def parse_view_csv(text: str, name: str = "upload.csv"):
    """A :class:`~optiacoustic.geometry.calibrate.CalibrationView` from CSV text (the library's reader)."""
    from .._atomic import write_text
    from ..geometry.calibrate import load_view

    with tempfile.TemporaryDirectory(prefix="oas-workbench-") as d:
        p = Path(d) / "view.csv"
        write_text(p, text)
        try:
            return load_view(p)
        except ValueError as exc:
            raise ValueError(str(exc).replace(str(p), name)) from None


def points_ply(points_sonar) -> bytes:
    """Binary PLY of ``(N, 3)`` sonar-frame points (m)."""
    import trimesh

    P = np.asarray(points_sonar, float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) == 0:
        raise ValueError("no reconstructed points to export")
    return trimesh.PointCloud(P).export(file_type="ply")


def view_png(fan_rgb, camera_rgb, fan_points, camera_points, camera_curves, fan_curves) -> bytes:
    """The fan and the camera image side by side with matches (numbered) and their curves.

    ``camera_curves`` / ``fan_curves``: per match a dict with ``solid`` and ``dashed`` polylines
    in that image's pixels.
    """
    import cv2

    from .images import png

    def draw(img, pts, curves, scale):
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
        for k, c in enumerate(curves):
            col = _color(k)
            for line in c.get("dashed", []):
                a = (np.asarray(line) * scale).astype(np.int32)
                for j in range(0, len(a) - 1, 4):
                    cv2.polylines(img, [a[j:j + 3]], False, col, 1, cv2.LINE_AA)
            for line in c.get("solid", []):
                cv2.polylines(img, [(np.asarray(line) * scale).astype(np.int32)], False, col, 2, cv2.LINE_AA)
        for k, p in enumerate(pts):
            q = tuple(int(round(x * scale)) for x in p)
            cv2.circle(img, q, 6, _color(k), 2, cv2.LINE_AA)
            cv2.putText(img, str(k + 1), (q[0] + 8, q[1] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1,
                        cv2.LINE_AA)
        return img

    h = max(camera_rgb.shape[0], 400)
    left = draw(np.ascontiguousarray(fan_rgb), fan_points, fan_curves, h / fan_rgb.shape[0])
    right = draw(np.ascontiguousarray(camera_rgb), camera_points, camera_curves, h / camera_rgb.shape[0])
    gap = np.full((h, 8, 3), 255, np.uint8)
    return png(np.concatenate([left, gap, right], axis=1))


_PALETTE = [(230, 25, 75), (60, 180, 75), (255, 225, 25), (0, 130, 200), (245, 130, 48), (145, 30, 180),
            (70, 240, 240), (240, 50, 230), (210, 245, 60), (250, 190, 212)]


def _color(k: int):
    return _PALETTE[k % len(_PALETTE)]
