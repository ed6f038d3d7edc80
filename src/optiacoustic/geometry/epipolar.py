"""Epipolar geometry of opti-acoustic stereo (thesis ch. 4), in our frames and for any rig.

Sonar to optical (sec. 4.2.1): a sonar point ``(r, theta)`` may appear anywhere on the conic
``m^T C m = 0`` in the image (``m = (u, v, 1)`` ideal pixels), the image of the arc where the
range sphere ``|P_s| = r`` meets the azimuth half-plane ``theta``. :func:`conic` gives ``C``;
:func:`conic_type` classifies it (Table 4.1); :func:`sonar_to_optical_curves` samples the true
candidates (only the half-plane ``theta``, in front of the camera, inside the sonar's elevation
aperture and the image) as polylines.

Optical to sonar (sec. 4.2.2): a pixel's viewing ray crosses the azimuth half-plane
``theta`` at one range :func:`sonar_range` ``r(theta)``; :func:`optical_to_sonar_curves`
samples it in the polar ``(r, theta)`` or fan ``(x_s, y_s)`` sonar image, and every such
curve starts at the :func:`epipole`, the camera centre seen by the sonar.

The derivations are in ``docs/derivations.md (ch. 4-5)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_azimuths, as_positive
from ..frames import fan_from_polar, sonar_from_spherical, spherical_from_sonar
from ..rig import Rig
from .projection import _bc, _check_rig, _sonar_window, normalized_coordinates

__all__ = [
    "CONIC_TYPES",
    "conic",
    "conic_type",
    "sampson_distance",
    "sonar_to_optical_curves",
    "sonar_range",
    "optical_to_sonar_curves",
    "Epipole",
    "epipole",
]

#: Names returned by :func:`conic_type` (thesis Table 4.1, with the degenerate cases named).
CONIC_TYPES = ("ellipse", "parabola", "hyperbola", "imaginary", "point", "line pair", "parallel lines", "double line")


def _K_inv(rig: Rig) -> np.ndarray:
    c = rig.camera
    return np.array([[1 / c.fx, 0.0, -c.cx / c.fx], [0.0, 1 / c.fy, -c.cy / c.fy], [0.0, 0.0, 1.0]])


def _plane_terms(rig: Rig, azimuths):
    """Normal ``a = R^T n(theta)`` (camera frame) and offset ``b = -n . t`` of the azimuth plane.

    ``n(theta) = (cos, -sin, 0)`` so the plane through the sonar's Z axis at azimuth
    ``theta`` is ``n . P_s = 0``; along a pixel ray ``P_s = Z R q + t`` it reads
    ``Z (a . q) = b``.
    """
    c, s = np.cos(azimuths), np.sin(azimuths)
    R, t = rig.R, rig.t
    a = np.stack([c * R[0, j] - s * R[1, j] for j in range(3)], -1)
    b = s * t[1] - c * t[0]
    return a, b


def conic(rig: Rig, ranges, azimuths) -> np.ndarray:
    """The sonar-to-optical epipolar conic of sonar points (eqs. 4.6-4.13, any ``R``, ``t``, ``K``).

    A point seen by the sonar at range ``r`` and azimuth ``theta`` projects to ideal
    (undistorted) pixels ``m = (u, v, 1)`` with ``m^T C m = 0``, where::

        C = K^-T Q K^-1,   Q = b^2 I + b (a g^T + g a^T) + (|t|^2 - r^2) a a^T
        a = R^T (cos theta, -sin theta, 0),  b = t_y sin theta - t_x cos theta,  g = R^T t

    The conic also holds points of the opposite half-plane ``theta + pi`` and points behind
    the camera; :func:`sonar_to_optical_curves` samples only the true candidates. When the
    camera centre lies in the azimuth plane (``b = 0``) ``C`` is the double line
    ``(a . q)^2 = 0``, the image of that plane.

    Parameters
    ----------
    rig : Rig
    ranges : array_like, shape (...)
        Sonar ranges (m).
    azimuths : array_like, shape broadcastable with ``ranges``
        Sonar azimuths (rad).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Symmetric conic matrices in ideal pixel homogeneous coordinates (natural scale,
        not normalised).
    """
    _check_rig(rig)
    r = as_array(ranges, "ranges")
    if np.any(r < 0):  # the conic holds r^2 only: a negative range would pass as |r|
        raise ValueError(f"ranges: must be >= 0 m (a range is a distance), got {float(np.min(r))!r}")
    th = as_azimuths(azimuths, "azimuths", limit=2 * np.pi)
    r, th = _bc(("ranges", r), ("azimuths", th))
    a, b = _plane_terms(rig, th)
    g = rig.R.T @ rig.t
    k = rig.t @ rig.t - r * r
    ag = a[..., :, None] * g
    Q = (b * b)[..., None, None] * np.eye(3) + b[..., None, None] * (ag + np.swapaxes(ag, -1, -2)) \
        + k[..., None, None] * (a[..., :, None] * a[..., None, :])
    Ki = _K_inv(rig)
    return Ki.T @ Q @ Ki


def _balance_scale(C: np.ndarray) -> np.ndarray:
    """The ``s`` of :func:`_balanced`'s ``S = diag(s, s, 1)``: ``sqrt(|c33| / |C_{1:2,1:2}|)``, 1 where either is 0."""
    A = np.linalg.norm(C[..., :2, :2], axis=(-2, -1))
    c33 = np.abs(C[..., 2, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(np.where((A > 0) & (c33 > 0), c33 / A, 1.0))


def _balanced(C: np.ndarray) -> np.ndarray:
    """``S C S`` with ``S = diag(s, s, 1)`` making the quadratic block and ``c33`` comparable, unit norm."""
    s = _balance_scale(C)
    S = np.ones(C.shape[:-1])
    S[..., :2] = s[..., None]
    Cb = C * S[..., :, None] * S[..., None, :]
    return Cb / np.linalg.norm(Cb, axis=(-2, -1))[..., None, None]


def conic_type(conics, *, rtol: float = 1e-12) -> np.ndarray:
    """Classify conics (thesis eq. 4.15 and Table 4.1).

    The sign of ``Pi = c11 c22 - c12^2`` (product of the eigenvalues of the quadratic block)
    gives ellipse (> 0), parabola (= 0) or hyperbola (< 0); a singular ``C`` is degenerate
    (point, line pair, parallel lines, double line) and a definite one imaginary. Both signs
    are unchanged by an affine change of pixel coordinates (such as ``K``), so the type is the
    same in pixels and in normalised coordinates.

    Parameters
    ----------
    conics : array_like, shape (..., 3, 3)
        Symmetric conic matrices.
    rtol : float
        Relative tolerance for "zero": singular values of the balanced matrix below ``rtol``
        times the largest, and ``|Pi|`` below ``rtol |A|^2``. Epipolar conics of real rigs are
        often thin (a circle seen nearly edge-on): their smallest eigenvalue can be 1e-8 of the
        largest and still be a genuine hyperbola, hence the tight default.

    Returns
    -------
    ndarray of str, shape (...)
        One of :data:`CONIC_TYPES` per conic.
    """
    if isinstance(rtol, bool) or not isinstance(rtol, (int, float, np.floating, np.integer)) or not 0 <= rtol < 1:
        raise ValueError(f"rtol: expected a relative tolerance in [0, 1), got {rtol!r}")
    C = as_array(conics, "conics", ("...", 3, 3))
    if not np.allclose(C, np.swapaxes(C, -1, -2), rtol=1e-9, atol=1e-12 * np.abs(C).max(initial=0.0)):
        raise ValueError("conics: expected symmetric 3x3 matrices")
    if np.any(np.linalg.norm(C, axis=(-2, -1)) == 0):
        raise ValueError("conics: a zero matrix is not a conic")
    Cb = _balanced(C)
    A = Cb[..., :2, :2]
    Anorm = np.linalg.norm(A, axis=(-2, -1))
    pi = np.linalg.det(A) / np.where(Anorm > 0, Anorm, 1.0) ** 2
    sv = np.linalg.svd(Cb, compute_uv=False)
    rank = np.sum(sv > rtol * sv[..., :1], axis=-1)
    det = np.linalg.det(Cb)
    tr = A[..., 0, 0] + A[..., 1, 1]
    pos, neg, zero = pi > rtol, pi < -rtol, np.abs(pi) <= rtol
    degenerate = rank < 3
    out = np.full(C.shape[:-2], "parabola", dtype=object)
    out[pos & ~degenerate & (det * tr < 0)] = "ellipse"
    out[pos & ~degenerate & (det * tr > 0)] = "imaginary"
    out[neg & ~degenerate] = "hyperbola"
    out[pos & degenerate] = "point"
    out[neg & degenerate] = "line pair"
    out[zero & degenerate] = "parallel lines"
    out[rank <= 1] = "double line"
    return out.astype(str)


def sampson_distance(conics, pixels) -> np.ndarray:
    """First-order geometric distance (pixels) of ideal pixels from conics.

    ``|m^T C m| / (2 |(C m)_{1:2}|)``: the distance to the conic of the point where its
    linearisation at ``m`` vanishes. Exact to first order in the distance. A double line
    (``C = s l l^T``, rank 1: the camera centre lies in the azimuth plane, e.g. a camera
    mounted straight above or below the sonar) has no first-order term on the line, and the
    formula would halve the distance off it (``s (l.m)^2 / (2 |s| |l.m| |l_12|)``) and divide
    round-off by round-off on it: its distance is taken exactly, ``|l . m| / |l_{1:2}|``
    (rank 1 when the adjugate of the balanced conic, ``S C S / |S C S|`` with
    ``S = diag(s, s, 1)``, is below ``1e-10``). ``C`` enters through its symmetric part.

    Parameters
    ----------
    conics : array_like, shape (..., 3, 3)
    pixels : array_like, shape (..., 2)
        Ideal (undistorted) pixels; use :func:`.projection.ideal_pixels` for a distorted camera.

    Returns
    -------
    ndarray, shape (...)
        NaN where the gradient vanishes off a double line (the centre of a conic, the
        crossing of a line pair), and for a zero matrix.
    """
    C = as_array(conics, "conics", ("...", 3, 3))
    uv = as_array(pixels, "pixels", ("...", 2))
    C = 0.5 * (C + np.swapaxes(C, -1, -2))
    m = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1)
    try:
        Cm = np.einsum("...ij,...j->...i", C, m)
    except ValueError:
        raise ValueError(f"conics{C.shape} and pixels{uv.shape}: leading shapes do not broadcast") from None
    val = np.einsum("...i,...i->...", m, Cm)
    grad = 2 * np.linalg.norm(Cm[..., :2], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(grad > 0, np.abs(val) / grad, np.nan)
        line = _double_line(C)  # (..., 3) pixel line of each rank-1 conic, NaN for the others
        ln = np.linalg.norm(line[..., :2], axis=-1)
        d_line = np.abs(np.einsum("...i,...i->...", line, m)) / ln
        return np.where(np.isfinite(d_line), d_line, d)


def _double_line(C: np.ndarray) -> np.ndarray:
    """The line ``l`` (pixel homogeneous, ``(..., 3)``) of each conic that is a double line ``s l l^T``;
    NaN for the others. Rank 1 is read on the balanced conic (:func:`_balanced`: unit norm, the
    quadratic block and ``c33`` comparable), whose adjugate (all 2 x 2 minors, ``~ sigma_1 sigma_2``)
    vanishes exactly for rank 1; the line is its largest column, mapped back by ``S``."""
    norm = np.linalg.norm(C, axis=(-2, -1))
    with np.errstate(divide="ignore", invalid="ignore"):
        Cb = _balanced(np.where(norm[..., None, None] > 0, C, np.nan))
        s = _balance_scale(C)  # _balanced's S = diag(s, s, 1)
    minors = [Cb[..., i1, j1] * Cb[..., i2, j2] - Cb[..., i1, j2] * Cb[..., i2, j1]
              for i1, i2 in ((0, 1), (0, 2), (1, 2)) for j1, j2 in ((0, 1), (0, 2), (1, 2))]
    adj = np.sqrt(sum(x * x for x in minors))
    cols = np.linalg.norm(Cb, axis=-2)  # (..., 3) norm of each column
    j = np.argmax(np.nan_to_num(cols, nan=-1.0), axis=-1)
    lb = np.take_along_axis(Cb, j[..., None, None], axis=-1)[..., 0]  # the largest column: ~ l_b (balanced)
    line = lb / np.stack([s, s, np.ones_like(s)], -1)  # Cb = S C S / k = sigma u u^T: C ~ (S^-1 u)(S^-1 u)^T
    rank1 = np.isfinite(adj) & (adj <= 1e-10)
    return np.where(rank1[..., None], line, np.nan)


def _sample_runs(params: np.ndarray, evaluate, n_bisect: int = 40) -> list[list[np.ndarray]]:
    """Polylines of the valid parts of ``N`` curves, with exact clip ends by bisection.

    Parameters
    ----------
    params : ndarray, shape (N, n)
        Increasing parameter samples of each curve.
    evaluate : callable
        ``evaluate(curve_index, param) -> (coords (..., 2), valid (...))`` for broadcast
        1-D arrays ``curve_index`` (int) and ``param`` (float).
    n_bisect : int
        Bisection steps that locate each end of a run between two samples.

    Returns
    -------
    list of list of ndarray
        For each curve, its valid runs as ``(M, 2)`` arrays (in parameter order).
    """
    N, n = params.shape
    idx = np.repeat(np.arange(N), n)
    coords, valid = evaluate(idx, params.reshape(-1))
    coords = coords.reshape(N, n, 2)
    valid = valid.reshape(N, n) & np.all(np.isfinite(coords), axis=-1)

    # Locate every change of validity between consecutive samples by bisection.
    ti, tj = np.nonzero(valid[:, :-1] != valid[:, 1:])
    ends = {}
    if ti.size:
        lo = params[ti, tj].copy()
        hi = params[ti, tj + 1].copy()
        lo_valid = valid[ti, tj]
        for _ in range(n_bisect):
            mid = 0.5 * (lo + hi)
            _, vm = evaluate(ti, mid)
            same = vm == lo_valid
            lo = np.where(same, mid, lo)
            hi = np.where(same, hi, mid)
        edge = np.where(lo_valid, lo, hi)
        ec, ev = evaluate(ti, edge)
        ok = ev & np.all(np.isfinite(ec), axis=-1)
        for k in range(ti.size):
            if ok[k]:
                ends[(int(ti[k]), int(tj[k]))] = ec[k]

    out: list[list[np.ndarray]] = []
    for i in range(N):
        runs = []
        v = valid[i]
        if v.any():
            d = np.diff(np.concatenate([[0], v.astype(np.int8), [0]]))
            starts, stops = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]
            for a, b in zip(starts, stops):
                pts = [coords[i, a:b]]
                if a > 0 and (i, a - 1) in ends:
                    pts.insert(0, ends[(i, a - 1)][None])
                if b < n and (i, b - 1) in ends:
                    pts.append(ends[(i, b - 1)][None])
                run = np.concatenate(pts, 0)
                if len(run) >= 2:
                    runs.append(run)
        out.append(runs)
    return out


MAX_CURVE_SAMPLES = 100_000  # per curve: a curve across an 8k image needs a few thousand


def _n_samples(n) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 2 <= n <= MAX_CURVE_SAMPLES:
        raise ValueError(f"n_samples: expected an integer in [2, {MAX_CURVE_SAMPLES}], got {n!r}")
    return int(n)


def _elevation_half(rig: Rig, clip_elevation: bool) -> float:
    return rig.fov_elevation / 2 if clip_elevation else np.pi / 2


def sonar_to_optical_curves(rig: Rig, ranges, azimuths, *, n_samples: int = 181, clip_elevation: bool = True,
                            clip_to_image: bool = True) -> list[list[np.ndarray]]:
    """The epipolar curves of sonar points in the optical image, as pixel polylines.

    Samples the arc ``P_s = r (cos phi sin theta, cos phi cos theta, sin phi)`` in elevation
    ``phi`` and projects it: exact, and it keeps only the true candidates of the conic
    (:func:`conic`): the half-plane ``theta``, in front of the camera, ``|phi| <=
    fov_elevation/2`` (sec. 4.3) and inside the image. Ends of clipped runs are located by
    bisection.

    Parameters
    ----------
    rig : Rig
    ranges, azimuths : array_like, broadcastable
        Sonar measurements (m, rad).
    n_samples : int
        Samples per curve before clipping.
    clip_elevation : bool
        Restrict to the sonar's elevation aperture (``rig.fov_elevation``); otherwise
        ``|phi| <= pi/2``.
    clip_to_image : bool
        Drop the parts outside the image.

    Returns
    -------
    list of list of ndarray
        For each sonar point (in C order of the broadcast shape), its curve pieces as
        ``(M, 2)`` image pixels (with the camera's distortion). Empty when the point's arc
        is not seen by the camera.
    """
    _check_rig(rig)
    r = as_array(ranges, "ranges")
    # Seen by the sonar (clip_elevation), an azimuth outside its fan (1 degree of slack for noise) is a
    # mistake, most often degrees given as radians; as pure geometry any azimuth in [-pi, pi] has a conic.
    fan = (float(rig.sonar.fov_azimuth) / 2 + np.deg2rad(1.0)) if (rig.sonar is not None and clip_elevation) else 2 * np.pi
    th = as_azimuths(azimuths, "azimuths", limit=fan)
    r, th = _bc(("ranges", r), ("azimuths", th))
    r, th = r.reshape(-1), th.reshape(-1)
    if np.any(r <= 0):
        raise ValueError("ranges: must be > 0")
    half = _elevation_half(rig, clip_elevation)
    cam = rig.camera
    n = _n_samples(n_samples)
    phis = np.broadcast_to(np.linspace(-half, half, n), (r.size, n))

    def evaluate(i, phi):
        p_o = rig.camera_from_sonar(sonar_from_spherical(r[i], th[i], phi))
        uv = cam.project(p_o)
        ok = p_o[..., 2] > 0
        if clip_to_image:
            ok &= cam.in_image(uv)
        return uv, ok

    return _sample_runs(np.array(phis), evaluate)


def sonar_range(rig: Rig, pixels, azimuths, *, clip_elevation: bool = False) -> np.ndarray:
    """The optical-to-sonar epipolar curve ``r(theta)`` of pixels (our eqs. 4.16-4.18).

    The viewing ray ``P_s = t + Z d``, ``d = R (x, y, 1)``, crosses the azimuth half-plane
    ``theta`` at depth ``Z = (t_y sin theta - t_x cos theta) / (d_x cos theta - d_y sin theta)``
    and range::

        r(theta)^2 = (w_z^2 + (w_x sin theta + w_y cos theta)^2) / (d_x cos theta - d_y sin theta)^2

    with ``w = t x d`` the ray's moment about the sonar's centre.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Image pixels.
    azimuths : array_like, broadcastable with ``pixels[..., 0]``
        Azimuths (rad) at which to evaluate the curve.
    clip_elevation : bool
        Also NaN where the crossing lies outside the sonar's elevation aperture.

    Returns
    -------
    ndarray, shape broadcast(...)
        Ranges (m); NaN where the ray does not cross the half-plane: parallel to it, crossing
        behind the camera, or crossing the opposite half-plane ``theta + pi``.
    """
    _check_rig(rig)
    x, y = normalized_coordinates(rig, pixels)
    th = as_azimuths(azimuths, "azimuths", limit=2 * np.pi)
    x, y, th = _bc(("pixels", x), ("pixels", y), ("azimuths", th))
    R, t = rig.R, rig.t
    d = [R[i, 0] * x + R[i, 1] * y + R[i, 2] for i in range(3)]
    wx = t[1] * d[2] - t[2] * d[1]
    wy = t[2] * d[0] - t[0] * d[2]
    wz = t[0] * d[1] - t[1] * d[0]
    c, s = np.cos(th), np.sin(th)
    D = c * d[0] - s * d[1]
    b = s * t[1] - c * t[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = b / D
        horiz = -wz / D  # e(theta) . P_s: distance from the sonar's Z axis, > 0 on the half-plane theta
        up = (wx * s + wy * c) / D  # Z_s of the crossing
        ok = (depth > 0) & (horiz > 0) & np.isfinite(depth)
        if clip_elevation:
            ok &= np.abs(np.arctan2(up, horiz)) <= rig.fov_elevation / 2
        return np.where(ok, np.hypot(horiz, up), np.nan)


def optical_to_sonar_curves(rig: Rig, pixels, *, n_samples: int = 200, coords: str = "polar",
                            clip_elevation: bool = True, clip_to_fan: bool = True,
                            max_range: float | None = None) -> list[list[np.ndarray]]:
    """The epipolar curves of pixels in the sonar image, as polylines.

    Samples each pixel's viewing ray ``P_s = t + Z d`` in depth ``Z`` from the camera centre
    (the :func:`epipole`) to range ``max_range`` and measures it with the sonar: exact, and it
    includes rays that lie in one azimuth plane (a radial segment, where ``r(theta)`` of
    :func:`sonar_range` is undefined). Ends of clipped runs are located by bisection.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Image pixels.
    n_samples : int
        Samples per ray before clipping.
    coords : {"polar", "fan"}
        ``(range, azimuth)`` (m, rad) or fan-image ``(x_s, y_s)`` (m).
    clip_elevation : bool
        Keep only ``|phi| <= fov_elevation/2`` (sec. 4.3).
    clip_to_fan : bool
        Keep only the sonar's azimuth aperture and range window (without a sonar on the
        rig: the half-space ahead, ``|theta| <= pi/2``).
    max_range : float, optional
        Farthest range sampled; default the sonar's ``range_max``, or 20 m without a sonar.

    Returns
    -------
    list of list of ndarray
        For each pixel (C order), the curve's pieces as ``(M, 2)`` arrays, near to far.
    """
    _check_rig(rig)
    if coords not in ("polar", "fan"):
        raise ValueError(f"coords: must be 'polar' or 'fan', got {coords!r}")
    x, y = normalized_coordinates(rig, pixels)
    x, y = x.reshape(-1), y.reshape(-1)
    d = np.stack([x, y, np.ones_like(x)], -1) @ rig.R.T
    t = rig.t
    win = _sonar_window(rig)
    if max_range is None:
        max_range = win["range_max"] if np.isfinite(win["range_max"]) else 20.0
    max_range = as_positive(max_range, "max_range")
    # Depth at which the ray reaches max_range: positive root of |t + Z d|^2 = max_range^2.
    dd = np.einsum("ij,ij->i", d, d)
    td = d @ t
    disc = td * td - dd * (t @ t - max_range ** 2)
    zmax = (-td + np.sqrt(np.maximum(disc, 0.0))) / dd
    zmax = np.where(zmax > 0, zmax, 0.0)
    n = _n_samples(n_samples)
    params = zmax[:, None] * np.linspace(0.0, 1.0, n)[None, :]
    half = _elevation_half(rig, clip_elevation)

    def evaluate(i, z):
        p = t + z[..., None] * d[i]
        r, th, ph = spherical_from_sonar(p)
        ok = (np.abs(ph) <= half) & (r <= max_range * (1 + 1e-12))
        if clip_to_fan:
            ok &= (np.abs(th) <= win["fov_azimuth"] / 2) & (r >= win["range_min"]) & (r <= win["range_max"])
        out = np.stack([r, th], -1) if coords == "polar" else np.stack(fan_from_polar(r, th), -1)
        return out, ok

    return _sample_runs(params, evaluate)


@dataclass(frozen=True)
class Epipole:
    """The camera centre seen by the sonar: where every optical-to-sonar curve starts.

    Attributes
    ----------
    range, azimuth, elevation : float
        ``|t|`` (m), ``atan2(t_x, t_y)``, ``atan2(t_z, hypot(t_x, t_y))`` (rad).
    x_s, y_s : float
        Fan-image coordinates (m).
    in_fan : bool
        Whether the sonar itself could see the camera centre (usually not: it sits beside it).
    """

    range: float
    azimuth: float
    elevation: float
    x_s: float
    y_s: float
    in_fan: bool


def epipole(rig: Rig) -> Epipole:
    """The epipole in the sonar image: the sonar measurements of the camera centre ``t``."""
    _check_rig(rig)
    r, th, ph = (float(v) for v in spherical_from_sonar(rig.t))
    w = _sonar_window(rig)
    inside = bool(abs(th) <= w["fov_azimuth"] / 2 and abs(ph) <= w["fov_elevation"] / 2
                  and w["range_min"] <= r <= w["range_max"])
    xs, ys = fan_from_polar(r, th)
    return Epipole(r, th, ph, float(xs), float(ys), inside)
