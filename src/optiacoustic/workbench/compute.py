"""The workbench's answers, each one library call away: curves, distances, 3D points, calibration, fusion.

Every function takes measurements and a :class:`~optiacoustic.rig.Rig` and returns plain
JSON-ready values (lists of floats), in the coordinates the page draws in: camera image
pixels, and sonar fan-image pixels (the :class:`~optiacoustic.sonar.frame.FanImage` grid the
page shows). No geometry is computed here that the library does not compute: the curves are
:func:`~optiacoustic.geometry.epipolar.sonar_to_optical_curves` and
:func:`~optiacoustic.geometry.epipolar.optical_to_sonar_curves`, the distances
:func:`~optiacoustic.geometry.epipolar.sampson_distance` and the ML cost of
:func:`~optiacoustic.geometry.reconstruct.refine`, the uncertainty
:func:`~optiacoustic.geometry.reconstruct.crlb`, the calibration
:func:`~optiacoustic.geometry.calibrate.extrinsics`, the overlay
:func:`~optiacoustic.fusion.map_fan` through the chapter-7 mappings.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..frames import fan_from_polar, polar_from_fan, sonar_from_spherical
from ..geometry import epipolar as ep
from ..geometry import projection as pr
from ..geometry import reconstruct as rc
from ..rig import Rig

__all__ = ["Sigmas", "sonar_measurement", "fan_pixels", "camera_curves", "sonar_curves", "reconstruct",
           "scene3d", "calibrate", "fusion_layer", "MAPPINGS"]

#: Chapter-7 mappings offered by the fusion overlay.
MAPPINGS = ("rbf", "rbf-smoothed", "plane", "piecewise")


@dataclass(frozen=True)
class Sigmas:
    """Measurement noise: pixel (px), range (m), azimuth (rad)."""

    pixel: float
    range: float
    azimuth: float

    def kwargs(self) -> dict:
        return dict(sigma_pixel=self.pixel, sigma_range=self.range, sigma_azimuth=self.azimuth)


def _poly(a, nd: int = 3) -> list:
    return np.round(np.asarray(a, float), nd).tolist()


def sonar_measurement(fan, spec, u, v) -> tuple[float, float]:
    """``(range, azimuth)`` (m, rad) of a fan-image pixel; ValueError outside the fan."""
    x, y = fan.from_pixel(u, v)
    r, th = (float(a) for a in polar_from_fan(x, y))
    if not (spec.range_min <= r <= spec.range_max and abs(th) <= spec.fov_azimuth / 2):
        raise ValueError(f"sonar point ({u:.1f}, {v:.1f}) px is outside the fan (range {r:.3f} m, "
                         f"azimuth {np.rad2deg(th):.2f} deg)")
    return r, th


def fan_pixels(fan, ranges, azimuths) -> np.ndarray:
    """Fan-image pixels ``(..., 2)`` of sonar measurements."""
    x, y = fan_from_polar(ranges, azimuths)
    u, v = fan.to_pixel(x, y)
    return np.stack([u, v], -1)


def camera_curves(rig: Rig, r: float, th: float, *, n_samples: int = 241) -> dict:
    """The epipolar curve of a sonar point ``(r, theta)`` in the camera image.

    ``solid``: the arc inside the sonar's elevation aperture; ``dashed``: the whole arc
    ``|phi| <= 90 deg`` (drawn under the solid one, it shows the part outside the aperture).
    Both are polylines of image pixels on the conic ``m^T C m = 0``, which is returned too.
    """
    solid = ep.sonar_to_optical_curves(rig, r, th, n_samples=n_samples)[0]
    # the whole arc spans 180 deg of elevation against the aperture's ~20: sample it finer
    full = ep.sonar_to_optical_curves(rig, r, th, n_samples=4 * n_samples, clip_elevation=False)[0]
    C = ep.conic(rig, r, th)
    return {"solid": [_poly(p) for p in solid], "dashed": [_poly(p) for p in full],
            "conic": (C / np.linalg.norm(C)).tolist(), "conic_type": str(ep.conic_type(C)),
            "range": r, "azimuth_deg": float(np.rad2deg(th))}


def sonar_curves(rig: Rig, fan, u: float, v: float, *, n_samples: int = 240) -> dict:
    """The epipolar curve of a camera pixel in the sonar fan (fan-image pixels).

    ``solid``: the viewing ray's points inside the elevation aperture; ``dashed``: inside
    the fan at any elevation.
    """
    def to_px(runs):
        return [_poly(np.stack(fan.to_pixel(p[:, 0], p[:, 1]), -1)) for p in runs]

    solid = ep.optical_to_sonar_curves(rig, [u, v], n_samples=n_samples, coords="fan")[0]
    full = ep.optical_to_sonar_curves(rig, [u, v], n_samples=n_samples, coords="fan", clip_elevation=False)[0]
    return {"solid": to_px(solid), "dashed": to_px(full)}


def reconstruct(rig: Rig, pixels, ranges, azimuths, sig: Sigmas) -> dict:
    """Maximum-likelihood points of matches with their Cramer-Rao bounds, and each match's distances.

    Returns
    -------
    dict
        Per match: ``distance_px`` (Sampson distance of the pixel from the sonar point's
        conic, px), ``distance_sigma`` (square root of the ML cost: the Mahalanobis distance
        of the four measurements from the epipolar constraint, in standard deviations),
        ``point_sonar`` (m), ``std_sonar`` (CRLB standard deviations along the sonar's
        X, Y, Z, m), ``axes_sonar`` (3-sigma axes of the CRLB ellipsoid, (3, 3) m) and
        ``valid``; and a ``message``.
    """
    px = np.asarray(pixels, float).reshape(-1, 2)
    n = len(px)
    out = {"n": n, "points": [], "message": "no matches"}
    if n == 0:
        return out
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    d_px = ep.sampson_distance(ep.conic(rig, r, th), pr.ideal_pixels(rig, px))
    ref = rc.refine(rig, px, r, th, **sig.kwargs())
    P = np.where(ref.valid[:, None], ref.points, np.nan)
    cov = rc.crlb(rig, np.where(ref.valid[:, None], P, [0.0, 0.0, 1.0]), **sig.kwargs())
    Ps = rig.sonar_from_camera(P)
    cov_s = rig.R @ cov @ rig.R.T
    lam, vec = np.linalg.eigh(cov_s)
    axes = 3 * np.sqrt(np.maximum(lam, 0))[:, None, :] * vec  # columns scaled
    for i in range(n):
        ok = bool(ref.valid[i])
        out["points"].append({
            "valid": ok,
            "status": rc.STATUS[int(ref.status[i])],
            "distance_px": None if not np.isfinite(d_px[i]) else float(d_px[i]),
            "distance_sigma": float(np.sqrt(ref.cost[i])) if ok and np.isfinite(ref.cost[i]) else None,
            "point_sonar": _poly(Ps[i], 5) if ok else None,
            "point_camera": _poly(P[i], 5) if ok else None,
            "std_sonar": _poly(np.sqrt(np.diag(cov_s[i])), 5) if ok else None,
            "axes_sonar": _poly(axes[i].T, 5) if ok else None,
        })
    out["message"] = ref.message
    return out


def _fan_wireframe(spec, n: int = 33) -> list:
    """Edges of the sonar's field of view (sonar frame, m): range arcs and azimuth edges."""
    ha, he = spec.fov_azimuth / 2, spec.fov_elevation / 2
    th = np.linspace(-ha, ha, n)
    lines = []
    for rr in (spec.range_min, spec.range_max):
        for ph in (-he, 0.0, he):
            lines.append(sonar_from_spherical(rr, th, ph))
    ph = np.linspace(-he, he, 9)
    for t in (-ha, ha):
        for rr in (spec.range_min, spec.range_max):
            lines.append(sonar_from_spherical(rr, t, ph))
        for p in (-he, 0.0, he):
            lines.append(sonar_from_spherical(np.array([spec.range_min, spec.range_max]), t, p))
    return [_poly(line) for line in lines]


