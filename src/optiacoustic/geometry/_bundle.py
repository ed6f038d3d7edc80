"""Maximum likelihood over a pose and planes, with the per-point structure eliminated.

Shared by :mod:`.motion` (eq. 6.17) and :mod:`.calibrate` (appendix A). The unknowns are

* one variable rigid transform ``(R_var, c_var)``: the camera motion ``(R_o, t_o)`` in
  motion estimation, the rig's ``(R, t)`` in calibration, parametrised on the left as
  ``R_var = exp(w) R_ref`` (``w`` in rad, so the covariance lives in the tangent space);
* ``k`` planes ``m_j`` in the reference camera frame, the plane being ``m_j . X = 1``
  (``m = n / d`` with ``n`` the unit normal pointing away from the camera and ``d > 0``
  its distance, in 1/m);
* per point, its position ``X`` in the reference camera frame: two parameters on a plane
  (the normalised camera coordinates ``(x, y)`` with ``X = (x, y, 1) / (m . (x, y, 1))``)
  or three when it is free (``X`` itself).

Every point is seen through a few *channels*: a camera or a sonar whose frame is
``Y = A X + b`` (fixed) or ``Y = L (R_var X + c_var) + e`` (moving with the variable
transform). A camera channel measures ideal pixels ``(fx Y0/Y2 + cx, fy Y1/Y2 + cy)``, a
sonar channel ``(|Y|, atan2(Y0, Y1))``. Residuals are whitened by the noise standard
deviations, so the cost is the negative log-likelihood up to a constant.

The per-point parameters are solved for (Gauss-Newton, vectorised over points) at every
evaluation, and the outer problem sees the *reduced* residual with the Kaufman Jacobian
``(I - J_p J_p^+) J_theta``: variable projection. At the optimum
``(J_red^T J_red)^{-1}`` is the Schur complement of the full bundle adjustment's
information matrix, i.e. the marginal covariance of ``(w, c, m_1..m_k)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..frames import skew

__all__: list[str] = []


# --------------------------------------------------------------------------- SO(3)
def exp_so3(w) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (rad), ``(..., 3) -> (..., 3, 3)``."""
    w = np.asarray(w, float)
    return Rotation.from_rotvec(w.reshape(-1, 3)).as_matrix().reshape(w.shape[:-1] + (3, 3))


