"""numba kernels of sonar image formation (imported only through :mod:`._kernels`, on first use).

Each kernel is one pass over the arrays it reads and computes what the numpy reference in
``formation.py`` / ``noise.py`` computes (the tests compare the two on seeded inputs).
They release the GIL (``nogil=True``) so that the caller can run beam ranges on two threads,
and are cached on disk (``cache=True``) so that only the first run on a machine compiles.
They use numpy's error model (``error_model="numpy"``): no zero-division check and branch at each
division (no kernel divides by zero; under Python's model one that did would have raised).

Why some kernels carry their own ``exp``, ``ln`` and ``(cos, sin)`` (``exp_row`` and the noise's
polynomials): numba vectorises a loop only when its body makes no libm call, and the vector math
library that would do it for us (Intel's SVML, which numba uses when present) needs the
SVML-patched LLVM of conda's llvmlite; PyPI's llvmlite wheels, which ``pip install`` gives, are not
patched (``python -m numba -s``: "llvmlite Using SVML Patched LLVM: False"). Each such function
states its error bound, and a test checks it against numpy's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .._embree_upload import SELF_GAP

try:  # the direct rtcIntersect1 path; without it RayCaster.front_hits is None and shadow_front never runs
    from .._embree_kernels import intersect_front, new_rayhit_scratch
except Exception:  # pragma: no cover - a numba/llvmlite without what _embree_kernels needs
    intersect_front = new_rayhit_scratch = None
from .speckle import MU_NO_SEABED

_MIN_COS_FOOTPRINT = 0.02  # same clamp as formation._MIN_COS_FOOTPRINT


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def subcell_footprint(x, y, ct, st, ch, sh, sgn, base, pad_w):
    """One sub-cell of a ray's cell (``subdivide`` and the fused aperture pass): with
    ``x = n.d``, ``y = n.d'`` of the ray, ``(ct, st)`` the cos/sin of the sub-cell's centre
    offset, ``(ch, sh)`` of half its extent, ``sgn`` the sign of ``x`` and ``base = r |x|``,
    returns ``(r_mid, c_mid, f_lo, f_hi)``: the range at its centre, the clamped cosine of
    incidence there, and its range footprint padded to at least ``pad_w`` (m)."""
    p_mid = (x * ct + y * st) * sgn
    p_dif = (y * ct - x * st) * sgn
    c_mid = max(p_mid, _MIN_COS_FOOTPRINT)
    p_a = max(p_mid * ch - p_dif * sh, _MIN_COS_FOOTPRINT)
    p_b = max(p_mid * ch + p_dif * sh, _MIN_COS_FOOTPRINT)
    r_mid = base / c_mid
    r_a = base / p_a
    r_b = base / p_b
    flo, fhi = min(r_a, r_b), max(r_a, r_b)
    pad = max(0.0, pad_w - (fhi - flo)) * 0.5
    return r_mid, c_mid, flo - pad, fhi + pad


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def table_weight(x, x0, dx, y):
    """Linear interpolation in the uniform table ``y`` (from ``x0`` in steps ``dx``), clamped at
    its ends as ``np.interp``: the two-way elevation pattern's weight at elevation ``x``."""
    n = y.size
    pos = (x - x0) / dx
    if pos <= 0.0:
        return y[0]
    if pos >= n - 1:
        return y[n - 1]
    j = int(pos)
    f = pos - j
    return y[j] + f * (y[j + 1] - y[j])


@njit(cache=True, nogil=True, error_model="numpy")
def ray_grid32(cp, sp, a, rz, out):
    """World unit directions of the (K, J) ray grid, ``cos(phi_k) a_j + sin(phi_k) R_z``, into ``out`` (K*J, 3)
    float32 (C-contiguous). Row by row over the row's ``3 J`` values as one flat loop, with ``a`` and ``R_z``
    laid out as the row (i14r: the inner loop of 3 components did not vectorise, 0.135 -> 0.04 ms for
    65 536 rays, on the serial path before the cast); the same products and sum per value."""
    K, J = cp.size, a.shape[0]
    n = 3 * J
    af = np.empty(n)
    rzt = np.empty(n)
    for j in range(J):
        for c in range(3):
            af[3 * j + c] = a[j, c]
            rzt[3 * j + c] = rz[c]
    of = out.reshape(-1)
    for k in range(K):
        ck = cp[k]
        sk = sp[k]
        o = of[k * n:(k + 1) * n]
        for t in range(n):
            o[t] = ck * af[t] + sk * rzt[t]


@njit(cache=True, nogil=True, error_model="numpy")
def fill_rows3(out, row):
    """Every row of ``out`` ``(N, 3)`` (C-contiguous) set to ``row`` ``(3,)`` (``formation._fill_rows``: the
    rays' common origin), as one flat loop over a row pattern (i14r: numpy's three strided column fills
    took 0.1-0.2 ms for 65 536 rows, on the serial path before the cast)."""
    n = out.shape[0]
    of = out.reshape(-1)
    m = min(n, 256)
    pat = np.empty(3 * m, out.dtype)
    for t in range(m):
        for c in range(3):
            pat[3 * t + c] = row[c]
    w = 3 * m
    for i0 in range(0, 3 * n, w):
        blk = of[i0:min(i0 + w, 3 * n)]
        for t in range(blk.size):
            blk[t] = pat[t]


@njit(cache=True, nogil=True, error_model="numpy")
def fill2(a, b, value, i0, i1):
    """``a[i0:i1] = b[i0:i1] = value`` (the cells' extents before edge refinement, filled chunk by chunk on
    the threads that cast the grid)."""
    for i in range(i0, i1):
        a[i] = value
        b[i] = value


@njit(cache=True, nogil=True, error_model="numpy")
def scan_rays(tfar, geom, prim, u, v, ng, corner_normals, tri_offset, smooth, cp, sp, a, rz, i0, i1,
              body, r, nd, ndd, cos_inc, slope, first=0):
    """Per ray of the grid (rows ``i0..i1``): body, range, ``n.d``, ``n.d'``, ``|n.d|`` and ``dr/dphi``.
    Embree's output (``tfar`` ... ``ng``) holds rays from ``first`` on (ray ``i`` at ``i - first``: one
    chunk of the cast, ``RayCaster.intersect_each``); the outputs are the whole grid's.

    ``d = cos(phi) a + sin(phi) R_z`` and ``d' = -sin(phi) a + cos(phi) R_z``; the normal is the
    interpolated corner normal (``smooth``) or Embree's geometric normal, normalised in float32
    as ``RayCaster.cast_raw`` does.
    """
    J = a.shape[0]
    # the ray's row and beam stepped along (i14o: an integer division per ray was 15 % of this pass)
    k = i0 // J
    j = i0 - k * J - 1
    for i in range(i0, i1):
        j += 1
        if j == J:
            j = 0
            k += 1
        g = geom[i - first]
        if g < 0:
            body[i] = -1
            r[i] = np.inf
            nd[i] = np.nan
            ndd[i] = np.nan
            cos_inc[i] = 0.0
            slope[i] = 0.0
            continue
        if smooth:
            t = tri_offset[g] + prim[i - first]
            w1 = u[i - first]
            w2 = v[i - first]
            w0 = np.float32(1.0) - w1 - w2
            n0 = w0 * corner_normals[t, 0, 0] + w1 * corner_normals[t, 1, 0] + w2 * corner_normals[t, 2, 0]
            n1 = w0 * corner_normals[t, 0, 1] + w1 * corner_normals[t, 1, 1] + w2 * corner_normals[t, 2, 1]
            n2 = w0 * corner_normals[t, 0, 2] + w1 * corner_normals[t, 1, 2] + w2 * corner_normals[t, 2, 2]
        else:
            n0, n1, n2 = ng[i - first, 0], ng[i - first, 1], ng[i - first, 2]
        inv = np.float32(1.0) / (np.sqrt(n0 * n0 + n1 * n1 + n2 * n2) + np.float32(1e-30))
        m0, m1, m2 = float(n0 * inv), float(n1 * inv), float(n2 * inv)
        c, s = cp[k], sp[k]
        d0 = c * a[j, 0] + s * rz[0]
        d1 = c * a[j, 1] + s * rz[1]
        d2 = c * a[j, 2] + s * rz[2]
        e0 = -s * a[j, 0] + c * rz[0]
        e1 = -s * a[j, 1] + c * rz[1]
        e2 = -s * a[j, 2] + c * rz[2]
        x = m0 * d0 + m1 * d1 + m2 * d2
        y = m0 * e0 + m1 * e1 + m2 * e2
        rr = float(tfar[i - first])
        body[i] = g
        r[i] = rr
        nd[i] = x
        ndd[i] = y
        ci = abs(x)
        cos_inc[i] = ci
        sgn = -1.0 if x < 0 else 1.0
        slope[i] = -rr * y / (sgn * max(ci, _MIN_COS_FOOTPRINT))


@njit(cache=True, nogil=True, error_model="numpy")
def footprints(body, r, cos_inc, slope, a, b, refl, weight_k, gain, J, pad_width, energy, lo, hi):
    """Energy and range footprint of every ray (``formation._scan``'s last step).

    ``weight_k`` (K,) elevation weights (or empty), ``gain`` (N,) propagation gain (or empty); the
    arrays hold whole rows of ``J`` rays, the first of them row 0 of ``weight_k``.
    """
    k = 0  # the ray's row, stepped along (no integer division per ray)
    j = -1
    for i in range(body.size):
        j += 1
        if j == J:
            j = 0
            k += 1
        g = body[i]
        if g < 0:
            energy[i] = 0.0
            lo[i] = np.nan
            hi[i] = np.nan
            continue
        e = refl[g] * cos_inc[i] * (a[i] + b[i])
        if weight_k.size:
            e *= weight_k[k]
        if gain.size:
            e *= gain[i]
        energy[i] = e
        x = r[i] - slope[i] * a[i]
        y = r[i] + slope[i] * b[i]
        if y < x:
            x, y = y, x
        pad = max(0.0, pad_width - (y - x)) * 0.5
        lo[i] = x - pad
        hi[i] = y + pad


