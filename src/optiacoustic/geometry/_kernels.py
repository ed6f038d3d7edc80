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


@njit(cache=True, nogil=True, error_model="numpy")
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
def _copy(src, dst):
    """``dst[:] = src`` (1-D) as a loop: numba's slice assignment costs seconds of compilation."""
    for i in range(src.shape[0]):
        dst[i] = src[i]


@njit(cache=True, nogil=True, error_model="numpy")
def _copy2(src, dst):
    """``dst[:, :] = src`` (2-D) as a loop."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[i, j] = src[i, j]


@njit(cache=True, nogil=True, error_model="numpy")
def _fill2(dst, v):
    """``dst[:, :] = v`` (2-D) as a loop."""
    for i in range(dst.shape[0]):
        for j in range(dst.shape[1]):
            dst[i, j] = v


@njit(cache=True, nogil=True, error_model="numpy")
def _no_theta(kinds):
    """``(False, 0)`` as run-time values: :func:`_point` called with the literals ``False`` or
    ``True`` would be compiled once more for each (numba specialises on literal arguments)."""
    return kinds.shape[0] < 0, kinds.shape[0] * 0


@njit(cache=True, nogil=True, error_model="numpy")
def residuals(P, M, plane, plane_model, kinds, moving, A, b, sig, meas, Rv, cv, K, want_theta, Jl, e, Jp, Jt):
    """Every point's residuals ``e (N, 2C)``, ``J_p (N, 2C, n_p)`` and (``want_theta``)
    ``J_theta (N, 2C, n_theta)`` (zeroed here): ``Problem._residual_numpy`` per point.
    ``M (N, 3)``: each point's plane (ignored for free points), ``plane (N,)`` its index."""
    N = P.shape[0]
    JX = np.empty((e.shape[1], 3))
    for n in range(N):
        if want_theta:
            _fill2(Jt[n], 0.0)
        _point(P[n], M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, want_theta, Jl,
               6 + 3 * plane[n], e[n], Jp[n], JX, Jt[n])


@njit(cache=True, nogil=True, error_model="numpy")
def _lm_point(p, m, plane_model, kinds, moving, A, b, sig, meas, Rv, cv, K, inner, inner_rtol, e, J,
              et, Jpt, JX, Jt1, Jl, H, g, d, gm, x, dp, pt):
    """Levenberg-Marquardt of one point from ``p`` (in place), ``e, J`` holding its residuals
    and their Jacobian there (updated); returns its final cost. ``Problem._lm_numpy`` for one
    point: the same damping, tests and stops. The other arrays are scratch."""
    R, n_p = J.shape
    no, zero = _no_theta(kinds)
    c0 = 0.0
    for r in range(R):
        c0 += e[r] * e[r]
    if not np.isfinite(c0):
        c0 = np.inf
    lam = 1e-6
    for _ in range(inner):
        _normal(J, e, H, g)
        # damping lam * D, D = max(diag(H), 1e-300 + 1e-12 max diag(H)); a singular or
        # non-finite system gives no step (``_bundle._solve_small``'s ``bad=0``)
        dmax = H[0, 0]
        for i in range(1, n_p):
            dmax = max(dmax, H[i, i])
        for i in range(n_p):
            d[i] = lam * max(H[i, i], 1e-300 + 1e-12 * dmax)
            gm[i, 0] = g[i]
        fin = _solve_diag(H, d, gm, x)
        for i in range(n_p):
            dp[i] = -x[i, 0] if fin else -0.0
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
        _point(pt, m, plane_model, kinds, moving, A, b, sig, meas, Rv, cv, K, no, Jl, zero, et, Jpt, JX, Jt1)
        ct = 0.0
        for r in range(R):
            ct += et[r] * et[r]
        ok = np.isfinite(ct) and ct <= c0
        gain = c0 - ct if ok else 0.0
        if ok:
            _copy(pt, p)
            _copy(et, e)
            _copy2(Jpt, J)
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
    return c0


