"""Compiled per-point work of the variable-projection bundle (numba, cached on disk).

The numpy path of :mod:`._bundle` (``Problem._residual_numpy``, ``Problem._lm_numpy``) is
the reference: these kernels do the same arithmetic, one point at a time, instead of some
hundred whole-array numpy calls per evaluation on a few hundred points (the bundle's time
was numpy's per-call overhead, not arithmetic). The tests compare the two. This module
imports numba, so only :mod:`._bundle` imports it, lazily, on a problem's first evaluation
(``import optiacoustic`` and ``oas --help`` stay free of it). ``OAS_KERNELS=numpy`` selects
the reference path.

The model (see :mod:`._bundle`): a point's parameters ``p`` are ``(x, y)`` on its plane
``m`` (``X = (x, y, 1) / (m . (x, y, 1))``) or ``X`` itself; channel ``i`` (``kinds[i]``:
0 camera, 1 sonar) sees ``Y = A_i X + b_i`` (fixed) or ``Y = A_i (R_v X + c_v) + b_i``
(``moving[i]``); residuals are whitened by ``sig[i]``. No bounds are checked: the caller
passes arrays of matching shapes (float64, C-contiguous).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_PI = np.pi
_TWO_PI = 2 * np.pi


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _point(p, m, plane_model, kinds, moving, A, b, sig, meas, Rv, cv, K, want_theta, Jl, col, e, Jp, JX, Jt):
    """Residuals ``e (2C,)``, ``J_p (2C, n_p)`` and (``want_theta``) ``J_theta`` rows
    ``Jt (2C, n_theta)`` (written where non-zero: the caller zeroes it) of one point;
    ``JX (2C, 3)`` is scratch; ``col``: the first column of the point's plane in ``Jt``."""
    fx, fy, cx, cy = K[0], K[1], K[2], K[3]
    inv = 1.0
    if plane_model:
        inv = 1.0 / (m[0] * p[0] + m[1] * p[1] + m[2])
        X0, X1, X2 = p[0] * inv, p[1] * inv, inv
    else:
        X0, X1, X2 = p[0], p[1], p[2]
    RX0 = X0 * Rv[0, 0] + X1 * Rv[0, 1] + X2 * Rv[0, 2]
    RX1 = X0 * Rv[1, 0] + X1 * Rv[1, 1] + X2 * Rv[1, 2]
    RX2 = X0 * Rv[2, 0] + X1 * Rv[2, 1] + X2 * Rv[2, 2]
    C = kinds.shape[0]
    for i in range(C):
        L = A[i]
        if moving[i]:
            Z0, Z1, Z2 = RX0 + cv[0], RX1 + cv[1], RX2 + cv[2]
        else:
            Z0, Z1, Z2 = X0, X1, X2
        Y0 = Z0 * L[0, 0] + Z1 * L[0, 1] + Z2 * L[0, 2] + b[i, 0]
        Y1 = Z0 * L[1, 0] + Z1 * L[1, 1] + Z2 * L[1, 2] + b[i, 1]
        Y2 = Z0 * L[2, 0] + Z1 * L[2, 1] + Z2 * L[2, 2] + b[i, 2]
        s0, s1 = sig[i, 0], sig[i, 1]
        r0, r1 = 2 * i, 2 * i + 1
        if kinds[i] == 0:  # camera: ideal pixels
            iz = 1.0 / Y2
            x, y = Y0 * iz, Y1 * iz
            e[r0] = (fx * x + (cx - meas[i, 0])) / s0
            e[r1] = (fy * y + (cy - meas[i, 1])) / s1
            a0, a1 = (fx / s0) * iz, (fy / s1) * iz
            g00 = a0 * (L[0, 0] - x * L[2, 0])
            g01 = a0 * (L[0, 1] - x * L[2, 1])
            g02 = a0 * (L[0, 2] - x * L[2, 2])
            g10 = a1 * (L[1, 0] - y * L[2, 0])
            g11 = a1 * (L[1, 1] - y * L[2, 1])
            g12 = a1 * (L[1, 2] - y * L[2, 2])
        else:  # sonar: range, azimuth
            rho2 = Y0**2 + Y1**2
            r = np.sqrt(rho2 + Y2**2)
            e[r0] = (r - meas[i, 0]) / s0
            e[r1] = ((np.arctan2(Y0, Y1) - meas[i, 1] + _PI) % _TWO_PI - _PI) / s1
            q = 1.0 / (r * s0)
            q0, q1, q2 = Y0 * q, Y1 * q, Y2 * q
            g00 = q0 * L[0, 0] + q1 * L[1, 0] + q2 * L[2, 0]
            g01 = q0 * L[0, 1] + q1 * L[1, 1] + q2 * L[2, 1]
            g02 = q0 * L[0, 2] + q1 * L[1, 2] + q2 * L[2, 2]
            k = 1.0 / (rho2 * s1)
            k1, k0 = Y1 * k, Y0 * k
            g10 = k1 * L[0, 0] - k0 * L[1, 0]
            g11 = k1 * L[0, 1] - k0 * L[1, 1]
            g12 = k1 * L[0, 2] - k0 * L[1, 2]
        if moving[i]:
            for j in range(3):
                JX[r0, j] = g00 * Rv[0, j] + g01 * Rv[1, j] + g02 * Rv[2, j]
                JX[r1, j] = g10 * Rv[0, j] + g11 * Rv[1, j] + g12 * Rv[2, j]
            if want_theta:
                # d (R X) / d w = -[R X]_x J_l, and a^T [v]_x = (a x v)^T
                u0, u1, u2 = RX1 * g02 - RX2 * g01, RX2 * g00 - RX0 * g02, RX0 * g01 - RX1 * g00
                v0, v1, v2 = RX1 * g12 - RX2 * g11, RX2 * g10 - RX0 * g12, RX0 * g11 - RX1 * g10
                for j in range(3):
                    Jt[r0, j] = u0 * Jl[0, j] + u1 * Jl[1, j] + u2 * Jl[2, j]
                    Jt[r1, j] = v0 * Jl[0, j] + v1 * Jl[1, j] + v2 * Jl[2, j]
                Jt[r0, 3], Jt[r0, 4], Jt[r0, 5] = g00, g01, g02
                Jt[r1, 3], Jt[r1, 4], Jt[r1, 5] = g10, g11, g12
        else:
            JX[r0, 0], JX[r0, 1], JX[r0, 2] = g00, g01, g02
            JX[r1, 0], JX[r1, 1], JX[r1, 2] = g10, g11, g12
    if plane_model:
        # dX/dp = (I - X m^T)[:, :2] / s and dX/dm = -X X^T, through v = (d e / d X) X
        for r in range(2 * C):
            v = JX[r, 0] * X0 + JX[r, 1] * X1 + JX[r, 2] * X2
            Jp[r, 0] = (JX[r, 0] - v * m[0]) * inv
            Jp[r, 1] = (JX[r, 1] - v * m[1]) * inv
            if want_theta:
                Jt[r, col] = -v * X0
                Jt[r, col + 1] = -v * X1
                Jt[r, col + 2] = -v * X2
    else:
        for r in range(2 * C):
            Jp[r, 0], Jp[r, 1], Jp[r, 2] = JX[r, 0], JX[r, 1], JX[r, 2]