def _frustum(rig: Rig, depth: float) -> list:
    """Camera frustum to ``depth`` (m, camera Z) in the sonar frame: four edges and the far rectangle."""
    c = rig.camera
    corners = np.array([[-0.5, -0.5], [c.width - 0.5, -0.5], [c.width - 0.5, c.height - 0.5], [-0.5, c.height - 0.5]])
    far = rig.sonar_from_camera(pr.camera_from_pixels(rig, corners, depth))
    o = rig.t
    lines = [[o, f] for f in far] + [np.vstack([far, far[:1]])]
    return [_poly(np.asarray(line)) for line in lines]


def _match_geometry(rig: Rig, pixels, ranges, azimuths, depth: float) -> list:
    """Per match, what each sensor alone knows (sonar frame, m): the sonar's elevation arc
    ``(r, theta, |phi| <= fov/2)`` and the camera's viewing ray to ``depth``; the point is where they meet."""
    he = rig.fov_elevation / 2
    ph = np.linspace(-he, he, 17)
    rays = pr.pixel_rays_in_sonar(rig, np.asarray(pixels, float).reshape(-1, 2))
    out = []
    for k, (r, th) in enumerate(zip(ranges, azimuths)):
        arc = sonar_from_spherical(r, th, ph)
        ray = np.stack([rays.origin, rays.at_depth(depth)[k]])
        out.append({"index": k, "arc": _poly(arc), "ray": _poly(ray)})
    return out


