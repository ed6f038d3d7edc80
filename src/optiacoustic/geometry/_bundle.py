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

Each evaluation starts every point where the last one left it, moved to first order with
``theta`` (``dp/dtheta = -H_pp^{-1} H_ptheta``, which the Kaufman Jacobian needs anyway); a
point whose Gauss-Newton step promises nothing then costs one residual evaluation.

The per-point work (residuals, Jacobians, the per-point solve, the projection) runs in the
numba kernels of :mod:`._kernels`, imported on a problem's first evaluation; with
``OAS_KERNELS=numpy`` (:mod:`optiacoustic._kernel_switch`) it runs in the numpy reference
methods here (``_residual_numpy``, ``_lm_numpy``, :func:`_converged`), which the tests compare
with the kernels. A problem reads the switch when it is built (``Problem.kernels``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import OptimizeResult, least_squares, leastsq
from scipy.spatial.transform import Rotation


__all__: list[str] = []


# --------------------------------------------------------------------------- SO(3)
def exp_so3(w) -> np.ndarray:
    """Rotation matrix of the rotation vector ``w`` (rad), ``(..., 3) -> (..., 3, 3)``."""
    w = np.asarray(w, float)
    if w.shape == (3,):  # Rodrigues' formula: one vector, without scipy's per-call overhead
        a2 = float(w @ w)
        W = _skew3(w)
        if a2 < 1e-14:
            return np.eye(3) + W + 0.5 * (W @ W)
        a = np.sqrt(a2)
        return np.eye(3) + (np.sin(a) / a) * W + ((1.0 - np.cos(a)) / a2) * (W @ W)
    return Rotation.from_rotvec(w.reshape(-1, 3)).as_matrix().reshape(w.shape[:-1] + (3, 3))


def _skew3(w) -> np.ndarray:
    """``[w]_x`` of one 3-vector."""
    x, y, z = float(w[0]), float(w[1]), float(w[2])
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def log_so3(R) -> np.ndarray:
    """Rotation vector (rad) of a rotation matrix, ``(..., 3, 3) -> (..., 3)``."""
    R = np.asarray(R, float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def left_jacobian(w) -> np.ndarray:
    """Left Jacobian of SO(3): ``exp(w + d) ~ exp(J_l(w) d) exp(w)``."""
    w = np.asarray(w, float)
    a = float(np.sqrt(w @ w))
    W = _skew3(w)
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

    Attributes
    ----------
    inner_rtol : float
        A point's own solve also stops, without its last step, once Gauss-Newton predicts at
        most this fraction of its cost left to gain (0: only the classic tests; see
        ``docs/derivations.md``, "Motion estimation: the bundle's Jacobians").
    ftol : float
        ``least_squares``'s relative tolerance on the cost (default 1e-8).
    """

    def __init__(self, K, blocks, n_planes, R_ref, inner_iterations=10):
        self.K = K
        self._K = np.asarray(K, float)
        self.blocks = [b for b in blocks if b.n > 0]
        self.k = int(n_planes)
        self.R_ref = np.asarray(R_ref, float)
        self.inner = int(inner_iterations)
        self.inner_rtol = 0.0  # see _lm
        self.ftol = 1e-8  # the outer solve's relative cost tolerance
        self.n_theta = 6 + 3 * self.k
        self._cache_key = None
        self._cache = None
        self._warm = {}
        self._sens = {}
        self._jl_key = self._jl = None
        self._unpack_key = self._unpacked = None
        self.warm_start = True
        self._branches_fixed = False
        self.kernels = _use_kernels()  # the compiled per-point path (:mod:`._kernels`), else numpy's
        self.fast_outer = True  # MINPACK through leastsq's thin wrapper (else least_squares's)
        self._chan = {}

    # ---------------------------------------------------------------- parameters
    def unpack(self, theta):
        theta = np.asarray(theta, float)
        key = theta.tobytes()
        if self._unpack_key != key:  # (called once per block and per point solve)
            w, c = theta[:3].copy(), theta[3:6].copy()
            planes = theta[6:].reshape(self.k, 3).copy()
            self._unpack_key, self._unpacked = key, (exp_so3(w) @ self.R_ref, c, planes)
        return self._unpacked

    # ---------------------------------------------------------------- per-point model
    def _channels(self, block: Block):
        """The block's channels as the kernels' arrays ``(kinds, moving, A, b, sigma)`` (cached)."""
        c = self._chan.get(id(block))
        if c is None:
            chs = block.channels
            c = (np.array([0 if ch.kind == "camera" else 1 for ch in chs], np.int64),
                 np.array([ch.moving for ch in chs], np.bool_),
                 np.ascontiguousarray([ch.A for ch in chs], float), np.ascontiguousarray([ch.b for ch in chs], float),
                 np.ascontiguousarray(block.sigma, float))
            self._chan[id(block)] = c
        return c

    def _residual(self, block: Block, p, m, Rv, cv, w, want_theta=False, meas=None, plane=None):
        """Whitened residuals ``(N, 2C)`` with ``J_p (N, 2C, n_p)`` and optionally ``J_theta``
        (:func:`._kernels.residuals`, or the numpy reference :meth:`_residual_numpy`)."""
        if not self.kernels:
            return self._residual_numpy(block, p, m, Rv, cv, w, want_theta, meas, plane)
        from . import _kernels as Kn

        meas = block.meas if meas is None else meas
        plane = block.plane if plane is None else plane
        p = np.ascontiguousarray(p, float)
        N, n_p = p.shape
        C = len(block.channels)
        kinds, moving, A, b, sig = self._channels(block)
        e = np.empty((N, 2 * C))
        Jp = np.empty((N, 2 * C, n_p))
        Jt = np.empty((N, 2 * C, self.n_theta)) if want_theta else np.empty((1, 1, 1))
        Jl = self._left_jacobian(w) if want_theta else np.eye(3)
        M = _plane_rows(m, N)
        pl = np.zeros(N, np.int64) if (plane is None or m is None) else np.ascontiguousarray(plane, np.int64)
        Kn.residuals(p, M, pl, m is not None, kinds, moving, A, b, sig, np.ascontiguousarray(meas, float),
                     np.ascontiguousarray(Rv, float), np.ascontiguousarray(cv, float), self._K, bool(want_theta),
                     np.ascontiguousarray(Jl, float), e, Jp, Jt)
        return e, Jp, (Jt if want_theta else None)

    def _residual_numpy(self, block: Block, p, m, Rv, cv, w, want_theta=False, meas=None, plane=None):
        """Whitened residuals ``(N, 2C)`` with ``J_p (N, 2C, n_p)`` and optionally ``J_theta``.

        ``meas`` and ``plane`` default to the block's (they are passed when the points are
        replicated for several starts, or for a subset of them). The chain rule is spelt out
        per row with outer products (no batched small matrix products): see
        ``docs/derivations.md``, "Motion estimation: the bundle's Jacobians".
        """
        meas = block.meas if meas is None else meas
        N = p.shape[0]
        C = len(block.channels)
        e = np.empty((N, 2 * C))
        JX = np.empty((N, 2 * C, 3))  # d e / d X (reference frame)
        if want_theta:
            Jt = np.zeros((N, 2 * C, self.n_theta))
            Jl = self._left_jacobian(w)
        fx, fy, cx, cy = self.K
        with np.errstate(divide="ignore", invalid="ignore"):
            if m is None:
                X = p
            else:  # X = q / (m . q), q = (x, y, 1)
                inv = 1.0 / (m[:, 0] * p[:, 0] + m[:, 1] * p[:, 1] + m[:, 2])
                X = np.empty((N, 3))
                X[:, :2] = p * inv[:, None]
                X[:, 2] = inv
            RX = X @ Rv.T if want_theta or any(ch.moving for ch in block.channels) else None
            for i, ch in enumerate(block.channels):
                L = ch.A
                Y = (RX + cv) @ L.T + ch.b if ch.moving else X @ L.T + ch.b
                s0, s1 = block.sigma[i]
                # rows of d e / d Y contracted with L: d e / d (R X + c) for a moving channel,
                # d e / d X for a fixed one, (N, 3) each
                if ch.kind == "camera":
                    iz = 1.0 / Y[:, 2]
                    x, y = Y[:, 0] * iz, Y[:, 1] * iz
                    e[:, 2 * i] = (fx * x + (cx - meas[:, i, 0])) / s0
                    e[:, 2 * i + 1] = (fy * y + (cy - meas[:, i, 1])) / s1
                    a0, a1 = (fx / s0) * iz, (fy / s1) * iz
                    g0 = a0[:, None] * (L[0] - x[:, None] * L[2])
                    g1 = a1[:, None] * (L[1] - y[:, None] * L[2])
                else:
                    rho2 = Y[:, 0] ** 2 + Y[:, 1] ** 2
                    r = np.sqrt(rho2 + Y[:, 2] ** 2)
                    e[:, 2 * i] = (r - meas[:, i, 0]) / s0
                    e[:, 2 * i + 1] = wrap(np.arctan2(Y[:, 0], Y[:, 1]) - meas[:, i, 1]) / s1
                    g0 = (Y * (1.0 / (r * s0))[:, None]) @ L
                    k = 1.0 / (rho2 * s1)
                    g1 = (Y[:, 1] * k)[:, None] * L[0] - (Y[:, 0] * k)[:, None] * L[1]
                if ch.moving:
                    JX[:, 2 * i] = g0 @ Rv
                    JX[:, 2 * i + 1] = g1 @ Rv
                    if want_theta:
                        # d (R X) / d w = -[R X]_x J_l, and a^T [v]_x = (a x v)^T
                        Jt[:, 2 * i, 0:3] = _cross(RX, g0) @ Jl
                        Jt[:, 2 * i + 1, 0:3] = _cross(RX, g1) @ Jl
                        Jt[:, 2 * i, 3:6] = g0
                        Jt[:, 2 * i + 1, 3:6] = g1
                else:
                    JX[:, 2 * i] = g0
                    JX[:, 2 * i + 1] = g1
            if m is None:
                Jp = JX
            else:
                # dX/dp = (I - X m^T)[:, :2] / s and dX/dm = -X X^T, through v = (d e / d X) X
                v = np.einsum("nri,ni->nr", JX, X)
                Jp = (JX[:, :, :2] - v[:, :, None] * m[:, None, :2]) * inv[:, None, None]
        if not want_theta:
            return e, Jp, None
        plane = block.plane if plane is None else plane
        if m is not None:
            Jm = -v[:, :, None] * X[:, None, :]  # (N, 2C, 3)
            if self.k == 1:
                Jt[:, :, 6:9] = Jm
            else:
                cols = 6 + 3 * plane[:, None] + np.arange(3)[None, :]  # (N, 3)
                rows = np.arange(2 * C)
                Jt[np.arange(N)[:, None, None], rows[None, :, None], cols[:, None, :]] = Jm
        return e, Jp, Jt

    def _left_jacobian(self, w):
        key = np.asarray(w, float).tobytes()
        if self._jl_key != key:
            self._jl_key, self._jl = key, left_jacobian(w)
        return self._jl

    def _lm(self, block, p, m, Rv, cv, w, meas, e=None, Jp=None):
        """Per-point Levenberg-Marquardt from ``p``; returns ``(p, cost)`` (:func:`._kernels.lm`,
        or the numpy reference :meth:`_lm_numpy`)."""
        if not self.kernels:
            return self._lm_numpy(block, p, m, Rv, cv, w, meas, e, Jp)
        from . import _kernels as Kn

        P = np.array(p, float, order="C")
        N = P.shape[0]
        kinds, moving, A, b, sig = self._channels(block)
        cost = np.empty(N)
        have = e is not None
        E0 = np.ascontiguousarray(e, float) if have else np.empty((1, 1))
        J0 = np.ascontiguousarray(Jp, float) if have else np.empty((1, 1, 1))
        Kn.lm(P, _plane_rows(m, N), m is not None, kinds, moving, A, b, sig, np.ascontiguousarray(meas, float),
              np.ascontiguousarray(Rv, float), np.ascontiguousarray(cv, float), self._K, self.inner,
              float(self.inner_rtol), have, E0, J0, cost)
        return P, cost

    def _lm_numpy(self, block, p, m, Rv, cv, w, meas, e=None, Jp=None):
        """Vectorised per-point Levenberg-Marquardt from ``p``; returns ``(p, cost)``.

        A point leaves the iteration once it has converged (Gauss-Newton predicts a negligible
        decrease: it takes that step and stops; or its step or gain is negligible; or its
        damping has blown up), so the later iterations only evaluate the points still moving.
        ``e, Jp``: the residuals and their Jacobian at ``p``, when known.
        """
        p = np.array(p, float)
        if e is None:
            e, Jp, _ = self._residual(block, p, m, Rv, cv, w, meas=meas)
        cost = np.einsum("nr,nr->n", e, e)
        cost[~np.isfinite(cost)] = np.inf
        N = p.shape[0]
        lam = np.full(N, 1e-6)
        act = np.arange(N)  # the points still iterating; e, Jp hold their rows only
        for _ in range(self.inner):
            H = np.einsum("nri,nrj->nij", Jp, Jp)
            g = np.einsum("nri,nr->ni", Jp, e)
            D = np.diagonal(H, axis1=1, axis2=2)
            D = np.maximum(D, 1e-300 + 1e-12 * D.max(1, keepdims=True))
            dp = -_solve_small(H, g, lam[act, None] * D)
            # Gauss-Newton's predicted decrease; where negligible, take the step without a
            # trial evaluation and stop
            pred = -np.einsum("ni,ni->n", g, dp)
            conv = pred <= 1e-10 * cost[act] + 1e-16
            # near enough (``inner_rtol``): at most that fraction of the cost is left to gain,
            # to second order; the step itself may be long where the point is poorly
            # determined, so it is not taken
            near = pred <= self.inner_rtol * cost[act]
            if conv.any() or near.any():
                p[act[conv]] += dp[conv]
                run = ~(conv | near)
                act, e, Jp, dp = act[run], e[run], Jp[run], dp[run]
                if act.size == 0:
                    break
            pt = p[act] + dp
            et, Jpt, _ = self._residual(block, pt, None if m is None else m[act], Rv, cv, w, meas=meas[act])
            ct = np.einsum("nr,nr->n", et, et)
            c0 = cost[act]
            ok = np.isfinite(ct) & (ct <= c0)
            gain = np.where(ok, c0 - ct, 0.0)
            p[act[ok]] = pt[ok]
            e = np.where(ok[:, None], et, e)
            Jp = np.where(ok[:, None, None], Jpt, Jp)
            cost[act[ok]] = ct[ok]
            la = np.where(ok, np.maximum(lam[act] * 0.1, 1e-12), np.minimum(lam[act] * 10.0, 1e12))
            lam[act] = la
            # a point is done when its step is negligible or its damping has blown up
            step = np.max(np.abs(dp), axis=1)
            done = ((step <= 1e-9 * (1 + np.max(np.abs(p[act]), axis=1))) | (ok & (gain <= 1e-12 * cost[act] + 1e-24))
                    | (la >= 1e8))
            if done.all():
                break
            run = ~done
            act, e, Jp = act[run], e[run], Jp[run]
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
            warm = p0 = self._predict(block, warm, theta)
            if want_theta:  # where the prediction is already the optimum, one evaluation
                e, Jp, Jt = self._residual(block, p0, m, Rv, cv, w, True, plane=plane)
                run = ~self._converged(e, Jp, max(1e-10, self.inner_rtol))
                if run.any():  # the others: their own iterations, from there
                    p0 = p0.copy()
                    sub = (None if m is None else m[run]), block.meas[run]
                    p0[run], _ = self._lm(block, p0[run], sub[0], Rv, cv, w, sub[1], e[run], Jp[run])
                    e, Jp, Jt = e.copy(), Jp.copy(), Jt.copy()
                    e[run], Jp[run], Jt[run] = self._residual(block, p0[run], sub[0], Rv, cv, w, True, sub[1],
                                                              plane[run])
                if np.all(np.isfinite(p0)):
                    self._warm[id(block)] = p0
                return p0, e, Jp, Jt
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

    def _converged(self, e, Jp, rtol):
        """:func:`_converged` (its kernel when selected)."""
        if not self.kernels:
            return _converged(e, Jp, rtol)
        from . import _kernels as Kn

        out = np.empty(e.shape[0], np.bool_)
        Kn.converged(e, Jp, float(rtol), out)
        return out

    def _predict(self, block, warm, theta):
        """``warm`` moved to first order to ``theta``: ``p + dp/dtheta (theta - theta_0)``, with
        ``dp/dtheta = -H_pp^{-1} H_ptheta`` (the optimum's sensitivity, implicit function
        theorem) stored by the evaluation at ``theta_0`` that produced ``warm``."""
        s = self._sens.get(id(block))
        if s is None or s[0] is not warm:
            return warm
        dp = -(s[2] @ (np.asarray(theta, float) - s[1]))
        return np.where(np.isfinite(dp), warm + dp, warm)

    # ---------------------------------------------------------------- outer problem
    def _evaluate(self, theta):
        key = np.asarray(theta, float).tobytes()
        if key == self._cache_key:
            return self._cache
        es, Js = [], []
        for b in self.blocks:
            fused = self._evaluate_fused(b, theta) if self.kernels else None
            if fused is not None:
                e, Y, Jred = fused
            else:
                _, e, Jp, Jt = self.solve_points(b, theta, want_theta=True)
                Y, Jred = self._project(Jp, Jt)
            p = self._warm.get(id(b))
            if p is not None:  # the sensitivity of this solution, for the next evaluation's start
                self._sens[id(b)] = (p, np.array(theta, float), Y)
            es.append(e.reshape(-1))
            Js.append(Jred.reshape(-1, self.n_theta))
        e = np.concatenate(es) if es else np.zeros(0)
        J = np.concatenate(Js) if Js else np.zeros((0, self.n_theta))
        e = np.where(np.isfinite(e), e, 1e6)
        J = np.where(np.isfinite(J), J, 0.0)
        self._cache_key, self._cache = key, (e, J)
        return e, J

    def _evaluate_fused(self, block, theta):
        """``solve_points(block, theta, want_theta=True)`` and :meth:`_project` in one kernel
        call (:func:`._kernels.evaluate`) when the points start where the last evaluation left
        them (the warm path); returns ``(e, Y, Jred)``, or None when they do not."""
        warm = self._warm.get(id(block)) if self.warm_start else None
        if warm is None or not (self._branches_fixed or not block.multi_start):
            return None
        from . import _kernels as Kn

        Rv, cv, planes = self.unpack(theta)
        w = np.asarray(theta, float)[:3]
        m = planes[block.plane] if block.model == "plane" else None
        P = np.array(self._predict(block, warm, theta), float, order="C")
        N, n_p = P.shape
        C = len(block.channels)
        kinds, moving, A, b, sig = self._channels(block)
        e = np.empty((N, 2 * C))
        Jp = np.empty((N, 2 * C, n_p))
        Jt = np.empty((N, 2 * C, self.n_theta))
        Y = np.empty((N, n_p, self.n_theta))
        Jred = np.empty((N, 2 * C, self.n_theta))
        pl = np.ascontiguousarray(block.plane, np.int64) if m is not None else np.zeros(N, np.int64)
        Kn.evaluate(P, _plane_rows(m, N), pl, m is not None, kinds, moving, A, b, sig,
                    np.ascontiguousarray(block.meas, float), np.ascontiguousarray(Rv, float),
                    np.ascontiguousarray(cv, float), self._K, np.ascontiguousarray(self._left_jacobian(w), float),
                    self.inner, float(self.inner_rtol), float(max(1e-10, self.inner_rtol)), e, Jp, Jt, Y, Jred)
        if np.all(np.isfinite(P)):
            self._warm[id(block)] = P
        return e, Y, Jred

    def _project(self, Jp, Jt):
        """``Y = H_pp^{-1} H_ptheta`` (trace-regularised; NaN rows where singular, their ``J``
        zeroed by the caller) and the Kaufman Jacobian ``J_theta - J_p Y``, per point."""
        if self.kernels:
            from . import _kernels as Kn

            Y = np.empty((Jp.shape[0], Jp.shape[2], Jt.shape[2]))
            Jred = np.empty(Jt.shape)
            Kn.project(Jp, Jt, Y, Jred)
            return Y, Jred
        H = np.einsum("nri,nrj->nij", Jp, Jp)
        tr = 1e-12 * np.trace(H, axis1=1, axis2=2) + 1e-300
        G = np.einsum("nri,nrj->nij", Jp, Jt)
        Y = _solve_small(H, G, np.repeat(tr[:, None], H.shape[1], 1), bad=np.nan)
        with np.errstate(invalid="ignore", over="ignore"):
            Jred = Jt - np.einsum("nri,nit->nrt", Jp, Y)
        return Y, Jred

    def residuals(self, theta):
        return self._evaluate(theta)[0]

    def jacobian(self, theta):
        return self._evaluate(theta)[1]

    def solve(self, theta0, max_nfev=100, starts=None):
        """Minimise the reduced cost from ``theta0``; returns the scipy result.

        Every point's branch is chosen at the start, unless ``starts`` (one ``(N, n_params)``
        array per block: every point's optimum at ``theta0``, its branch chosen) are given.
        """
        self._branches_fixed = False
        self._warm = {}
        self._cache_key = None
        if starts is None:
            for b in self.blocks:  # choose every point's branch at the start
                self.solve_points(b, theta0)
        else:
            if [np.shape(p) for p in starts] != [(b.n, b.n_params) for b in self.blocks]:
                raise ValueError("starts: expected one (N, n_params) array per non-empty block")
            self._warm = {id(b): np.array(p, float) for b, p in zip(self.blocks, starts)}
        self._branches_fixed = True
        try:
            return self._least_squares(theta0, max_nfev)
        finally:
            self._branches_fixed = False

    def _least_squares(self, theta0, max_nfev):
        """MINPACK's Levenberg-Marquardt (``lmder``) from ``theta0``: the call that
        ``least_squares(method="lm", x_scale="jac")`` makes (``factor=100``, ``diag=None``, the
        same tolerances), through ``scipy.optimize.leastsq``, whose wrapper costs far less per
        evaluation; then, as ``least_squares`` does, the Jacobian at the solution (which leaves
        the points at its optimum). Returns an ``OptimizeResult`` with ``x``, ``cost``, ``fun``,
        ``nfev``, ``njev``."""
        x0 = np.array(theta0, float)
        if not self.fast_outer or self.residuals(x0).size < x0.size:  # (least_squares's own error)
            return least_squares(self.residuals, x0, jac=self.jacobian, method="lm", x_scale="jac", ftol=self.ftol,
                                 xtol=1e-10, gtol=1e-10, max_nfev=max_nfev)
        x, _, info, _, _ = leastsq(self.residuals, x0, Dfun=self.jacobian, full_output=True, col_deriv=False,
                                   ftol=self.ftol, xtol=1e-10, gtol=1e-10, maxfev=max_nfev, factor=100.0, diag=None)
        f = info["fvec"]
        self.jacobian(x)
        return OptimizeResult(x=x, cost=0.5 * float(f @ f), fun=f, nfev=int(info["nfev"]), njev=info.get("njev"))

    def adopt_points(self, other: "Problem") -> bool:
        """Start every block's points from ``other``'s last solution, following its branches:
        the points of a solve warm-start a problem built afresh at its optimum (e.g. with the
        rotation re-referenced there).

        Only when both problems have the same blocks in the same order (the same measurements
        on the same planes, checked element by element, not by size alone): otherwise nothing is
        adopted, the points are solved afresh, and False is returned."""
        same = len(self.blocks) == len(other.blocks) and all(
            b.model == o.model and b.meas.shape == o.meas.shape and np.array_equal(b.meas, o.meas)
            and np.array_equal(b.plane, o.plane) and id(o) in other._warm
            for b, o in zip(self.blocks, other.blocks))
        self._cache_key = None
        if not same:
            self._warm = {}
            self._branches_fixed = False
            return False
        self._warm = {id(b): other._warm[id(o)] for b, o in zip(self.blocks, other.blocks)}
        self._branches_fixed = True
        return True

    def point_chi2(self, block: Block, theta, plane=None):
        """Reduced chi-square of every point of ``block`` (under ``plane`` indices if given)."""
        _, e, _, _ = self.solve_points(block, theta, plane=plane)
        c = np.sum(e * e, axis=1)
        return np.where(np.isfinite(c), c, np.inf)


def _use_kernels() -> bool:
    from .._kernel_switch import use_numba

    return use_numba()


def _plane_rows(m, N):
    """Each point's plane ``(N, 3)`` for the kernels (zeros for free points)."""
    if m is None:
        return np.zeros((N, 3))
    m = np.asarray(m, float)
    return m if m.shape == (N, 3) and m.flags.c_contiguous else np.ascontiguousarray(np.broadcast_to(m, (N, 3)))


def _cross(a, b):
    """Row-wise cross product of two (N, 3) arrays (``np.cross`` without its axis handling)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _solve_small(H, B, damping=None, bad=0.0):
    """``(H + diag(damping))^{-1} B`` for a batch of small symmetric systems.

    ``H (N, n, n)``, ``B (N, n)`` or ``(N, n, m)``, ``damping (N, n)``. Two unknowns (a point
    on a plane) by the closed form, more by ``numpy.linalg.solve``; a system that is singular
    or not finite gives ``bad``.
    """
    n = H.shape[1]
    vec = B.ndim == 2
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        if n == 2:
            a, b, c = H[:, 0, 0], H[:, 0, 1], H[:, 1, 1]
            if damping is not None:
                a, c = a + damping[:, 0], c + damping[:, 1]
            inv = 1.0 / (a * c - b * b)
            x = np.empty(B.shape)
            if not vec:
                a, b, c, inv = a[:, None], b[:, None], c[:, None], inv[:, None]
            x[:, 0] = (c * B[:, 0] - b * B[:, 1]) * inv
            x[:, 1] = (a * B[:, 1] - b * B[:, 0]) * inv
        else:
            Hd = H if damping is None else H + damping[:, :, None] * np.eye(n)
            try:
                x = np.linalg.solve(Hd, B[..., None])[..., 0] if vec else np.linalg.solve(Hd, B)
            except np.linalg.LinAlgError:
                x = np.full(B.shape, np.nan)
    ok = np.all(np.isfinite(x.reshape(x.shape[0], -1)), 1)
    return np.where(ok.reshape((-1,) + (1,) * (x.ndim - 1)), x, bad)


def _converged(e, Jp, rtol) -> np.ndarray:
    """Points for which Gauss-Newton predicts a gain of at most ``rtol`` of their cost, (N,)."""
    cost = np.einsum("nr,nr->n", e, e)
    H = np.einsum("nri,nrj->nij", Jp, Jp)
    g = np.einsum("nri,nr->ni", Jp, e)
    tr = 1e-12 * np.trace(H, axis1=1, axis2=2) + 1e-300
    pred = np.einsum("ni,ni->n", g, _solve_small(H, g, np.repeat(tr[:, None], H.shape[1], 1)))
    ok = np.isfinite(cost) & np.all(np.isfinite(g), 1)
    return ok & (pred <= rtol * cost + 1e-16)


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