@njit(cache=True, nogil=True, error_model="numpy")
def lm(P, M, plane_model, kinds, moving, A, b, sig, meas, Rv, cv, K, inner, inner_rtol, have_e, E0, J0, cost):
    """Per-point Levenberg-Marquardt from ``P (N, n_p)``, in place; ``cost (N,)`` receives each
    point's final cost (``Problem._lm_numpy``). ``have_e``: ``E0 (N, 2C)``, ``J0 (N, 2C, n_p)``
    hold the residuals and their Jacobian at ``P`` (else they are computed)."""
    N, n_p = P.shape
    R = kinds.shape[0] * 2
    e, J, et, Jpt = np.empty(R), np.empty((R, n_p)), np.empty(R), np.empty((R, n_p))
    JX, Jt1, Jl = np.empty((R, 3)), np.empty((R, 1)), np.empty((3, 3))
    H, g, d = np.empty((n_p, n_p)), np.empty(n_p), np.empty(n_p)
    gm, x, dp, pt = np.empty((n_p, 1)), np.empty((n_p, 1)), np.empty(n_p), np.empty(n_p)
    no, zero = _no_theta(kinds)
    for n in range(N):
        if have_e:
            _copy(E0[n], e)
            _copy2(J0[n], J)
        else:
            _point(P[n], M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, no, Jl, zero, e, J, JX, Jt1)
        cost[n] = _lm_point(P[n], M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, inner, inner_rtol,
                            e, J, et, Jpt, JX, Jt1, Jl, H, g, d, gm, x, dp, pt)


@njit(cache=True, nogil=True, error_model="numpy")
def _solve_diag(H, d, B, X):
    """``X = (H + diag(d))^{-1} B`` for one small system (``H (n, n)``, ``B (n, k)``); returns
    whether it is finite. Two unknowns by ``_bundle._solve_small``'s closed form, three by
    elimination with partial pivoting."""
    n, k = B.shape
    ok = True
    if n == 2:
        a, c, bb = H[0, 0] + d[0], H[1, 1] + d[1], H[0, 1]
        inv = 1.0 / (a * c - bb * bb)
        for j in range(k):
            X[0, j] = (c * B[0, j] - bb * B[1, j]) * inv
            X[1, j] = (a * B[1, j] - bb * B[0, j]) * inv
            ok = ok and np.isfinite(X[0, j]) and np.isfinite(X[1, j])
        return ok
    W = np.empty((n, n + k))
    for i in range(n):
        for j in range(n):
            W[i, j] = H[i, j]
        W[i, i] += d[i]
        for j in range(k):
            W[i, n + j] = B[i, j]
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(W[r, c]) > abs(W[piv, c]):
                piv = r
        if piv != c:
            for j in range(n + k):
                W[c, j], W[piv, j] = W[piv, j], W[c, j]
        for r in range(c + 1, n):
            f = W[r, c] / W[c, c]
            for j in range(c + 1, n + k):
                W[r, j] -= f * W[c, j]
    for j in range(k):
        for i in range(n - 1, -1, -1):
            s = W[i, n + j]
            for q in range(i + 1, n):
                s -= W[i, q] * X[q, j]
            X[i, j] = s / W[i, i]
            ok = ok and np.isfinite(X[i, j])
    return ok


@njit(cache=True, nogil=True, error_model="numpy")
def _normal(J, e, H, g):
    """``H = J^T J`` and ``g = J^T e`` of one point."""
    R, n_p = J.shape
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


@njit(cache=True, nogil=True, error_model="numpy")
def _converged_point(e, J, rtol, H, g, d, gm, x):
    """``_bundle._converged`` for one point: whether Gauss-Newton (trace-regularised normal
    equations) predicts a gain of at most ``rtol`` of its cost."""
    R, n_p = J.shape
    _normal(J, e, H, g)
    cost = 0.0
    for r in range(R):
        cost += e[r] * e[r]
    tr = 0.0
    fin = True
    for i in range(n_p):
        tr += H[i, i]
        gm[i, 0] = g[i]
        fin = fin and np.isfinite(g[i])
    for i in range(n_p):
        d[i] = 1e-12 * tr + 1e-300
    pred = 0.0
    if _solve_diag(H, d, gm, x):
        for i in range(n_p):
            pred += g[i] * x[i, 0]
    return np.isfinite(cost) and fin and pred <= rtol * cost + 1e-16


@njit(cache=True, nogil=True, error_model="numpy")
def converged(e, Jp, rtol, out):
    """``_bundle._converged`` for every point, into ``out (N,)``."""
    N, R, n_p = Jp.shape
    H, g, d = np.empty((n_p, n_p)), np.empty(n_p), np.empty(n_p)
    gm, x = np.empty((n_p, 1)), np.empty((n_p, 1))
    for n in range(N):
        out[n] = _converged_point(e[n], Jp[n], rtol, H, g, d, gm, x)