def scene3d(rig: Rig, recon: dict, pixels=(), ranges=(), azimuths=()) -> dict:
    """What the 3D view draws, in the sonar frame (m): the fan, the camera frustum, the points,
    and per match the sonar's elevation arc and the camera's ray."""
    spec = rig.sonar
    pts = [p for p in recon.get("points", []) if p["valid"]]
    depth = float(np.median([p["point_camera"][2] for p in pts])) if pts else 0.5 * float(spec.range_max)
    far = 1.25 * max([p["point_camera"][2] for p in pts], default=depth)
    return {"frame": "sonar: X right, Y forward, Z up (m)", "fan": _fan_wireframe(spec),
            "range_max": float(spec.range_max),
            "frustum": _frustum(rig, max(depth, 0.5)), "camera_centre": _poly(rig.t),
            "points": [{"index": i, "p": p["point_sonar"], "axes": p["axes_sonar"]}
                       for i, p in enumerate(recon.get("points", [])) if p["valid"]],
            "matches": _match_geometry(rig, pixels, ranges, azimuths, max(far, 0.5)) if len(ranges) else []}


def calibrate(rig: Rig, views, sig: Sigmas) -> tuple[object, dict]:
    """Appendix-A extrinsics from grid views, with the observability report."""
    from ..geometry.calibrate import extrinsics

    res = extrinsics(rig.camera, views, sonar=rig.sonar, **sig.kwargs())
    d = res.to_dict()
    report = {"success": bool(res), "message": res.message, "n_views": len(views)}
    if res:
        report.update({
            "R": _poly(res.R, 9), "t": _poly(res.t, 6),
            "rotation_about_sonar_xyz_deg": _poly(d["rotation_about_sonar_xyz_deg"], 4),
            "std": {k: round(v, 4) for k, v in d["std_deg_or_mm"].items()},
            "std_units": "pitch, roll, yaw in deg; t_x, t_y, t_z in mm",
            "weak": d["weak"], "eigenvalues": d["eigenvalues"],
            "rms_pixel": d["rms_pixel"], "rms_range_mm": 1e3 * d["rms_range"], "rms_azimuth_deg": d["rms_azimuth_deg"],
            "chi2": d["chi2"], "dof": d["dof"],
        })
    return res, report