@njit(cache=True, nogil=True, error_model="numpy")
def spreading_gain(body, r, k_abs, gain):
    """``propagation.two_way_gain`` of every ray (reference range 1 m): ``exp(k_abs (r - 1)) / r^2``
    with ``k_abs = -0.2 ln(10) alpha`` (alpha in dB/m) where ``body >= 0``, 0 on a miss (the same
    factor as the aperture kernel's sub-cells; float64 rounding apart, ``10^(-2 alpha (r - 1) / 10) / r^2``;
    ``exp`` from :func:`exp_row`, within an ulp or two of libm's)."""
    n = body.size
    x = np.empty(n)
    sc = np.empty(n)
    for i in range(n):
        x[i] = k_abs * (r[i] - 1.0) if body[i] >= 0 else 0.0
    exp_row(x, n, gain, sc)  # exp vectorised (within 1 ulp of libm's here)
    for i in range(n):
        ri = r[i]
        gain[i] = gain[i] / (ri * ri) if body[i] >= 0 else 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def bucket_by_beam(beam, lo_m, hi_m, energy, slot, range_min, scale, n_cells, n_beams, rec, starts):
    """The lit rays (``energy > 0``) as records grouped by beam (a counting sort), in their
    original order within a beam: ``rec[k] = (x0, x1, density, slot)`` with the footprint
    ``[x0, x1]`` in fine cells (clipped to ``[0, n_cells]``) and the energy density per cell;
    beam ``j`` holds ``rec[starts[j]:starts[j + 1]]``. One sequential pass over the rays, so
    that the per-beam pass reads its rays contiguously. ``rec`` (>= lit rays, 4) and ``starts``
    (n_beams + 1) are written (kernels return nothing: boxing a returned array calls back
    into Python, where a Ctrl-C would surface as a SystemError instead of KeyboardInterrupt)."""
    counts = np.zeros(n_beams + 1, np.int64)
    for i in range(beam.size):
        if energy[i] > 0:
            counts[beam[i] + 1] += 1
    for j in range(n_beams):
        counts[j + 1] += counts[j]
    starts[:] = counts
    for i in range(beam.size):
        e = energy[i]
        if e > 0:
            j = beam[i]
            k = counts[j]
            counts[j] += 1
            x0 = (lo_m[i] - range_min) * scale
            x1 = (hi_m[i] - range_min) * scale
            rec[k, 2] = e / (x1 - x0)
            rec[k, 0] = min(max(x0, 0.0), n_cells)
            rec[k, 1] = min(max(x1, 0.0), n_cells)
            rec[k, 3] = slot[i]


@njit(cache=True, nogil=True, error_model="numpy")
def echo_rows(rec, starts, n_cells, H, V, full, q, n_bins, j0, j1, out):
    """Box-integrate rays into fine range cells, low-pass and decimate, for beams ``j0..j1``.

    Every lit ray deposits into slot 0 (the whole echo) and, when ``slot[i] > 0``, into its
    class's slot as well (the seabed/target split, in the same pass). A box of energy ``e``
    over ``[lo, hi]`` (fine-cell units) is a step up at ``lo`` and down at ``hi``, each a
    linear two-cell deposit (``formation._box_integrate``); the fine profile is the
    cumulative sum of the deposits and the image its anti-aliased decimation
    (``formation._decimate``). Both are linear, so each deposit ``a`` at fine cell
    ``c = q b + p`` is carried straight to the output: ``a H[p, m + D]`` into bins
    ``b + m``, ``|m| <= D`` (the decimation weights of the cells at or after ``c``), and a
    step of ``a full`` (the sum of all weights, ``q``) from bin ``b + D + 1`` on (one cumulative sum over bins per row). Fine
    cells past the end do not exist (zero border): ``V`` removes what the steps put there.
    Cost is linear in rays plus bins, with no fine array. ``out`` (S, n_beams, n_bins)
    float32 (rows per beam: a column stride of a power of two thrashes the caches): rows
    ``j0..j1`` are written whole.
    """
    S = out.shape[0]
    D = (H.shape[1] - 1) // 2
    row = np.zeros((S, n_bins))
    step = np.zeros((S, n_bins + 1))
    end = np.zeros(S)
    used = np.zeros(S, np.bool_)
    for j in range(j0, j1):
        for idx in range(starts[j], starts[j + 1]):
            x0 = rec[idx, 0]
            x1 = rec[idx, 1]
            dens = rec[idx, 2]
            s = int(rec[idx, 3])
            p0 = int(x0)
            f0 = x0 - p0
            p1 = int(x1)
            f1 = x1 - p1
            for t in range(8):
                ss = 0 if t < 4 else s
                if t == 4 and s <= 0:
                    break
                tt = t & 3
                if tt == 0:
                    c, a = p0, dens - dens * f0
                elif tt == 1:
                    c, a = p0 + 1, dens * f0
                elif tt == 2:
                    c, a = p1, dens * f1 - dens
                else:
                    c, a = p1 + 1, -dens * f1
                if c >= n_cells:  # only cells past the end, which are cut
                    continue
                used[ss] = True
                end[ss] += a
                if q == 2:  # the default oversampling: no integer division
                    b = c >> 1
                    ph = c & 1
                else:
                    b = c // q
                    ph = c - b * q
                if D == 3 and 3 <= b < n_bins - 3:  # every preset's pulse: seven taps the compiler unrolls
                    for m in range(7):  # (a constant trip count; the same additions in the same order)
                        row[ss, b - 3 + m] += a * H[ph, m]
                elif D <= b < n_bins - D:
                    for m in range(2 * D + 1):
                        row[ss, b - D + m] += a * H[ph, m]
                else:
                    for m in range(-D, D + 1):
                        bb = b + m
                        if 0 <= bb < n_bins:
                            row[ss, bb] += a * H[ph, m + D]
                sb = b + D + 1
                if sb < n_bins:
                    step[ss, sb] += a * full
        for ss in range(S):
            if not used[ss]:
                out[ss, j, :] = 0.0
                continue
            acc = 0.0
            for bb in range(n_bins):
                acc += step[ss, bb]
                out[ss, j, bb] = row[ss, bb] + acc
            for t in range(V.size):
                bb = n_bins - V.size + t
                if bb >= 0:
                    out[ss, j, bb] -= end[ss] * V[t]
            row[ss, :] = 0.0
            step[ss, :] = 0.0
            end[ss] = 0.0
            used[ss] = False


@njit(cache=True, nogil=True, error_model="numpy")
def shares(parts, intensity, slot_of_share, r0, r1, out):
    """Seabed shares from class images: ``out[m] = clip(parts[slot] / parts[0], 0, 1)`` where the
    intensity is positive; the share whose slot is 0 is the remainder ``clip(1 - others, 0, 1)``.

    ``parts`` (S, B, J) float32 (slot 0: the whole echo), ``intensity`` (B, J),
    ``out`` (M, B, J) float32; rows ``r0..r1``.
    """
    M = slot_of_share.size
    J = intensity.shape[1]
    for bb in range(r0, r1):
        for j in range(J):
            if not intensity[bb, j] > 0:
                for m in range(M):
                    out[m, bb, j] = 0.0
                continue
            tt = parts[0, bb, j]
            rest = np.float32(1.0)
            rest_m = -1
            for m in range(M):
                s = slot_of_share[m]
                if s == 0:
                    rest_m = m
                    continue
                v = np.float32(0.0)
                ps = parts[s, bb, j]
                if ps != 0 and tt > 0:  # most cells hold one class only
                    v = min(max(ps / tt, np.float32(0.0)), np.float32(1.0))
                out[m, bb, j] = v
                rest -= v
            if rest_m >= 0:
                out[rest_m, bb, j] = min(max(rest, np.float32(0.0)), np.float32(1.0))


@njit(cache=True, nogil=True, error_model="numpy")
def noise_counter(I, shares, N, cumw, lams, k0, k1, stream, gaussian_bottom, target_speckle, use_psi, r0, r1, out):
    """The thesis noise model (``NoiseModel``, Rayleigh-family bottoms or none), rows ``r0..r1``, its
    variates drawn here from a counter stream (``NoiseModel._apply_numpy`` on the same words): per
    row :func:`_noise_variates_row` then :func:`_noise_combine_row`, no array of draws. A cell's
    numbers depend on its index alone: any rows, any thread, the same image."""
    T = shares.shape[0]
    J = I.shape[1]
    s = _noise_scratch(T, J)
    E = np.empty((1, J), np.float32)
    lam = np.empty((T, 1, J), np.float32)
    cs = np.empty((1, J), np.float32)
    for i in range(r0, r1):
        _noise_variates_row(i, k0, k1, stream, cumw, lams, gaussian_bottom, use_psi, s, E, lam, cs, 0)
        _noise_combine_row(I, shares, N, i, E, lam, cs, 0, gaussian_bottom, target_speckle, use_psi, out)


@njit(cache=True, nogil=True, error_model="numpy")
def noise_variates(k0, k1, stream, cumw, lams, gaussian_bottom, use_psi, r0, r1, E, lam, cs):
    """The echo-free part of :func:`noise_counter`, rows ``r0..r1``: ``E`` (B, J) float32, the
    component's power ``lam`` (T, B, J) float32 per bottom type (``gaussian_bottom``) and
    ``cos psi`` ``cs`` (B, J) float32 (``use_psi``; else (B, 0)), as :func:`_noise_variates_row`
    forms them. Drawn beside the scan (``NoiseModel.draw(..., _field=True)``); :func:`noise_apply`
    finishes the image from them, the same numbers as :func:`noise_counter`."""
    s = _noise_scratch(lam.shape[0], E.shape[1])
    for i in range(r0, r1):
        _noise_variates_row(i, k0, k1, stream, cumw, lams, gaussian_bottom, use_psi, s, E, lam, cs, i)


@njit(cache=True, nogil=True, error_model="numpy")
def noise_apply(I, shares, N, E, lam, cs, gaussian_bottom, target_speckle, use_psi, r0, r1, out):
    """:func:`noise_counter` from the variates :func:`noise_variates` formed beforehand (the same numbers)."""
    for i in range(r0, r1):
        _noise_combine_row(I, shares, N, i, E, lam, cs, i, gaussian_bottom, target_speckle, use_psi, out)


@njit(cache=True, nogil=True, error_model="numpy")
def _noise_scratch(T, J):
    """Per-call scratch of :func:`_noise_variates_row`: the words (4 a block), the float64 rows of the
    ``ln`` and of the uniforms, ``-2 ln x``, and the unit pair ``(cos, sin)``."""
    n_blocks = (2 + T + 3) // 4
    return (np.empty((4 * n_blocks, J), np.uint32), np.empty(J), np.empty(J), np.empty(J),
            np.empty(J, np.float32), np.empty(J), np.empty(2 * J, np.float32), np.ones(J, np.float32),
            np.full(J, np.float32(2.0)))


