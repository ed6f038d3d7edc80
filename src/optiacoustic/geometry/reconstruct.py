"""3D reconstruction from opti-acoustic matches (thesis ch. 5), in our frames and for any rig.

A match is a pixel ``(u, v)`` and a sonar measurement ``(r, theta)`` of the same point. Four
measurements, three unknowns:

* :func:`range_solution`: the pixel ray meets the range sphere (exact positive root; the
  thesis's eq. 5.4 drops terms);
* :func:`azimuth_solution`: the pixel ray meets the azimuth half-plane (eq. 5.5);
* :func:`combined_solution`: the two depths combined with their first-order (co)variances
  (best linear unbiased combination of two correlated estimates);
* :func:`refine`: maximum likelihood over all four (eqs. 5.7-5.9), "direct" over the 3D point,
  "indirect" over the measurements constrained to the epipolar conic, batched over any number
  of points, with the Gauss-Newton covariance at the optimum;
* :func:`first_order_mse` (eq. 5.10) and :func:`crlb` (Cramer-Rao bound).

Measurement noise is Gaussian and independent: ``sigma_pixel`` on the ideal (undistorted)
pixel coordinates, ``sigma_range`` (m), ``sigma_azimuth`` (rad). All points are in the camera
frame (m). Derivations: ``docs/derivations.md (ch. 4-5)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_azimuths, as_positive, broadcast_points
from ..rig import Rig
from .projection import _bc, _check_rig, normalized_coordinates

__all__ = [
    "STATUS",
    "ClosedFormSolution",
    "range_solution",
    "azimuth_solution",
    "combined_solution",
    "closed_form_jacobian",
    "measurement_jacobian",
    "FirstOrderError",
    "first_order_mse",
    "crlb",
    "Refinement",
    "refine",
]

#: Status codes of :class:`ClosedFormSolution` and :class:`Refinement`.
STATUS = {
    0: "ok",
    1: "no real root: the ray misses the range sphere",
    2: "behind the camera",
    3: "no crossing: the ray is parallel to the azimuth plane, or the camera centre lies in it",
    4: "the crossing lies on the opposite half-plane (azimuth + pi)",
    5: "outside the sonar's elevation aperture",
    6: "the optimisation did not converge",
    7: "no valid initial guess",
}


def _message(status: np.ndarray, what: str, table: dict | None = None) -> str:
    """``what``'s summary of the status codes, worded by ``table`` (default :data:`STATUS`)."""
    table = STATUS if table is None else table
    n = status.size
    bad = status != 0
    if not bad.any():
        return f"{what}: all {n} points valid"
    codes, counts = np.unique(status[bad], return_counts=True)
    parts = "; ".join(f"{c} x {table[int(k)]}" for k, c in zip(codes, counts))
    return f"{what}: {n - int(bad.sum())} of {n} points valid ({parts})"


@dataclass(frozen=True, eq=False)
class ClosedFormSolution:
    """Points from a closed-form solution.

    Attributes
    ----------
    points : ndarray, shape (..., 3)
        Camera-frame points (m); NaN where ``valid`` is False.
    valid : ndarray of bool, shape (...)
    status : ndarray of int8, shape (...)
        Why a point is invalid (:data:`STATUS`); 0 where valid.
    ambiguous : ndarray of bool, shape (...)
        Range solution only: the ray crosses the range sphere twice in front of the camera
        (possible only when ``r < |t|``); the far crossing is returned.
    variance : ndarray, shape (...) or None
        :func:`combined_solution` only: first-order variance of the depth (m^2).
    message : str
        Summary of the invalid points. The object is falsy when no point is valid.
    """

    points: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    ambiguous: np.ndarray
    variance: np.ndarray | None = None
    message: str = ""

    @property
    def depths(self) -> np.ndarray:
        """Camera-frame Z of the points (m), shape (...)."""
        return self.points[..., 2]

    def __bool__(self) -> bool:
        return bool(np.any(self.valid))


def _sigmas(sigma_pixel, sigma_range, sigma_azimuth) -> tuple[float, float, float, float]:
    sp = np.atleast_1d(as_array(sigma_pixel, "sigma_pixel"))
    if sp.shape not in ((1,), (2,)) or np.any(sp <= 0):
        raise ValueError(f"sigma_pixel: expected one or two numbers > 0 (pixels), got {np.asarray(sigma_pixel).tolist()}")
    su, sv = (float(sp[0]), float(sp[-1]))
    return su, sv, as_positive(sigma_range, "sigma_range"), as_positive(sigma_azimuth, "sigma_azimuth")


def _inputs(rig, pixels, **named):
    """Normalised pixel coordinates and measurements, broadcast and flattened.

    ``ranges`` must be >= 0 (a negative one would be used as ``|r|`` by every form but the range
    solution's); ``azimuths`` in radians within ``+-pi`` (:func:`as_azimuths`: degrees gave
    "valid" points metres off, or NaN without a word)."""
    _check_rig(rig)
    x, y = normalized_coordinates(rig, pixels)
    arrs = [("pixels", x), ("pixels", y)]
    for k, v in named.items():
        a = as_azimuths(v, k) if k == "azimuths" else as_array(v, k)
        if k == "ranges" and np.any(a < 0):
            i = np.unravel_index(int(np.argmax(a < 0)), a.shape) if a.ndim else ()
            raise ValueError(f"ranges: must be >= 0 m (a range is a distance), got {float(a[i])!r}"
                             + (f" at index {tuple(int(j) for j in i) if len(i) > 1 else int(i[0])}" if a.ndim else ""))
        arrs.append((k, a))
    out = _bc(*arrs)
    shape = out[0].shape
    return shape, [np.ascontiguousarray(a).reshape(-1) for a in out]