def log_so3(R) -> np.ndarray:
    """Rotation vector (rad) of a rotation matrix, ``(..., 3, 3) -> (..., 3)``."""
    R = np.asarray(R, float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def left_jacobian(w) -> np.ndarray:
    """Left Jacobian of SO(3): ``exp(w + d) ~ exp(J_l(w) d) exp(w)``."""
    w = np.asarray(w, float)
    a = float(np.linalg.norm(w))
    W = skew(w)
    if a < 1e-7:
        return np.eye(3) + 0.5 * W + W @ W / 6.0
    return np.eye(3) + (1 - np.cos(a)) / a**2 * W + (a - np.sin(a)) / a**3 * (W @ W)


def wrap(a):
    """Angles wrapped to ``(-pi, pi]``."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# --------------------------------------------------------------------------- measurements
@dataclass(frozen=True)
class Channel:
    """One sensor view of a block of points.

    ``kind`` is ``"camera"`` or ``"sonar"``. A fixed channel has ``Y = A X + b``; a moving
    one (``moving=True``) has ``Y = L (R_var X + c_var) + e``, the arrays below being
    ``A, b`` or ``L, e``.
    """

    kind: str
    moving: bool
    A: np.ndarray
    b: np.ndarray


@dataclass
class Block:
    """Points seen through the same channels.

    Attributes
    ----------
    channels : tuple of Channel
    meas : ndarray (N, n_channels, 2)
        Measurements: ideal pixels or (range, azimuth).
    sigma : ndarray (n_channels, 2)
        Standard deviations that whiten each measurement.
    model : "plane" or "free"
    plane : ndarray of int (N,)
        Plane index of each point (plane model).
    init : callable (R_var, c_var, planes (k, 3), plane (N,)) -> ndarray (N, n_params) or (N, C, n_params)
        Start(s) of the per-point solve, a function of the outer parameters only.
    multi_start : bool
        ``init`` returns several candidates (branches) per point.
    """

    channels: tuple
    meas: np.ndarray
    sigma: np.ndarray
    model: str
    init: object
    plane: np.ndarray = field(default=None)
    multi_start: bool = False

    @property
    def n(self) -> int:
        return self.meas.shape[0]

    @property
    def n_params(self) -> int:
        return 2 if self.model == "plane" else 3


def point_from_params(p, m):
    """Reference-frame points ``X (N, 3)`` from per-point parameters, with ``dX/dp`` and ``dX/dm``.

    Plane model: ``p = (x, y)``, ``X = q / (m . q)`` with ``q = (x, y, 1)``;
    ``dX/dp = (I - X m^T)[:, :2] / s`` and ``dX/dm = -X X^T`` (``s = m . q``).
    Free model (``m is None``): ``X = p``.
    """
    if m is None:
        N = p.shape[0]
        return p.copy(), np.broadcast_to(np.eye(3), (N, 3, 3)), None
    s = m[:, 0] * p[:, 0] + m[:, 1] * p[:, 1] + m[:, 2]
    N = p.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / s
        X = np.empty((N, 3))
        X[:, :2] = p * inv[:, None]
        X[:, 2] = inv
        # (I - X m^T)[:, :2] / s
        dXdp = X[:, :, None] * (-m[:, None, :2] * inv[:, None, None])
        dXdp[:, 0, 0] += inv
        dXdp[:, 1, 1] += inv
    dXdm = -X[:, :, None] * X[:, None, :]
    return X, dXdp, dXdm


class Problem:
    """The reduced (variable projection) least-squares problem; see the module docstring.

    Parameters
    ----------
    K : tuple (fx, fy, cx, cy)
        Camera intrinsics of the ideal pixels.
    blocks : list of Block
    n_planes : int
    R_ref : ndarray (3, 3)
        The variable rotation is ``exp(w) R_ref``.
    inner_iterations : int
        Gauss-Newton steps of the per-point solve.
    """

    def __init__(self, K, blocks, n_planes, R_ref, inner_iterations=10):
        self.K = K
        self.blocks = [b for b in blocks if b.n > 0]
        self.k = int(n_planes)
        self.R_ref = np.asarray(R_ref, float)
        self.inner = int(inner_iterations)
        self.n_theta = 6 + 3 * self.k
        self._cache_key = None
        self._cache = None
        self._warm = {}
        self.warm_start = True
        self._branches_fixed = False

    # ---------------------------------------------------------------- parameters
    def unpack(self, theta):
        theta = np.asarray(theta, float)
        w, c = theta[:3], theta[3:6]
        planes = theta[6:].reshape(self.k, 3)
        return exp_so3(w) @ self.R_ref, c, planes

    # ---------------------------------------------------------------- per-point model
    def _residual(self, block: Block, p, m, Rv, cv, w, want_theta=False, meas=None, plane=None):
        """Whitened residuals ``(N, 2C)`` with ``J_p (N, 2C, n_p)`` and optionally ``J_theta``.

        ``meas`` and ``plane`` default to the block's (they are passed when the points are
        replicated for several starts).
        """
        meas = block.meas if meas is None else meas
        X, dXdp, dXdm = point_from_params(p, m)
        N = X.shape[0]
        C = len(block.channels)
        e = np.empty((N, 2 * C))
        Jc = np.empty((N, 2 * C, 3))  # d e / d Y, times the channel's A (or L)
        if want_theta:
            Jt = np.zeros((N, 2 * C, self.n_theta))
            Jl = left_jacobian(w)
            RX = X @ Rv.T  # (N, 3)
        fx, fy = self.K[0], self.K[1]
        with np.errstate(divide="ignore", invalid="ignore"):
            for i, ch in enumerate(block.channels):
                A = ch.A @ Rv if ch.moving else ch.A
                Y = X @ A.T + ((ch.A @ cv + ch.b) if ch.moving else ch.b)
                s0, s1 = block.sigma[i]
                # rows of d e / d Y, contracted with ch.A directly (outer products, no
                # batched 2x3 @ 3x3 products)
                L = ch.A
                if ch.kind == "camera":
                    iz = 1.0 / Y[:, 2]
                    x, y = Y[:, 0] * iz, Y[:, 1] * iz
                    e[:, 2 * i] = (fx * x + (self.K[2] - meas[:, i, 0])) / s0
                    e[:, 2 * i + 1] = (fy * y + (self.K[3] - meas[:, i, 1])) / s1
                    a0, a1 = (fx / s0) * iz, (fy / s1) * iz
                    Jc[:, 2 * i] = a0[:, None] * (L[0] - x[:, None] * L[2])
                    Jc[:, 2 * i + 1] = a1[:, None] * (L[1] - y[:, None] * L[2])
                else:
                    rho2 = Y[:, 0] ** 2 + Y[:, 1] ** 2
                    r = np.sqrt(rho2 + Y[:, 2] ** 2)
                    e[:, 2 * i] = (r - meas[:, i, 0]) / s0
                    e[:, 2 * i + 1] = wrap(np.arctan2(Y[:, 0], Y[:, 1]) - meas[:, i, 1]) / s1
                    Jc[:, 2 * i] = (Y / (r * s0)[:, None]) @ L
                    k = 1.0 / (rho2 * s1)
                    Jc[:, 2 * i + 1] = (Y[:, 1] * k)[:, None] * L[0] - (Y[:, 0] * k)[:, None] * L[1]
                if want_theta and ch.moving:
                    Jci = Jc[:, 2 * i:2 * i + 2]
                    # d Y / d w = -L [R X]_x J_l, and a^T [v]_x = (a x v)^T
                    Jt[:, 2 * i:2 * i + 2, 0:3] = np.cross(RX[:, None, :], Jci) @ Jl
                    Jt[:, 2 * i:2 * i + 2, 3:6] = Jci
            # d e / d X: moving channels see X through R_var
            JX = Jc.copy() if want_theta else Jc
            for i, ch in enumerate(block.channels):
                if ch.moving:
                    JX[:, 2 * i:2 * i + 2] = JX[:, 2 * i:2 * i + 2] @ Rv
            Jp = JX @ dXdp
        if not want_theta:
            return e, Jp, None
        plane = block.plane if plane is None else plane
        if dXdm is not None:
            Jm = JX @ dXdm  # (N, 2C, 3)
            if self.k == 1:
                Jt[:, :, 6:9] = Jm
            else:
                cols = 6 + 3 * plane[:, None] + np.arange(3)[None, :]  # (N, 3)
                rows = np.arange(2 * C)
                Jt[np.arange(N)[:, None, None], rows[None, :, None], cols[:, None, :]] = Jm
        return e, Jp, Jt

    def _lm(self, block, p, m, Rv, cv, w, meas):
        """Vectorised per-point Levenberg-Marquardt from ``p``; returns ``(p, cost)``."""
        e, Jp, _ = self._residual(block, p, m, Rv, cv, w, meas=meas)
        cost = np.sum(e * e, 1)
        cost = np.where(np.isfinite(cost), cost, np.inf)
        N = p.shape[0]
        lam = np.full(N, 1e-6)
        eye = np.eye(p.shape[1])
        for _ in range(self.inner):
            H = np.einsum("nri,nrj->nij", Jp, Jp)
            g = np.einsum("nri,nr->ni", Jp, e)
            D = np.diagonal(H, axis1=1, axis2=2)
            Hd = H + (lam[:, None] * np.maximum(D, 1e-300 + 1e-12 * D.max(1, keepdims=True)))[:, :, None] * eye
            with np.errstate(invalid="ignore", over="ignore"):
                try:
                    dp = np.linalg.solve(Hd, -g[..., None])[..., 0]
                except np.linalg.LinAlgError:
                    dp = np.zeros_like(p)
            dp = np.where(np.all(np.isfinite(dp), 1)[:, None], dp, 0.0)
            # Gauss-Newton's predicted decrease; when negligible everywhere, take the step
            # without a trial evaluation and stop
            pred = -np.einsum("ni,ni->n", g, dp)
            if np.all(pred <= 1e-10 * cost + 1e-16):
                return p + dp, cost
            pt = p + dp
            et, Jpt, _ = self._residual(block, pt, m, Rv, cv, w, meas=meas)
            ct = np.sum(et * et, 1)
            ok = np.isfinite(ct) & (ct <= cost)
            gain = np.where(ok, cost - ct, 0.0)
            p = np.where(ok[:, None], pt, p)
            e = np.where(ok[:, None], et, e)
            Jp = np.where(ok[:, None, None], Jpt, Jp)
            cost = np.where(ok, ct, cost)
            lam = np.where(ok, np.maximum(lam * 0.1, 1e-12), np.minimum(lam * 10.0, 1e12))
            # a point is done when its step is negligible or its damping has blown up
            step = np.max(np.abs(dp), axis=1)
            done = ((step <= 1e-9 * (1 + np.max(np.abs(p), axis=1))) | (ok & (gain <= 1e-12 * cost + 1e-24))
                    | (lam >= 1e8))
            if done.all():
                break
        return p, cost

    def solve_points(self, block: Block, theta, plane=None, want_theta=False):
        """Per-point Levenberg-Marquardt; returns ``p, e, J_p, J_theta`` (``J_theta`` only if asked).

        ``block.init`` may return several candidate starts per point, ``(N, C, n_p)`` (e.g.
        both elevation roots of a sonar point on a plane): each is refined (and so is the
        best fit is kept. :meth:`solve` chooses the branches once, at its start, and then
        follows them (each point restarts from its last solution), so that the outer solver
        sees a smooth cost; the branches are chosen afresh at the next :meth:`solve` (the
        relabelling iterations). A block with a single start always restarts from its last
        solution.
        """
        Rv, cv, planes = self.unpack(theta)
        w = np.asarray(theta, float)[:3]
        own = plane is None
        plane = block.plane if own else plane
        m = planes[plane] if block.model == "plane" else None
        N = block.n
        warm = self._warm.get(id(block)) if (own and self.warm_start) else None
        if warm is not None and (self._branches_fixed or not block.multi_start):
            p0 = warm
        else:
            p0 = np.asarray(block.init(Rv, cv, planes, plane), float)
        if p0.ndim == 2:
            # one start: the last solution when there is one (one or two iterations), else it
            p, _ = self._lm(block, warm if warm is not None else p0, m, Rv, cv, w, block.meas)
        else:
            starts = [p0[:, c] for c in range(p0.shape[1])]
            S = len(starts)
            P = np.concatenate([np.where(np.isfinite(x), x, 0.0) for x in starts])
            bad = np.concatenate([~np.all(np.isfinite(x), 1) for x in starts])
            mt = None if m is None else np.tile(m, (S, 1))
            Pf, cost = self._lm(block, P, mt, Rv, cv, w, np.tile(block.meas, (S, 1, 1)))
            cost = np.where(bad, np.inf, cost).reshape(S, N)
            k = np.argmin(cost, 0)
            p = Pf.reshape(S, N, -1)[k, np.arange(N)]
        e, Jp, Jt = self._residual(block, p, m, Rv, cv, w, want_theta, plane=plane)
        if own and self.warm_start and np.all(np.isfinite(p)):
            self._warm[id(block)] = p
        return p, e, Jp, Jt

    # ---------------------------------------------------------------- outer problem
    def _evaluate(self, theta):
        key = np.asarray(theta, float).tobytes()
        if key == self._cache_key:
            return self._cache
        es, Js = [], []
        for b in self.blocks:
            _, e, Jp, Jt = self.solve_points(b, theta, want_theta=True)
            H = np.einsum("nri,nrj->nij", Jp, Jp)
            H = H + (1e-12 * np.trace(H, axis1=1, axis2=2) + 1e-300)[:, None, None] * np.eye(Jp.shape[2])
            G = np.einsum("nri,nrj->nij", Jp, Jt)
            with np.errstate(invalid="ignore", over="ignore"):
                Jred = Jt - Jp @ np.linalg.solve(H, G)
            es.append(e.reshape(-1))
            Js.append(Jred.reshape(-1, self.n_theta))
        e = np.concatenate(es) if es else np.zeros(0)
        J = np.concatenate(Js) if Js else np.zeros((0, self.n_theta))
        e = np.where(np.isfinite(e), e, 1e6)
        J = np.where(np.isfinite(J), J, 0.0)
        self._cache_key, self._cache = key, (e, J)
        return e, J

    def residuals(self, theta):
        return self._evaluate(theta)[0]

    def jacobian(self, theta):
        return self._evaluate(theta)[1]

    def solve(self, theta0, max_nfev=100):
        """Minimise the reduced cost from ``theta0``; returns the scipy result."""
        self._branches_fixed = False
        self._warm = {}
        self._cache_key = None
        for b in self.blocks:  # choose every point's branch at the start
            self.solve_points(b, theta0)
        self._branches_fixed = True
        try:
            return self._least_squares(theta0, max_nfev)
        finally:
            self._branches_fixed = False

    def _least_squares(self, theta0, max_nfev):
        return least_squares(self.residuals, np.asarray(theta0, float), jac=self.jacobian, method="lm",
                             x_scale="jac", ftol=1e-8, xtol=1e-10, gtol=1e-10, max_nfev=max_nfev)

    def point_chi2(self, block: Block, theta, plane=None):
        """Reduced chi-square of every point of ``block`` (under ``plane`` indices if given)."""
        _, e, _, _ = self.solve_points(block, theta, plane=plane)
        c = np.sum(e * e, axis=1)
        return np.where(np.isfinite(c), c, np.inf)


def covariance_from_jacobian(J) -> tuple[np.ndarray, bool]:
    """``(J^T J)^{-1}`` and whether ``J`` has full column rank (else a pseudo-inverse).

    Through the eigen-decomposition of the column-equilibrated normal matrix: it is small
    (parameters x parameters), so this costs nothing next to an SVD of ``J``.
    """
    n = J.shape[1]
    if J.shape[0] < n:
        return np.full((n, n), np.nan), False
    c = np.linalg.norm(J, axis=0)
    c = np.where(c > 0, c, 1.0)
    Js = J / c
    lam, V = np.linalg.eigh(Js.T @ Js)
    ok = lam[0] > 1e-20 * lam[-1] and lam[-1] > 0
    inv = np.where(lam > 1e-20 * lam[-1], 1.0 / np.maximum(lam, 1e-300), 0.0)
    C = (V * inv) @ V.T
    return C / c[:, None] / c[None, :], bool(ok)