@njit(cache=True, nogil=True, error_model="numpy")
def _noise_variates_row(i, k0, k1, stream, cumw, lams, gaussian_bottom, use_psi, s, E, lam, cs, q):
    """The variates of image row ``i`` from its counter words, into row ``q`` of ``E`` (., J), ``lam``
    (T, ., J) and ``cs`` (., J) (whole arrays and a row index: their rows are contiguous for the
    compiler, so the loops vectorise). Cell ``n = i J + j`` has the words of Philox4x32-10 of the
    counters ``(n, b, stream, 0)`` under the key ``(k0, k1)``, ``b = 0 .. n_blocks - 1``
    (:func:`_counter_words_row`): word 0 gives ``E = -ln x``, ``x = (w0 + 1/2) 2^-32``
    (:func:`_radius2_row`'s ``-2 ln x``, halved: exact), word 1 ``cos psi``,
    ``psi = 2 pi w1 2^-32`` (:func:`_normals_row`'s ``cos``), word ``2 + t`` the uniform
    ``(w + 1/2) 2^-32`` of bottom type ``t``'s mixture component, whose power ``lams[t, c]`` goes to
    ``lam[t]`` (``c``: the cumulative weights ``cumw[t]`` it passes)."""
    w, x, e, mant, r2, u, pair, ones, r2_one = s
    J = E.shape[1]
    T = lam.shape[0] if gaussian_bottom else 0
    C = lams.shape[1]
    for b in range(w.shape[0] // 4):
        _counter_words_row(k0, k1, i * J, b, stream, w[4 * b], w[4 * b + 1], w[4 * b + 2], w[4 * b + 3])
    _radius2_row(w[0], x, e, mant, r2)
    half = np.float32(0.5)
    Eq = E[q]
    for j in range(J):
        Eq[j] = r2[j] * half
    if use_psi:
        _normals_row(w[1], r2_one, ones, pair)  # sqrt(1 x 1/2 x 2) = 1: the unscaled (cos, sin) pair
        cq = cs[q]
        for j in range(J):
            cq[j] = pair[2 * j]
    for t in range(T):
        lt = lam[t, q]
        _uniform_bits_row(w[2 + t], u)
        if C <= 4:  # thresholds by selects (no inner loop, no branch on the data): the loop vectorises
            c0 = cumw[t, 0] if C > 1 else 2.0  # above any uniform: a threshold never passed
            c1 = cumw[t, 1] if C > 2 else 2.0
            c2 = cumw[t, 2] if C > 3 else 2.0
            l0 = np.float32(lams[t, 0])
            l1 = np.float32(lams[t, 1]) if C > 1 else l0
            l2 = np.float32(lams[t, 2]) if C > 2 else l0
            l3 = np.float32(lams[t, 3]) if C > 3 else l0
            for j in range(J):
                uu = u[j]
                v = l0
                v = l1 if uu >= c0 else v
                v = l2 if uu >= c1 else v
                v = l3 if uu >= c2 else v
                lt[j] = v
        else:
            for j in range(J):
                k = 0
                for c in range(C - 1):
                    k += np.int64(u[j] >= cumw[t, c])
                lt[j] = np.float32(lams[t, k])


@njit(cache=True, nogil=True, error_model="numpy")
def _noise_combine_row(I, shares, N, i, E, lam, cs, q, gaussian_bottom, target_speckle, use_psi, out):
    """Image row ``i`` from its variates, row ``q`` of ``E``, ``lam``, ``cs``
    (:func:`_noise_variates_row`). Per cell: bottom types ``t`` add their share ``I share_t`` to
    the bottom; Gaussian bottoms add circular Gaussian power ``I share_t lam_t`` to ``P``, which
    starts at the noise floor ``N[i]``; the target echo ``max(I - bottom, 0)`` joins ``P``
    (``target_speckle``) or is the steady part ``S``. Without reverberation the bottom is steady
    (``S = bottom``, the target speckled) or the whole echo is (``S = I``). The intensity is
    ``max(S + P E + 2 sqrt(S P E) cos psi, 0)`` (``use_psi``)."""
    T = shares.shape[0]
    J = I.shape[1]
    zero = np.float32(0.0)
    two = np.float32(2.0)
    n = N[i]
    Ii = I[i]
    oi = out[i]
    Eq = E[q]
    if T == 1 and gaussian_bottom and target_speckle:  # the thesis scenes: the loop vectorises
        s0 = shares[0, i]
        l0 = lam[0, q]
        for j in range(J):
            xx = Ii[j]
            part = xx * s0[j]
            P = n + part * l0[j]
            target = max(xx - part, zero)
            oi[j] = (P + target) * Eq[j]
        return
    for j in range(J):
        xx = Ii[j]
        bottom = zero
        P = n
        for t in range(T):
            part = xx * shares[t, i, j]
            bottom += part
            if gaussian_bottom:
                P += part * lam[t, q, j]
        target = max(xx - bottom, zero)
        S = zero
        if gaussian_bottom:
            if target_speckle:
                P += target
            else:
                S = target
        elif target_speckle:
            P += target
            S = bottom
        else:
            S = xx
        pe = P * Eq[j]
        v = S + pe
        if use_psi:
            v += two * np.sqrt(max(S, zero) * pe) * cs[q, j]
        oi[j] = max(v, zero)


@njit(cache=True, nogil=True, error_model="numpy")
def _counter_words_row(k0, k1, first, block, stream, w0, w1, w2, w3):
    """Words 0..3 of Philox4x32-10 of the counters ``(cell, block, stream, 0)`` under the key
    ``(k0, k1)``, cells ``first .. first + len(w0)`` (uint32 rows ``w0 .. w3``)."""
    z = np.uint32(0)
    bk = np.uint32(block)
    st = np.uint32(stream)
    for j in range(w0.size):
        a, b, c, d = _philox(np.uint32(first + j), bk, st, z, k0, k1)
        w0[j] = a
        w1[j] = b
        w2[j] = c
        w3[j] = d


@njit(cache=True, nogil=True, error_model="numpy")
def counter_words(k0, k1, stream, r0, r1, out):
    """The words of :func:`noise_counter`, rows ``r0..r1``, into ``out`` (4 n_blocks, B, J) uint32
    (the tests compare them with ``noise._philox_numpy``)."""
    J = out.shape[2]
    for i in range(r0, r1):
        for b in range(out.shape[0] // 4):
            _counter_words_row(k0, k1, i * J, b, stream, out[4 * b, i], out[4 * b + 1, i], out[4 * b + 2, i],
                               out[4 * b + 3, i])


@njit(cache=True, nogil=True, error_model="numpy")
def truth_maps(beam, lo_m, hi_m, energy, body, el_lo, el_hi, range_min, inv_bin, n_bins, n_beams,
               body_map, el_min, el_max, rec, j0, j1):
    """Per cell the body of the strongest single contribution and the elevation span that echoes
    (``formation._truth_maps``): every lit ray visits the bins its footprint overlaps. Beams
    ``j0..j1`` only (their columns of the maps; the rays of other beams are skipped), so that
    beam ranges can run on several threads. ``rec`` (n_bins, n_beams, 4) float32 is scratch that
    holds a cell's strongest weight, its body (exact in float32), and the elevation span side by
    side, so that a ray's update of a cell touches one cache line instead of four; the maps are
    written once from it."""
    for bb in range(n_bins):
        for j in range(j0, j1):
            rec[bb, j, 0] = 0.0
            rec[bb, j, 1] = -1.0
            rec[bb, j, 2] = np.inf
            rec[bb, j, 3] = -np.inf
    for i in range(beam.size):
        j = beam[i]
        if j < j0 or j >= j1:
            continue
        e = energy[i]
        if not e > 0:
            continue
        x0 = np.float32((lo_m[i] - range_min) * inv_bin)
        x1 = np.float32((hi_m[i] - range_min) * inv_bin)
        if not (x1 > 0 and x0 < n_bins):
            continue
        dens = np.float32(e / (x1 - x0))
        b0 = int(min(max(x0, 0.0), n_bins - 1))
        b1 = int(min(max(x1, 0.0), n_bins - 1))
        lo_e = np.float32(el_lo[i])
        hi_e = np.float32(el_hi[i])
        g = np.float32(body[i])
        for bb in range(b0, b1 + 1):
            w = dens * max(min(x1, np.float32(bb + 1)) - max(x0, np.float32(bb)), np.float32(0.0))
            if w > rec[bb, j, 0] or (w == rec[bb, j, 0] and g > rec[bb, j, 1]):
                rec[bb, j, 0] = w
                rec[bb, j, 1] = g
            if lo_e < rec[bb, j, 2]:
                rec[bb, j, 2] = lo_e
            if hi_e > rec[bb, j, 3]:
                rec[bb, j, 3] = hi_e
    for bb in range(n_bins):
        for j in range(j0, j1):
            body_map[bb, j] = np.int16(rec[bb, j, 1])
            lo_e = rec[bb, j, 2]
            if np.isfinite(lo_e):
                el_min[bb, j] = lo_e
                el_max[bb, j] = rec[bb, j, 3]
            else:
                el_min[bb, j] = np.nan
                el_max[bb, j] = np.nan


@njit(cache=True, nogil=True, error_model="numpy")
def subcell_counts(body, lo, hi, bin_width, max_sub, sub_bins, n_sub):
    """Sub-cells of each hit ray for :func:`subdivide` into ``n_sub``; returns their total."""
    total = 0
    for i in range(body.size):
        s = 0
        if body[i] >= 0:
            s = int(np.ceil((hi[i] - lo[i]) / bin_width / sub_bins))
            s = min(max(s, 1), max_sub)
        n_sub[i] = s
        total += s
    return total


@njit(cache=True, nogil=True, error_model="numpy")
def subdivide(body, rng, lo, hi, nd, ndd, a, b, refl, elevation, beam, bin_width, n_sub,
              table_x0, table_dx, table_y, alpha_db, spreading,
              o_r, o_e, o_body, o_c, o_lo, o_hi, o_beam, o_el, o_el_lo, o_el_hi, i0=0, i1=-1, m0=0):
    """``formation._subdivide`` in one pass: each hit ray's elevation cell split into sub-cells
    no longer than about ``sub_bins`` range bins (at most ``max_sub``), each with its own range,
    footprint, Lambert factor, two-way pattern weight (linear interpolation in ``table_y``,
    a uniform table from ``table_x0`` in steps of ``table_dx``, clamped at its ends as
    ``np.interp``) and, with ``spreading``, the two-way gain ``r^-2 10^(-alpha (r - 1) / 5)``.
    ``n_sub`` from :func:`subcell_counts`; writes the flat arrays ``o_*`` (range, energy, body,
    cos_incidence, lo, hi, beam, elevation, elevation_lo, elevation_hi) of ``n_sub.sum()``.
    Rays ``i0..i1`` only (``i1 = -1``: to the end), their first sub-cell written at ``m0``
    (the sum of ``n_sub`` before ``i0``): disjoint parts run on several threads.
    """
    N = body.size if i1 < 0 else i1
    pad_w = 1e-4 * bin_width
    k_abs = -0.2 * np.log(10.0) * alpha_db
    m = m0
    # the trigonometry of a cell depends only on (a, b, S), which neighbouring rays share
    # (all but the refined edges): computed once per change, the same numbers bit for bit
    last_a, last_b, last_S = np.nan, np.nan, -1
    ch = sh = cd = sd = ct0 = st0 = delta = 0.0
    for i in range(i0, N):
        S = n_sub[i]
        if S == 0:
            continue
        if a[i] != last_a or b[i] != last_b or S != last_S:
            last_a, last_b, last_S = a[i], b[i], S
            delta = (a[i] + b[i]) / S
            ch = np.cos(0.5 * delta)
            sh = np.sin(0.5 * delta)
            cd, sd = np.cos(delta), np.sin(delta)
            t0 = -a[i] + 0.5 * delta
            ct0, st0 = np.cos(t0), np.sin(t0)
        x, y = nd[i], ndd[i]
        sgn = -1.0 if x < 0 else 1.0
        base = rng[i] * abs(x)
        t = -a[i] + 0.5 * delta
        ct, st = ct0, st0
        for k in range(S):
            if k > 0:  # rotate by delta: cos/sin of t + k delta without two trigonometric calls each
                t = -a[i] + (k + 0.5) * delta
                ct, st = ct * cd - st * sd, st * cd + ct * sd
            r_mid, c_mid, f_lo, f_hi = subcell_footprint(x, y, ct, st, ch, sh, sgn, base, pad_w)
            el = elevation[i] + t
            w = table_weight(el, table_x0, table_dx, table_y)
            e = refl[i] * c_mid * delta * w
            if spreading:
                e *= np.exp(k_abs * (r_mid - 1.0)) / (r_mid * r_mid)
            o_r[m] = r_mid
            o_e[m] = e
            o_body[m] = body[i]
            o_c[m] = c_mid
            o_lo[m] = f_lo
            o_hi[m] = f_hi
            o_beam[m] = beam[i]
            o_el[m] = el
            o_el_lo[m] = el - 0.5 * delta
            o_el_hi[m] = el + 0.5 * delta
            m += 1


@njit(cache=True, nogil=True, error_model="numpy")
def subcell_area(body, is_seabed, rng, cos_inc, el_lo, el_hi, elevation, beam, dtheta, out):
    """Seabed area of each ray or sub-cell (``formation.cell_area``): ``r^2 cos(phi) dtheta
    (phi_hi - phi_lo) / max(cos_incidence, 0.05)`` where ``is_seabed[body]``, else 0."""
    for i in range(body.size):
        b = body[i]
        if b >= 0 and is_seabed[b]:
            r = rng[i]
            out[i] = r * r * np.cos(elevation[i]) * dtheta[beam[i]] * (el_hi[i] - el_lo[i]) / max(cos_inc[i], 0.05)
        else:
            out[i] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def box_muller(bits, scale, out):
    """Pairs of independent normals (Box-Muller) times ``scale``: ``out[..., 0]``, ``out[..., 1]`` =
    ``scale sqrt(-2 ln x) (cos, sin)(2 pi u)`` with ``x = (b1 + 1/2) 2^-32``, ``u = b2 2^-32``
    from the uint32 words ``bits[1]``, ``bits[2]`` ``(3, B, J)``; ``scale`` float32 (B, J),
    ``out`` (B, J, 2) float32 (C-contiguous)."""
    B, J = scale.shape
    x = np.empty(J)
    e = np.empty(J)
    mant = np.empty(J)
    r2 = np.empty(J, np.float32)
    power = np.empty(J, np.float32)
    for i in range(B):
        _radius2_row(bits[1, i], x, e, mant, r2)
        sc = scale[i]
        for j in range(J):
            power[j] = sc[j] * sc[j] * np.float32(2.0)
        _normals_row(bits[2, i], r2, power, out[i].reshape(2 * J))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _invert_poisson(uu, p, m):
    """The least ``n`` with ``P(N <= n) >= uu`` for a Poisson mean ``m`` whose ``P(N = 0)`` is ``p``
    (float64): the terms ``p m^n / n!`` added up until they pass ``uu`` (at most 1000)."""
    c = p
    n = 0
    while uu > c and n < 1000:
        n += 1
        p *= m / n
        c += p
    return n


@njit(cache=True, nogil=True, error_model="numpy")
def poisson_inverse(mu, u, mu_max, out):
    """Poisson counts by inversion: the least ``n`` with ``P(N <= n) >= u`` (``scipy.stats.poisson.ppf``),
    for ``0 < mu < mu_max``; ``mu <= 0`` gives 0, ``mu >= mu_max`` gives -1 (left to the caller)."""
    for i in range(mu.size):
        m = mu.flat[i]
        if not m > 0:
            out.flat[i] = 0
            continue
        if m >= mu_max:
            out.flat[i] = -1
            continue
        out.flat[i] = _invert_poisson(u.flat[i], np.exp(-m), m)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _philox(c0, c1, c2, c3, k0, k1):
    """Philox4x32-10 (Salmon, Moraes, Dror and Shaw 2011, "Parallel random numbers: as easy as
    1, 2, 3"): the four uint32 words of counter ``(c0, c1, c2, c3)`` under key ``(k0, k1)``, ten
    rounds of two 32 x 32 -> 64-bit products (Random123's constants; its known-answer vectors
    in tests/sonar/test_kernels.py). A counter-based generator: each cell's words are a pure
    function of its index, so rows are drawn inside the kernels, on any thread, in any order,
    with no array of draws (and the loops over cells vectorise: ``vpmuludq``)."""
    M0 = np.uint64(0xD2511F53)
    M1 = np.uint64(0xCD9E8D57)
    W0 = np.uint32(0x9E3779B9)
    W1 = np.uint32(0xBB67AE85)
    for _ in range(10):
        p0 = M0 * np.uint64(c0)
        p1 = M1 * np.uint64(c2)
        hi0 = np.uint32(p0 >> np.uint64(32))
        lo0 = np.uint32(p0 & np.uint64(0xFFFFFFFF))
        hi1 = np.uint32(p1 >> np.uint64(32))
        lo1 = np.uint32(p1 & np.uint64(0xFFFFFFFF))
        # (no uint32 casts of the xors: they stay below 2^32, and the casts cost 3x)
        c0, c1, c2, c3 = hi1 ^ c1 ^ k0, lo1, hi0 ^ c3 ^ k1, lo0
        k0 = np.uint32(k0 + W0)
        k1 = np.uint32(k1 + W1)
    return c0, c1, c2, c3


@njit(cache=True, nogil=True, error_model="numpy")
def philox_block(c0, c1, c2, c3, k0, k1, out):
    """``out[:] = Philox4x32-10((c0, c1, c2, c3), (k0, k1))`` (uint32 (4,)): the known-answer check."""
    a, b, c, d = _philox(np.uint32(c0), np.uint32(c1), np.uint32(c2), np.uint32(c3), np.uint32(k0), np.uint32(k1))
    out[0] = a
    out[1] = b
    out[2] = c
    out[3] = d


@njit(cache=True, nogil=True, error_model="numpy")
def _cell_words_row(k0, k1, first, w0, w1, w2):
    """The noise words of cells ``first .. first + len(w0)``: words 0..2 of Philox4x32-10 of counter
    ``(cell, 0, 0, 0)`` under key ``(k0, k1)`` (uint32 rows ``w0``, ``w1``, ``w2``)."""
    z = np.uint32(0)
    for j in range(w0.size):
        a, b, c, _ = _philox(np.uint32(first + j), z, z, z, k0, k1)
        w0[j] = a
        w1[j] = b
        w2[j] = c


@njit(cache=True, nogil=True, error_model="numpy")
def cell_words(k0, k1, cells, out):
    """The noise words (:func:`_cell_words_row`) of the flat cell indices ``cells`` (int64) into
    ``out`` (3, n) uint32."""
    z = np.uint32(0)
    for t in range(cells.size):
        a, b, c, _ = _philox(np.uint32(cells[t]), z, z, z, k0, k1)
        out[0, t] = a
        out[1, t] = b
        out[2, t] = c


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _uniform_bits(b):
    """``(b + 1/2) 2^-32`` (float64, exact) of one uint32 random word (through int32, whose conversion
    vectorises)."""
    return (np.float64(np.int32(np.int64(b) - 2147483648)) + 2147483648.5) * (2.0 ** -32)


@njit(cache=True, nogil=True, error_model="numpy")
def _uniform_bits_row(b, out):
    """``(b + 1/2) 2^-32`` (float64, in ``(0, 1)``) of a row of uint32 random words: the midpoints of
    the 2^32 equal cells of ``[0, 1)`` (the word through int32, whose conversion vectorises)."""
    for j in range(b.size):
        out[j] = _uniform_bits(b[j])


@njit(cache=True, nogil=True, error_model="numpy")
def _radius2_row(b, x, e, mant, out):
    """``-2 ln x`` (float32), ``x = (b + 1/2) 2^-32``, of a row of uint32 words: the squared
    Box-Muller radius, ``2 Exp(1)`` truncated at ``2 ln 2^33 = 45.7`` (6.76 sigma). ``ln x`` from
    the exponent and mantissa of ``x`` (bit fields of the float64, through the int64 views of the
    scratch rows ``x`` and ``mant``; ``e`` float64 scratch) and the atanh series of the mantissa
    reduced to ``[sqrt(1/2), sqrt(2))`` to 5 terms (error < 4e-10): no libm call, so the loops
    vectorise (the scalar ``log`` cost more than the rest of the field)."""
    J = b.size
    _uniform_bits_row(b, x)
    xb = x.view(np.int64)
    mb = mant.view(np.int64)
    mask = np.int64((1 << 52) - 1)
    one = np.int64(1023) << 52
    for j in range(J):
        w = xb[j]
        e[j] = np.float64(np.int32(w >> 52)) - 1023.0
        mb[j] = (w & mask) | one
    for j in range(J):
        m = mant[j]
        hi = np.float64(m > 1.4142135623730951)
        m = m * (1.0 - 0.5 * hi)
        s = (m - 1.0) / (m + 1.0)
        s2 = s * s
        ln_m = 2.0 * s * (1.0 + s2 * (1.0 / 3 + s2 * (1.0 / 5 + s2 * (1.0 / 7 + s2 * (1.0 / 9)))))
        out[j] = np.float32(-2.0 * ((e[j] + hi) * 0.6931471805599453 + ln_m))


@njit(cache=True, nogil=True, error_model="numpy")
def _normals_row(b, r2, power, out):
    """Complex normals of power ``power`` (float32 row): ``out[2j], out[2j + 1] =
    sqrt(power r2 / 2) (cos, sin)(2 pi u)``, ``u = b 2^-32`` the phase word, ``r2`` from
    :func:`_radius2_row` (so each part is a normal of variance ``power / 2``). ``(cos, sin)``
    from the nearest quarter turn and Taylor series on ``[-pi/4, pi/4]`` to degree 10 / 11
    (error < 2e-9 before float32 rounding), by arithmetic selects: the loop vectorises."""
    half = np.float32(0.5)
    one = np.float32(1.0)
    two = np.float32(2.0)
    for j in range(b.size):
        w = np.float32(np.int32(np.int64(b[j]) - 2147483648)) * np.float32(2.0 ** -30) + two  # 4u, [0, 4]
        q = np.floor(w + half)  # nearest quarter turn, 0..4
        r = (w - q) * np.float32(np.pi / 2)
        r2_ = r * r
        sn = r * (one + r2_ * (np.float32(-1.0 / 6) + r2_ * (np.float32(1.0 / 120) + r2_ * (np.float32(-1.0 / 5040)
                                                                                          + r2_ * np.float32(1.0 / 362880)))))
        cs = one + r2_ * (np.float32(-0.5) + r2_ * (np.float32(1.0 / 24) + r2_ * (np.float32(-1.0 / 720) + r2_ * (
            np.float32(1.0 / 40320) + r2_ * np.float32(-1.0 / 3628800)))))
        # rotate by q quarter turns: odd q swaps (cos, sin) -> (-sin, cos); signs from q mod 4
        h = q * half
        odd = q - two * np.floor(h)
        a = cs + odd * (sn - cs)
        c = sn + odd * (cs - sn)
        h1 = (q + one) * half
        sign_c = one - two * (np.floor(h1) - two * np.floor(h1 * half))
        sign_s = one - two * (np.floor(h) - two * np.floor(h * half))
        s = np.sqrt(power[j] * half * r2[j])
        out[2 * j] = a * sign_c * s
        out[2 * j + 1] = c * sign_s * s


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def _exp_neg_row(m, mu_clamp, p, scale):
    """``exp(-min(max(m, 0), mu_clamp)) = P(r) 2^-k`` of a row (float64, within 2 ulp; ``mu_clamp``
    <= 40): ``k = round(m / ln 2)``, ``P`` the Taylor series of ``exp(-r)`` to degree 13 on
    ``|r| <= ln 2 / 2`` (truncation < 5e-18) into ``p``, ``2^-k`` built as float64 bits into
    ``scale`` (float64, written through its int64 view). No libm call: the loop vectorises."""
    sb = scale.view(np.int64)
    for j in range(m.size):
        mc = min(max(m[j], 0.0), mu_clamp)
        k = np.int32(mc * 1.4426950408889634 + 0.5)
        x = (k * 6.93147180369123816490e-01 - mc) + k * 1.90821492927058770002e-10  # -r, ln 2 in two parts
        p[j] = 1.0 + x * (1.0 + x * (1.0 / 2 + x * (1.0 / 6 + x * (1.0 / 24 + x * (1.0 / 120 + x * (1.0 / 720 + x * (
            1.0 / 5040 + x * (1.0 / 40320 + x * (1.0 / 362880 + x * (1.0 / 3628800 + x * (1.0 / 39916800 + x * (
                1.0 / 479001600 + x * (1.0 / 6227020800)))))))))))))
        sb[j] = (np.int64(1023) - k) << 52


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def exp_row(x, n, out, scale):
    """``out[:n] = exp(x[:n])`` (float64) without a libm call, so that the loops vectorise (issue 14,
    i14j: the aperture kernel's spreading ran ``exp`` sub-cell by sub-cell, ~5 ns each).
    ``x = k ln 2 + r``, ``k = floor(x / ln 2 + 1/2)``, ``|r| <= ln 2 / 2`` (``ln 2`` in two parts, as
    :func:`_exp_neg_row`), ``exp(r)`` by its Taylor series to degree 13 (truncation < 5e-18
    relative), ``2^k`` built as float64 bits in ``scale`` (float64 scratch of ``n`` at least,
    written through its int64 view). Within a few ulp of libm's ``exp`` for ``-708 <= x <= 709``
    (``tests/sonar/test_kernels.py`` bounds it at 8 ulp); 0 below -708 (where ``exp`` is below
    ``3.4e-308``); inputs above 709 (which overflow) are clamped there."""
    sb = scale.view(np.int64)
    for j in range(n):
        xc = min(max(x[j], -708.0), 709.0)
        k = np.floor(xc * 1.4426950408889634 + 0.5)
        r = (xc - k * 6.93147180369123816490e-01) - k * 1.90821492927058770002e-10
        out[j] = 1.0 + r * (1.0 + r * (1.0 / 2 + r * (1.0 / 6 + r * (1.0 / 24 + r * (1.0 / 120 + r * (1.0 / 720 + r * (
            1.0 / 5040 + r * (1.0 / 40320 + r * (1.0 / 362880 + r * (1.0 / 3628800 + r * (1.0 / 39916800 + r * (
                1.0 / 479001600 + r * (1.0 / 6227020800)))))))))))))
        sb[j] = (np.int64(1023) + np.int64(k)) << 52
    for j in range(n):
        out[j] = out[j] * scale[j] * np.float64(x[j] >= -708.0)


@njit(cache=True, nogil=True)
def _field_row_scratch(J):
    """The per-row scratch of the scatterer field's rows (:func:`scatterer_field`, :func:`scatterer_speckle`):
    ``m_row, p0, scale, n_row, u_row, x, e, mant, r2, power, fix, w0, w1, w2, p32, s32``, each ``(J,)``."""
    return (np.empty(J), np.empty(J), np.empty(J), np.empty(J, np.int32), np.empty(J), np.empty(J), np.empty(J),
            np.empty(J), np.empty(J, np.float32), np.empty(J, np.float32), np.empty(J, np.int64),
            np.empty(J, np.uint32), np.empty(J, np.uint32), np.empty(J, np.uint32),
            np.empty(J, np.float32), np.empty(J, np.float32))


@njit(cache=True, nogil=True, error_model="numpy")
def scatterer_field(intensity, gain, back, area, density, k0, k1, mu_max, r0, r1, z, big, mean):
    """``ScattererNoise``'s white complex field, rows ``r0..r1``: per cell the Poisson count ``n``
    of mean ``mu = density area`` (the least ``n`` with ``P(N <= n) >= u``, ``u = (b0 + 1/2)
    2^-32``: :func:`poisson_inverse`'s inversion), the power ``echo n / mu + back`` with
    ``echo = intensity gain`` (float32; ``echo + back`` where ``mu <= MU_NO_SEABED``: no seabed)
    and a complex normal of that power from the words ``b1``, ``b2`` (:func:`box_muller`);
    ``mean = echo + back``. The words ``b0, b1, b2`` of each cell come from Philox4x32-10 under
    the key ``(k0, k1)`` (:func:`_cell_words_row`), drawn row by row here. Cells with
    ``mu >= mu_max`` (<= 40) are flagged in ``big`` (their count is drawn by the caller) and
    get ``z = 0``.

    Row by row in loops without libm calls or branches on the data, which vectorise:
    ``exp(-mu)`` and the first four steps of the inversion (counts 0..3: all but a few cells of
    a resolution-cell-sized mean) in float32, screened (:func:`_poisson_small_row32`: the float64
    inversion's counts), the radius (:func:`_radius2_row`) and the normals (:func:`_normals_row`);
    a scalar loop finishes the rare counts above 3 and the cells too close to call in float32.
    """
    J = intensity.shape[1]
    m_row, p0, scale, n_row, u_row, x, e, mant, r2, power, fix, w0, w1, w2, p32, s32 = _field_row_scratch(J)
    for i in range(r0, r1):
        _cell_words_row(k0, k1, i * J, w0, w1, w2)
        bk = back[i]
        a_row = area[i]
        for j in range(J):
            m_row[j] = density * a_row[j]
        _poisson_small_row32(a_row, density, m_row, w0, mu_max, n_row, fix, p32, s32, p0, scale, u_row)
        _field_power_row(m_row, n_row, intensity[i], gain, bk, mu_max, power, big[i], mean[i])
        _radius2_row(w1, x, e, mant, r2)
        _normals_row(w2, r2, power, z[i].reshape(2 * J))


@njit(cache=True, nogil=True, error_model="numpy")
def field_words(k0, k1, r0, r1, u_words, r2, unit):
    """The part of :func:`scatterer_field` that does not depend on the echo, rows ``r0..r1``: per cell
    the count's word ``b0`` (``u_words`` (B, J) uint32), the squared Box-Muller radius of ``b1``
    (``r2`` (B, J) float32, :func:`_radius2_row`) and the signed ``(cos, sin)(2 pi u)`` of ``b2``
    (``unit`` (B, J, 2) float32: :func:`_normals_row` before its scale), from Philox4x32-10 under
    ``(k0, k1)``. Drawn beside the scan (``ScattererNoise.draw``); :func:`scatterer_field_words`
    finishes the field from them, the same numbers as :func:`scatterer_field`."""
    J = u_words.shape[1]
    x = np.empty(J)
    e = np.empty(J)
    mant = np.empty(J)
    ones = np.ones(J, np.float32)
    r2_one = np.full(J, np.float32(2.0))  # sqrt(1 x 1/2 x 2) = 1: the unscaled (cos, sin) pair
    w1 = np.empty(J, np.uint32)
    w2 = np.empty(J, np.uint32)
    for i in range(r0, r1):
        _cell_words_row(k0, k1, i * J, u_words[i], w1, w2)
        _radius2_row(w1, x, e, mant, r2[i])
        _normals_row(w2, r2_one, ones, unit[i].reshape(2 * J))


@njit(cache=True, nogil=True, error_model="numpy")
def scatterer_field_words(intensity, gain, back, area, density, mu_max, r0, r1, u_words, r2, unit, z, big, mean):
    """:func:`scatterer_field` from the words :func:`field_words` drew beforehand (the same numbers:
    the counts from ``u_words``, then ``z = unit x sqrt(power r2 / 2)``, as :func:`_normals_row`)."""
    J = intensity.shape[1]
    m_row = np.empty(J)
    p0 = np.empty(J)
    scale = np.empty(J)
    n_row = np.empty(J, np.int32)
    u_row = np.empty(J)
    power = np.empty(J, np.float32)
    fix = np.empty(J, np.int64)
    p32 = np.empty(J, np.float32)
    s32 = np.empty(J, np.float32)
    half = np.float32(0.5)
    for i in range(r0, r1):
        bk = back[i]
        a_row = area[i]
        for j in range(J):
            m_row[j] = density * a_row[j]
        _poisson_small_row32(a_row, density, m_row, u_words[i], mu_max, n_row, fix, p32, s32, p0, scale, u_row)
        _field_power_row(m_row, n_row, intensity[i], gain, bk, mu_max, power, big[i], mean[i])
        r2i = r2[i]
        ui = unit[i].reshape(2 * J)
        zi = z[i].reshape(2 * J)
        for j in range(J):
            sc = np.sqrt(power[j] * half * r2i[j])
            zi[2 * j] = ui[2 * j] * sc
            zi[2 * j + 1] = ui[2 * j + 1] * sc


#: Half-width of the band around each cumulative probability in which :func:`_poisson_small_row32`'s
#: float32 decision is not trusted (relative part, absolute part): its float32 ``P(N <= n)`` are within
#: ~2e-6 relative of the float64 ones for means up to 30 (``exp`` to a few ulp, the mean's own rounding
#: times up to 30 for ``exp(-mu)``, three more for ``mu^3``) and its uniform within 1e-7 of the float64 one.
_SCREEN_REL = np.float32(1e-5)
_SCREEN_ABS = np.float32(2e-7)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _poisson_small_row32(a_row, density, m_row, w_row, mu_max, n_row, fix, p32, s32, p0, scale, fm):
    """The scatterer field's Poisson counts of a row, from the cells' areas ``a_row`` (float32), the
    count words ``w_row`` (uint32) and ``m_row = density a_row`` (float64): the counts of the float64
    inversion (``exp(-mu)`` by :func:`_exp_neg_row`, the uniform ``(b + 1/2) 2^-32``, the first four
    cumulative probabilities compared, the rest by :func:`_invert_poisson`), with most of the work in
    float32 (issue 14, i14s: twice the lanes of float64, a degree-7 ``exp``): ``exp(-mu)`` as
    ``P(r) 2^-k`` (``ln 2`` in two parts, ``2^-k`` built as float32 bits in ``s32``, ``P`` in ``p32``),
    the uniform and the first four cumulative probabilities ``c`` in float32. Where the float32
    uniform lies within ``_SCREEN_REL c + _SCREEN_ABS`` of a float32 ``c`` (about 6e-5 of the cells at
    means below 1), its comparison could differ from float64's: such a cell, like a count above 3, is
    counted again from the start in float64 (``exp(-mu)`` by :func:`_exp_neg_row` of those cells' means
    gathered into ``fm``, into ``p0``, ``scale``; the uniform as :func:`_uniform_bits_row`). Elsewhere
    the float32 comparisons agree with float64's, so the counts are the float64 inversion's
    (tests/sonar/test_kernels.py holds that inversion, the kernels' before i14s, and checks it with
    uniforms placed at the boundaries). The integer work (the count of 4s) in a loop of its own: in
    the float loop it stopped the vectorisation."""
    J = a_row.size
    half = np.float32(0.5)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    d32 = np.float32(density)
    sb = s32.view(np.int32)
    for j in range(J):  # exp(-m) = 2^-k exp(k ln 2 - m), |k ln 2 - m| <= ln 2 / 2
        m = min(max(d32 * a_row[j], zero), np.float32(40.0))
        ki = np.int32(m * np.float32(1.4426950408889634) + half)
        k = np.float32(ki)
        r = (k * np.float32(0.693359375) - m) + k * np.float32(-2.12194440e-4)  # k ln2_hi exact (k <= 58)
        p32[j] = one + r * (one + r * (half + r * (np.float32(1.0 / 6) + r * (np.float32(1.0 / 24) + r * (
            np.float32(1.0 / 120) + r * (np.float32(1.0 / 720) + r * np.float32(1.0 / 5040)))))))
        sb[j] = np.int32((np.int32(127) - ki) * np.int32(8388608))  # 2^-k: the exponent field
    wi = w_row.view(np.int32)
    for j in range(J):  # counts 0..3, or 4: above 3 or too close to call in float32
        m = min(max(d32 * a_row[j], zero), np.float32(40.0))
        p = p32[j] * s32[j]
        wv = wi[j]  # the word as int32: b = wv + 2^32 [wv < 0]
        uu = np.float32(wv) * np.float32(2.0 ** -32) + (one if wv < 0 else zero)
        t1 = p * m
        c1 = p + t1
        t2 = t1 * (m * half)
        c2 = c1 + t2
        c3 = c2 + t2 * (m * np.float32(1.0 / 3))
        n = np.int32(uu > p) + np.int32(uu > c1) + np.int32(uu > c2) + np.int32(uu > c3)
        d0 = uu - p
        d1 = uu - c1
        d2 = uu - c2
        d3 = uu - c3
        near = ((d0 * d0 <= (_SCREEN_REL * p + _SCREEN_ABS) ** 2) | (d1 * d1 <= (_SCREEN_REL * c1 + _SCREEN_ABS) ** 2)
                | (d2 * d2 <= (_SCREEN_REL * c2 + _SCREEN_ABS) ** 2) | (d3 * d3 <= (_SCREEN_REL * c3 + _SCREEN_ABS) ** 2))
        n_row[j] = np.int32(4) if near else n
    fours = 0
    for j in range(J):  # (vectorised)
        fours += n_row[j] == 4
    n_fix = 0
    j = 0
    while fours > 0:  # the row's 4s (about one a row): a scan that ends at the last
        if n_row[j] == 4:
            fours -= 1
            m = m_row[j]
            if m > MU_NO_SEABED and m < mu_max:
                fix[n_fix] = j
                n_fix += 1
        j += 1
    if n_fix == 0:
        return
    for t in range(n_fix):  # exp(-m) of these cells alone (element by element: the row's numbers)
        fm[t] = m_row[fix[t]]
    _exp_neg_row(fm[:n_fix], 40.0, p0, scale)
    for t in range(n_fix):  # the inversion from the start in float64
        j = fix[t]
        n_row[j] = _invert_poisson(_uniform_bits(w_row[j]), p0[t] * scale[t], m_row[j])


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _field_power_row(m_row, n_row, i_row, gain, bk, mu_max, power, b_row, mean_row):
    """:func:`scatterer_field`'s power of a row (none where the count is left to the caller), its
    mean ``echo + back`` and the flags of the cells of large mean."""
    one = np.float32(1.0)
    for j in range(m_row.size):
        m = m_row[j]
        sea = m > MU_NO_SEABED
        bg = sea & (m >= mu_max)
        seaf = np.float32(sea)
        ratio = np.float32(n_row[j] / (m if sea else 1.0)) * seaf + (one - seaf)
        echo = i_row[j] * gain
        power[j] = (echo * ratio + bk) * (one - np.float32(bg))
        mean_row[j] = echo + bk
        b_row[j] = bg


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_origins(pos, t, n, eps, origin, d_act, o32, d32):
    """Continuation rays of the acoustic shadow (``formation._shadow_mask``): for the ``n`` rays
    ``pos[:n]`` (rows of ``d_act``, float64 unit directions) the float32 origin
    ``origin + d (t + eps)`` (computed in float64) and direction, into ``o32``/``d32`` rows ``0..n``."""
    for k in range(n):
        p = pos[k]
        s = t[k] + eps
        for c in range(3):
            o32[k, c] = origin[c] + d_act[p, c] * s
            d32[k, c] = d_act[p, c]


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_step(pos, t, n, eps, geom, tfar, ng, first_body, gap_end, d_act, hid_r, hid_n):
    """One round of continuation hits of ``formation._shadow_mask`` (the multi-cast path): a
    front-facing hit (``n . d < 0`` with Embree's geometric normal normalised in float32 as
    ``RayCaster.cast_raw`` does) is the hidden surface (``hid_r``, ``hid_n``), unless it is a front
    face of the body the ray first hit at a range up to ``gap_end`` (the first hit again, through
    float32 rounding). Rays not done move on: ``pos``, ``t`` are compacted in place; returns their count."""
    m = 0
    for k in range(n):
        g = geom[k]
        if g < 0:
            continue
        p = pos[k]
        tt = t[k] + eps + float(tfar[k])
        n0, n1, n2 = ng[k, 0], ng[k, 1], ng[k, 2]
        nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2) + np.float32(1e-30)
        m0, m1, m2 = float(n0 / nn), float(n1 / nn), float(n2 / nn)
        if m0 * d_act[p, 0] + m1 * d_act[p, 1] + m2 * d_act[p, 2] < 0 and not (g == first_body[p] and tt <= gap_end[p]):
            hid_r[p] = tt
            hid_n[p, 0] = m0
            hid_n[p, 1] = m1
            hid_n[p, 2] = m2
            continue
        pos[m] = p
        t[m] = tt
        m += 1
    return m


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_gap_ends(t, eps, origin, d_act, p0, p1, out):
    """``t + eps + self_gap(o)`` for rays ``p0..p1``, ``o`` the float32 start ``origin + d (t + eps)``:
    the range up to which a front face of the first body is that body's first hit again."""
    for p in range(p0, p1):
        s = t[p] + eps
        size = max(abs(np.float32(origin[0] + d_act[p, 0] * s)), abs(np.float32(origin[1] + d_act[p, 1] * s)),
                   abs(np.float32(origin[2] + d_act[p, 2] * s)), np.float32(1.0))
        out[p] = s + SELF_GAP * float(size)  # as _embree_kernels.self_gap


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_front(fn, scene, args, t, eps, origin, d_act, far, first_body, p0, p1, hid_r, hid_n):
    """The hidden surfaces of ``formation._shadow_mask`` in one cast per ray (the direct path): rays
    ``p0..p1`` (float64 unit directions ``d_act``, first hits at ``t``) start at ``origin + d (t +
    eps)`` (float64, then float32, as ``shadow_origins``) and go to their closest front-facing hit
    (``rtcIntersect1`` with the back-face filter, ``optiacoustic._embree_kernels``), whose range
    ``t + eps + distance`` and float32-normalised normal go to ``hid_r``, ``hid_n`` (left as they are
    on a miss). A front face of the body the ray first hit (``first_body``) within ``self_gap`` of the
    start is that first hit again (float32 rounding) and is skipped, as in ``shadow_step``."""
    f, u, addr = new_rayhit_scratch()
    for p in range(p0, p1):
        s = t[p] + eps
        dist, g, n0, n1, n2 = intersect_front(
            fn, scene, args, f, u, addr,
            np.float32(origin[0] + d_act[p, 0] * s), np.float32(origin[1] + d_act[p, 1] * s),
            np.float32(origin[2] + d_act[p, 2] * s),
            np.float32(d_act[p, 0]), np.float32(d_act[p, 1]), np.float32(d_act[p, 2]), far, first_body[p])
        if g < 0:
            continue
        nn = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2) + np.float32(1e-30)
        hid_r[p] = s + float(dist)
        hid_n[p, 0] = float(n0 / nn)
        hid_n[p, 1] = float(n1 / nn)
        hid_n[p, 2] = float(n2 / nn)


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_boxes(hid_r, hid_n, d_act, dd_act, step, min_half, lo, hi):
    """Range footprint ``r -+ half`` of each hidden surface (``half = step r |n.d'| / (2 max(|n.d|, c))``,
    at least ``min_half``); NaN where the ray found none (``hid_r`` infinite)."""
    for p in range(hid_r.size):
        r = hid_r[p]
        if not np.isfinite(r):
            lo[p] = np.nan
            hi[p] = np.nan
            continue
        nd = abs(hid_n[p, 0] * d_act[p, 0] + hid_n[p, 1] * d_act[p, 1] + hid_n[p, 2] * d_act[p, 2])
        ndd = abs(hid_n[p, 0] * dd_act[p, 0] + hid_n[p, 1] * dd_act[p, 1] + hid_n[p, 2] * dd_act[p, 2])
        half = 0.5 * step * r * ndd / max(nd, _MIN_COS_FOOTPRINT)
        half = max(half, min_half)
        lo[p] = r - half
        hi[p] = r + half


