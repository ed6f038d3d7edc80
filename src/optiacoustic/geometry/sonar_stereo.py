"""Two-view sonar triangulation (thesis appendix B), in our frames, with its degeneracies reported.

A point ``P`` (sonar frame of view 1) is measured as ``(r, theta)`` in view 1 and
``(r', theta')`` in view 2, the views being related by the sonar motion
``P' = R_s P + t_s`` (``R_s = R R_o R^T``, ``t_s = (I - R_s) t + R t_o`` for a rig moving by
``(R_o, t_o)``, see :mod:`.motion`). Four measurements, three unknowns:

* :func:`closed_forms` gives the linear solutions of appendix B: (B.3) from the two
  azimuth planes and the radical plane of the two range spheres (with (b3) corrected to
  ``(r'^2 - r^2 - |t_s|^2) / 2``), its refinements (B.5) and (B.7), and a fourth form that
  intersects the two azimuth planes with the range sphere ``|P| = r`` and keeps both roots,
  which stays exact where (B.3) is singular (pure rotation, motion within the azimuth plane),
  and a fifth that intersects view 1's azimuth plane, the radical plane and the range sphere,
  which stays exact where the two azimuth planes coincide (pure heave);
* :func:`triangulate` starts from the best of them and refines every point by maximum
  likelihood (``scipy.optimize.least_squares``), with per-point covariances, the elevation's
  standard deviation, and flags: ``degenerate`` (the elevation is not known better than the
  aperture already says), ``ambiguous`` (a second point fits the four measurements, the
  mirror image of motion within the azimuth plane), and the motion's own flags
  (``"pure_rotation"``, ``"planar_motion"``).

Derivations: ``docs/derivations.md (ch. 6, app. A-B)`` (appendix B).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares
from scipy.stats import chi2 as _chi2

from .._validate import as_array, as_azimuths, as_positive
from ..frames import sonar_from_spherical, spherical_from_sonar
from ._bundle import wrap

__all__ = [
    "SonarMeasurements",
    "ClosedForms",
    "SonarTriangulation",
    "measure",
    "closed_forms",
    "triangulate",
    "motion_flags",
]


# --------------------------------------------------------------------------- forward model
@dataclass(frozen=True, eq=False)
class SonarMeasurements:
    """What two sonar views measure of points.

    Attributes
    ----------
    ranges_1, azimuths_1, ranges_2, azimuths_2 : ndarray, shape (...)
        Range (m) and azimuth (rad) in view 1 and view 2.
    elevations_1, elevations_2 : ndarray, shape (...)
        The elevations (rad) the sonar does not measure.
    """

    ranges_1: np.ndarray
    azimuths_1: np.ndarray
    ranges_2: np.ndarray
    azimuths_2: np.ndarray
    elevations_1: np.ndarray
    elevations_2: np.ndarray


def _motion(R_s, t_s):
    R_s = as_array(R_s, "R_s", (3, 3))
    t_s = as_array(t_s, "t_s", (3,))
    if not np.allclose(R_s.T @ R_s, np.eye(3), atol=1e-6) or abs(np.linalg.det(R_s) - 1) > 1e-6:
        raise ValueError(f"R_s: not a proper rotation matrix: {np.round(R_s, 6).tolist()}")
    return R_s, t_s


def measure(points_sonar, R_s, t_s) -> SonarMeasurements:
    """Range and azimuth of sonar-frame points in view 1 and in view 2 (``P' = R_s P + t_s``).

    Parameters
    ----------
    points_sonar : array_like, shape (..., 3)
        Points in the sonar frame of view 1 (m).
    R_s : array_like, shape (3, 3)
        Sonar rotation from view 1 to view 2.
    t_s : array_like, shape (3,)
        Sonar translation (m).

    Returns
    -------
    SonarMeasurements
    """
    P = as_array(points_sonar, "points_sonar", ("...", 3))
    R_s, t_s = _motion(R_s, t_s)
    r1, th1, ph1 = spherical_from_sonar(P)
    r2, th2, ph2 = spherical_from_sonar(P @ R_s.T + t_s)
    return SonarMeasurements(r1, th1, r2, th2, ph1, ph2)


def motion_flags(R_s, t_s, scale: float = 1.0, tol: float = 1e-6) -> tuple[str, ...]:
    """The degenerate sonar motions, by name.

    ``"pure_rotation"``: ``|t_s| <= tol * scale``: the sonar turns about its own centre, so
    the range spheres coincide and (B.3) is singular. ``"planar_motion"``: the sonar stays
    in its azimuth plane (rotation about its Z axis, no heave): every point and its mirror
    image through that plane give the same measurements, so the elevation's sign is not
    observable and near zero elevation neither is its size.

    Parameters
    ----------
    R_s : array_like (3, 3)
    t_s : array_like (3,)
        Sonar motion (m).
    scale : float
        Length (m) the tolerance is relative to (a typical range).
    tol : float
        Relative tolerance.
    """
    R_s, t_s = _motion(R_s, t_s)
    flags = []
    if np.linalg.norm(t_s) <= tol * scale:
        flags.append("pure_rotation")
    if abs(R_s[2, 2] - 1.0) <= tol and abs(t_s[2]) <= tol * scale:
        flags.append("planar_motion")
    return tuple(flags)


# --------------------------------------------------------------------------- closed forms
@dataclass(frozen=True, eq=False)
class ClosedForms:
    """Closed-form two-view sonar triangulations (appendix B), sonar frame of view 1.

    Attributes
    ----------
    b3, b5, b7 : ndarray, shape (N, 3)
        (B.3), (B.5) and (B.7) (m); NaN where the 3x3 system is singular.
    planes : ndarray, shape (N, 2, 3)
        The two intersections of the azimuth planes' common line with the sphere ``|P| = r``
        (m); NaN where the two azimuth planes coincide.
    condition : ndarray, shape (N,)
        Condition number of (B.3)'s matrix with unit rows (inf when singular).
    radical : ndarray, shape (N, 2, 3)
        The two intersections of the line where view 1's azimuth plane meets the radical
        plane of the two range spheres with the sphere ``|P| = r`` (m): uses ``r, theta, r'``,
        not ``theta'``, and stays exact where the two azimuth planes coincide (pure heave, for
        one); NaN for pure rotation, or where the second sonar centre lies on the normal of
        view 1's azimuth plane through the first.
    """

    b3: np.ndarray
    b5: np.ndarray
    b7: np.ndarray
    planes: np.ndarray
    condition: np.ndarray
    radical: np.ndarray = None  # type: ignore[assignment]


def _inputs(ranges_1, azimuths_1, ranges_2, azimuths_2):
    r1 = as_array(ranges_1, "ranges_1", (None,))
    n = r1.shape[0]
    th1 = as_azimuths(as_array(azimuths_1, "azimuths_1", (n,)), "azimuths_1")
    r2 = as_array(ranges_2, "ranges_2", (n,))
    th2 = as_azimuths(as_array(azimuths_2, "azimuths_2", (n,)), "azimuths_2")
    if np.any(r1 <= 0) or np.any(r2 <= 0):
        raise ValueError("ranges_1, ranges_2: must be > 0")
    return r1, th1, r2, th2


def _linear_system(r1, th1, r2, th2, R_s, t_s):
    """Rows ``a1, a2, a3`` and right-hand sides of (B.1)-(B.2) in our frames, ``(N, 3, 3)``, ``(N, 3)``."""
    n = r1.shape[0]
    c1, s1 = np.cos(th1), np.sin(th1)
    c2, s2 = np.cos(th2), np.sin(th2)
    a1 = np.stack([c1, -s1, np.zeros(n)], -1)  # X cos(theta) - Y sin(theta) = 0
    a2 = c2[:, None] * R_s[0] - s2[:, None] * R_s[1]  # the same for P' = R_s P + t_s
    b2 = s2 * t_s[1] - c2 * t_s[0]
    a3 = np.broadcast_to(t_s @ R_s, (n, 3))  # |P'|^2 - |P|^2 = r'^2 - r^2
    b3 = 0.5 * (r2**2 - r1**2 - t_s @ t_s)  # (b3) corrected: the 1/2 covers every term
    A = np.stack([a1, a2, a3], 1)
    b = np.stack([np.zeros(n), b2, b3], -1)
    return A, b


def _lstsq(A, b):
    """Batched least squares ``(N, m, 3), (N, m) -> (N, 3)``; NaN where rank-deficient."""
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    ok = s[:, -1] > 1e-10 * s[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.einsum("nji,nj->ni", Vt, np.einsum("nji,nj->ni", U, b) / s)
    return np.where(ok[:, None], x, np.nan)


def closed_forms(ranges_1, azimuths_1, ranges_2, azimuths_2, R_s, t_s) -> ClosedForms:
    """Appendix B's closed-form triangulations of points seen in two sonar views.

    Parameters
    ----------
    ranges_1, azimuths_1 : array_like, shape (N,)
        Range (m) and azimuth (rad) in view 1.
    ranges_2, azimuths_2 : array_like, shape (N,)
        The same points in view 2.
    R_s : array_like, shape (3, 3)
    t_s : array_like, shape (3,)
        Sonar motion ``P' = R_s P + t_s`` (m).

    Returns
    -------
    ClosedForms
    """
    r1, th1, r2, th2 = _inputs(ranges_1, azimuths_1, ranges_2, azimuths_2)
    R_s, t_s = _motion(R_s, t_s)
    return _closed_forms(r1, th1, r2, th2, R_s, t_s)


def _closed_forms(r1, th1, r2, th2, R_s, t_s) -> ClosedForms:
    n = r1.shape[0]
    A, b = _linear_system(r1, th1, r2, th2, R_s, t_s)
    An = A / np.maximum(np.linalg.norm(A, axis=2, keepdims=True), 1e-300)
    sv = np.linalg.svd(An, compute_uv=False)
    with np.errstate(divide="ignore"):
        cond = np.where(sv[:, -1] > 1e-12 * sv[:, 0], sv[:, 0] / sv[:, -1], np.inf)
    # tiny singular values relative to the data scale mean no solution: NaN, not noise
    ok3 = np.isfinite(cond) & (cond < 1e10)
    P3 = np.full((n, 3), np.nan)
    if ok3.any():
        P3[ok3] = np.linalg.solve(A[ok3], b[ok3][..., None])[..., 0]
    # (B.5): |P|^2 = r^2 linearised as P3 . P = r^2 ; (B.7): (P3 / |P3|) . P = r
    A5 = np.concatenate([A, P3[:, None, :]], 1)
    b5 = np.concatenate([b, (r1**2)[:, None]], 1)
    u3 = P3 / np.linalg.norm(P3, axis=1, keepdims=True)
    A7 = np.concatenate([A, u3[:, None, :]], 1)
    b7 = np.concatenate([b, r1[:, None]], 1)
    P5 = np.full((n, 3), np.nan)
    P7 = np.full((n, 3), np.nan)
    if ok3.any():
        P5[ok3] = _lstsq(A5[ok3], b5[ok3])
        P7[ok3] = _lstsq(A7[ok3], b7[ok3])
    # two azimuth planes and the range sphere |P| = r
    planes = _line_sphere(A[:, [0, 1]], b[:, [0, 1]], r1)
    # the azimuth plane of view 1, the radical plane and the range sphere (no theta'): pure heave
    radical = _line_sphere(A[:, [0, 2]], b[:, [0, 2]], r1)
    return ClosedForms(P3, P5, P7, planes, cond, radical)


def _line_sphere(A2, b2, r):
    """The two points ``(N, 2, 3)`` where the line of two planes ``A2 P = b2`` (``(N, 2, 3)``, ``(N, 2)``)
    meets the sphere ``|P| = r``: ``P0 +- lambda d`` with ``P0`` the line's point nearest the centre;
    NaN where the planes are parallel (``|a x a'| <= 1e-9 |a| |a'|``)."""
    n = A2.shape[0]
    d = np.cross(A2[:, 0], A2[:, 1])
    nd = np.linalg.norm(d, axis=1)
    ok = nd > 1e-9 * np.linalg.norm(A2[:, 0], axis=1) * np.linalg.norm(A2[:, 1], axis=1)
    out = np.full((n, 2, 3), np.nan)
    if ok.any():
        d_u = d[ok] / nd[ok, None]
        Ak, bk = A2[ok], b2[ok]
        # minimum-norm solution of the two plane equations (it is orthogonal to d)
        P0 = np.einsum("nij,ni->nj", Ak, np.linalg.solve(Ak @ np.swapaxes(Ak, 1, 2), bk[..., None])[..., 0])
        lam2 = r[ok] ** 2 - np.einsum("ni,ni->n", P0, P0)
        lam = np.sqrt(np.maximum(lam2, 0.0))  # tangent when noise pushes the line off the sphere
        out[ok, 0] = P0 + lam[:, None] * d_u
        out[ok, 1] = P0 - lam[:, None] * d_u
    return out


# --------------------------------------------------------------------------- ML refinement
def _whitened(x, r1, th1, r2, th2, R_s, t_s, sr, sa):
    """Residuals ``(N, 4)`` and Jacobians ``(N, 4, 3)`` in the parameters ``(r, theta, phi)``."""
    r, th, ph = x[:, 0], x[:, 1], x[:, 2]
    P = sonar_from_spherical(r, th, ph)
    cp, sp_, ct, st = np.cos(ph), np.sin(ph), np.cos(th), np.sin(th)
    D = np.zeros((x.shape[0], 3, 3))  # dP / d(r, theta, phi)
    D[:, :, 0] = np.stack([cp * st, cp * ct, sp_], -1)
    D[:, :, 1] = np.stack([r * cp * ct, -r * cp * st, np.zeros_like(r)], -1)
    D[:, :, 2] = np.stack([-r * sp_ * st, -r * sp_ * ct, r * cp], -1)
    Q = P @ R_s.T + t_s
    rq = np.linalg.norm(Q, axis=1)
    rho2 = Q[:, 0] ** 2 + Q[:, 1] ** 2
    e = np.stack([(r - r1) / sr, wrap(th - th1) / sa, (rq - r2) / sr,
                  wrap(np.arctan2(Q[:, 0], Q[:, 1]) - th2) / sa], -1)
    J = np.zeros((x.shape[0], 4, 3))
    J[:, 0, 0] = 1 / sr
    J[:, 1, 1] = 1 / sa
    dQ = R_s[None] @ D
    J[:, 2] = np.einsum("ni,nij->nj", Q / rq[:, None], dQ) / sr
    g = np.stack([Q[:, 1] / rho2, -Q[:, 0] / rho2, np.zeros_like(rho2)], -1)
    J[:, 3] = np.einsum("ni,nij->nj", g, dQ) / sa
    return e, J, D


def _refine(x0, r1, th1, r2, th2, R_s, t_s, sr, sa, half=None):
    """Per-point ML in ``(r, theta, phi)`` with ``least_squares`` on the block-diagonal problem;
    with ``half``, the elevations bounded to ``|phi| <= half`` (scipy's bounded trust region;
    the starts are clipped into the bounds)."""
    n = x0.shape[0]
    rows = np.repeat(np.arange(4 * n).reshape(n, 4), 3, axis=1).reshape(-1)
    cols = np.tile(np.arange(3 * n).reshape(n, 1, 3), (1, 4, 1)).reshape(-1)

    def fun(z):
        e, _, _ = _whitened(z.reshape(n, 3), r1, th1, r2, th2, R_s, t_s, sr, sa)
        return e.reshape(-1)

    def jac(z):
        _, J, _ = _whitened(z.reshape(n, 3), r1, th1, r2, th2, R_s, t_s, sr, sa)
        return sp.csr_matrix((J.reshape(-1), (rows, cols)), shape=(4 * n, 3 * n))

    x0 = np.array(x0, float)
    bounds = (-np.inf, np.inf)
    if half is not None:
        lo = np.tile([-np.inf, -np.inf, -half], n)
        hi = np.tile([np.inf, np.inf, half], n)
        # strictly inside: least_squares needs a feasible start
        x0[:, 2] = np.clip(x0[:, 2], -half * (1 - 1e-9), half * (1 - 1e-9))
        bounds = (lo, hi)
    res = least_squares(fun, x0.reshape(-1), jac=jac, method="trf", tr_solver="lsmr", x_scale="jac",
                        ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=50, bounds=bounds)
    return res.x.reshape(n, 3)


@dataclass(frozen=True, eq=False)
class SonarTriangulation:
    """Points triangulated from two sonar views.

    ``bool(result)`` is False when no point could be triangulated; ``message`` says why.

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        Maximum likelihood points in the sonar frame of view 1 (m) (or the requested closed
        form); NaN where no solution exists.
    elevations : ndarray, shape (N,)
        Their elevation (rad) in view 1.
    covariance : ndarray, shape (N, 3, 3)
        First-order covariance of each point (m^2), sonar frame of view 1.
    elevation_std : ndarray, shape (N,)
        First-order standard deviation of the elevation (rad); inf where it is unobservable.
    chi2 : ndarray, shape (N,)
        Whitened squared residual of the four measurements (1 degree of freedom).
    degenerate : ndarray of bool, shape (N,)
        No solution, or ``elevation_std`` larger than half the elevation aperture: the
        second view tells nothing the aperture did not.
    ambiguous : ndarray of bool, shape (N,)
        A second, different point in the aperture fits the measurements as well (the mirror
        image in the azimuth plane for planar motion).
    condition : ndarray, shape (N,)
        Condition number of (B.3)'s 3x3 system with unit rows.
    closed : ClosedForms
        Appendix B's closed forms.
    flags : tuple of str
        Degenerate motion (:func:`motion_flags`).
    message : str
    """

    points: np.ndarray
    elevations: np.ndarray
    covariance: np.ndarray
    elevation_std: np.ndarray
    chi2: np.ndarray
    degenerate: np.ndarray
    ambiguous: np.ndarray
    condition: np.ndarray
    closed: ClosedForms
    flags: tuple
    message: str

    def __bool__(self) -> bool:
        return bool(np.any(self.valid))

    @property
    def valid(self) -> np.ndarray:
        """Points triangulated without degeneracy or ambiguity, shape (N,)."""
        return ~self.degenerate & ~self.ambiguous


def _chi2_of(P, r1, th1, r2, th2, R_s, t_s, sr, sa, fov=None):
    """Whitened squared residual of points ``P (N, 3)`` (inf where not finite, and, with the
    aperture ``fov``, where the point is outside it or behind the sonar: the candidates' check)
    and their ``(r, theta, phi)``."""
    r, th, ph = spherical_from_sonar(P)
    x = np.stack([r, th, ph], -1)
    c = np.full(P.shape[0], np.inf)
    ok = np.all(np.isfinite(P), 1) & (r > 0)
    if fov is not None:
        with np.errstate(invalid="ignore"):
            ok &= (np.abs(ph) <= fov / 2 + 1e-9) & (P[:, 1] > 0)
    if ok.any():
        e, _, _ = _whitened(x[ok], r1[ok], th1[ok], r2[ok], th2[ok], R_s, t_s, sr, sa)
        c[ok] = np.sum(e * e, 1)
    c = np.where(np.isfinite(c), c, np.inf)
    return c, x


def triangulate(
    ranges_1,
    azimuths_1,
    ranges_2,
    azimuths_2,
    R_s,
    t_s,
    *,
    sigma_range: float = 0.01,
    sigma_azimuth: float = float(np.deg2rad(0.2)),
    fov_elevation: float | None = None,
    method: str = "ml",
) -> SonarTriangulation:
    """Triangulate points seen in two sonar views with a known sonar motion.

    Parameters
    ----------
    ranges_1, azimuths_1 : array_like, shape (N,)
        Range (m) and azimuth (rad) of each point in view 1.
    ranges_2, azimuths_2 : array_like, shape (N,)
        The same points in view 2.
    R_s : array_like, shape (3, 3)
        Sonar rotation, ``P' = R_s P + t_s``.
    t_s : array_like, shape (3,)
        Sonar translation (m).
    sigma_range : float
        Range noise standard deviation (m).
    sigma_azimuth : float
        Azimuth noise standard deviation (rad).
    fov_elevation : float, optional
        Elevation aperture (rad, in (0, pi]); selects among roots, bounds the refined
        elevations to ``+-fov_elevation / 2`` and sets the ``degenerate`` threshold.
        Default: pi (no aperture).
    method : {"ml", "b3", "b5", "b7", "planes", "radical"}
        ``"ml"`` refines the best closed form by maximum likelihood; the others return
        that closed form (for ``"planes"`` and ``"radical"``, the root of better fit).

    Returns
    -------
    SonarTriangulation
        Falsy, with a message, when every point is degenerate.
    """
    r1, th1, r2, th2 = _inputs(ranges_1, azimuths_1, ranges_2, azimuths_2)
    R_s, t_s = _motion(R_s, t_s)
    sr = as_positive(sigma_range, "sigma_range")
    sa = as_positive(sigma_azimuth, "sigma_azimuth")
    fov = np.pi if fov_elevation is None else as_positive(fov_elevation, "fov_elevation")
    if fov > np.pi:
        raise ValueError(f"fov_elevation: an aperture in radians within (0, pi], got {fov:g} "
                         f"(degrees? use np.deg2rad({fov:g}) = {np.deg2rad(fov):.4g} rad)")
    if method not in ("ml", "b3", "b5", "b7", "planes", "radical"):
        raise ValueError(f"method: expected one of 'ml', 'b3', 'b5', 'b7', 'planes', 'radical', got {method!r}")
    n = r1.shape[0]
    scale = float(np.median(r1)) if n else 1.0
    flags = motion_flags(R_s, t_s, scale)
    cf = _closed_forms(r1, th1, r2, th2, R_s, t_s)
    # candidates: each closed form; a root must be ahead of the sonar and inside the aperture
    cands = np.stack([cf.b3, cf.b5, cf.b7, cf.planes[:, 0], cf.planes[:, 1], cf.radical[:, 0], cf.radical[:, 1]],
                     1)  # (N, 7, 3)
    c2 = np.stack([_chi2_of(cands[:, k], r1, th1, r2, th2, R_s, t_s, sr, sa)[0] for k in range(cands.shape[1])], 1)
    with np.errstate(invalid="ignore"):
        _, _, ph_c = spherical_from_sonar(cands)
        inside = (np.abs(ph_c) <= fov / 2 + 1e-9) & (cands[..., 1] > 0)
    c2 = np.where(inside, c2, np.inf)
    pick = {"b3": [0], "b5": [1], "b7": [2], "planes": [3, 4], "radical": [5, 6], "ml": [0, 1, 2, 3, 4, 5, 6]}[method]
    sub = c2[:, pick]
    best = np.array(pick)[np.argmin(sub, 1)]
    P = cands[np.arange(n), best]
    found = np.isfinite(sub.min(1)) if n else np.zeros(0, bool)
    P = np.where(found[:, None], P, np.nan)
    # a different root that fits as well, inside the aperture: of each two-root form, the root
    # farther from the solution (for the planes form, the mirror image of motion in the azimuth
    # plane) is a second solution if, refined by ML, it stays a different point inside the
    # aperture that fits as well (a root on the slope of the same minimum, as the mirror of a
    # point near zero elevation under heave, slides back to it)
    thr = float(_chi2.ppf(0.99, 1))
    _, _, el_0 = spherical_from_sonar(P)
    idx, ks = [], []
    for k0 in (3, 5):
        with np.errstate(invalid="ignore"):
            da = np.abs(ph_c[:, k0] - el_0)
            db = np.abs(ph_c[:, k0 + 1] - el_0)
            k_far = np.where(np.nan_to_num(da, nan=-1.0) >= np.nan_to_num(db, nan=-1.0), k0, k0 + 1)
            c_far = c2[np.arange(n), k_far]
            d_far = np.where(k_far == k0, da, db)
            test = np.flatnonzero(found & np.isfinite(c_far) & (c_far < thr) & (d_far > 1e-6))
        idx.append(test)
        ks.append(k_far[test])
    i_alt, k_alt = np.concatenate(idx), np.concatenate(ks)
    # the solutions (method "ml") and those roots refined in one problem (one solver's overhead)
    own = np.flatnonzero(found) if method == "ml" else np.zeros(0, int)
    rows = np.concatenate([own, i_alt])
    if rows.size:
        starts = np.concatenate([P[own], cands[i_alt, k_alt]])
        x0 = np.stack(spherical_from_sonar(starts), -1)
        x = _refine(x0, r1[rows], th1[rows], r2[rows], th2[rows], R_s, t_s, sr, sa)
        # the solutions stay inside the aperture: those the free refinement took out of it are
        # refined again with their elevation bounded to it (the ML of a point this sonar saw;
        # scipy's bounded solve is several times slower, so only for them, ~1 point in 8000 of
        # a noisy Monte Carlo); the second roots are judged by where the free refinement leaves them
        out = np.flatnonzero(np.abs(x[: own.size, 2]) > fov / 2)
        if out.size:
            j = rows[out]
            x[out] = _refine(x0[out], r1[j], th1[j], r2[j], th2[j], R_s, t_s, sr, sa, half=fov / 2)
        x[:, 2] = np.clip(x[:, 2], -np.pi / 2, np.pi / 2)
        Pr = sonar_from_spherical(x[:, 0], x[:, 1], x[:, 2])
        P[own] = Pr[: own.size]
        P_alt, x_alt = Pr[own.size:], x[own.size:]
    chi = np.full(n, np.inf)
    cov = np.full((n, 3, 3), np.nan)
    el_std = np.full(n, np.inf)
    if found.any():
        chi_f, x = _chi2_of(P[found], r1[found], th1[found], r2[found], th2[found], R_s, t_s, sr, sa, fov)
        _, J, D = _whitened(x, r1[found], th1[found], r2[found], th2[found], R_s, t_s, sr, sa)
        H = np.einsum("nri,nrj->nij", J, J)
        good = np.all(np.isfinite(H), axis=(1, 2))
        sv = np.zeros((H.shape[0], 3))
        sv[good] = np.linalg.svd(H[good], compute_uv=False)
        inv_ok = good & (sv[:, -1] > 1e-12 * sv[:, 0])
        cov_x = np.full(H.shape, np.nan)
        cov_x[inv_ok] = np.linalg.inv(H[inv_ok])
        chi[found] = chi_f
        el_std[found] = np.where(inv_ok, np.sqrt(np.abs(cov_x[:, 2, 2])), np.inf)
        cov[found] = D @ cov_x @ np.swapaxes(D, 1, 2)
    # (a point outside the aperture, which the bounded refinement leaves none of, has chi2 inf)
    degenerate = ~found | ~(el_std <= fov / 2) | ~np.isfinite(chi)
    _, _, el_p = spherical_from_sonar(P)
    alt = np.zeros(n, bool)
    if i_alt.size:
        i = i_alt
        cf_i, _ = _chi2_of(P_alt, r1[i], th1[i], r2[i], th2[i], R_s, t_s, sr, sa)
        ok_i = (np.abs(x_alt[:, 2]) <= fov / 2 + 1e-9) & (P_alt[:, 1] > 0) & (cf_i < thr)
        np.logical_or.at(alt, i, ok_i & (np.abs(x_alt[:, 2] - el_p[i]) > 1e-5))
    ambiguous = found & alt
    bad = degenerate | ambiguous
    n_bad = int(bad.sum())
    why = {"pure_rotation": "pure rotation about the sonar centre (no range parallax)",
           "planar_motion": "motion within the azimuth plane (no elevation parallax, mirror ambiguity)"}
    if n == 0:
        message = "no points"
    elif n_bad == n:
        reasons = [why[f] for f in flags] or ["no elevation parallax for these points"]
        message = (f"all {n} points degenerate or ambiguous ({int(degenerate.sum())} degenerate, "
                   f"{int((ambiguous & ~degenerate).sum())} ambiguous): " + "; ".join(reasons))
    else:
        message = f"{n - n_bad} of {n} points triangulated"
        if flags:
            message += f"; degenerate motion: {', '.join(flags)}"
        if n_bad:
            message += f"; {int(degenerate.sum())} degenerate, {int((ambiguous & ~degenerate).sum())} ambiguous"
    _, _, el = spherical_from_sonar(P)
    return SonarTriangulation(P, el, cov, el_std, chi, degenerate, ambiguous, cf.condition, cf, flags, message)