def _ray(rig, x, y):
    """Components of ``d = R q``, ``q = (x, y, 1)``."""
    R = rig.R
    return [R[i, 0] * x + R[i, 1] * y + R[i, 2] for i in range(3)]


# --------------------------------------------------------------------------- closed forms
def _range_depth(rig, x, y, r):
    """Depth of the far crossing of the ray with the sphere ``|P_s| = r``, with status."""
    t = rig.t
    d = _ray(rig, x, y)
    qq = x * x + y * y + 1.0
    c = t[0] * d[0] + t[1] * d[1] + t[2] * d[2]
    k = float(t @ t) - r * r
    disc = c * c - qq * k
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.sqrt(disc)
        # (-c + s) / qq without cancellation when c > 0: = -k / (s + c).
        z = np.where(c <= 0, (s - c) / qq, -k / (s + c))
    status = np.zeros(z.shape, np.int8)
    status[~(disc >= 0)] = 1
    status[(status == 0) & ~(z > 0)] = 2
    ambiguous = (status == 0) & (k > 0) & (c < 0)
    return z, status, ambiguous


def _azimuth_depth(rig, x, y, th):
    """Depth where the ray crosses the azimuth half-plane ``theta``, with status."""
    t = rig.t
    d = _ray(rig, x, y)
    cs, sn = np.cos(th), np.sin(th)
    D = cs * d[0] - sn * d[1]  # n . R q = a . q
    b = sn * t[1] - cs * t[0]  # -n . t
    with np.errstate(invalid="ignore", divide="ignore"):
        z = b / D
        horiz = sn * (t[0] + z * d[0]) + cs * (t[1] + z * d[1])  # e . P_s
    status = np.zeros(z.shape, np.int8)
    scale = np.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2) * max(float(np.linalg.norm(t)), 1e-300)
    status[~np.isfinite(z) | (np.abs(b) <= 1e-14 * scale)] = 3
    status[(status == 0) & ~(z > 0)] = 2
    status[(status == 0) & ~(horiz > 0)] = 4
    return z, status


def _finish(shape, x, y, z, status, ambiguous, rig, clip_elevation, what, variance=None):
    if clip_elevation:
        p_s = _sonar_points(rig, x, y, z)
        with np.errstate(invalid="ignore"):
            el = np.arctan2(p_s[2], np.hypot(p_s[0], p_s[1]))
            status[(status == 0) & ~(np.abs(el) <= rig.fov_elevation / 2)] = 5
    valid = status == 0
    z = np.where(valid, z, np.nan)
    pts = np.stack([z * x, z * y, z], -1).reshape(shape + (3,))
    var = None if variance is None else np.where(valid, variance, np.nan).reshape(shape)
    return ClosedFormSolution(pts, valid.reshape(shape), status.reshape(shape), ambiguous.reshape(shape), var,
                              _message(status, what))


def _sonar_points(rig, x, y, z):
    d = _ray(rig, x, y)
    return [rig.t[i] + z * d[i] for i in range(3)]


def range_solution(rig: Rig, pixels, ranges, *, clip_elevation: bool = False) -> ClosedFormSolution:
    """Intersect each pixel's ray with its range sphere (exact; thesis eq. 5.4 corrected).

    The depth ``Z`` is the positive root of ``|q|^2 Z^2 + 2 (t . R q) Z + (|t|^2 - r^2) = 0``,
    ``q = (x, y, 1)``; the far one when both are positive (``r < |t|``, flagged ``ambiguous``).

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Image pixels.
    ranges : array_like, broadcastable with ``pixels[..., 0]``
        Sonar ranges (m).
    clip_elevation : bool
        Also mark invalid (status 5) the points outside the sonar's elevation aperture.
        Off by default: noise can push a good estimate past a nominal aperture.

    Returns
    -------
    ClosedFormSolution
        Camera-frame points (m), NaN where the ray misses the sphere (status 1) or the
        crossing is behind the camera (status 2).
    """
    shape, (x, y, r) = _inputs(rig, pixels, ranges=ranges)
    z, status, amb = _range_depth(rig, x, y, r)
    return _finish(shape, x, y, z, status, amb, rig, clip_elevation, "range solution")


def azimuth_solution(rig: Rig, pixels, azimuths, *, clip_elevation: bool = False) -> ClosedFormSolution:
    """Intersect each pixel's ray with its azimuth half-plane (thesis eq. 5.5, any rig).

    ``Z = (t_y sin theta - t_x cos theta) / (R^T n . q)`` with ``n = (cos theta, -sin theta, 0)``.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Image pixels.
    azimuths : array_like, broadcastable with ``pixels[..., 0]``
        Sonar azimuths (rad).
    clip_elevation : bool
        Also mark invalid (status 5) the points outside the sonar's elevation aperture.

    Returns
    -------
    ClosedFormSolution
        Camera-frame points (m); NaN where the ray is parallel to the plane or the camera
        centre lies in it (status 3: e.g. ``t_x = 0`` at ``theta = 0``, or ``t = (t_x, 0, 0)``
        at ``theta = +-90 deg``), where it crosses behind the camera (2) or on the opposite
        half-plane (4).
    """
    shape, (x, y, th) = _inputs(rig, pixels, azimuths=azimuths)
    z, status = _azimuth_depth(rig, x, y, th)
    return _finish(shape, x, y, z, status, np.zeros(z.shape, bool), rig, clip_elevation, "azimuth solution")