@njit(cache=True, nogil=True, error_model="numpy")
def grid_directions(idx, cp, sp, a, rz, d, dd):
    """World ``d = cos(phi) a + sin(phi) R_z`` and ``d' = -sin(phi) a + cos(phi) R_z`` (float64) of the
    grid rays ``idx`` (flat ``k * J + j``), as ``formation._grid_directions``."""
    J = a.shape[0]
    for m in range(idx.size):
        k = idx[m] // J
        j = idx[m] - k * J
        c, s = cp[k], sp[k]
        for q in range(3):
            d[m, q] = c * a[j, q] + s * rz[q]
            dd[m, q] = -s * a[j, q] + c * rz[q]


@njit(cache=True, nogil=True, error_model="numpy")
def fan_remap(img, base, flags, fx, fy, n_cols, out):
    """Bilinear resampling through precomputed taps (``display._fan_taps``): pixel ``p`` reads the
    polar image (flat) at ``base[p]`` and its right / lower neighbours (``flags`` bit 0: one column
    on, bit 1: one row on; absent at the image's edge, which replicates the border as
    ``cv2.BORDER_REPLICATE``) with weights ``fx``, ``fy``; ``base < 0``: outside the fan, 0."""
    for p in range(base.size):
        b = base[p]
        if b < 0:
            out[p] = 0.0
            continue
        f = flags[p]
        dc = 1 if f & 1 else 0
        dr = n_cols if f & 2 else 0
        v00 = img[b]
        v01 = img[b + dc]
        v10 = img[b + dr]
        v11 = img[b + dr + dc]
        x = fx[p]
        top = v00 + x * (v01 - v00)
        bot = v10 + x * (v11 - v10)
        out[p] = top + fy[p] * (bot - top)