@njit(cache=True, nogil=True, error_model="numpy")
def residuals(P, M, plane, plane_model, kinds, moving, A, b, sig, meas, Rv, cv, K, want_theta, Jl, e, Jp, Jt):
    """Every point's residuals ``e (N, 2C)``, ``J_p (N, 2C, n_p)`` and (``want_theta``)
    ``J_theta (N, 2C, n_theta)`` (zeroed here): ``Problem._residual_numpy`` per point.
    ``M (N, 3)``: each point's plane (ignored for free points), ``plane (N,)`` its index."""
    N = P.shape[0]
    JX = np.empty((e.shape[1], 3))
    for n in range(N):
        if want_theta:
            Jt[n, :, :] = 0.0
        _point(P[n], M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, want_theta, Jl,
               6 + 3 * plane[n], e[n], Jp[n], JX, Jt[n])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _solve_damped(H, g, lam, dp):
    """``dp = -(H + lam diag(D))^{-1} g`` with ``D = max(diag(H), 1e-300 + 1e-12 max diag(H))``;
    0 where the system is singular or not finite (``_bundle._solve_small``: the closed form
    for two unknowns, elimination with partial pivoting for three)."""
    n = g.shape[0]
    dmax = H[0, 0]
    for i in range(1, n):
        dmax = max(dmax, H[i, i])
    floor = 1e-300 + 1e-12 * dmax
    if n == 2:
        a = H[0, 0] + lam * max(H[0, 0], floor)
        c = H[1, 1] + lam * max(H[1, 1], floor)
        bb = H[0, 1]
        inv = 1.0 / (a * c - bb * bb)
        x0 = (c * g[0] - bb * g[1]) * inv
        x1 = (a * g[1] - bb * g[0]) * inv
        if np.isfinite(x0) and np.isfinite(x1):
            dp[0], dp[1] = -x0, -x1
        else:
            dp[0], dp[1] = -0.0, -0.0
        return
    W = np.empty((3, 4))
    for i in range(3):
        for j in range(3):
            W[i, j] = H[i, j]
        W[i, i] += lam * max(H[i, i], floor)
        W[i, 3] = g[i]
    for c in range(3):
        piv = c
        for r in range(c + 1, 3):
            if abs(W[r, c]) > abs(W[piv, c]):
                piv = r
        if piv != c:
            for j in range(4):
                W[c, j], W[piv, j] = W[piv, j], W[c, j]
        for r in range(c + 1, 3):
            f = W[r, c] / W[c, c]
            for j in range(c + 1, 4):
                W[r, j] -= f * W[c, j]
    ok = True
    for i in range(2, -1, -1):
        s = W[i, 3]
        for j in range(i + 1, 3):
            s -= W[i, j] * dp[j]
        dp[i] = s / W[i, i]
        ok = ok and np.isfinite(dp[i])
    for i in range(3):
        dp[i] = -dp[i] if ok else -0.0