@njit(cache=True, nogil=True, error_model="numpy")
def _project_point(J, Jt, Y, Jred, H, G, d):
    """One point's ``Y = (H + (1e-12 tr(H) + 1e-300) I)^{-1} J_p^T J_theta`` (``H = J_p^T
    J_p``; NaN where singular) and ``Jred = J_theta - J_p Y``."""
    R, n_p = J.shape
    T = Jt.shape[1]
    tr = 0.0
    for i in range(n_p):
        for j in range(n_p):
            h = 0.0
            for r in range(R):
                h += J[r, i] * J[r, j]
            H[i, j] = h
        tr += H[i, i]
        for t in range(T):
            s = 0.0
            for r in range(R):
                s += J[r, i] * Jt[r, t]
            G[i, t] = s
    for i in range(n_p):
        d[i] = 1e-12 * tr + 1e-300
    if not _solve_diag(H, d, G, Y):
        _fill2(Y, np.nan)
    for r in range(R):
        for t in range(T):
            s = 0.0
            for i in range(n_p):
                s += J[r, i] * Y[i, t]
            Jred[r, t] = Jt[r, t] - s


@njit(cache=True, nogil=True, error_model="numpy")
def project(Jp, Jt, Y, Jred):
    """The Kaufman Jacobian of variable projection for every point: ``Y (N, n_p, n_theta)``
    and ``Jred (N, 2C, n_theta)`` of :func:`_project_point`."""
    N, R, n_p = Jp.shape
    H, G, d = np.empty((n_p, n_p)), np.empty((n_p, Jt.shape[2])), np.empty(n_p)
    for n in range(N):
        _project_point(Jp[n], Jt[n], Y[n], Jred[n], H, G, d)


@njit(cache=True, nogil=True, error_model="numpy")
def evaluate(P, M, plane, plane_model, kinds, moving, A, b, sig, meas, Rv, cv, K, Jl, inner, inner_rtol, conv_rtol,
             e, Jp, Jt, Y, Jred):
    """One evaluation of the reduced problem for a block whose points start at ``P`` (in
    place): every point's residuals and Jacobians at ``theta``; a point whose Gauss-Newton
    step promises more than ``conv_rtol`` of its cost runs its own Levenberg-Marquardt from
    there and is evaluated again; then :func:`_project_point`. ``Problem.solve_points``'s warm
    path followed by ``Problem._project``, one point at a time."""
    N, n_p = P.shape
    R = kinds.shape[0] * 2
    et, Jpt, JX, Jt1 = np.empty(R), np.empty((R, n_p)), np.empty((R, 3)), np.empty((R, 1))
    H, g, d = np.empty((n_p, n_p)), np.empty(n_p), np.empty(n_p)
    gm, x, dp, pt = np.empty((n_p, 1)), np.empty((n_p, 1)), np.empty(n_p), np.empty(n_p)
    G = np.empty((n_p, Jt.shape[2]))
    yes = not _no_theta(kinds)[0]
    for n in range(N):
        col = 6 + 3 * plane[n]
        _fill2(Jt[n], 0.0)
        _point(P[n], M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, yes, Jl, col, e[n], Jp[n], JX,
               Jt[n])
        if not _converged_point(e[n], Jp[n], conv_rtol, H, g, d, gm, x):
            _lm_point(P[n], M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, inner, inner_rtol,
                      e[n], Jp[n], et, Jpt, JX, Jt1, Jl, H, g, d, gm, x, dp, pt)
            _fill2(Jt[n], 0.0)
            _point(P[n], M[n], plane_model, kinds, moving, A, b, sig, meas[n], Rv, cv, K, yes, Jl, col, e[n], Jp[n],
                   JX, Jt[n])
        _project_point(Jp[n], Jt[n], Y[n], Jred[n], H, G, d)


# --------------------------------------------------------------------------- sonar scale searches
# ``motion._golden`` of ``motion._plane_scale``'s and ``motion._essential_scale``'s chi-square
# of one sonar match's elevation, one match at a time (40 steps of a dozen numpy calls each on
# 50 numbers were most of their time).
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


@njit(cache=True, nogil=True, error_model="numpy")
def _wrap(x):
    return (x + _PI) % _TWO_PI - _PI