@njit(cache=True, nogil=True, error_model="numpy")
def finish_echo(parts, scale, thr, slot_of_share, r0, r1, intensity, out):
    """The echo image and its seabed shares from :func:`echo_rows`' per-beam rows, bins ``r0..r1``:
    ``intensity[b, j] = parts[0, j, b] scale`` (zeroed below ``thr``, the cumulative sums' rounding
    residue), and the shares as :func:`shares` computes them from the scaled class rows. One pass:
    transposition, scaling, thresholding and shares together. ``parts`` (S, J, B) float32,
    ``intensity`` (B, J), ``out`` (M, B, J) float32 (M = 0: no shares)."""
    M = slot_of_share.size
    J = parts.shape[1]
    for bb in range(r0, r1):
        for j in range(J):
            tt = parts[0, j, bb] * scale
            if tt < thr:
                tt = np.float32(0.0)
            intensity[bb, j] = tt
            if M == 0:
                continue
            if not tt > 0:
                for m in range(M):
                    out[m, bb, j] = 0.0
                continue
            rest = np.float32(1.0)
            rest_m = -1
            for m in range(M):
                s = slot_of_share[m]
                if s == 0:
                    rest_m = m
                    continue
                v = np.float32(0.0)
                ps = parts[s, j, bb] * scale
                if ps != 0:
                    v = min(max(ps / tt, np.float32(0.0)), np.float32(1.0))
                out[m, bb, j] = v
                rest -= v
            if rest_m >= 0:
                out[rest_m, bb, j] = min(max(rest, np.float32(0.0)), np.float32(1.0))


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_cells(beam, lo_m, hi_m, range_min, inv_bin, n_bins, elevation_min, out):
    """Acoustic shadow from the hidden surfaces' footprints (``formation._shadow_mask``): a cell is
    shadow when a footprint ``[lo_m, hi_m]`` (m) puts more than 1e-9 of its unit energy into it
    (the footprint's energy spread uniformly, as the box integration of the echo) and no direct
    ray echoes there (``elevation_min`` NaN). ``out`` (n_bins, n_beams) bool, all False on entry."""
    for i in range(beam.size):
        x0 = (lo_m[i] - range_min) * inv_bin
        x1 = (hi_m[i] - range_min) * inv_bin
        if not (x1 > 0 and x0 < n_bins):
            continue
        dens = 1.0 / (x1 - x0)
        j = beam[i]
        b0 = int(max(x0, 0.0))
        b1 = int(min(x1, n_bins - 1.0))
        for bb in range(b0, b1 + 1):
            w = dens * (min(x1, bb + 1.0) - max(x0, float(bb)))
            if w > 1e-9 and np.isnan(elevation_min[bb, j]):
                out[bb, j] = True