@njit(cache=True, nogil=True, error_model="numpy")
def lm(P, M, plane_model, kinds, moving, A, b, sig, meas, Rv, cv, K, inner, inner_rtol, have_e, E0, J0, cost):
    """Per-point Levenberg-Marquardt from ``P (N, n_p)``, in place; ``cost (N,)`` receives each
    point's final cost. ``Problem._lm_numpy`` one point at a time: the same damping, tests
    and stops. ``have_e``: ``E0 (N, 2C)``, ``J0 (N, 2C, n_p)`` hold the residuals and their
    Jacobian at ``P`` (else they are computed)."""
    N, n_p = P.shape
    R = kinds.shape[0] * 2
    e = np.empty(R)
    J = np.empty((R, n_p))
    et = np.empty(R)
    Jpt = np.empty((R, n_p))
    JX = np.empty((R, 3))
    Jt = np.empty((R, 1))
    Jl = np.empty((3, 3))
    H = np.empty((n_p, n_p))
    g = np.empty(n_p)
    dp = np.empty(n_p)
    pt = np.empty(n_p)
    for n in range(N):
        p = P[n]
        if have_e:
            e[:] = E0[n]
            J[:, :] = J0[n]
        else:
            _point(p, M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, False, Jl, 0, e, J, JX, Jt)
        c0 = 0.0
        for r in range(R):
            c0 += e[r] * e[r]
        if not np.isfinite(c0):
            c0 = np.inf
        lam = 1e-6
        for _ in range(inner):
            for i in range(n_p):
                gi = 0.0
                for r in range(R):
                    gi += J[r, i] * e[r]
                g[i] = gi
                for j in range(n_p):
                    h = 0.0
                    for r in range(R):
                        h += J[r, i] * J[r, j]
                    H[i, j] = h
            _solve_damped(H, g, lam, dp)
            pred = 0.0
            for i in range(n_p):
                pred += g[i] * dp[i]
            pred = -pred
            if pred <= 1e-10 * c0 + 1e-16:  # Gauss-Newton predicts nothing: take the step, stop
                for i in range(n_p):
                    p[i] += dp[i]
                break
            if pred <= inner_rtol * c0:  # near enough: stop without the step
                break
            for i in range(n_p):
                pt[i] = p[i] + dp[i]
            _point(pt, M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, False, Jl, 0, et, Jpt, JX, Jt)
            ct = 0.0
            for r in range(R):
                ct += et[r] * et[r]
            ok = np.isfinite(ct) and ct <= c0
            gain = c0 - ct if ok else 0.0
            if ok:
                p[:] = pt
                e[:] = et
                J[:, :] = Jpt
                c0 = ct
                lam = max(lam * 0.1, 1e-12)
            else:
                lam = min(lam * 10.0, 1e12)
            step = 0.0
            pmax = 0.0
            for i in range(n_p):
                step = max(step, abs(dp[i]))
                pmax = max(pmax, abs(p[i]))
            if step <= 1e-9 * (1 + pmax) or (ok and gain <= 1e-12 * c0 + 1e-24) or lam >= 1e8:
                break
        cost[n] = c0