@njit(cache=True, nogil=True, error_model="numpy")
def _chi_plane(phi, r1, th1, r2, th2, sr, sa, Rs, a, b, n_s, nst):
    """``motion._plane_scale``'s ``chi`` of one match at elevation ``phi``."""
    cp, sp = np.cos(phi), np.sin(phi)
    P0, P1, P2 = r1 * cp * np.sin(th1), r1 * cp * np.cos(th1), r1 * sp
    do = P0 * n_s[0] + P1 * n_s[1] + P2 * n_s[2] - nst
    Q0 = P0 * Rs[0, 0] + P1 * Rs[0, 1] + P2 * Rs[0, 2] + a[0] + do * b[0]
    Q1 = P0 * Rs[1, 0] + P1 * Rs[1, 1] + P2 * Rs[1, 2] + a[1] + do * b[1]
    Q2 = P0 * Rs[2, 0] + P1 * Rs[2, 1] + P2 * Rs[2, 2] + a[2] + do * b[2]
    if not do > 0:
        return np.inf
    rq = np.sqrt(Q0 * Q0 + Q1 * Q1 + Q2 * Q2)
    return ((rq - r2) / sr) ** 2 + (_wrap(np.arctan2(Q0, Q1) - th2) / sa) ** 2


@njit(cache=True, nogil=True, error_model="numpy")
def _chi_essential(phi, r1, th1, r2, th2, sr, sa, Rs, a, b, bb, sign):
    """``motion._essential_scale``'s ``chi`` of one match at elevation ``phi``, and its scale."""
    cp, sp = np.cos(phi), np.sin(phi)
    P0, P1, P2 = r1 * cp * np.sin(th1), r1 * cp * np.cos(th1), r1 * sp
    c0 = P0 * Rs[0, 0] + P1 * Rs[0, 1] + P2 * Rs[0, 2] + a[0]
    c1 = P0 * Rs[1, 0] + P1 * Rs[1, 1] + P2 * Rs[1, 2] + a[1]
    c2 = P0 * Rs[2, 0] + P1 * Rs[2, 1] + P2 * Rs[2, 2] + a[2]
    bc = c0 * b[0] + c1 * b[1] + c2 * b[2]
    disc = bc**2 - bb * ((c0 * c0 + c1 * c1 + c2 * c2) - r2**2)
    s = (-bc + sign * np.sqrt(max(disc, 0.0))) / bb
    if not s > 0:
        return np.inf, s
    Q0, Q1, Q2 = c0 + s * b[0], c1 + s * b[1], c2 + s * b[2]
    rq = np.sqrt(Q0 * Q0 + Q1 * Q1 + Q2 * Q2)
    return ((rq - r2) / sr) ** 2 + (_wrap(np.arctan2(Q0, Q1) - th2) / sa) ** 2, s


@njit(cache=True, nogil=True, error_model="numpy")
def golden_scale(essential, lo, hi, iters, r1, th1, r2, th2, sr, sa, Rs, a, b, n_s, nst, bb, sign, phi, chi):
    """Golden-section minimisation of every match's chi-square over ``[lo, hi]`` (``motion._golden``,
    the same steps), into ``phi`` and ``chi``: ``motion._plane_scale``'s (``essential`` False:
    ``n_s``, ``nst``) or ``motion._essential_scale``'s branch ``sign`` (``bb = b . b``)."""
    g = _GOLDEN
    for m in range(lo.shape[0]):
        A, Bh = lo[m], hi[m]
        c, e = Bh - g * (Bh - A), A + g * (Bh - A)
        if essential:
            fc = _chi_essential(c, r1[m], th1[m], r2[m], th2[m], sr, sa, Rs, a, b, bb, sign)[0]
            fe = _chi_essential(e, r1[m], th1[m], r2[m], th2[m], sr, sa, Rs, a, b, bb, sign)[0]
        else:
            fc = _chi_plane(c, r1[m], th1[m], r2[m], th2[m], sr, sa, Rs, a, b, n_s, nst)
            fe = _chi_plane(e, r1[m], th1[m], r2[m], th2[m], sr, sa, Rs, a, b, n_s, nst)
        for _ in range(iters):
            left = fc < fe  # the minimum is in [a, e]
            if left:
                Bh = e
                x = Bh - g * (Bh - A)
            else:
                A = c
                x = A + g * (Bh - A)
            if essential:
                fx = _chi_essential(x, r1[m], th1[m], r2[m], th2[m], sr, sa, Rs, a, b, bb, sign)[0]
            else:
                fx = _chi_plane(x, r1[m], th1[m], r2[m], th2[m], sr, sa, Rs, a, b, n_s, nst)
            if left:
                e, fe, c, fc = c, fc, x, fx
            else:
                c, fc, e, fe = e, fe, x, fx
        x = 0.5 * (A + Bh)
        phi[m] = x
        if essential:
            chi[m] = _chi_essential(x, r1[m], th1[m], r2[m], th2[m], sr, sa, Rs, a, b, bb, sign)[0]
        else:
            chi[m] = _chi_plane(x, r1[m], th1[m], r2[m], th2[m], sr, sa, Rs, a, b, n_s, nst)