@njit(cache=True, nogil=True, error_model="numpy")
def edge_pairs(body, r, slope, K, J, step, min_jump, kk, jj):
    """Visibility discontinuities between elevation samples ``k`` and ``k + 1`` of each beam
    (``formation._refine_edges``): another body, a miss, or a range jump larger than
    ``1.5 (reach_k + reach_k+1) + min_jump`` (``reach = |dr/dphi| step``) onto a hit. Writes the
    pairs ``(k, j)`` in row-major order into ``kk``, ``jj`` and returns their count."""
    n = 0
    for k in range(K - 1):
        for j in range(J):
            lo = k * J + j
            up = lo + J
            bl, bu = body[lo], body[up]
            disc = bl != bu
            if not disc and bu >= 0:
                reach = np.abs(slope[up]) * step + np.abs(slope[lo]) * step
                disc = np.abs(r[up] - r[lo]) > 1.5 * reach + min_jump
            if disc:
                kk[n] = k
                jj[n] = j
                n += 1
    return n


@njit(cache=True, nogil=True, error_model="numpy")
def edge_directions32(kk, jj, cp, sp, sth, cth, R, i0, i1, out):
    """World unit directions of the edge sub-rays of discontinuities ``i0..i1`` into ``out``
    ``(len(kk) * S, 3)`` float32 (``formation._refine_edges``): sub-ray ``s`` of pair ``(k, j)`` is
    ``R (cos(phi) sin(theta), cos(phi) cos(theta), sin(phi))`` with ``cos(phi), sin(phi)`` the
    tables ``cp[k, s]``, ``sp[k, s]`` ``(K - 1, S)`` and ``sin(theta), cos(theta)`` ``sth[j]``,
    ``cth[j]``: the products and the rotation's sums in the order of the numpy path
    (``Pose.directions_to_world``'s einsum adds the terms of components 0 and 2 first, then 1:
    measured, bit for bit), the same float64 numbers, rounded to float32."""
    S = cp.shape[1]
    for e in range(i0, i1):
        k = kk[e]
        j = jj[e]
        st = sth[j]
        ct = cth[j]
        for s in range(S):
            c = cp[k, s]
            x = c * st
            y = c * ct
            z = sp[k, s]
            m = e * S + s
            for i in range(3):
                out[m, i] = (R[i, 0] * x + R[i, 2] * z) + R[i, 1] * y


