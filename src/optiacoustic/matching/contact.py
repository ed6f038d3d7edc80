"""Where along a vertical face an echo comes from: the face's foot on the seabed (a prior).

Boxes' sides, standing cylinders, walls and pilings stand vertically on the seabed. For such a
face the sonar feature ``(r, theta)`` fixes its elevation through the face's *foot*: the arc
point ``X(phi) = r (cos phi sin theta, cos phi cos theta, sin phi)`` (sonar frame) dropped along
the seabed's normal onto the seabed plane the sonar itself measured (:mod:`.acoustic`) is
``F(phi) = X(phi) - h(phi) n``. When ``X(phi)`` lies on a vertical face, ``F(phi)`` lies on the
face's contact line with the seabed, so in the camera image

- the pixel ``q(phi)`` of ``F(phi)`` is on an edge (the object's boundary with the seabed), and
- the segment from ``q(phi)`` up to ``p(phi)``, the pixel of ``X(phi)``, runs up the face
  without crossing an edge.

For ``phi`` below the true elevation ``F`` lies on the open seabed in front of the face (no
edge at ``q``); above it, ``F`` is hidden behind the object and ``q`` falls on the face. The
search takes the lowest elevation inside the acoustic interval where both conditions hold: the
foot of the nearest face. The camera's height above the seabed makes ``q`` move down the image
as ``F`` comes nearer, so the lowest such elevation is the first face the arc meets.

The prior fails on spheres, lying cylinders and tilted faces: there the segment usually crosses
an edge or the foot is not on one, and no elevation is returned (the caller falls back on
:mod:`.arc_search`); where it returns a wrong one, the score (:mod:`.match`) is what separates
them. Vectorised over (feature, elevation sample, segment sample).

This lever is weak, measured on the training scenes: at the rig's 18 deg grazing view the foot
moves about 0.5-1 px in the image per range bin of the echo, so the foot's edge must be found to
under a pixel and the seabed plane known to a few millimetres (lowering or raising the plane by
1 cm took the foot search's precision from 0.60 to 0.45 and 0.24). The match therefore does not
take this pixel; it uses its agreement with the arc search's as evidence in the score.

:func:`crease_points` uses the same prior from the top: seen from a sonar above it, a vertical
face's nearest point in a beam is its top edge (the crease with the top face, a cylinder's rim),
so the echo's onset in the feature's beam, ``r_on``, is the crease's range, and the upper end of
the arc search's edge-free run is the crease in the image. The crease is the point of that
pixel's ray at sonar range ``r_on`` (the ray runs nearly along the sonar's range direction: well
conditioned), and the feature's own point is below it on the face, ``X = C - t n`` with
``|X| = r``. An error of one bin in ``r_on`` moves the answer by about one bin in range (the face's
range changes by 0.3 m per metre of height at this view): well conditioned, unlike the foot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ContactChoice", "CreaseChoice", "FootChoice", "crease_points", "crease_positions", "echo_end_ranges",
           "echo_start_ranges", "foot_edges", "foot_points", "search_contacts"]


@dataclass(frozen=True, eq=False)
class ContactChoice:
    """The pixel each sonar feature's foot search chose.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        Pixel ``(u, v)`` of the arc point over the face's foot; NaN where none was found.
    elevations : ndarray, shape (N,)
        Its elevation (rad, sonar frame).
    heights : ndarray, shape (N,)
        Height (m) of that arc point above the seabed plane.
    foot_edge : ndarray, shape (N,)
        Gradient at the foot's pixel (gray levels per px).
    segment_px : ndarray, shape (N,)
        Length (px) of the image segment from the foot up to the point.
    n_candidates : ndarray, shape (N,)
        Elevations (separate runs of samples) inside the interval where both conditions hold.
    found : ndarray of bool, shape (N,)
    """

    pixels: np.ndarray
    elevations: np.ndarray
    heights: np.ndarray
    foot_edge: np.ndarray
    segment_px: np.ndarray
    n_candidates: np.ndarray
    found: np.ndarray


def search_contacts(rig, seabed, ranges, azimuths, low, high, gradient, *, threshold: float = 3.0,
                    edge_threshold: float = 6.0, min_height: float = 0.05, min_segment_px: float = 8.0,
                    margin: float = float(np.deg2rad(0.25)), n_samples: int = 400,
                    n_segment: int = 16) -> ContactChoice:
    """For every sonar feature, the arc point whose foot on the seabed sits on an image edge below an edge-free face.

    Parameters
    ----------
    rig : Rig
        With the sonar attached.
    seabed : SeabedPlane
        The seabed in the sonar frame (:func:`.acoustic.fit_seabed`).
    ranges, azimuths : array_like, shape (N,)
        Sonar features (m, rad).
    low, high : array_like, shape (N,)
        Elevation interval of each feature (rad), widened by ``margin`` each side.
    gradient : ndarray, shape (H, W)
        :func:`.arc_search.gradient_image` of the camera image.
    threshold : float
        Gradient below which a segment pixel is edge-free (gray levels per px).
    edge_threshold : float
        Gradient (largest within 2 px of the foot's pixel) above which the foot is on an edge.
    min_height : float
        Lowest height (m) above the seabed plane of a point on a face.
    min_segment_px : float
        Shortest segment (px) from the foot to the point.
    n_samples, n_segment : int
        Elevation samples across the aperture; samples along each segment.

    Returns
    -------
    ContactChoice
    """
    import cv2

    from ..frames import sonar_from_spherical

    r = np.asarray(ranges, float).reshape(-1)
    th = np.asarray(azimuths, float).reshape(-1)
    N = r.size
    nan = np.full(N, np.nan)
    if N == 0 or not seabed:
        return ContactChoice(np.full((N, 2), np.nan), nan, nan, nan, nan, np.zeros(N, int), np.zeros(N, bool))
    half = rig.fov_elevation / 2
    phis = np.linspace(-half, half, n_samples)
    X = sonar_from_spherical(r[:, None], th[:, None], phis[None, :])  # (N, n, 3) sonar frame
    n_up = np.asarray(seabed.normal, float)
    h = seabed.height(X)  # (N, n)
    F = X - h[..., None] * n_up
    cam = rig.camera
    Pc = rig.camera_from_sonar(X)
    Fc = rig.camera_from_sonar(F)
    p = cam.project(Pc)
    q = cam.project(Fc)
    ok = (Pc[..., 2] > 0) & (Fc[..., 2] > 0) & cam.in_image(p) & cam.in_image(q) & (h >= min_height)
    lo = np.asarray(low, float).reshape(-1)[:, None] - margin
    hi = np.asarray(high, float).reshape(-1)[:, None] + margin
    ok &= (phis[None, :] >= lo) & (phis[None, :] <= hi)
    from .arc_search import pixel_values

    g_max = cv2.dilate(gradient.astype(np.float32), np.ones((5, 5), np.uint8))
    edge = pixel_values(g_max, q)  # (N, n)
    d = np.nan_to_num(p - q)
    L = np.linalg.norm(d, axis=-1)
    ok &= (L >= min_segment_px) & (edge >= edge_threshold)
    # Segment from 3 px above the foot to 2 px below the point (both ends are edges on a face).
    t = np.linspace(0.0, 1.0, n_segment)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = 3.0 / np.maximum(L, 1e-9)
        b = 1.0 - 2.0 / np.maximum(L, 1e-9)
    s = a[..., None] + (b - a)[..., None] * t  # (N, n, m)
    seg = q[..., None, :] + s[..., None] * d[..., None, :]
    flat = np.all(pixel_values(gradient, seg) < threshold, axis=-1)
    cand = ok & flat
    # Separate runs of candidate samples: each is one elevation hypothesis.
    starts = cand & ~np.concatenate([np.zeros((N, 1), bool), cand[:, :-1]], axis=1)
    n_cand = starts.sum(1)
    found = n_cand > 0
    first = np.argmax(starts, axis=1)
    # Within the first run, the sample whose foot sits on the strongest edge.
    idx = np.arange(n_samples)[None, :]
    run_end = np.where(~cand & (idx > first[:, None]), idx, n_samples).min(1)
    in_run = (idx >= first[:, None]) & (idx < run_end[:, None])
    # The edge's centre: the largest (bilinear) gradient at the foot's pixel within the run.
    from scipy.ndimage import map_coordinates

    g_q = map_coordinates(gradient.astype(np.float32), [np.nan_to_num(q[..., 1]).ravel(),
                                                        np.nan_to_num(q[..., 0]).ravel()],
                          order=1, mode="nearest").reshape(edge.shape)
    k = np.argmax(np.where(in_run, g_q, -np.inf), axis=1)
    rows = np.arange(N)
    px = np.where(found[:, None], p[rows, k], np.nan)
    return ContactChoice(px, np.where(found, phis[k], np.nan), np.where(found, h[rows, k], np.nan),
                         np.where(found, edge[rows, k], np.nan), np.where(found, L[rows, k], np.nan),
                         n_cand, found)


@dataclass(frozen=True, eq=False)
class CreaseChoice:
    """The arc point below each feature's crease on a vertical face (:func:`crease_points`).

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        Its pixel ``(u, v)``; NaN where not found.
    elevations : ndarray, shape (N,)
        Its elevation (rad, sonar frame).
    drop : ndarray, shape (N,)
        How far (m) below the crease it is along the seabed's normal.
    found : ndarray of bool, shape (N,)
        The point exists and its elevation lies inside the arc search's run.
    """

    pixels: np.ndarray
    elevations: np.ndarray
    drop: np.ndarray
    found: np.ndarray


#: Echo level (3 x 3 mean over the CFAR background) above which a cell belongs to an echo when looking
#: for its start (the crease of a face seen from above).
ECHO_START_FACTOR = 3.0


def echo_start_ranges(image, ranges, bins, beams, *, factor: float = ECHO_START_FACTOR, maps=None) -> np.ndarray:
    """Range (m) where the echo containing each cell ``(bins[i], beams[i])`` starts along its beam.

    A cell is part of an echo when its 3 x 3 mean exceeds ``factor`` times its CFAR background
    (:func:`.sonar_features.cfar_map`); the start is the first cell of the unbroken run of such
    cells that ends at or beyond the feature, walking back toward the sonar (the cell's own range
    when it is not part of an echo). Shape (N,). ``maps``: ``cfar_map(image)`` when the caller has it
    (the same numbers; computed here otherwise).
    """
    from .sonar_features import cfar_map, given_maps

    img = np.asarray(image, float)
    r = np.asarray(ranges, float)
    maps = given_maps(maps, img.shape, "echo_start_ranges")
    smooth, background = cfar_map(img) if maps is None else maps
    echo = smooth > factor * background
    idx = np.arange(img.shape[0])[:, None]
    last_quiet = np.maximum.accumulate(np.where(~echo, idx, -1), axis=0)
    b = np.asarray(bins, int)
    start = np.minimum(last_quiet[b, np.asarray(beams, int)] + 1, b)  # a quiet cell starts where it is
    return r[start]


def crease_positions(rig, top_pixels, onset_ranges):
    """Sonar-frame points (m) at sonar range ``onset_ranges`` on the rays of ``top_pixels`` ``(N, 2)``.

    The far root of ``|o + Z d| = r_on`` (``o`` the camera's centre, ``d`` the pixel's unit ray, both
    in the sonar frame). Returns ``(C (N, 3), ok (N,))``; ``ok`` is False where the pixel is NaN or
    the ray never reaches that range in front of the camera.
    """
    top = np.asarray(top_pixels, float).reshape(-1, 2)
    r_on = np.asarray(onset_ranges, float).reshape(-1)
    good = np.all(np.isfinite(top), axis=1)
    rays = rig.camera.pixel_rays(np.where(good[:, None], top, 0.0))
    rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    o_s = rig.sonar_from_camera(np.zeros(3))
    d_s = rig.sonar_from_camera(rays) - o_s
    b = d_s @ o_s
    disc = b ** 2 - (o_s @ o_s - r_on ** 2)
    Z = -b + np.sqrt(np.maximum(disc, 0.0))
    C = o_s + Z[:, None] * d_s
    return C, good & (disc >= 0) & (Z > 0)



def crease_points(rig, seabed, ranges, azimuths, onset_ranges, top_pixels, run_low, run_high) -> CreaseChoice:
    """The point at range ``r`` on the vertical face below the crease seen at ``top_pixels``.

    Parameters
    ----------
    rig : Rig
        With the sonar attached.
    seabed : SeabedPlane
        Only its normal (the vertical, sonar frame) is used.
    ranges, azimuths : array_like, shape (N,)
        Sonar features (m, rad).
    onset_ranges : array_like, shape (N,)
        Range (m) of the crease: where the feature's echo starts in its beam
        (:func:`echo_start_ranges`), at most the feature's range.
    top_pixels : array_like, shape (N, 2)
        Pixel of the crease: the upper end of the feature's edge-free run (:mod:`.arc_search`).
    run_low, run_high : array_like, shape (N,)
        Elevations (rad) of that run's ends: the point is kept only inside it.

    Returns
    -------
    CreaseChoice
    """
    from ..frames import sonar_from_spherical, spherical_from_sonar

    r = np.asarray(ranges, float).reshape(-1)
    N = r.size
    nan = np.full(N, np.nan)
    top = np.asarray(top_pixels, float).reshape(-1, 2)
    if N == 0 or not seabed:
        return CreaseChoice(np.full((N, 2), np.nan), nan, nan, np.zeros(N, bool))
    r_on = np.minimum(np.asarray(onset_ranges, float).reshape(-1), r)
    C, good = crease_positions(rig, top, r_on)
    n_up = np.asarray(seabed.normal, float)
    a = -(C @ n_up)  # how far the crease lies below the sonar along the vertical
    # X = C - t n with |X| = r: t^2 + 2 a t + r_on^2 - r^2 = 0, the non-negative root.
    t = -a + np.sqrt(np.maximum(a ** 2 + r ** 2 - r_on ** 2, 0.0))
    X = C - t[:, None] * n_up
    _, _, phi = spherical_from_sonar(X)
    Pc = rig.camera_from_sonar(sonar_from_spherical(r, np.asarray(azimuths, float).reshape(-1), phi))
    px = rig.camera.project(Pc)
    found = good & (Pc[:, 2] > 0) & rig.camera.in_image(px) & \
        (phi >= np.asarray(run_low, float) - 1e-9) & (phi <= np.asarray(run_high, float) + 1e-9)
    return CreaseChoice(np.where(found[:, None], px, np.nan), np.where(found, phi, np.nan),
                        np.where(found, t, np.nan), found)


#: Echo level (3 x 3 mean over the CFAR background) above which a cell still belongs to the echo
#: when looking for its end: a face's echo fades toward its foot before the shadow starts, so the
#: end is looser than the detection's. 1.5 was chosen on training scenes 5000-5023 (the foot point
#: right for 39%, 45%, 55%, 50% of the visible features at 3, 2, 1.5, 1.2).
ECHO_END_FACTOR = 1.5


def echo_end_ranges(image, ranges, bins, beams, *, factor: float = ECHO_END_FACTOR, maps=None) -> np.ndarray:
    """Range (m) where the echo containing each cell ``(bins[i], beams[i])`` ends along its beam.

    The mirror of :func:`echo_start_ranges`: the last cell of the unbroken run of cells whose 3 x 3
    mean exceeds ``factor`` times their CFAR background that starts at or before the feature,
    walking away from the sonar (the cell's own range when it is not part of an echo). On a face
    standing on the seabed this is its foot: behind it the object's shadow starts. Shape (N,).
    ``maps``: ``cfar_map(image)`` when the caller has it (the same numbers; computed here otherwise).
    """
    from .sonar_features import cfar_map, given_maps

    img = np.asarray(image, float)
    r = np.asarray(ranges, float)
    maps = given_maps(maps, img.shape, "echo_end_ranges")
    smooth, background = cfar_map(img) if maps is None else maps
    echo = smooth > factor * background
    n = img.shape[0]
    idx = np.arange(n)[:, None]
    first_quiet = np.minimum.accumulate(np.where(~echo, idx, n)[::-1], axis=0)[::-1]
    b = np.asarray(bins, int)
    end = np.clip(first_quiet[b, np.asarray(beams, int)] - 1, b, n - 1)  # a quiet cell ends where it is
    return r[end]


@dataclass(frozen=True, eq=False)
class FootChoice:
    """The arc point above each feature's foot on a vertical face (:func:`foot_points`).

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        Its pixel ``(u, v)``; NaN where not found.
    elevations : ndarray, shape (N,)
        Its elevation (rad, sonar frame).
    height : ndarray, shape (N,)
        Its height (m) above the seabed plane, along the seabed's normal.
    found : ndarray of bool, shape (N,)
    """

    pixels: np.ndarray
    elevations: np.ndarray
    height: np.ndarray
    found: np.ndarray


def foot_points(rig, seabed, ranges, azimuths, end_ranges) -> FootChoice:
    """The point at range ``r`` on the vertical face whose foot is where the feature's echo ends.

    Acoustic only: a face standing on the seabed echoes from its top (nearest) down to its foot
    (farthest), where its shadow starts, so the echo's end in the feature's beam, ``r_end``
    (:func:`echo_end_ranges`), is the foot's range and the foot is the point of the seabed plane
    the sonar measured (:mod:`.acoustic`) at ``(r_end, theta)``: ``F``. The feature's point is above
    it on the face, ``X = F + t n`` with ``|X| = r`` (``n`` the seabed's normal), the lower root. An
    error of one bin in ``r_end`` moves ``F`` by one bin of horizontal distance and the answer by
    about one bin of range on the face. Closed form, vectorised over features.

    Parameters
    ----------
    rig : Rig
        With the sonar attached.
    seabed : SeabedPlane
        The seabed in the sonar frame (:func:`.acoustic.fit_seabed`).
    ranges, azimuths : array_like, shape (N,)
        Sonar features (m, rad).
    end_ranges : array_like, shape (N,)
        Range (m) of the foot: where the feature's echo ends, at least the feature's range.

    Returns
    -------
    FootChoice
    """
    from ..frames import sonar_from_spherical, spherical_from_sonar

    r = np.asarray(ranges, float).reshape(-1)
    th = np.asarray(azimuths, float).reshape(-1)
    N = r.size
    nan = np.full(N, np.nan)
    if N == 0 or not seabed:
        return FootChoice(np.full((N, 2), np.nan), nan, nan, np.zeros(N, bool))
    r_end = np.maximum(np.asarray(end_ranges, float).reshape(-1), r)
    n_up = np.asarray(seabed.normal, float)
    # The seabed point at (r_end, theta): n . X(phi) = offset, X(phi) = r_end (cos phi u + sin phi z)
    # with u = (sin theta, cos theta, 0): a cos phi + b sin phi = c.
    a = r_end * (n_up[0] * np.sin(th) + n_up[1] * np.cos(th))
    b = r_end * n_up[2]
    c = float(seabed.offset)
    rho = np.hypot(a, b)
    ok = rho > abs(c)
    base = np.arctan2(b, a)
    dphi = np.arccos(np.clip(c / np.where(rho > 0, rho, 1.0), -1.0, 1.0))
    # Of the two roots, the one nearer the horizon in front of the sonar (the seabed ahead).
    phi_f = np.where(np.abs(base - dphi) < np.abs(base + dphi), base - dphi, base + dphi)
    F = sonar_from_spherical(r_end, th, phi_f)
    g = F @ n_up  # = offset: the foot's height coordinate
    disc = g ** 2 - (np.sum(F * F, axis=1) - r ** 2)
    t = -g - np.sqrt(np.maximum(disc, 0.0))
    X = F + t[:, None] * n_up
    _, _, phi = spherical_from_sonar(X)
    # The feature's own arc at that elevation: X's azimuth differs from the beam's by the tilt of
    # the vertical in the sonar frame, and the truth is judged at the feature's azimuth.
    Pc = rig.camera_from_sonar(sonar_from_spherical(r, th, phi))
    px = rig.camera.project(Pc)
    half = rig.fov_elevation / 2
    found = ok & (disc >= 0) & (t >= 0) & (Pc[:, 2] > 0) & rig.camera.in_image(px) & (np.abs(phi) <= half)
    return FootChoice(np.where(found[:, None], px, np.nan), np.where(found, phi, np.nan), np.where(found, t, np.nan),
                      found)


def foot_edges(rig, seabed, ranges, azimuths, elevations, gradient, *, n_segment: int = 16,
               reach: float = 0.85) -> tuple[np.ndarray, np.ndarray]:
    """The image's evidence that each candidate point stands on a vertical face: its foot on an edge, the way down edge-free.

    Each candidate ``X = (r, theta, phi)`` (sonar frame) dropped along the seabed's normal onto the
    seabed plane the sonar measured (:mod:`.acoustic`) gives ``F = X - h n``. If ``X`` lies on a
    vertical face standing on the seabed, ``F`` is on the face's contact line, so ``F``'s pixel ``q``
    sits on an image edge (the object's boundary with the seabed) and the segment from ``X``'s pixel
    ``p`` down to it runs over the face without crossing one. This is :func:`search_contacts`'s test,
    evaluated at given elevations (every candidate of a match) instead of searched for, and returned
    as two numbers rather than a yes/no: the foot moves 0.5-1 px per range bin at this rig's grazing
    view, too little for a hard test, enough to weigh.

    Parameters
    ----------
    rig : Rig
        With the sonar attached.
    seabed : SeabedPlane
        The seabed in the sonar frame (:func:`.acoustic.fit_seabed`); falsy: every value NaN.
    ranges, azimuths, elevations : array_like, shape (N,)
        The candidates' points (m, rad, rad; sonar frame); NaN elevation: no candidate (NaN out).
    gradient : ndarray, shape (H, W)
        :func:`.arc_search.gradient_image` of the camera image (gray levels per px).
    n_segment : int
        Samples along the segment.
    reach : float
        Fraction of the way from ``p`` to ``q`` the segment is sampled over (the last part is the
        foot's own edge, blurred).

    Returns
    -------
    foot_edge : ndarray, shape (N,)
        Largest gradient within 2 px (a 5 x 5 window) of ``q`` (gray levels per px).
    face_edge : ndarray, shape (N,)
        Largest gradient along the segment from ``p`` to ``p + reach (q - p)``.
    """
    import cv2

    from ..frames import sonar_from_spherical
    from .arc_search import pixel_values

    r = np.asarray(ranges, float).reshape(-1)
    th = np.asarray(azimuths, float).reshape(-1)
    phi = np.asarray(elevations, float).reshape(-1)
    if not (r.size == th.size == phi.size):
        raise ValueError(f"foot_edges: ranges, azimuths and elevations must have one length, got {r.size}, "
                         f"{th.size}, {phi.size}")
    grad = np.asarray(gradient, np.float32)
    if grad.ndim != 2:
        raise ValueError(f"foot_edges: gradient must be (H, W), got shape {grad.shape}")
    nan = np.full(r.size, np.nan)
    if r.size == 0 or not seabed:
        return nan, nan.copy()
    X = sonar_from_spherical(r, th, np.nan_to_num(phi))
    n_up = np.asarray(seabed.normal, float)
    F = X - seabed.height(X)[:, None] * n_up
    p = rig.camera.project(rig.camera_from_sonar(X))
    q = rig.camera.project(rig.camera_from_sonar(F))
    g_max = cv2.dilate(grad, np.ones((5, 5), np.uint8))
    t = np.linspace(0.0, reach, n_segment)
    seg = p[:, None, :] + t[None, :, None] * (q - p)[:, None, :]
    has = np.isfinite(phi)
    return (np.where(has, pixel_values(g_max, q).astype(float), np.nan),
            np.where(has, pixel_values(grad, seg).astype(float).max(axis=1), np.nan))
