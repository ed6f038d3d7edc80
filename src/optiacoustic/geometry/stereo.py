"""The stereo-optical baseline of thesis sec. 5.1: two pinhole cameras, linear and optimal triangulation.

For the comparison of chapter 5 the sonar of an opti-acoustic :class:`~optiacoustic.Rig` is
replaced by a second camera at the sonar's centre, looking along the sonar's boresight
(:meth:`StereoRig.from_rig`): same baseline, same first camera, so errors are comparable.

Frames: ``P_2 = R P_1 + t`` with ``R = R_camera2_from_camera1`` and ``t`` the first camera's
centre in the second camera's frame; points are returned in the first camera's frame (m).
Pixel noise is Gaussian, independent, ``sigma_pixel`` on ideal (undistorted) pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, broadcast_points, is_integer
from ..camera import PinholeCamera
from ..frames import R_SONAR_FROM_CAMERA_FORWARD, checked_rigid
from ..rig import Rig
from .projection import _bc
from .reconstruct import STATUS, ClosedFormSolution, FirstOrderError, Refinement, _inv3, _lm
from .reconstruct import _message as _status_message

__all__ = [
    "StereoRig",
    "StereoProjection",
    "project",
    "triangulate_linear",
    "triangulate_optimal",
    "crlb",
    "first_order_mse",
]


@dataclass(frozen=True, eq=False)
class StereoRig:
    """Two calibrated cameras: ``P_2 = R P_1 + t``.

    Parameters
    ----------
    R : array_like (3, 3)
        ``R_camera2_from_camera1``.
    t : array_like (3,)
        Centre of camera 1 in camera 2's frame (m).
    camera1, camera2 : PinholeCamera
    """

    R: np.ndarray
    t: np.ndarray
    camera1: PinholeCamera
    camera2: PinholeCamera

    def __post_init__(self):
        R, t = checked_rigid(self.R, self.t, "StereoRig")
        for name in ("camera1", "camera2"):
            if not isinstance(getattr(self, name), PinholeCamera):
                raise ValueError(f"StereoRig.{name}: expected a PinholeCamera, got {type(getattr(self, name)).__name__}")
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    @classmethod
    def from_rig(cls, rig: Rig, camera2: PinholeCamera | None = None) -> "StereoRig":
        """Replace the sonar of ``rig`` by a camera at its centre looking along its boresight.

        ``P_2 = R_F^T P_s = R_F^T (R P_1 + t)`` with ``R_F`` = ``R_SONAR_FROM_CAMERA_FORWARD``.
        ``camera2`` defaults to the rig's camera (same intrinsics).
        """
        if not isinstance(rig, Rig):
            raise ValueError(f"rig: expected an optiacoustic.Rig, got {type(rig).__name__}")
        F = R_SONAR_FROM_CAMERA_FORWARD
        return cls(F.T @ rig.R, F.T @ rig.t, rig.camera, rig.camera if camera2 is None else camera2)

    @property
    def baseline(self) -> float:
        """Distance between the camera centres (m)."""
        return float(np.linalg.norm(self.t))

    def projection_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """OpenCV-style ``3 x 4`` projection matrices ``K1 [I | 0]`` and ``K2 [R | t]`` (camera-1 frame)."""
        return (self.camera1.K @ np.hstack([np.eye(3), np.zeros((3, 1))]),
                self.camera2.K @ np.hstack([self.R, self.t[:, None]]))


@dataclass(frozen=True, eq=False)
class StereoProjection:
    """Pixels of camera-1-frame points in both cameras (NaN behind a camera) and visibility."""

    pixels1: np.ndarray
    pixels2: np.ndarray
    visible: np.ndarray


# Status codes as in :data:`~optiacoustic.geometry.reconstruct.STATUS`, with code 3 in stereo's own words.
STEREO_STATUS = {**STATUS, 3: "at infinity or undetermined: the two rays are parallel, or they coincide "
                              "(the point lies on the line through both camera centres)"}


def _message(status: np.ndarray, what: str) -> str:
    return _status_message(status, what, STEREO_STATUS)


def _check(stereo) -> StereoRig:
    if not isinstance(stereo, StereoRig):
        raise ValueError(f"stereo: expected a StereoRig, got {type(stereo).__name__}")
    return stereo


def project(stereo: StereoRig, points_camera) -> StereoProjection:
    """Project camera-1-frame points ``(..., 3)`` (m) into both images.

    Returns
    -------
    StereoProjection
        ``pixels1``, ``pixels2`` ``(..., 2)`` and ``visible`` ``(...)`` (in front of and inside both images).
    """
    _check(stereo)
    p1 = as_array(points_camera, "points_camera", ("...", 3), finite=False)
    p2 = p1 @ stereo.R.T + stereo.t
    u1, u2 = stereo.camera1.project(p1), stereo.camera2.project(p2)
    vis = stereo.camera1.in_image(u1) & stereo.camera2.in_image(u2)
    return StereoProjection(u1, u2, vis)


def _normalized(stereo, pixels1, pixels2):
    a = as_array(pixels1, "pixels1", ("...", 2))
    b = as_array(pixels2, "pixels2", ("...", 2))
    n1 = stereo.camera1.normalized(a)
    n2 = stereo.camera2.normalized(b)
    n1, n2 = _bc(("pixels1", n1), ("pixels2", n2))
    shape = n1.shape[:-1]
    return shape, n1.reshape(-1, 2), n2.reshape(-1, 2)


def _dlt(R, t, n1, n2):
    """Homogeneous DLT in normalised coordinates: rows ``x P^3 - P^1``, ``y P^3 - P^2`` of both cameras."""
    P2 = np.hstack([R, t[:, None]])
    A = np.empty((n1.shape[0], 4, 4))
    A[:, 0] = n1[:, 0, None] * np.array([0, 0, 1.0, 0]) - np.array([1.0, 0, 0, 0])
    A[:, 1] = n1[:, 1, None] * np.array([0, 0, 1.0, 0]) - np.array([0, 1.0, 0, 0])
    A[:, 2] = n2[:, 0, None] * P2[2] - P2[0]
    A[:, 3] = n2[:, 1, None] * P2[2] - P2[1]
    # Scale rows to unit norm (Hartley's normalisation, for conditioning).
    A /= np.linalg.norm(A, axis=-1, keepdims=True)
    _, s, Vt = np.linalg.svd(A)
    return Vt[:, -1, :], s


def _dlt_points(R, t, n1, n2):
    """DLT points ``(n, 3)`` (camera-1 frame) and their status: 3 at infinity or undetermined, 2 behind a camera.

    At infinity: ``w`` of the unit homogeneous solution is rounding (parallel rays). Undetermined:
    a second null vector (the rays coincide: the point lies on the baseline, or the baseline is zero).
    """
    X, s = _dlt(R, t, n1, n2)
    w = X[:, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        P = X[:, :3] / w[:, None]
    status = np.zeros(w.shape, np.int8)
    status[~(np.abs(w) > 1e-12 * np.linalg.norm(X[:, :3], axis=-1)) | ~(s[:, -2] > 1e-12 * s[:, 0])] = 3
    with np.errstate(invalid="ignore", over="ignore"):
        z2 = P @ R[2] + t[2]
        status[(status == 0) & ~((P[:, 2] > 0) & (z2 > 0))] = 2
    return P, status


def triangulate_linear(stereo: StereoRig, pixels1, pixels2) -> ClosedFormSolution:
    """Linear (DLT, SVD) triangulation: the thesis's stereo-optical baseline.

    Parameters
    ----------
    stereo : StereoRig
    pixels1, pixels2 : array_like, shape (..., 2)
        Matching image pixels in cameras 1 and 2.

    Returns
    -------
    ClosedFormSolution
        Camera-1-frame points (m); NaN with status 3 at infinity (parallel rays) or undetermined
        (coincident rays: a point on the baseline, or a zero baseline) and status 2 behind
        either camera.
    """
    _check(stereo)
    shape, n1, n2 = _normalized(stereo, pixels1, pixels2)
    P, status = _dlt_points(stereo.R, stereo.t, n1, n2)
    valid = status == 0
    P = np.where(valid[:, None], P, np.nan)
    return ClosedFormSolution(P.reshape(shape + (3,)), valid.reshape(shape), status.reshape(shape),
                              np.zeros(shape, bool), None, _message(status, "linear triangulation"))


def _residuals(stereo, P, meas, inv_sig):
    """Whitened reprojection residuals ``(n, 4)`` (normalised coordinates) and Jacobian ``(n, 4, 3)``."""
    R, t = stereo.R, stereo.t
    P2 = P @ R.T + t
    res = np.empty(P.shape[:1] + (4,))
    J = np.zeros(P.shape[:1] + (4, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        for c, (Q, M) in enumerate(((P, np.eye(3)), (P2, R))):
            iz = 1.0 / Q[:, 2]
            x, y = Q[:, 0] * iz, Q[:, 1] * iz
            s0, s1 = inv_sig[2 * c], inv_sig[2 * c + 1]
            res[:, 2 * c] = (x - meas[:, 2 * c]) * s0
            res[:, 2 * c + 1] = (y - meas[:, 2 * c + 1]) * s1
            # d(x, y)/dQ = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]], then dQ/dP = M.
            J[:, 2 * c, :] = (iz[:, None] * (M[0] - x[:, None] * M[2])) * s0
            J[:, 2 * c + 1, :] = (iz[:, None] * (M[1] - y[:, None] * M[2])) * s1
    bad = ~((P[:, 2] > 0) & (P2[:, 2] > 0))
    res[bad] = np.inf
    return res, J


def _covariance(J):
    """``(J^T J)^-1`` for whitened Jacobians ``(n, 4, 3)``; NaN where the Fisher matrix is singular.

    Well-conditioned points (``J^T J`` of condition number below 1e8, nearly all) by the
    adjugate inverse of ``J^T J``; the others from the SVD of ``J`` (``V S^-2 V^T``: positive
    semi-definite by construction, and accurate where ``J^T J`` squares the condition number of
    a distant point; an SVD for every point cost 40 % of :func:`triangulate_optimal`). Singular:
    the smallest singular value below 1e-10 of the largest (the depth of a point more than
    ~1e10 baselines away, a zero baseline, a point on the baseline), where an inverse would
    return rounding noise, even negative variances.
    """
    ok = np.all(np.isfinite(J), axis=(-2, -1))
    J = np.where(ok[:, None, None], J, np.eye(4, 3))
    A = np.einsum("nki,nkj->nij", J, J)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        cov = _inv3(A)
        cond = np.linalg.norm(A, axis=(-2, -1)) * np.linalg.norm(cov, axis=(-2, -1))
    hard = ok & ~(cond < 1e8)
    if hard.any():
        _, s, Vt = np.linalg.svd(J[hard], full_matrices=False)
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            ch = np.einsum("nki,nk,nkj->nij", Vt, 1.0 / s**2, Vt)
        ch[~(s[:, -1] > 1e-10 * s[:, 0])] = np.nan
        cov[hard] = ch
    ok &= np.all(np.isfinite(cov), axis=(-2, -1))
    return np.where(ok[:, None, None], cov, np.nan)


def _in_front(stereo, P):
    """True for camera-1-frame points ``(n, 3)`` in front of both cameras."""
    with np.errstate(invalid="ignore"):
        return (P[:, 2] > 0) & (P @ stereo.R[2] + stereo.t[2] > 0)


def _inv_sig(stereo, sigma_pixel):
    sp = np.atleast_1d(as_array(sigma_pixel, "sigma_pixel"))
    if sp.shape not in ((1,), (2,)) or np.any(sp <= 0):
        raise ValueError(f"sigma_pixel: expected one or two numbers > 0 (pixels), got {np.asarray(sigma_pixel).tolist()}")
    su, sv = float(sp[0]), float(sp[-1])
    c1, c2 = stereo.camera1, stereo.camera2
    return np.array([c1.fx / su, c1.fy / sv, c2.fx / su, c2.fy / sv])


def triangulate_optimal(stereo: StereoRig, pixels1, pixels2, *, sigma_pixel=1.0, initial=None,
                        max_iter: int = 50) -> Refinement:
    """Optimal (maximum-likelihood) triangulation: minimise the reprojection error (eq. 5.1).

    Levenberg-Marquardt over the camera-1-frame point, run on all points at once from
    :func:`triangulate_linear` (or ``initial``). The minimiser over the point equals the
    minimiser of eq. 5.1 under the epipolar constraint (consistent pixel pairs are exactly
    the projections of points).

    Parameters
    ----------
    stereo : StereoRig
    pixels1, pixels2 : array_like, shape (..., 2)
        Matching image pixels.
    sigma_pixel : float or (2,) floats
        Pixel noise (px); scales the cost and the covariance, not the minimiser.
    initial : array_like, shape (..., 3), optional
    max_iter : int

    Returns
    -------
    Refinement
        ``measurements`` are the ML pixels ``(u1, v1, u2, v2)`` (ideal, undistorted pixels);
        ``cost`` is chi-square with 1 degree of freedom for correct matches. Invalid (NaN)
        with status 3 where the views do not determine the point (parallel rays: a point at
        infinity; coincident rays; a singular Fisher matrix), 7 where the linear start lies
        behind a camera, 6 where the optimisation did not converge.
    """
    _check(stereo)
    if not is_integer(max_iter) or max_iter < 1:
        raise ValueError(f"max_iter: must be a positive integer, got {max_iter!r}")
    inv_sig = _inv_sig(stereo, sigma_pixel)
    shape, n1, n2 = _normalized(stereo, pixels1, pixels2)
    meas = np.concatenate([n1, n2], -1)
    if initial is None:
        init, lin_status = _dlt_points(stereo.R, stereo.t, n1, n2)
        # parallel or coincident rays: no finite point to refine (the DLT's 1/w is rounding)
        at_inf = lin_status == 3
    else:
        init = broadcast_points(initial, "initial", shape)
        at_inf = np.zeros(len(init), bool)
    no_init = ~at_inf & (~np.all(np.isfinite(init), -1) | ~_in_front(stereo, init))
    init = np.where((no_init | at_inf)[:, None], np.array([0.0, 0.0, 1.0]), init)

    def fun(P, idx):
        return _residuals(stereo, P, meas[idx], inv_sig)

    P, res, J, cost, conv, n_iter = _lm(fun, init, max_iter=int(max_iter))
    status = np.zeros(len(P), np.int8)
    status[at_inf] = 3
    status[no_init] = 7
    # a start from ``initial`` that ran off to infinity (the DLT's own test: |P| w / |X| <= 1e-12)
    status[(status == 0) & ~(np.linalg.norm(P, axis=-1) < 1e12)] = 3
    status[(status == 0) & ~conv] = 6
    cov = _covariance(J)
    # singular Fisher matrix at the optimum: the two views do not determine the point
    status[(status == 0) & ~np.all(np.isfinite(cov), axis=(-2, -1))] = 3
    valid = status == 0
    P = np.where(valid[:, None], P, np.nan)
    cov = np.where(valid[:, None, None], cov, np.nan)
    # ML pixels on the ideal (undistorted) pinhole, as the noise model and the docstring say
    m1 = stereo.camera1.project(P, distort=False)
    m2 = stereo.camera2.project(P @ stereo.R.T + stereo.t, distort=False)
    mml = np.concatenate([m1, m2], -1)
    return Refinement(P.reshape(shape + (3,)), cov.reshape(shape + (3, 3)),
                      np.where(valid, cost, np.nan).reshape(shape), mml.reshape(shape + (4,)),
                      (conv & valid).reshape(shape), valid.reshape(shape), status.reshape(shape), int(n_iter),
                      "optimal", _message(status, "optimal triangulation"))


def crlb(stereo: StereoRig, points_camera, *, sigma_pixel=1.0) -> np.ndarray:
    """Cramer-Rao bound ``(J^T W J)^-1`` (m^2) of a camera-1-frame point from its two pixels.

    Parameters
    ----------
    stereo : StereoRig
    points_camera : array_like, shape (..., 3)
        True points (m).
    sigma_pixel : float or (2,) floats
        Pixel noise (px).

    Returns
    -------
    ndarray, shape (..., 3, 3)
        NaN for points not in front of both cameras, and where the two views do not
        determine the point (singular Fisher matrix: zero baseline, a point on the baseline).
    """
    _check(stereo)
    inv_sig = _inv_sig(stereo, sigma_pixel)
    P = as_array(points_camera, "points_camera", ("...", 3))
    Pf = P.reshape(-1, 3)
    _, J = _residuals(stereo, Pf, np.zeros((len(Pf), 4)), inv_sig)
    cov = np.where(_in_front(stereo, Pf)[:, None, None], _covariance(J), np.nan)
    return cov.reshape(P.shape + (3,))


def first_order_mse(stereo: StereoRig, points_camera, *, sigma_pixel=1.0, method: str = "linear") -> FirstOrderError:
    """First-order error of stereo triangulation at true points.

    ``method="optimal"`` gives the :func:`crlb`; ``"linear"`` propagates the (ideal) pixel
    noise through the DLT with a central-difference Jacobian (step 1e-4 px).

    Returns
    -------
    FirstOrderError
        NaN for points not in front of both cameras and where the DLT fails (at infinity,
        undetermined).
    """
    if method not in ("linear", "optimal"):
        raise ValueError(f"method: must be 'linear' or 'optimal', got {method!r}")
    _check(stereo)
    P = as_array(points_camera, "points_camera", ("...", 3))
    if method == "optimal":
        cov = crlb(stereo, P, sigma_pixel=sigma_pixel)
    else:
        inv_sig = _inv_sig(stereo, sigma_pixel)
        sig = np.array([stereo.camera1.fx, stereo.camera1.fy, stereo.camera2.fx, stereo.camera2.fy]) / inv_sig
        # perturb the ideal pixels (the noise model) in normalised coordinates: no distortion round trip
        Pf = P.reshape(-1, 3)
        front = _in_front(stereo, Pf)
        P2 = Pf @ stereo.R.T + stereo.t
        with np.errstate(invalid="ignore", divide="ignore"):
            m = np.concatenate([Pf[:, :2] / Pf[:, 2:], P2[:, :2] / P2[:, 2:]], -1)
        m = np.where(front[:, None], m, 0.0)  # masked below
        f = np.array([stereo.camera1.fx, stereo.camera1.fy, stereo.camera2.fx, stereo.camera2.fy])
        h = 1e-4
        J = np.empty(m.shape[:1] + (3, 4))
        for k in range(4):
            e = np.zeros(4)
            e[k] = h / f[k]
            a, sa = _dlt_points(stereo.R, stereo.t, (m + e)[:, :2], (m + e)[:, 2:])
            b, sb = _dlt_points(stereo.R, stereo.t, (m - e)[:, :2], (m - e)[:, 2:])
            J[:, :, k] = np.where(((sa == 0) & (sb == 0) & front)[:, None], (a - b) / (2 * h), np.nan)
        cov = np.einsum("nik,k,njk->nij", J, sig ** 2, J).reshape(P.shape + (3,))
    return FirstOrderError(cov, np.trace(cov, axis1=-2, axis2=-1), cov[..., 2, 2])