@njit(cache=True, nogil=True, error_model="numpy")
def edge_split(kk, jj, h_body, h_dist, body, r, slope, step, S, J, a, b):
    """Move the shared cell boundary of each discontinuity to where its ``S`` sub-rays change
    from the surface below to the one above (``formation._refine_edges``). ``h_body`` (int32) and
    ``h_dist`` (float32, Embree's) of the sub-rays ``(len(kk) * S,)``; ``a``, ``b`` updated in place."""
    for e in range(kk.size):
        lower = kk[e] * J + jj[e]
        upper = lower + J
        bl, bu = body[lower], body[upper]
        sl, su = slope[lower] * step, slope[upper] * step
        cnt = 0
        for s in range(S):
            frac = (s + 0.5) / S
            hb = h_body[e * S + s]
            hd = float(h_dist[e * S + s])
            miss = hb < 0
            if miss and bl < 0:
                err_l = 0.0
            elif hb == bl:
                err_l = abs(hd - (r[lower] + sl * frac))
            else:
                err_l = np.inf
            if miss and bu < 0:
                err_u = 0.0
            elif hb == bu:
                err_u = abs(hd - (r[upper] - su * (1 - frac)))
            else:
                err_u = np.inf
            if err_l < err_u or (np.isinf(err_u) and np.isinf(err_l) and frac < 0.5):
                cnt += 1
        t = cnt / S
        b[lower] = step * t
        a[upper] = step * (1 - t)


@njit(cache=True, nogil=True, error_model="numpy")
def finish_two(parts, scale, thr, j0, j1, r0, r1, intensity, share):
    """:func:`finish_echo` for one bottom type (slot 0, the class with most rays) and the targets
    (slot 1), the thesis scenes' case: the bottom type's share ``clip(1 - clip(target / echo))``
    only (the targets' share is not kept), from loops without inner loops or data branches.
    The targets' rows are read over the beams ``j0..j1`` only (their live span: zeros outside,
    where the share is 1 on lit cells, as the zeros give; i14j: the aperture path's mixing no
    longer writes those zeros, nor this pass reads them)."""
    J = parts.shape[1]
    zero, one = np.float32(0.0), np.float32(1.0)
    for bb in range(r0, r1):
        for j in range(j0):
            tt = parts[0, j, bb] * scale
            tt = zero if tt < thr else tt
            intensity[bb, j] = tt
            share[bb, j] = one if tt > 0 else zero
        for j in range(j0, j1):
            tt = parts[0, j, bb] * scale
            tt = zero if tt < thr else tt
            intensity[bb, j] = tt
            lit = tt > 0
            v = min(max((parts[1, j, bb] * scale) / (tt if lit else one), zero), one)
            share[bb, j] = min(max(one - v, zero), one) if lit else zero
        for j in range(j1, J):
            tt = parts[0, j, bb] * scale
            tt = zero if tt < thr else tt
            intensity[bb, j] = tt
            share[bb, j] = one if tt > 0 else zero


