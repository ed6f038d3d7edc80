"""The face-plane model: one vertical plane per image face, fitted to the creases of all its echoes.

A face of an object (a box's side, a standing cylinder's flank) is seen by the camera as an
image region with no edge inside it, and by the sonar as the set of features whose arcs' edge-free
runs lie in that region. :func:`.contact.crease_points` places each feature alone: the upper end
of its run is the face's top edge in the image, the start of its echo in its beam is that edge's
range, so the crease ``C`` (the pixel's ray at that range, sonar frame) is well conditioned, and the
feature's point is on the vertical below ``C``. One crease is one beam's guess: a wrong echo start
(another object's onset in the same beam, noise) or a run cut short by a texture edge moves it by
bins. This module pools them: every feature of a face contributes its crease, the face's top edge
is a horizontal line through them (fitted robustly in the horizontal plane of the sonar's own
seabed fit), the face is the vertical plane through that line, and each feature's point is where
its arc meets that plane, ``n . X(phi) = d`` with ``X(phi) = r (cos phi sin theta, cos phi cos theta,
sin phi)``: one elevation, in closed form.

The faces are the connected components of the image's edge-free pixels
(:func:`face_labels`, OpenCV); a feature belongs to the face its arc search's pixel lies in. Planes
are fitted locally: for each feature, its face's creases within ``window`` (rad) of its azimuth, so a
standing cylinder is approximated by its local tangent plane. The fit draws every pair of creases
as a hypothesis (a RANSAC over all pairs: there are tens of creases per face at most), keeps the
one with most creases within ``inlier_m`` and refines it on those by
``scipy.optimize.least_squares`` with a soft-L1 loss. Where a face's creases span too little
across (one beam's), the plane is taken square to the sonar's look direction through their median
(the crease point of :mod:`.contact`).

A face's features give few creases (a median of 4 per plane on the training scenes), but every
beam that crosses a vertical face starts an echo at its top edge, feature or not:
:func:`beam_creases` takes one crease per echo start (:func:`echo_run_starts`) of every beam the
face's features span, where that beam's arc leaves the face's image region going up, and
:func:`face_planes` fits them beside the features' own (``extra``; a median of 16 inliers). Where the
arc meets the plane, as a fraction of the face's height (``FacePlaneChoice.fit_height``), also says
whether the echo fits on the face at all: outside [0, 1] the arc search's surface is a wrong one.

The prior (vertical faces on a seabed) fails on spheres, lying cylinders and tilted faces; the
score (:mod:`.match`) decides whether the plane's point is taken. Vectorised over features and
hypotheses; the only Python loop is over faces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BeamCreases", "FacePlaneChoice", "arc_plane_elevations", "beam_creases", "echo_run_starts", "face_labels",
           "face_planes", "fit_line_2d"]


#: Azimuth window (rad) of a feature's plane fit: its face's creases within it enter the fit.
FACE_WINDOW = float(np.deg2rad(3.0))


def face_labels(gradient, threshold: float = 3.0) -> np.ndarray:
    """Connected components (4-connected) of the pixels whose gradient is below ``threshold``, shape (H, W).

    0 marks edge pixels; every face of the image is one positive label.
    """
    import cv2

    flat = (np.asarray(gradient) < threshold).astype(np.uint8)
    _, labels = cv2.connectedComponents(flat, connectivity=4)
    return labels.astype(np.int32)


def arc_plane_elevations(ranges, azimuths, normals, offsets, near):
    """Elevation (rad) where each feature's arc meets its plane ``normals[i] . X = offsets[i]`` (sonar frame).

    ``r (A cos phi + B sin phi) = d`` with ``A = n_x sin theta + n_y cos theta``, ``B = n_z``; of the two
    roots the one nearer ``near`` (rad) is returned; NaN where the arc misses the plane.
    """
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    n = np.asarray(normals, float).reshape(-1, 3)
    A = n[:, 0] * np.sin(th) + n[:, 1] * np.cos(th)
    B = n[:, 2]
    R = np.hypot(A, B)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.asarray(offsets, float) / (r * R)
        psi = np.arctan2(B, A)
        w = np.arccos(np.where(np.abs(c) <= 1, c, np.nan))
    phi1, phi2 = psi - w, psi + w
    near = np.asarray(near, float)
    return np.where(np.abs(phi1 - near) <= np.abs(phi2 - near), phi1, phi2)


def echo_run_starts(echo, *, min_run: int = 3) -> np.ndarray:
    """Cells that start an echo along their beam: ``echo[i, j]`` set, ``echo[i - 1, j]`` not, and the run
    at least ``min_run`` cells long (a speckle cell above threshold is not a face's top). Shape (n_bins, n_beams).
    """
    e = np.asarray(echo, bool)
    start = e.copy()
    start[1:] &= ~e[:-1]
    for k in range(1, min_run):
        start[:-k] &= e[k:]
        start[-k:] = False
    return start


@dataclass(frozen=True, eq=False)
class BeamCreases:
    """Creases from every beam a face's features span (:func:`beam_creases`).

    Attributes
    ----------
    points : ndarray, shape (M, 3)
        Sonar-frame crease (m): the point of the arc at an echo's start range where the arc leaves its
        face's image region going up.
    azimuths : ndarray, shape (M,)
        The beam's azimuth (rad).
    face : ndarray of int, shape (M,)
        The face label the crease belongs to.
    """

    points: np.ndarray
    azimuths: np.ndarray
    face: np.ndarray


def beam_creases(rig, starts, ranges, azimuths, labels, faces, az_low, az_high, r_low, r_high, *,
                 n_samples: int = 200, min_inside: int = 5) -> BeamCreases:
    """More creases per face than its features give: one per echo start of every beam the face spans.

    Seen from a sonar above it, a vertical face's nearest point in a beam is its top edge, so every
    beam crossing the face starts an echo at the top edge's range, whether or not the detector put a
    feature there. For each face ``faces[k]`` every echo start (``starts``, :func:`echo_run_starts`) of
    a beam with azimuth in ``[az_low[k], az_high[k]]`` and range in ``[r_low[k], r_high[k]]`` gives
    an arc ``X(phi) = r (cos phi sin theta, cos phi cos theta, sin phi)``; where that arc leaves the
    face's image region going up (its highest sample whose pixel carries the face's label, with the
    next sample still inside the image and the aperture, and at least ``min_inside`` samples of the
    arc in the region) is the top edge in the image, and the arc's point there is the crease. An echo
    start that is not this face's top (another object, noise) gives a crease off the face's top edge
    line; :func:`fit_line_2d`'s consensus leaves it out.

    Parameters
    ----------
    rig : Rig
        With the sonar attached.
    starts : ndarray of bool, shape (n_bins, n_beams)
        Echo starts (:func:`echo_run_starts`).
    ranges, azimuths : ndarray, shape (n_bins,), (n_beams,)
        Bin ranges (m) and beam azimuths (rad).
    labels : ndarray of int, shape (H, W)
        :func:`face_labels` of the image.
    faces, az_low, az_high, r_low, r_high : array_like, shape (K,)
        Each face's label and the azimuth (rad) and range (m) spans searched.
    n_samples : int
        Elevation samples across the aperture.
    min_inside : int
        Fewest samples of the arc inside the face's region.

    Returns
    -------
    BeamCreases
    """
    from ..frames import sonar_from_spherical

    r_b = np.asarray(ranges, float)
    th_b = np.asarray(azimuths, float)
    st = np.asarray(starts, bool)
    rr, tt, ff = [], [], []
    for lab, a0, a1, r0, r1 in zip(np.asarray(faces, int), az_low, az_high, r_low, r_high):
        jb = np.nonzero((th_b >= a0) & (th_b <= a1))[0]
        ib = np.nonzero((r_b >= r0) & (r_b <= r1))[0]
        if jb.size == 0 or ib.size == 0:
            continue
        ii, jj = np.nonzero(st[np.ix_(ib, jb)])
        rr.append(r_b[ib[ii]])
        tt.append(th_b[jb[jj]])
        ff.append(np.full(ii.size, lab))
    if not rr or sum(a.size for a in rr) == 0:
        return BeamCreases(np.zeros((0, 3)), np.zeros(0), np.zeros(0, int))
    r, th, fc = np.concatenate(rr), np.concatenate(tt), np.concatenate(ff)
    half = rig.fov_elevation / 2
    phis = np.linspace(-half, half, n_samples)
    X = sonar_from_spherical(r[:, None], th[:, None], phis[None, :])  # (M, n, 3)
    Pc = rig.camera_from_sonar(X)
    px = rig.camera.project(Pc)
    seen = (Pc[..., 2] > 0) & rig.camera.in_image(px)
    H, W = labels.shape
    ui = np.clip(np.rint(np.nan_to_num(px[..., 0])).astype(int), 0, W - 1)
    vi = np.clip(np.rint(np.nan_to_num(px[..., 1])).astype(int), 0, H - 1)
    inside = seen & (labels[vi, ui] == fc[:, None])
    idx = np.arange(n_samples)[None, :]
    top = np.where(inside, idx, -1).max(1)
    rows = np.arange(r.size)
    above = np.minimum(top + 1, n_samples - 1)
    ok = (top >= 0) & (top < n_samples - 1) & seen[rows, above] & (inside.sum(1) >= min_inside)
    return BeamCreases(X[rows[ok], top[ok]], th[ok], fc[ok])


@dataclass(frozen=True, eq=False)
class FacePlaneChoice:
    """Each feature's point on its face's fitted plane (:func:`face_planes`).

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        Pixel ``(u, v)`` of the arc's point on the plane; NaN where not found.
    elevations : ndarray, shape (N,)
        Its elevation (rad, sonar frame).
    normals : ndarray, shape (N, 3)
        The plane's unit normal (sonar frame, horizontal).
    offsets : ndarray, shape (N,)
        The plane's offset (m): ``normal . X = offset``.
    n_creases, n_inliers : ndarray of int, shape (N,)
        Creases of the feature's face within the window, and those within ``inlier_m`` of the plane.
    spread : ndarray, shape (N,)
        Extent (m) of the inlier creases along the plane's top edge.
    own_residual : ndarray, shape (N,)
        Distance (m) of the feature's own crease from the plane (NaN where it has none).
    height : ndarray, shape (N,)
        The point's height above the seabed as a fraction of the face's top edge height
        (median height of the inlier creases): 0 at the foot, 1 at the crease.
    in_face : ndarray of bool, shape (N,)
        The point's pixel lies in the feature's face (same label).
    found : ndarray of bool, shape (N,)
    fit_height : ndarray, shape (N,)
        Like ``height`` but before the height gate: where the arc meets the plane, above the seabed, as a
        fraction of the face's top edge height, wherever the arc meets a fitted plane (NaN elsewhere).
        Outside [0, 1] the feature's echo does not fit on its face between foot and top: the arc
        search's run is likely a wrong surface.
    """

    pixels: np.ndarray
    elevations: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    n_creases: np.ndarray
    n_inliers: np.ndarray
    spread: np.ndarray
    own_residual: np.ndarray
    height: np.ndarray
    in_face: np.ndarray
    found: np.ndarray
    fit_height: np.ndarray


def _horizontal_basis(n_up):
    n_up = np.asarray(n_up, float) / np.linalg.norm(n_up)
    a = np.array([1.0, 0.0, 0.0]) if abs(n_up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = a - (a @ n_up) * n_up
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n_up, e1)


def fit_line_2d(q, *, inlier_m: float = 0.02, min_spread: float = 0.05, fallback_normal=None):
    """Robust line ``q . (cos a, sin a) = d`` through 2D points ``q`` ``(M, 2)`` (m).

    Every pair of points is a hypothesis; the one with most points within ``inlier_m`` is refined on
    those by ``scipy.optimize.least_squares`` (soft-L1 loss, scale ``inlier_m``). When the points
    span less than ``min_spread`` the line's normal is ``fallback_normal`` (2D) through their median.

    Returns
    -------
    (normal (2,), d, inlier mask (M,), spread) or None when ``q`` is empty.
    """
    from scipy.optimize import least_squares

    q = np.asarray(q, float).reshape(-1, 2)
    M = len(q)
    if M == 0:
        return None
    spread0 = float(np.max(np.linalg.norm(q - np.median(q, axis=0), axis=1))) * 2 if M > 1 else 0.0
    if M < 2 or spread0 < min_spread:
        nv = np.asarray(fallback_normal, float)
        nv = nv / np.linalg.norm(nv)
        d = float(np.median(q @ nv))
        inl = np.abs(q @ nv - d) <= inlier_m
        return nv, d, inl, 0.0
    i, j = np.triu_indices(M, 1)
    t = q[j] - q[i]
    L = np.linalg.norm(t, axis=1)
    ok = L >= min_spread / 2
    if not ok.any():
        ok = L > 0
    i, j, t, L = i[ok], j[ok], t[ok], L[ok]
    nrm = np.column_stack([-t[:, 1], t[:, 0]]) / L[:, None]
    d = np.sum(nrm * q[i], axis=1)
    res = np.abs(q @ nrm.T - d[None, :])  # (M, hypotheses)
    count = (res <= inlier_m).sum(0)
    best = int(np.argmax(count - 1e-3 * res.clip(max=inlier_m).sum(0) / max(inlier_m, 1e-12) / (M + 1)))
    inl = res[:, best] <= inlier_m
    a0 = float(np.arctan2(nrm[best, 1], nrm[best, 0]))

    def resid(p):
        return q[inl] @ np.array([np.cos(p[0]), np.sin(p[0])]) - p[1]

    sol = least_squares(resid, [a0, d[best]], loss="soft_l1", f_scale=inlier_m)
    nv = np.array([np.cos(sol.x[0]), np.sin(sol.x[0])])
    dd = float(sol.x[1])
    inl = np.abs(q @ nv - dd) <= inlier_m
    along = q[inl] @ np.array([-nv[1], nv[0]])
    return nv, dd, inl, float(np.ptp(along)) if along.size else 0.0


def face_planes(rig, seabed, ranges, azimuths, face, creases, crease_ok, near, labels, *,
                window: float = FACE_WINDOW, inlier_m: float = 0.02,
                min_spread: float = 0.05, height_margin: float = 0.03, extra: BeamCreases | None = None
                ) -> FacePlaneChoice:
    """For every feature, the point where its arc meets the vertical plane fitted to its face's creases.

    Parameters
    ----------
    rig : Rig
        With the sonar attached.
    seabed : SeabedPlane
        The seabed in the sonar frame (:func:`.acoustic.fit_seabed`): its normal is the vertical.
    ranges, azimuths : array_like, shape (N,)
        Sonar features (m, rad).
    face : array_like of int, shape (N,)
        Each feature's face label (:func:`face_labels` at its arc search's pixel; <= 0: none).
    creases : array_like, shape (N, 3)
        Each feature's crease, sonar frame (m) (:func:`crease_positions`).
    crease_ok : array_like of bool, shape (N,)
        Where the crease exists.
    near : array_like, shape (N,)
        Elevation (rad) the root nearest to is taken (the arc search's).
    labels : ndarray of int, shape (H, W)
        :func:`face_labels` of the image.
    window : float
        Creases of the same face within this azimuth (rad) of the feature's enter its plane.
    inlier_m, min_spread : float
        See :func:`fit_line_2d`.
    height_margin : float
        The point must lie between ``height_margin`` (m) below the seabed and as far above the face's
        top edge (the median height of its inlier creases); elsewhere it is not found.
    extra : BeamCreases, optional
        More creases of the faces (:func:`beam_creases`): they enter the fits of their face's features
        within ``window`` of their azimuth, beside the features' own.

    Returns
    -------
    FacePlaneChoice
    """
    from ..frames import sonar_from_spherical

    r = np.asarray(ranges, float).reshape(-1)
    th = np.asarray(azimuths, float).reshape(-1)
    N = r.size
    nan = np.full(N, np.nan)
    zi = np.zeros(N, int)
    empty = FacePlaneChoice(np.full((N, 2), np.nan), nan, np.full((N, 3), np.nan), nan, zi, zi, nan, nan, nan,
                            np.zeros(N, bool), np.zeros(N, bool), nan)
    if N == 0 or not seabed:
        return empty
    face = np.asarray(face, int).reshape(-1)
    C = np.asarray(creases, float).reshape(-1, 3)
    cok = np.asarray(crease_ok, bool).reshape(-1) & (face > 0)
    # Every crease: the features' own (rows 0..N-1), then the extra ones.
    th_c, face_c = th, face
    if extra is not None and len(extra.face):
        C = np.concatenate([C, np.asarray(extra.points, float).reshape(-1, 3)])
        th_c = np.concatenate([th, np.asarray(extra.azimuths, float)])
        face_c = np.concatenate([face, np.asarray(extra.face, int)])
        cok = np.concatenate([cok, np.asarray(extra.face, int) > 0])
    n_up = np.asarray(seabed.normal, float)
    e1, e2 = _horizontal_basis(n_up)
    q = np.column_stack([C @ e1, C @ e2])
    h = C @ n_up - seabed.offset  # crease heights above the seabed
    normals = np.full((N, 3), np.nan)
    offsets = nan.copy()
    n_cr, n_in = zi.copy(), zi.copy()
    spread, own, top_h = nan.copy(), nan.copy(), nan.copy()
    for lab in np.unique(face_c[cok]):
        members = np.nonzero(face == lab)[0]
        if members.size == 0:
            continue
        pts = np.nonzero(cok & (face_c == lab))[0]
        # Features with the same window share a fit: group them by the window's set of creases.
        near_sets = np.abs(th[members][:, None] - th_c[pts][None, :]) <= window  # (members, creases)
        keys, inv = np.unique(near_sets, axis=0, return_inverse=True)
        for k in range(len(keys)):
            sel = pts[keys[k]]
            who = members[inv.reshape(-1) == k]
            if sel.size == 0:
                continue
            look = np.array([np.sin(np.median(th_c[sel])), np.cos(np.median(th_c[sel])), 0.0])
            fb = np.array([look @ e1, look @ e2])
            fit = fit_line_2d(q[sel], inlier_m=inlier_m, min_spread=min_spread, fallback_normal=fb)
            nv, d, inl, sp = fit
            n3 = nv[0] * e1 + nv[1] * e2
            normals[who] = n3
            offsets[who] = d
            n_cr[who], n_in[who], spread[who] = sel.size, int(inl.sum()), sp
            top_h[who] = float(np.median(h[sel][inl])) if inl.any() else np.nan
            own[who] = np.abs(q[who] @ nv - d)
    own = np.where(cok[:N], own, np.nan)
    has = np.all(np.isfinite(normals), axis=1)
    phi = arc_plane_elevations(r, th, np.nan_to_num(normals), np.nan_to_num(offsets), near)
    half = rig.fov_elevation / 2
    X = sonar_from_spherical(r, th, np.nan_to_num(phi))
    Pc = rig.camera_from_sonar(X)
    px = rig.camera.project(Pc)
    inimg = (Pc[:, 2] > 0) & rig.camera.in_image(px)
    found = has & np.isfinite(phi) & (np.abs(np.nan_to_num(phi)) <= half) & inimg
    H, W = labels.shape
    ui = np.clip(np.rint(np.nan_to_num(px[:, 0])).astype(int), 0, W - 1)
    vi = np.clip(np.rint(np.nan_to_num(px[:, 1])).astype(int), 0, H - 1)
    # A point on a face standing on the seabed lies between the seabed and the face's top edge.
    h_pt = X @ n_up - seabed.offset
    with np.errstate(invalid="ignore", divide="ignore"):
        fit_height = np.where(has & np.isfinite(phi), h_pt / top_h, np.nan)
        found &= (h_pt >= -height_margin) & (h_pt <= top_h + height_margin)
    in_face = found & (labels[vi, ui] == face)
    with np.errstate(invalid="ignore", divide="ignore"):
        hf = np.where(found, h_pt / top_h, np.nan)
    return FacePlaneChoice(np.where(found[:, None], px, np.nan), np.where(found, phi, np.nan), normals, offsets,
                           n_cr, n_in, spread, own, hf, in_face, found, fit_height)