def _depth_gradients(rig, x, y, r, th, zr, zt, fx, fy):
    """Gradients of the two closed-form depths w.r.t. ``(u, v, r, theta)``, 4 arrays each."""
    t = rig.t
    d = _ray(rig, x, y)
    R = rig.R
    # Range: dZ = (r dr - Z p~ . dq) / (q . p~), p~ = R^T P_s.
    ps = [t[i] + zr * d[i] for i in range(3)]
    pt = [R[0, j] * ps[0] + R[1, j] * ps[1] + R[2, j] * ps[2] for j in range(3)]
    qp = x * pt[0] + y * pt[1] + pt[2]
    with np.errstate(invalid="ignore", divide="ignore"):
        gr = (-zr * pt[0] / (fx * qp), -zr * pt[1] / (fy * qp), r / qp, np.zeros_like(x))
        # Azimuth: dZ/dq = -Z a / (a . q), dZ/dtheta = (e . P_s) / (a . q).
        cs, sn = np.cos(th), np.sin(th)
        a = [cs * R[0, j] - sn * R[1, j] for j in range(3)]
        aq = a[0] * x + a[1] * y + a[2]
        horiz = sn * (t[0] + zt * d[0]) + cs * (t[1] + zt * d[1])
        ga = (-zt * a[0] / (fx * aq), -zt * a[1] / (fy * aq), np.zeros_like(x), horiz / aq)
    return gr, ga


def _blue_weight(gr, ga, var):
    """Weight ``w`` of the range depth in the BLUE ``w Z_r + (1 - w) Z_theta``, and its variance."""
    vr = sum(g * g * s for g, s in zip(gr, var))
    va = sum(g * g * s for g, s in zip(ga, var))
    cov = sum(g * h * s for g, h, s in zip(gr, ga, var))
    den = vr + va - 2 * cov
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(den > 0, (va - cov) / den, 1.0)
        v = np.where(den > 0, (vr * va - cov * cov) / den, vr)
    return w, v


def _combined_depth(rig, x, y, r, th, var):
    """BLUE depth of the two closed forms, its variance, status and ambiguity flags."""
    zr, st_r, amb = _range_depth(rig, x, y, r)
    za, st_a = _azimuth_depth(rig, x, y, th)
    cam = rig.camera
    gr, ga = _depth_gradients(rig, x, y, r, th, zr, za, cam.fx, cam.fy)
    w, v = _blue_weight(gr, ga, var)
    ok_r, ok_a = st_r == 0, st_a == 0
    vr = sum(g * g * s for g, s in zip(gr, var))
    va = sum(g * g * s for g, s in zip(ga, var))
    both = ok_r & ok_a & np.isfinite(w)
    z = np.where(both, w * zr + (1 - w) * za, np.where(ok_r, zr, za))
    v = np.where(both, v, np.where(ok_r, vr, va))
    status = np.where(ok_r | ok_a, 0, st_r).astype(np.int8)
    with np.errstate(invalid="ignore"):
        status[(status == 0) & ~(z > 0)] = 2
    return z, v, status, amb & ok_r


def combined_solution(rig: Rig, pixels, ranges, azimuths, *, sigma_pixel, sigma_range, sigma_azimuth,
                      clip_elevation: bool = False) -> ClosedFormSolution:
    """Best linear unbiased combination of the range and azimuth depths along each pixel ray.

    Both closed forms put the point on the same ray, so only their depths differ; they are
    correlated through the shared pixel. With first-order variances ``v_r``, ``v_a`` and
    covariance ``c`` (from the analytic gradients at the noisy measurements)::

        Z = w Z_r + (1 - w) Z_a,   w = (v_a - c) / (v_r + v_a - 2 c),
        var(Z) = (v_r v_a - c^2) / (v_r + v_a - 2 c).

    Falls back to whichever closed form is valid. This is the default initial guess of
    :func:`refine`.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
    ranges, azimuths : array_like, broadcastable with ``pixels[..., 0]``
        Sonar measurements (m, rad).
    sigma_pixel : float or (2,) floats
        Pixel noise standard deviation (pixels), for ``u`` and ``v``.
    sigma_range : float
        Range noise (m).
    sigma_azimuth : float
        Azimuth noise (rad).
    clip_elevation : bool
        As in :func:`range_solution`.

    Returns
    -------
    ClosedFormSolution
        With ``variance`` the first-order variance of the depth (m^2).
    """
    su, sv, sr, sa = _sigmas(sigma_pixel, sigma_range, sigma_azimuth)
    shape, (x, y, r, th) = _inputs(rig, pixels, ranges=ranges, azimuths=azimuths)
    z, var, status, amb = _combined_depth(rig, x, y, r, th, (su * su, sv * sv, sr * sr, sa * sa))
    return _finish(shape, x, y, z, status, amb, rig, clip_elevation, "combined solution", var)


# --------------------------------------------------------------------------- Jacobians
def closed_form_jacobian(rig: Rig, pixels, ranges, azimuths, *, method: str = "range") -> np.ndarray:
    """Analytic Jacobian of a closed-form point w.r.t. the measurements ``(u, v, r, theta)``.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Ideal pixels (the derivative is w.r.t. undistorted pixel coordinates).
    ranges, azimuths : array_like, broadcastable
        Sonar measurements (m, rad).
    method : {"range", "azimuth"}
        Which closed form. The range solution does not depend on ``theta`` nor the azimuth
        solution on ``r``: those columns are zero.

    Returns
    -------
    ndarray, shape (..., 3, 4)
        ``d P_camera / d (u, v, r, theta)`` (m/px, m/px, m/m, m/rad); NaN where the solution
        is invalid.
    """
    if method not in ("range", "azimuth"):
        raise ValueError(f"method: must be 'range' or 'azimuth', got {method!r}")
    shape, (x, y, r, th) = _inputs(rig, pixels, ranges=ranges, azimuths=azimuths)
    zr, st_r, _ = _range_depth(rig, x, y, r)
    za, st_a = _azimuth_depth(rig, x, y, th)
    cam = rig.camera
    gr, ga = _depth_gradients(rig, x, y, r, th, zr, za, cam.fx, cam.fy)
    g, z, st = (gr, zr, st_r) if method == "range" else (ga, za, st_a)
    J = _point_jacobian(x, y, z, g, cam.fx, cam.fy)
    J[st != 0] = np.nan
    return J.reshape(shape + (3, 4))