@njit(cache=True, nogil=True, error_model="numpy")
def shadow_active(body, is_floor, cp, sp, a, rz, r, active, t):
    """The grid rays whose continuation the acoustic shadow needs (``formation._shadow_mask``): every
    hit but those going down (``d_z < 0``, ``d = cos(phi) a + sin(phi) R_z``) through a floor plane
    (``is_floor[body]``). Their flat indices into ``active`` and ranges into ``t``; returns the count."""
    J = a.shape[0]
    n = 0
    for k in range(body.size // J):  # row by row: no division per ray
        c, s = cp[k], sp[k] * rz[2]
        for j in range(J):
            i = k * J + j
            g = body[i]
            if g < 0:
                continue
            if is_floor[g] and c * a[j, 2] + s < 0:
                continue
            active[n] = i
            t[n] = r[i]
            n += 1
    return n


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def _taps(dst, src, w, step, n):
    """``dst[q] += sum_k w[k] src[q + step k]``, ``q < n``: four taps per sweep over ``dst``, so that
    the sums stay in registers (one load and store of ``dst`` per four multiply-adds)."""
    K = w.size
    d = dst[:n]
    k = 0
    while k + 4 <= K:  # (slices, not offset indices: an index that might be negative stops vectorisation)
        w0, w1, w2, w3 = w[k], w[k + 1], w[k + 2], w[k + 3]
        s0 = src[step * k: step * k + n]
        s1 = src[step * (k + 1): step * (k + 1) + n]
        s2 = src[step * (k + 2): step * (k + 2) + n]
        s3 = src[step * (k + 3): step * (k + 3) + n]
        for q in range(n):
            d[q] += w0 * s0[q] + w1 * s1[q] + w2 * s2[q] + w3 * s3[q]
        k += 4
    while k < K:
        w0 = w[k]
        s0 = src[step * k: step * k + n]
        for q in range(n):
            d[q] += w0 * s0[q]
        k += 1


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def _taps_folded(dst, src, w, step, n):
    """``dst[q] = sum_k w[k] src[q + step k]``, ``q < n`` (assigned, not added: no zeroing pass), for
    a symmetric kernel of odd length ``K`` (``w[k] == w[K - 1 - k]``, :func:`_is_symmetric`), its
    taps folded: ``w[K // 2] src[q + step K // 2] + sum_{k < K // 2} w[k] (src[q + step k] +
    src[q + step (K - 1 - k)])``. Half the multiply-adds of :func:`_taps`, the other half as plain
    adds (which the core runs on other pipes): the same sum to float32 rounding (another order). The first sweep takes the centre tap and the pairs left
    over from fours, then four pairs per sweep over ``dst`` (issue 14, i14n)."""
    K = w.size
    H = K // 2
    d = dst[:n]
    r = H % 4
    k = H - r
    wc = w[H]
    c = src[step * H: step * H + n]
    if r == 0:
        for q in range(n):
            d[q] = wc * c[q]
    elif r == 1:
        w0 = w[k]
        a0 = src[step * k: step * k + n]
        b0 = src[step * (K - 1 - k): step * (K - 1 - k) + n]
        for q in range(n):
            d[q] = w0 * (a0[q] + b0[q]) + wc * c[q]
    elif r == 2:
        w0, w1 = w[k], w[k + 1]
        a0 = src[step * k: step * k + n]
        a1 = src[step * (k + 1): step * (k + 1) + n]
        b0 = src[step * (K - 1 - k): step * (K - 1 - k) + n]
        b1 = src[step * (K - 2 - k): step * (K - 2 - k) + n]
        for q in range(n):
            d[q] = w0 * (a0[q] + b0[q]) + w1 * (a1[q] + b1[q]) + wc * c[q]
    else:
        w0, w1, w2 = w[k], w[k + 1], w[k + 2]
        a0 = src[step * k: step * k + n]
        a1 = src[step * (k + 1): step * (k + 1) + n]
        a2 = src[step * (k + 2): step * (k + 2) + n]
        b0 = src[step * (K - 1 - k): step * (K - 1 - k) + n]
        b1 = src[step * (K - 2 - k): step * (K - 2 - k) + n]
        b2 = src[step * (K - 3 - k): step * (K - 3 - k) + n]
        for q in range(n):
            d[q] = w0 * (a0[q] + b0[q]) + w1 * (a1[q] + b1[q]) + w2 * (a2[q] + b2[q]) + wc * c[q]
    k = 0
    while k + 4 <= H:
        w0, w1, w2, w3 = w[k], w[k + 1], w[k + 2], w[k + 3]
        a0 = src[step * k: step * k + n]
        a1 = src[step * (k + 1): step * (k + 1) + n]
        a2 = src[step * (k + 2): step * (k + 2) + n]
        a3 = src[step * (k + 3): step * (k + 3) + n]
        b0 = src[step * (K - 1 - k): step * (K - 1 - k) + n]
        b1 = src[step * (K - 2 - k): step * (K - 2 - k) + n]
        b2 = src[step * (K - 3 - k): step * (K - 3 - k) + n]
        b3 = src[step * (K - 4 - k): step * (K - 4 - k) + n]
        for q in range(n):
            d[q] += w0 * (a0[q] + b0[q]) + w1 * (a1[q] + b1[q]) + w2 * (a2[q] + b2[q]) + w3 * (a3[q] + b3[q])
        k += 4


@njit(cache=True, nogil=True, error_model="numpy")
def _is_symmetric(w):
    """Whether ``w[k] == w[K - 1 - k]`` for all ``k`` (exactly, in its own dtype)."""
    K = w.size
    for k in range(K // 2):
        if w[k] != w[K - 1 - k]:
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def _speckle_row(i, B, J, zf, mf, base, h_r, h_r2, h_b, h_b2, sym_r, sym_b, tz, tm, fz, fm, fa, mr, t, o):
    """:func:`speckle_image`'s output row ``i`` (of ``B`` rows, ``J`` beams) into ``o``: the field rows
    ``zf`` (flat float32, ``2 J`` a row) and mean rows ``mf`` (flat, ``J`` a row) hold image rows from
    ``base`` on (row ``i + m - Dr`` of the range taps is at ``i + m - Dr - base``); ``mr`` the mean's row
    ``i``, ``t`` its TVG; ``tz``, ``tm``, ``fz``, ``fm``, ``fa`` scratch as :func:`speckle_image` makes
    them (the zero margins of ``tz`` and ``tm`` left zero)."""
    Kr = h_r.size
    Dr = Kr // 2
    Db = h_b.size // 2
    k0 = max(0, Dr - i)  # the range taps whose rows exist (zero rows beyond the image)
    k1 = min(Kr, B + Dr - i)
    w = h_r[k0:k1]
    w2 = h_r2[k0:k1]
    tzi = tz[2 * Db: 2 * Db + 2 * J]
    tmi = tm[Db: Db + J]
    first = i + k0 - Dr - base
    if sym_r and k0 == 0 and k1 == Kr:  # the whole range kernel: its symmetric taps folded
        _taps_folded(tzi, zf[first * 2 * J:], w, 2 * J, 2 * J)
        _taps_folded(tmi, mf[first * J:], w2, J, J)
    else:  # rows near the image's ends (a truncated kernel) or an asymmetric kernel
        tzi[:] = 0.0
        tmi[:] = 0.0
        _taps(tzi, zf[first * 2 * J:], w, 2 * J, 2 * J)
        _taps(tmi, mf[first * J:], w2, J, J)
    if sym_b:
        _taps_folded(fz, tz, h_b, 2, 2 * J)
        _taps_folded(fm, tm, h_b2, 1, J)
    else:
        fz[:] = 0.0
        fm[:] = 0.0
        _taps(fz, tz, h_b, 2, 2 * J)
        _taps(fm, tm, h_b2, 1, J)
    for j in range(J):  # |f|^2 first: with the division in the same loop, it did not vectorise
        a = fz[2 * j]
        b = fz[2 * j + 1]
        fa[j] = a * a + b * b
    for j in range(J):
        e = fm[j]
        pos = e > 0
        v = fa[j] * (mr[j] / (e if pos else np.float32(1.0))) * t
        o[j] = v if pos else np.float32(0.0)


@njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
def speckle_image(z, mean, h_r, h_b, tvg, r0, r1, out):
    """``ScattererNoise``'s image in one pass, rows ``r0..r1``: the field ``z`` ``(B, J, 2)`` float32
    filtered by ``h_r`` along rows (range) and ``h_b`` along beams, ``f`` (``speckle.filter_complex``),
    the mean ``(B, J)`` filtered by the squared kernels, ``expected`` (``speckle.filter_real``), and
    ``out = |f|^2 mean / expected x tvg`` (0 where ``expected <= 0``). Zero
    borders as ``cv2.BORDER_CONSTANT``; kernels of odd length, centred (any shape; a symmetric one, as the pulse's
    and the beam pattern's are, has its taps folded: :func:`_taps_folded`, half the multiply-adds).
    Per output row the range taps first (a weighted sum of ``len(h_r)`` input rows),
    then the beam taps along the zero-padded row (:func:`_taps`), all in float32 with fused
    multiply-adds (cv2's sums in another order): neither ``f`` nor ``expected`` is stored, and
    the rows are independent, so that threads can take row ranges (:func:`_speckle_row`)."""
    B, J = mean.shape
    Db = h_b.size // 2
    h_b2 = h_b * h_b
    h_r2 = h_r * h_r  # (not per row: an allocation each)
    sym_r = _is_symmetric(h_r)
    sym_b = _is_symmetric(h_b)
    tz = np.zeros(2 * (J + 2 * Db), np.float32)  # the range-filtered field row, zero-padded by Db beams
    tm = np.zeros(J + 2 * Db, np.float32)  # the range-filtered mean row, zero-padded
    fz = np.empty(2 * J, np.float32)
    fm = np.empty(J, np.float32)
    fa = np.empty(J, np.float32)
    zf = z.reshape(B * 2 * J)
    mf = mean.reshape(B * J)
    for i in range(r0, r1):
        _speckle_row(i, B, J, zf, mf, 0, h_r, h_r2, h_b, h_b2, sym_r, sym_b, tz, tm, fz, fm, fa, mean[i], tvg[i],
                     out[i])


#: Output rows per block of :func:`scatterer_speckle` (its field rows, with the range taps' margins,
#: stay in the core's cache between being formed and filtered).
_SPECKLE_BLOCK = 32


@njit(cache=True, nogil=True, error_model="numpy")  # (no contraction: the field's rows as scatterer_field's)
def scatterer_speckle(intensity, gain, back, area, density, mu_max, k0, k1, have_words, u_words, r2, unit,
                      h_r, h_b, tvg, r0, r1, out):
    """:func:`scatterer_field` (or :func:`scatterer_field_words` when ``have_words``: the words
    :func:`field_words` drew) and :func:`speckle_image` in one pass, output rows ``r0..r1``: per block of
    :data:`_SPECKLE_BLOCK` output rows the field and mean rows it reads (the block's rows and ``len(h_r)
    // 2`` on either side, inside the image) are formed into local scratch, then filtered into ``out``
    (issue 14, i14q: neither the field ``(B, J, 2)`` nor the mean ``(B, J)`` is stored, and one pass
    instead of two). The next block keeps the rows the blocks share. Rows within ``len(h_r) // 2`` of
    ``r0`` or ``r1`` are formed by both neighbouring row ranges (the same numbers). The same numbers as
    the two kernels, operation for operation. Returns the number of cells of large mean (``mu >=
    mu_max``, whose counts the caller draws): where it is not 0, the rows of ``out`` near them are
    wrong and the caller must take the two-pass path instead."""
    B, J = intensity.shape
    Kr = h_r.size
    Dr = Kr // 2
    Db = h_b.size // 2
    h_b2 = h_b * h_b
    h_r2 = h_r * h_r
    sym_r = _is_symmetric(h_r)
    sym_b = _is_symmetric(h_b)
    tz = np.zeros(2 * (J + 2 * Db), np.float32)
    tm = np.zeros(J + 2 * Db, np.float32)
    fz = np.empty(2 * J, np.float32)
    fm = np.empty(J, np.float32)
    fa = np.empty(J, np.float32)
    nb = _SPECKLE_BLOCK + 2 * Dr
    zb = np.empty((nb, J, 2), np.float32)  # field rows buf0 .. buf1 at zb[row - buf0]
    mb = np.empty((nb, J), np.float32)
    zf = zb.reshape(nb * 2 * J)
    mf = mb.reshape(nb * J)
    # the field's row scratch (scatterer_field's)
    m_row, p0, scale, n_row, u_row, x, e, mant, r2_row, power, fix, w0, w1, w2, p32, s32 = _field_row_scratch(J)
    big = np.empty(J, np.bool_)
    half = np.float32(0.5)
    n_big = 0
    buf0 = 0
    buf1 = 0  # rows buf0 .. buf1 are in the scratch
    for i0 in range(r0, r1, _SPECKLE_BLOCK):
        i1 = min(i0 + _SPECKLE_BLOCK, r1)
        need0 = max(i0 - Dr, 0)
        need1 = min(i1 + Dr, B)
        if buf1 > need0:  # keep the rows this block shares with the last: to the top of the scratch
            off = need0 - buf0  # > 0: row by row upwards, so overlapping ranges (a kernel longer than a block) copy right
            for t in range(buf1 - need0):
                zb[t] = zb[off + t]
                mb[t] = mb[off + t]
            start = buf1
        else:
            start = need0
        buf0 = need0
        for i in range(start, need1):
            zi = zb[i - buf0].reshape(2 * J)
            mi = mb[i - buf0]
            bk = back[i]
            a_row = area[i]
            for j in range(J):
                m_row[j] = density * a_row[j]
            if have_words:
                _poisson_small_row32(a_row, density, m_row, u_words[i], mu_max, n_row, fix, p32, s32, p0, scale, u_row)
            else:
                _cell_words_row(k0, k1, i * J, w0, w1, w2)
                _poisson_small_row32(a_row, density, m_row, w0, mu_max, n_row, fix, p32, s32, p0, scale, u_row)
            _field_power_row(m_row, n_row, intensity[i], gain, bk, mu_max, power, big, mi)
            for j in range(J):
                n_big += big[j]
            if have_words:
                r2i = r2[i]
                ui = unit[i].reshape(2 * J)
                for j in range(J):
                    sc = np.sqrt(power[j] * half * r2i[j])
                    zi[2 * j] = ui[2 * j] * sc
                    zi[2 * j + 1] = ui[2 * j + 1] * sc
            else:
                _radius2_row(w1, x, e, mant, r2_row)
                _normals_row(w2, r2_row, power, zi)
        buf1 = need1
        for i in range(i0, i1):
            _speckle_row(i, B, J, zf, mf, buf0, h_r, h_r2, h_b, h_b2, sym_r, sym_b, tz, tm, fz, fm, fa,
                         mb[i - buf0], tvg[i], out[i])
    return n_big