def _mapping(kind: str, rig: Rig, xy: np.ndarray, px: np.ndarray, pixel_size: float):
    from ..fusion import PiecewisePlanarMapping, PlaneMapping, RBFMapping, cross_validate

    if kind == "plane":
        return PlaneMapping.fit(rig, xy, px)
    if kind == "piecewise":
        return PiecewisePlanarMapping.fit(rig, xy, px)
    sigmas = np.geomspace(20 * pixel_size, 2000 * pixel_size, 7)
    if kind == "rbf":
        cv = cross_validate(xy, px, sigmas=sigmas, base="none")
        return RBFMapping.fit(xy, px, sigma=cv.best_sigma)
    if kind == "rbf-smoothed":
        cv = cross_validate(xy, px, sigmas=sigmas, smoothings=np.concatenate([[0.0], np.logspace(-6, 1, 5)]),
                            base="homography")
        return RBFMapping.fit(xy, px, sigma=cv.best_sigma, smoothing=cv.best_smoothing, base="homography")
    raise ValueError(f"mapping: expected one of {list(MAPPINGS)}, got {kind!r}")


def fusion_layer(kind: str, rig: Rig, fan_small, ranges, azimuths, pixels) -> tuple[np.ndarray, str]:
    """The sonar fan mapped into the camera image through a chapter-7 mapping fitted to the matches.

    Parameters
    ----------
    kind : one of :data:`MAPPINGS`
    fan_small : FanImage
        The display fan (data in [0, 1]) at the resolution to map.
    ranges, azimuths, pixels : the matches.

    Returns
    -------
    echo : ndarray (H, W) float32
        The mapped echo in [0, 1], NaN where nothing maps.
    message : str
    """
    from ..fusion import map_fan

    x, y = fan_from_polar(np.asarray(ranges, float), np.asarray(azimuths, float))
    xy = np.stack([x, y], -1)
    px = np.asarray(pixels, float).reshape(-1, 2)
    need = 4 if kind == "rbf-smoothed" else 3
    if len(xy) < need:
        raise ValueError(f"the {kind} mapping needs at least {need} matches, there are {len(xy)}")
    m = _mapping(kind, rig, xy, px, fan_small.pixel_size)
    cam = rig.camera
    # map only the part of the fan near the matches: learned mappings are trusted only there, and
    # the interpolation behind map_fan (a Delaunay triangulation of the mapped fan pixels) grows
    # with the number of fan pixels
    maxd = 0.5 * float(np.max(np.ptp(xy, axis=0))) + 1.0
    echo = map_fan(fan_small, m, (cam.height, cam.width), max_distance=maxd, centres=xy)
    desc = {"rbf": "Gaussian RBF (exact, width by leave-one-out)",
            "rbf-smoothed": "Gaussian RBF on a homography (smoothed, by leave-one-out)",
            "plane": "plane through the rig (least-squares plane of the reconstructed matches)",
            "piecewise": "piecewise planar through the rig (Delaunay triangles of the matches)"}[kind]
    sig = getattr(m, "sigma", None)
    return echo, desc + (f", sigma = {sig:.3g} m" if sig is not None else "")


def suggest(pair, rig: Rig, seabed=None) -> tuple[list, str]:
    """Matches proposed by the automatic matcher, as ``(u, v, range, azimuth)`` rows, and its message.
    ``seabed``: a ``SeabedPlane`` from the navigation (``oas workbench --seabed-altitude``), which a
    soft-beam frame (every real one) needs; ``None``: the matcher fits it to the sonar image."""
    from .sources import matcher_available

    ok, msg = matcher_available()
    if not ok:
        raise ValueError(msg)
    from ..matching import match

    cam = pair.camera_linear if pair.camera_linear is not None else pair.camera_rgb8
    m = match(pair.sonar_frame(), cam, rig, seabed=seabed)
    rows = [(float(u), float(v), float(r), float(a)) for (u, v), r, a in zip(m.pixels, m.ranges, m.azimuths)]
    return rows, m.message or f"{len(rows)} matches"