def _point_jacobian(x, y, z, g, fx, fy):
    """``dP/dm = q dZ/dm + Z dq/dm`` for ``P = Z q``, ``(n, 3, 4)``."""
    J = np.empty(x.shape + (3, 4))
    for k in range(4):
        J[:, 0, k] = x * g[k]
        J[:, 1, k] = y * g[k]
        J[:, 2, k] = g[k]
    J[:, 0, 0] += z / fx
    J[:, 1, 1] += z / fy
    return J


def _measurement_jacobian_flat(rig, P):
    """``d (u, v, r, theta) / d P_camera`` for ``(n, 3)`` points, ``(n, 4, 3)``, with the measurements."""
    cam = rig.camera
    R, t = rig.R, rig.t
    X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
    ps = P @ R.T + t
    rng = np.linalg.norm(ps, axis=-1)
    rho2 = ps[:, 0] ** 2 + ps[:, 1] ** 2
    J = np.zeros(P.shape[:1] + (4, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        J[:, 0, 0] = cam.fx / Z
        J[:, 0, 2] = -cam.fx * X / (Z * Z)
        J[:, 1, 1] = cam.fy / Z
        J[:, 1, 2] = -cam.fy * Y / (Z * Z)
        J[:, 2, :] = (ps / rng[:, None]) @ R
        dth = np.stack([ps[:, 1] / rho2, -ps[:, 0] / rho2, np.zeros_like(rho2)], -1)
        J[:, 3, :] = dth @ R
    return J


def measurement_jacobian(rig: Rig, points_camera) -> np.ndarray:
    """Jacobian of the measurements ``(u, v, r, theta)`` w.r.t. the camera-frame point.

    Parameters
    ----------
    rig : Rig
    points_camera : array_like, shape (..., 3)
        Points (m), in front of the camera.

    Returns
    -------
    ndarray, shape (..., 4, 3)
        Rows ``du/dP`` (px/m), ``dv/dP`` (px/m), ``dr/dP`` (1), ``dtheta/dP`` (rad/m), for the
        ideal (undistorted) pixels.
    """
    _check_rig(rig)
    P = as_array(points_camera, "points_camera", ("...", 3))
    return _measurement_jacobian_flat(rig, P.reshape(-1, 3)).reshape(P.shape[:-1] + (4, 3))


# --------------------------------------------------------------------------- error analysis
@dataclass(frozen=True, eq=False)
class FirstOrderError:
    """First-order (linearised) error of an estimator at given true points.

    Attributes
    ----------
    covariance : ndarray, shape (..., 3, 3)
        Covariance of the estimated camera-frame point (m^2).
    mse : ndarray, shape (...)
        ``trace(covariance)``: mean squared 3D error (m^2).
    mse_depth : ndarray, shape (...)
        ``covariance[..., 2, 2]``: mean squared error of the depth ``Z`` (m^2), eq. 5.10.
    """

    covariance: np.ndarray
    mse: np.ndarray
    mse_depth: np.ndarray


def _inv3(A):
    """Inverse of ``(..., 3, 3)`` matrices by the adjugate (fast for many small matrices)."""
    a, b, c = A[..., 0, 0], A[..., 0, 1], A[..., 0, 2]
    d, e, f = A[..., 1, 0], A[..., 1, 1], A[..., 1, 2]
    g, h, i = A[..., 2, 0], A[..., 2, 1], A[..., 2, 2]
    co = np.stack([
        np.stack([e * i - f * h, c * h - b * i, b * f - c * e], -1),
        np.stack([f * g - d * i, a * i - c * g, c * d - a * f], -1),
        np.stack([d * h - e * g, b * g - a * h, a * e - b * d], -1),
    ], -2)
    det = a * co[..., 0, 0] + b * co[..., 1, 0] + c * co[..., 2, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        return co / det[..., None, None]


def _cov3(A):
    """Covariances ``A^-1`` of ``(..., 3, 3)`` Fisher matrices; NaN where ``A`` is not finite or singular.

    Singular: a condition number of ``1e12`` or more (the measurements do not determine the point,
    e.g. on the sonar's axis, where the azimuth is undefined), where the adjugate inverse is
    rounding and can have negative variances. The condition number is the Frobenius one,
    ``|A|_F |A^-1|_F`` (within a factor 3 of the 2-norm one for these 3 x 3 matrices), from the
    inverse already at hand: no eigen-decomposition on :func:`refine`'s path."""
    A = np.asarray(A, float)
    ok = np.all(np.isfinite(A), axis=(-2, -1))
    As = np.where(ok[..., None, None], 0.5 * (A + np.swapaxes(A, -1, -2)), np.eye(3))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        cov = _inv3(As)
        cond = np.linalg.norm(As, axis=(-2, -1)) * np.linalg.norm(cov, axis=(-2, -1))
    ok &= np.all(np.isfinite(cov), axis=(-2, -1)) & (cond < 1e12)
    ok &= np.all(np.diagonal(cov, axis1=-2, axis2=-1) > 0, axis=-1)  # a covariance has positive variances
    return np.where(ok[..., None, None], cov, np.nan)


def crlb(rig: Rig, points_camera, *, sigma_pixel, sigma_range, sigma_azimuth) -> np.ndarray:
    """Cramer-Rao bound on the covariance of any unbiased estimate of a camera-frame point.

    ``(J^T W J)^-1`` with ``J`` the :func:`measurement_jacobian` and
    ``W = diag(1/sigma_u^2, 1/sigma_v^2, 1/sigma_r^2, 1/sigma_theta^2)`` the Fisher
    information of the four Gaussian measurements.

    Parameters
    ----------
    rig : Rig
    points_camera : array_like, shape (..., 3)
        True points (m).
    sigma_pixel, sigma_range, sigma_azimuth : float
        Noise standard deviations (px, m, rad).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Lower bound on the covariance (m^2). NaN for points not in front of the camera
        (``points_camera[..., 2] <= 0``): the camera cannot see them, so no bound exists; NaN
        too where the four measurements do not determine the point (a singular Fisher
        matrix, e.g. on the sonar's axis, where the azimuth is undefined);
        ``np.isfinite(cov[..., 0, 0])`` is the mask of valid points.
    """
    su, sv, sr, sa = _sigmas(sigma_pixel, sigma_range, sigma_azimuth)
    J = measurement_jacobian(rig, points_camera)
    w = np.array([1 / su ** 2, 1 / sv ** 2, 1 / sr ** 2, 1 / sa ** 2])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        cov = _cov3(np.einsum("...ki,k,...kj->...ij", J, w, J))
    behind = ~(np.asarray(points_camera, float)[..., 2] > 0)
    if np.any(behind):
        cov = np.array(cov, copy=True)
        cov[behind] = np.nan
    return cov


def first_order_mse(rig: Rig, points_camera, *, sigma_pixel, sigma_range, sigma_azimuth,
                    method: str = "range") -> FirstOrderError:
    """First-order error of an estimator of the point from its noisy match (eq. 5.10).

    ``cov = J S J^T`` with ``J`` the analytic Jacobian of the estimator w.r.t. the
    measurements at the true measurements of ``points_camera`` and
    ``S = diag(sigma_u^2, sigma_v^2, sigma_r^2, sigma_theta^2)``.

    Parameters
    ----------
    rig : Rig
    points_camera : array_like, shape (..., 3)
        True points (m).
    sigma_pixel, sigma_range, sigma_azimuth : float
        Noise standard deviations (px, m, rad).
    method : {"range", "azimuth", "combined", "ml"}
        The estimator: a closed form, their BLUE combination, or maximum likelihood (whose
        first-order covariance is the :func:`crlb`).

    Returns
    -------
    FirstOrderError
    """
    if method not in ("range", "azimuth", "combined", "ml"):
        raise ValueError(f"method: must be 'range', 'azimuth', 'combined' or 'ml', got {method!r}")
    su, sv, sr, sa = _sigmas(sigma_pixel, sigma_range, sigma_azimuth)
    _check_rig(rig)
    P = as_array(points_camera, "points_camera", ("...", 3))
    if method == "ml":
        cov = crlb(rig, P, sigma_pixel=(su, sv), sigma_range=sr, sigma_azimuth=sa)
    else:
        shape = P.shape[:-1]
        Pf = P.reshape(-1, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            x, y, z = Pf[:, 0] / Pf[:, 2], Pf[:, 1] / Pf[:, 2], Pf[:, 2]
        ps = Pf @ rig.R.T + rig.t
        r = np.linalg.norm(ps, axis=-1)
        th = np.arctan2(ps[:, 0], ps[:, 1])
        cam = rig.camera
        gr, ga = _depth_gradients(rig, x, y, r, th, z, z, cam.fx, cam.fy)
        var = (su * su, sv * sv, sr * sr, sa * sa)
        if method == "range":
            g = gr
        elif method == "azimuth":
            g = ga
        else:
            w, _ = _blue_weight(gr, ga, var)
            g = tuple(w * a + (1 - w) * b for a, b in zip(gr, ga))
        J = _point_jacobian(x, y, z, g, cam.fx, cam.fy)
        cov = np.einsum("nik,k,njk->nij", J, np.array(var), J).reshape(shape + (3, 3))
        cov[~(P[..., 2] > 0)] = np.nan
    return FirstOrderError(cov, np.trace(cov, axis1=-2, axis2=-1), cov[..., 2, 2])


# --------------------------------------------------------------------------- maximum likelihood
@dataclass(frozen=True, eq=False)
class Refinement:
    """Maximum-likelihood points from opti-acoustic matches.

    Attributes
    ----------
    points : ndarray, shape (..., 3)
        Camera-frame points (m); NaN where ``valid`` is False.
    covariance : ndarray, shape (..., 3, 3)
        ``(J^T W J)^-1`` at the optimum (m^2): the Gauss-Newton covariance of the estimate.
    cost : ndarray, shape (...)
        Sum of squared normalised residuals at the optimum; chi-square with 1 degree of
        freedom for correct matches (4 measurements, 3 unknowns): a match test.
    measurements : ndarray, shape (..., 4)
        The ML measurements ``(u, v, r, theta)`` (ideal pixels, m, rad): they satisfy the
        epipolar constraint exactly.
    converged : ndarray of bool, shape (...)
    valid : ndarray of bool, shape (...)
        Converged, in front of the camera and with a finite covariance.
    status : ndarray of int8, shape (...)
        :data:`STATUS` codes; 0 where valid.
    n_iter : int
        Iterations used by the slowest point (``solver="scipy"``: function evaluations).
    method : str
    message : str
        Summary; the object is falsy when no point is valid.
    """

    points: np.ndarray
    covariance: np.ndarray
    cost: np.ndarray
    measurements: np.ndarray
    converged: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    n_iter: int
    method: str
    message: str

    def __bool__(self) -> bool:
        return bool(np.any(self.valid))


def _direct_residuals(rig, P, meas, inv_sig):
    """Whitened residuals ``(n, 4)`` and Jacobian ``(n, 4, 3)`` of the direct ML problem.

    ``meas`` holds ``(x, y, r, theta)`` with ``x, y`` normalised coordinates; ``inv_sig``
    the inverse standard deviations in those units.
    """
    R, t = rig.R, rig.t
    X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
    xs = R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z + t[0]
    ys = R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z + t[1]
    zs = R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z + t[2]
    rho2 = xs * xs + ys * ys
    rng = np.sqrt(rho2 + zs * zs)
    with np.errstate(invalid="ignore", divide="ignore"):
        iz = 1.0 / Z
        px, py = X * iz, Y * iz
        dth = np.arctan2(xs, ys) - meas[:, 3]
        dth = (dth + np.pi) % (2 * np.pi) - np.pi
        res = np.stack([(px - meas[:, 0]) * inv_sig[0], (py - meas[:, 1]) * inv_sig[1],
                        (rng - meas[:, 2]) * inv_sig[2], dth * inv_sig[3]], -1)
        J = np.empty(P.shape[:1] + (4, 3))
        J[:, 0, 0] = iz * inv_sig[0]
        J[:, 0, 1] = 0.0
        J[:, 0, 2] = -px * iz * inv_sig[0]
        J[:, 1, 0] = 0.0
        J[:, 1, 1] = iz * inv_sig[1]
        J[:, 1, 2] = -py * iz * inv_sig[1]
        ir = inv_sig[2] / rng
        gx, gy, gz = xs * ir, ys * ir, zs * ir
        ia = inv_sig[3] / rho2
        hx, hy = ys * ia, -xs * ia
        for j in range(3):
            J[:, 2, j] = gx * R[0, j] + gy * R[1, j] + gz * R[2, j]
            J[:, 3, j] = hx * R[0, j] + hy * R[1, j]
    bad = ~(Z > 0)
    res[bad] = np.inf
    return res, J


def _normal_equations(J, res):
    A = np.einsum("nki,nkj->nij", J, J)
    g = np.einsum("nki,nk->ni", J, res)
    return A, g


def _lm(fun, x0, *, max_iter=50, xtol=1e-10, dtol=1e-15):
    """Levenberg-Marquardt on many independent 3-parameter problems at once.

    ``fun(x, idx) -> (res (n, m), J (n, m, 3))`` for the problems ``idx``. Every problem
    has its own damping, acceptance and convergence: the result equals solving each alone.
    """
    n = x0.shape[0]
    x = x0.copy()
    allidx = np.arange(n)
    res, J = fun(x, allidx)
    cost = np.sum(res * res, axis=-1)
    lam = np.full(n, 1e-3)
    active = np.isfinite(cost)
    converged = np.zeros(n, bool)
    it = 0
    for it in range(1, max_iter + 1):
        ia = np.nonzero(active)[0]
        if ia.size == 0:
            it -= 1
            break
        A, g = _normal_equations(J[ia], res[ia])
        # Gauss-Newton decrement g^T A^-1 g: the cost decrease a full step would bring. When
        # it is below rounding the point is converged (a scale-free gradient test).
        dec = np.einsum("ni,ni->n", g, np.einsum("nij,nj->ni", _inv3(A), g))
        small_grad = ~(dec > dtol * (1 + cost[ia]))
        diag = np.einsum("nii->ni", A)
        Ad = A + (lam[ia, None] * np.maximum(diag, 1e-12))[:, :, None] * np.eye(3)
        step = -np.einsum("nij,nj->ni", _inv3(Ad), g)
        xn = x[ia] + step
        rn, Jn = fun(xn, ia)
        cn = np.sum(rn * rn, axis=-1)
        better = np.isfinite(cn) & (cn <= cost[ia]) & np.all(np.isfinite(step), -1)
        acc = ia[better]
        x[acc], res[acc], J[acc], cost[acc] = xn[better], rn[better], Jn[better], cn[better]
        lam[acc] = np.maximum(lam[acc] * 0.1, 1e-12)
        rej = ia[~better]
        lam[rej] *= 10.0
        tiny_step = np.linalg.norm(step, axis=-1) <= xtol * (np.linalg.norm(x[ia], axis=-1) + xtol)
        done = small_grad | (better & tiny_step)
        converged[ia[done]] = True
        stuck = lam[ia] > 1e12
        active[ia[done | stuck]] = False
    return x, res, J, cost, converged, it


def _least_squares(fun, x0, *, max_iter=50, dtol=1e-8):
    """The same batched problem through one ``scipy.optimize.least_squares`` call.

    All points' parameters form one vector; the Jacobian is block diagonal (analytic, sparse)
    and the trust region (``trf`` with ``lsmr``) is shared. Per-point convergence is checked
    afterwards with the Gauss-Newton decrement. Points with non-finite ``x0`` are left out.
    """
    import scipy.sparse as sp
    from scipy.optimize import least_squares

    n = x0.shape[0]
    ok = np.all(np.isfinite(x0), -1)
    idx = np.nonzero(ok)[0]
    x = x0.copy()
    res, J = fun(x, np.arange(n))
    if idx.size:
        k = idx.size
        m = res.shape[1]
        rows = np.repeat(np.arange(m * k).reshape(k, m), 3, axis=1).reshape(-1)
        cols = np.tile(np.arange(3 * k).reshape(k, 1, 3), (1, m, 1)).reshape(-1)

        def f(z):
            r_, _ = fun(z.reshape(k, 3), idx)
            return np.where(np.isfinite(r_), r_, 1e10).reshape(-1)

        def jac(z):
            _, J_ = fun(z.reshape(k, 3), idx)
            return sp.csr_matrix((np.nan_to_num(J_).reshape(-1), (rows, cols)), shape=(m * k, 3 * k))

        out = least_squares(f, x0[idx].reshape(-1), jac=jac, method="trf", tr_solver="lsmr", x_scale="jac",
                            xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_iter * 4)
        x[idx] = out.x.reshape(k, 3)
        res, J = fun(x, np.arange(n))
        n_iter = int(out.nfev)
    else:
        n_iter = 0
    cost = np.sum(res * res, axis=-1)
    A, g = _normal_equations(J, np.where(np.isfinite(res), res, 0.0))
    dec = np.einsum("ni,ni->n", g, np.einsum("nij,nj->ni", _inv3(A), g))
    converged = ok & np.isfinite(cost) & (dec <= dtol * (1 + cost))
    return x, res, J, cost, converged, n_iter


def _indirect_constraint(rig, m):
    """Epipolar conic ``g = q^T Q(r, theta) q`` and its gradient w.r.t. ``(x, y, r, theta)``."""
    R, t = rig.R, rig.t
    x, y, r, th = m[:, 0], m[:, 1], m[:, 2], m[:, 3]
    cs, sn = np.cos(th), np.sin(th)
    G = R.T @ t
    a = [cs * R[0, j] - sn * R[1, j] for j in range(3)]
    ap = [-(sn * R[0, j] + cs * R[1, j]) for j in range(3)]  # da/dtheta = -R^T e
    b = sn * t[1] - cs * t[0]
    bp = cs * t[1] + sn * t[0]  # e . t
    k = float(t @ t) - r * r
    qq = x * x + y * y + 1
    al = a[0] * x + a[1] * y + a[2]
    be = G[0] * x + G[1] * y + G[2]
    alp = ap[0] * x + ap[1] * y + ap[2]
    g = b * b * qq + 2 * b * al * be + k * al * al
    dq = [2 * b * b * qc + 2 * b * (be * a[j] + al * G[j]) + 2 * k * al * a[j] for j, qc in enumerate((x, y))]
    dr = -2 * r * al * al
    dth = 2 * b * bp * qq + 2 * bp * al * be + 2 * b * alp * be + 2 * k * al * alp
    return g, np.stack([dq[0], dq[1], dr, dth], -1)


def _indirect(rig, meas, var, max_iter, m0):
    """Closest measurements (Mahalanobis) on the epipolar conic, by constrained Gauss-Newton.

    Iterates ``m <- m^ - S grad (grad^T S grad)^-1 (g(m) + grad^T (m^ - m))``: its fixed
    points are the KKT points of ``min |m - m^|_S^-1  s.t.  g(m) = 0``. Starting at the
    consistent measurements ``m0`` of an initial point keeps it on the true branch of the
    conic (from the raw measurements it can slide to the opposite half-plane's branch).
    """
    m = np.where(np.isfinite(m0), m0, meas)
    conv = np.zeros(len(m), bool)
    it = 0
    for it in range(1, max_iter + 1):
        g, dg = _indirect_constraint(rig, m)
        Sg = dg * var
        den = np.sum(dg * Sg, -1)
        with np.errstate(invalid="ignore", divide="ignore"):
            lam = (g + np.sum(dg * (meas - m), -1)) / den
        mn = meas - Sg * lam[:, None]
        step = np.sqrt(np.sum((mn - m) ** 2 / var, -1))
        m = np.where(np.isfinite(mn), mn, m)
        conv = step <= 1e-10
        if np.all(conv | ~np.isfinite(step)):
            break
    return m, conv & np.isfinite(step), it


def refine(rig: Rig, pixels, ranges, azimuths, *, sigma_pixel, sigma_range, sigma_azimuth,
           method: str = "direct", initial=None, max_iter: int = 50, solver: str = "lm") -> Refinement:
    """Maximum-likelihood 3D points from noisy opti-acoustic matches (thesis eqs. 5.7-5.9).

    ``"direct"`` (5.9) minimises over the camera-frame point ``P`` the Mahalanobis distance
    ``sum_k ((h_k(P) - m_k) / sigma_k)^2`` of the four predicted measurements
    ``h = (u, v, r, theta)`` from the measured ones, by Levenberg-Marquardt run on all points
    at once (each with its own damping and stopping test), from :func:`combined_solution`.

    ``"indirect"`` (5.7) finds the measurements closest (Mahalanobis) to the measured ones
    that satisfy the epipolar conic (4.12) exactly, by constrained Gauss-Newton on the
    Lagrangian (the thesis uses a penalty instead, 5.8), then applies the range solution.
    Consistent measurements are exactly the projections of 3D points, so both methods solve
    the same problem: they agree to solver precision (a useful cross-check).

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Image pixels.
    ranges, azimuths : array_like, broadcastable with ``pixels[..., 0]``
        Sonar measurements (m, rad).
    sigma_pixel : float or (2,) floats
        Pixel noise (px) on ``u`` and ``v`` (ideal pixels).
    sigma_range : float
        Range noise (m).
    sigma_azimuth : float
        Azimuth noise (rad).
    method : {"direct", "indirect"}
    initial : array_like, shape (..., 3), optional
        Initial camera-frame points for "direct"; default :func:`combined_solution`.
    max_iter : int
        Iteration limit.
    solver : {"lm", "scipy"}
        "direct" only. ``"lm"``: Levenberg-Marquardt vectorised over the points, each point
        with its own damping and stopping test, so a point's result does not depend on the
        batch and outliers do not slow the others. ``"scipy"``: one
        ``scipy.optimize.least_squares`` (trf) call with the block-diagonal sparse Jacobian;
        as fast on clean data, about 4x slower with 1% gross outliers
        (``benchmarks/bench_geometry.py``); same optimum to ~1e-7 m.

    Returns
    -------
    Refinement
    """
    if solver not in ("lm", "scipy"):
        raise ValueError(f"solver: must be 'lm' or 'scipy', got {solver!r}")
    if method not in ("direct", "indirect"):
        raise ValueError(f"method: must be 'direct' or 'indirect', got {method!r}")
    if not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter: must be a positive integer, got {max_iter!r}")
    su, sv, sr, sa = _sigmas(sigma_pixel, sigma_range, sigma_azimuth)
    shape, (x, y, r, th) = _inputs(rig, pixels, ranges=ranges, azimuths=azimuths)
    cam = rig.camera
    meas = np.stack([x, y, r, th], -1)
    sig_n = np.array([su / cam.fx, sv / cam.fy, sr, sa])  # sigmas in normalised units
    inv_sig = 1.0 / sig_n
    status = np.zeros(x.shape, np.int8)

    if method == "direct":
        if initial is None:
            z0, _, _, _ = _combined_depth(rig, x, y, r, th, tuple(sig_n ** 2 * np.array([cam.fx ** 2, cam.fy ** 2, 1, 1])))
            init = np.stack([z0 * x, z0 * y, z0], -1)
        else:
            init = broadcast_points(initial, "initial", shape)
        no_init = ~np.all(np.isfinite(init), -1) | ~(init[:, 2] > 0)
        init = np.where(no_init[:, None], np.array([0.0, 0.0, 1.0]), init)

        def fun(P, idx):
            return _direct_residuals(rig, P, meas[idx], inv_sig)

        if solver == "lm":
            P, res, J, cost, conv, n_iter = _lm(fun, init, max_iter=int(max_iter))
        else:
            P, res, J, cost, conv, n_iter = _least_squares(fun, np.where(no_init[:, None], np.nan, init),
                                                           max_iter=int(max_iter))
        conv &= ~no_init
        status[no_init] = 7
    else:
        var = sig_n ** 2
        z0, _, _, _ = _combined_depth(rig, x, y, r, th, tuple(var * np.array([cam.fx ** 2, cam.fy ** 2, 1, 1])))
        p0 = z0[:, None] * np.stack([x, y, np.ones_like(x)], -1) @ rig.R.T + rig.t
        m0 = np.stack([x, y, np.linalg.norm(p0, axis=-1), np.arctan2(p0[:, 0], p0[:, 1])], -1)
        m, conv, n_iter = _indirect(rig, meas, var, int(max_iter), m0)
        z, st_r, _ = _range_depth(rig, m[:, 0], m[:, 1], m[:, 2])
        P = np.stack([z * m[:, 0], z * m[:, 1], z], -1)
        res, J = _direct_residuals(rig, P, meas, inv_sig)
        cost = np.sum(res * res, -1)
        status[st_r != 0] = st_r[st_r != 0]
        # The conic g = 0 is necessary for consistent measurements, not sufficient: it also holds
        # the opposite half-plane and points behind the camera, and the iteration can end there
        # (about 1e-4 of noisy matches on random rigs). The consistent measurements closest to
        # the measured ones are the projections of the ML point, so solve those matches in point
        # coordinates (the direct form of the same problem), from the point the indirect started at.
        ps = P @ rig.R.T + rig.t
        with np.errstate(invalid="ignore"):
            wrong = np.abs(((np.arctan2(ps[:, 0], ps[:, 1]) - m[:, 3]) + np.pi) % (2 * np.pi) - np.pi) > 1e-6
        redo = np.flatnonzero(wrong | (st_r != 0) | ~conv)
        init = z0[redo, None] * np.stack([x[redo], y[redo], np.ones(redo.size)], -1)
        redo = redo[np.all(np.isfinite(init), -1) & (init[:, 2] > 0)]
        if redo.size:
            def fun_redo(Pp, idx):
                return _direct_residuals(rig, Pp, meas[redo][idx], inv_sig)

            init = z0[redo, None] * np.stack([x[redo], y[redo], np.ones(redo.size)], -1)
            P[redo], res[redo], J[redo], cost[redo], conv[redo], _ = _lm(fun_redo, init, max_iter=int(max_iter))
            wrong[redo] = False
            status[redo] = 0
        status[(status == 0) & wrong] = 4
    status[(status == 0) & ~conv] = 6
    with np.errstate(invalid="ignore"):
        status[(status == 0) & ~(P[:, 2] > 0)] = 2
    A, _ = _normal_equations(J, np.zeros(J.shape[:2]))
    cov = _cov3(A)
    status[(status == 0) & ~np.all(np.isfinite(cov), axis=(-2, -1))] = 6
    valid = status == 0
    P = np.where(valid[:, None], P, np.nan)
    cov = np.where(valid[:, None, None], cov, np.nan)
    cost = np.where(valid, cost, np.nan)
    # ML measurements: the prediction of the estimated point (ideal pixels).
    ps = P @ rig.R.T + rig.t
    with np.errstate(invalid="ignore", divide="ignore"):
        mml = np.stack([cam.fx * P[:, 0] / P[:, 2] + cam.cx, cam.fy * P[:, 1] / P[:, 2] + cam.cy,
                        np.linalg.norm(ps, axis=-1), np.arctan2(ps[:, 0], ps[:, 1])], -1)
    return Refinement(P.reshape(shape + (3,)), cov.reshape(shape + (3, 3)), cost.reshape(shape),
                      mml.reshape(shape + (4,)), (conv & valid).reshape(shape), valid.reshape(shape),
                      status.reshape(shape), int(n_iter), method, _message(status, f"refine ({method})"))

