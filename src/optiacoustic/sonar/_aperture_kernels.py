"""numba kernel of the aperture model's image formation (imported only through :mod:`._kernels`).

One pass per beam over the primary rays' grid forms, for the beams ``j0..j1``, what three passes
formed before (issue 10, cost): each hit ray's sub-cells (``formation._subdivide``, never stored),
their echo with the seabed/target split (``_numba_kernels.bucket_by_beam`` + ``echo_rows``) and
the seabed area per cell (``formation.cell_area``). The sub-cells of a beam are visited in the
order the materialised path buckets them (elevation sample, then sub-cell), with the same
formulas: the areas are the same deposits summed in the same order, each sub-cell's
``cos(elevation)`` by angle addition (i14j: a few float64 ulp from libm's ``cos``); the echo is the same linear map of the
same deposits summed in another order (deposit, then convolve: see ``aperture_echo_rows``), the
same to float64 rounding; the spreading's ``exp`` is :func:`._numba_kernels.exp_row` (vectorised,
within an ulp of libm's ``exp`` that the materialised path calls: float64 rounding again). The tests compare it with the materialised numba path and with the
numpy reference (``OAS_KERNELS=numpy``: materialised sub-cells, ``_form_image``, ``cell_area``).
numpy's error model, as ``_numba_kernels``: no zero-division checks (the footprints are padded to
1e-4 of a bin, the pattern table's step is positive).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._numba_kernels import exp_row, subcell_footprint, table_weight
_AREA_BLOCK = 16  # beams whose area rows are written to the image layout together


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _box_edges(lo, hi, value, range_min, scale, n):
    """The box ``[lo, hi]`` (m) holding ``value`` as its two edges' four deposits on a grid of ``n``
    cells of ``1 / scale`` m from ``range_min`` (``formation._box_integrate``'s linear two-cell split
    of each edge): returns the edges' cells ``p0``, ``p1`` (int32) and the four values. Branch-free
    (clamps by min/max), so that the loops calling it vectorise; the echo's fine cells and the
    seabed area's bins both use it."""
    x0 = (lo - range_min) * scale
    x1 = (hi - range_min) * scale
    dens = value / (x1 - x0)
    x0 = min(max(x0, 0.0), n)
    x1 = min(max(x1, 0.0), n)
    p0 = np.int32(x0)
    f0 = x0 - p0
    p1 = np.int32(x1)
    f1 = x1 - p1
    return p0, p1, dens - dens * f0, dens * f0, dens * f1 - dens, -dens * f1


@njit(cache=True, nogil=True, error_model="numpy")
def aperture_echo_rows(rng, nd, ndd, a, b, half_step, refl_of_body, elevation_k, word, K, J,
                       table_x0, table_dx, table_y, alpha_db, spreading, bin_width,
                       slot_of_body, is_seabed, dtheta, range_min, n_cells, H, V, full, q, n_bins,
                       want_area, max_s, j0, j1, out, area_out, live):
    """Echo rows (``(S, n_beams, n_bins)`` float32, as ``echo_rows``) and the seabed area
    (``(n_bins, n_beams)`` float32, the image layout, one cell per bin, no anti-aliasing, as
    ``cell_area``; beams ``j0..j1`` are its columns) of the
    aperture model's sub-cells, for beams ``j0..j1``, straight from the primary rays.

    Per ray ``i = k J + j`` (flat ``(K * J,)`` arrays ``rng``, ``nd``, ``ndd``, ``a``, ``b`` in the
    grid's layout; ``half_step`` the cells' extents ``a``, ``b`` but at refined edges) the
    ray's word ``word[j K + k]`` (int64, **beam-major**: :func:`aperture_words`) holds its
    sub-cell count ``Sn`` (bits 0-7, 0 for a miss), whether its cell was refined (bit 8: then
    ``a[i]``, ``b[i]`` are read) and its body id (bits 16 on); the body's reflectivity, output slot
    and seabed flag come from tables per body id (``refl_of_body``, ``slot_of_body``,
    ``is_seabed``), the ray's elevation from ``elevation_k[k]`` (the grid's row). So the beam's
    loop over its ``K`` rays reads one contiguous array, and the per-ray values at the grid's
    stride of ``J`` only for hit rays (i14o: ten strided per-ray reads were most of the sub-cells'
    formation). Each ray has ``Sn`` sub-cells, each with the range, footprint, Lambert factor,
    two-way pattern weight and gain of ``_numba_kernels.subdivide``; a sub-cell of energy ``> 0``
    deposits its box into slot 0 and its class's slot ``slot_of_body[body]``; a seabed sub-cell
    deposits its area ``r^2 cos(phi) dtheta_j dphi / max(cos, 0.05)`` into ``area_out`` (when
    ``want_area``). ``max_s``: the largest ``Sn`` (1 at least). ``live[s, j]`` (bool
    ``(S, n_beams)``) tells whether row ``out[s, j]`` has deposits (a row without is written as
    zeros).

    Deposit, then convolve: a box's two edges each put their two fine-cell values (the
    linear two-cell split of ``formation._box_integrate``) into the beam's per-slot array of
    fine-cell deposits ``dep[s, cell]`` (four adds per slot instead of ``2 (2 D + 2)`` taps and
    two steps); after the beam's sub-cells, :func:`_rows_from_deposits` applies ``echo_rows``'
    linear map to each slot's array once (the ``H`` taps around each deposit's bin, a step of
    ``full`` from ``D + 1`` bins on, ``V`` at the row's end), over the bins the deposits reach,
    in loops over bins that the compiler vectorises. The same linear map as ``echo_rows``
    applied deposit by deposit, summed in another order (float64): the rows differ from it by
    float64 rounding of the partial sums (``~1e-16`` of the largest running sum of a row, which
    a short footprint's ``+dens``/``-dens`` pair can make ``~1e4`` times its echo).
    The area (no anti-aliasing: one cell per bin) is the cumulative sum of its deposits,
    the same additions in the same order as ``echo_rows`` with one cell per bin; each sub-cell's
    ``cos(elevation)`` is ``cos(e) cos(t) - sin(e) sin(t)`` from the ray's elevation ``e`` and the
    ``(cos t, sin t)`` of its footprint (a few float64 ulp from ``cos(e + t)``), and the area's
    deposits of all the beam's sub-cells (zeros off the seabed) are formed in branch-free loops
    that vectorise (i14j: the per-sub-cell libm ``cos`` and the compacting loop took ~1/4 of the
    kernel).
    """
    S = out.shape[0]
    D = (H.shape[1] - 1) // 2
    # fine-cell deposits per slot; cells n_cells, n_cells + 1 take the deposits past the end
    # (cut: never read, zeroed with the rest)
    dep = np.zeros((S, n_cells + 2))
    lo_c = np.full(S, n_cells + 2, np.int64)  # fine cells reached by each slot's deposits (inclusive)
    hi_c = np.full(S, -1, np.int64)
    ph = np.zeros((q, n_bins + 2 * D))
    cum = np.empty(n_bins + D + 2)
    blk0 = j0
    rowbuf = np.zeros(n_bins)
    # the area's deposits, one cell per bin, of a block of _AREA_BLOCK beams (bin-major: the block's
    # cumulative sums run side by side, written straight into the image layout)
    a_dep = np.zeros((n_bins + 2, _AREA_BLOCK))
    a_acc = np.empty(_AREA_BLOCK)
    a_lo = n_bins + 2
    a_hi = -1
    pad_w = 1e-4 * bin_width
    k_abs = -0.2 * np.log(10.0) * alpha_db
    scale = q / bin_width
    a_scale = 1.0 / bin_width
    # the trigonometry of a cell depends only on (a, b, S): most cells have the grid's (a, b)
    # (all but the refined edges), so it is tabulated per S for those (the same numbers)
    a_g = b_g = half_step  # formation._scan's cells before edge refinement
    trig = np.empty((max_s + 1, 7))
    for Sn in range(1, max_s + 1):
        d_ = (a_g + b_g) / Sn
        t0 = -a_g + 0.5 * d_
        trig[Sn, 0] = d_
        trig[Sn, 1] = np.cos(0.5 * d_)
        trig[Sn, 2] = np.sin(0.5 * d_)
        trig[Sn, 3] = np.cos(d_)
        trig[Sn, 4] = np.sin(d_)
        trig[Sn, 5] = np.cos(t0)
        trig[Sn, 6] = np.sin(t0)
    # one beam's sub-cells, formed in a first pass and deposited after: the exp and cos run in
    # loops of their own (libm calls in the big loop spill its registers)
    cap = K * max_s
    c_r = np.empty(cap)
    c_lo = np.empty(cap)
    c_hi = np.empty(cap)
    c_c = np.empty(cap)
    c_el = np.empty(cap)
    c_d = np.empty(cap)
    c_e = np.empty(cap)
    c_s = np.empty(cap, np.int64)
    c_sea = np.empty(cap, np.bool_)
    c_cos = np.empty(cap)  # cos(elevation) at the sub-cell's centre (for the area)
    c_x = np.empty(cap)  # the spreading's exponents, exp and scratch (exp_row)
    c_g = np.empty(cap)
    c_t = np.empty(cap)
    # cos(elevation) of a sub-cell by angle addition, cos(e + t) = cos(e) cos(t) - sin(e) sin(t), from
    # the ray's elevation e and the (cos t, sin t) its footprint uses (i14j; libm's cos per sub-cell,
    # memoised, kept the area's loop from vectorising). (cos e, sin e) once per elevation sample (row)
    cos_e = np.empty(K)
    sin_e = np.empty(K)
    for k in range(K):
        cos_e[k] = np.cos(elevation_k[k])
        sin_e[k] = np.sin(elevation_k[k])
    # the area's deposits of every sub-cell of a beam (zeros off the seabed: they add nothing), in
    # loops without branches or compaction, which vectorise (int32 cells: AVX2 converts to those)
    a_v = np.empty((4, cap))
    e_v = np.empty((4, cap))  # the echo's, likewise (then added for the lit sub-cells only)
    e_p0 = np.empty(cap, np.int32)
    e_p1 = np.empty(cap, np.int32)
    a_p0 = np.empty(cap, np.int32)
    a_p1 = np.empty(cap, np.int32)
    for j in range(j0, j1):
        dth = dtheta[j]
        nc = 0
        jK = j * K
        for k in range(K):
            w = word[jK + k]  # the ray's word, beam-major: read contiguously (most rays stop here)
            Sn = w & 255
            if Sn == 0:
                continue
            i = k * J + j
            bid = w >> 16
            if (w >> 8) & 1:  # a refined edge's cell (a, b not the grid's)
                a_i = a[i]
                delta = (a_i + b[i]) / Sn
                ch = np.cos(0.5 * delta)
                sh = np.sin(0.5 * delta)
                cd, sd = np.cos(delta), np.sin(delta)
                t0 = -a_i + 0.5 * delta
                ct0, st0 = np.cos(t0), np.sin(t0)
            else:
                a_i = a_g
                delta, ch, sh, cd, sd, ct0, st0 = (trig[Sn, 0], trig[Sn, 1], trig[Sn, 2], trig[Sn, 3], trig[Sn, 4],
                                                   trig[Sn, 5], trig[Sn, 6])
            x, y = nd[i], ndd[i]
            sgn = -1.0 if x < 0 else 1.0
            base = rng[i] * abs(x)
            t = -a_i + 0.5 * delta
            ct, st = ct0, st0
            s = slot_of_body[bid]
            seabed = want_area and is_seabed[bid]  # a ray with sub-cells is a hit
            e_i = elevation_k[k]
            r_i = refl_of_body[bid]
            ce = se = 0.0
            if seabed:
                ce, se = cos_e[k], sin_e[k]
            for kk in range(Sn):
                if kk > 0:
                    t = -a_i + (kk + 0.5) * delta
                    ct, st = ct * cd - st * sd, st * cd + ct * sd
                r_mid, c_mid, f_lo, f_hi = subcell_footprint(x, y, ct, st, ch, sh, sgn, base, pad_w)
                el = e_i + t
                w = table_weight(el, table_x0, table_dx, table_y)
                c_r[nc] = r_mid
                c_lo[nc] = f_lo
                c_hi[nc] = f_hi
                c_c[nc] = c_mid
                c_el[nc] = el
                c_d[nc] = delta
                c_e[nc] = r_i * c_mid * delta * w
                c_s[nc] = s
                c_sea[nc] = seabed
                c_cos[nc] = ce * ct - se * st
                nc += 1
        if spreading:  # the two-way gain exp(k_abs (r - 1)) / r^2, its exp vectorised (exp_row)
            for ic in range(nc):
                c_x[ic] = k_abs * (c_r[ic] - 1.0)
            exp_row(c_x, nc, c_g, c_t)
            for ic in range(nc):
                r_mid = c_r[ic]
                c_e[ic] *= c_g[ic] / (r_mid * r_mid)
        # the echo: each box's edges as four fine-cell deposits per slot (slot 0, the class's);
        # their places and values first, in a loop without stores to the rows (deposits of
        # neighbouring sub-cells share cells: adds that wait on the divisions serialise the loop)
        for ic in range(nc):  # every sub-cell's box as four fine-cell deposits (0 where unlit), branch-free: vectorises
            e = c_e[ic]
            e_p0[ic], e_p1[ic], e_v[0, ic], e_v[1, ic], e_v[2, ic], e_v[3, ic] = _box_edges(
                c_lo[ic], c_hi[ic], e if e > 0 else 0.0, range_min, scale, n_cells)
        # as bucket_by_beam: the lit sub-cells only, into slot 0 (the whole echo), then into their
        # class's slot (when it has one) in a second loop: each slot's cells take their deposits in
        # the sub-cells' order, as before. The cells reached (lo_c, hi_c) in loops of their own (a
        # running min and max in memory made a chain of dependent loads and stores)
        d0 = dep[0]
        n_cls = 0
        lo0 = lo_c[0]
        hi0 = hi_c[0]
        for ic in range(nc):
            if c_e[ic] > 0:
                lo0 = min(lo0, e_p0[ic])
                hi0 = max(hi0, e_p1[ic] + 1)
                n_cls += c_s[ic] > 0
        lo_c[0] = lo0
        hi_c[0] = hi0
        for ic in range(nc):
            if not c_e[ic] > 0:
                continue
            p0 = e_p0[ic]
            p1 = e_p1[ic]
            d0[p0] += e_v[0, ic]
            d0[p0 + 1] += e_v[1, ic]
            d0[p1] += e_v[2, ic]
            d0[p1 + 1] += e_v[3, ic]
        if n_cls > 0:
            for ic in range(nc):
                ss = c_s[ic]
                if not (c_e[ic] > 0 and ss > 0):
                    continue
                p0 = e_p0[ic]
                p1 = e_p1[ic]
                dep[ss, p0] += e_v[0, ic]
                dep[ss, p0 + 1] += e_v[1, ic]
                dep[ss, p1] += e_v[2, ic]
                dep[ss, p1 + 1] += e_v[3, ic]
                lo_c[ss] = min(lo_c[ss], p0)
                hi_c[ss] = max(hi_c[ss], p1 + 1)
        if want_area:
            for ic in range(nc):  # the seabed area of each sub-cell (0 off the seabed)
                r_mid = c_r[ic]
                delta = c_d[ic]
                el = c_el[ic]
                el_lo = el - 0.5 * delta
                el_hi = el + 0.5 * delta
                ar = r_mid * r_mid * c_cos[ic] * dth * (el_hi - el_lo) / max(c_c[ic], 0.05)
                a_v[0, ic] = ar if (c_sea[ic] and ar > 0) else 0.0
            for ic in range(nc):  # its box deposit (as the echo's, one cell per bin)
                a_p0[ic], a_p1[ic], a_v[0, ic], a_v[1, ic], a_v[2, ic], a_v[3, ic] = _box_edges(
                    c_lo[ic], c_hi[ic], a_v[0, ic], range_min, a_scale, n_bins)
            # one cell per bin (echo_rows with D = 0); cells past the end are not read
            jb = j - blk0
            for ia in range(nc):
                p0 = a_p0[ia]
                p1 = a_p1[ia]
                a_dep[p0, jb] += a_v[0, ia]
                a_dep[p0 + 1, jb] += a_v[1, ia]
                a_dep[p1, jb] += a_v[2, ia]
                a_dep[p1 + 1, jb] += a_v[3, ia]
                a_lo = min(a_lo, p0)
                a_hi = max(a_hi, p1 + 1)
        for ss in range(S):
            first = lo_c[ss]
            last = hi_c[ss]
            lo_c[ss] = n_cells + 2
            hi_c[ss] = -1
            live[ss, j] = _rows_from_deposits(dep[ss], first, last, H, V, full, q, n_bins, ph, cum, rowbuf,
                                              out[ss, j])
        if want_area:
            jb = j - blk0
            if jb == _AREA_BLOCK - 1 or j == j1 - 1:
                # the block's cumulative sums (each beam's the same additions in the same order as
                # one beam's alone: zeros before its first deposit and after its last add nothing),
                # the beams side by side (their running sums interleave: no chain of dependent adds)
                # and written into the image layout a bin at a time (16 contiguous beams)
                nb = jb + 1
                a_acc[:] = 0.0
                for bb in range(n_bins):
                    row = a_dep[bb]
                    dst = area_out[bb]
                    for t in range(nb):
                        a_acc[t] += row[t]
                        dst[blk0 + t] = a_acc[t]
                if a_hi >= 0:
                    a_dep[a_lo:a_hi + 1, :] = 0.0
                a_lo = n_bins + 2
                a_hi = -1
                blk0 = j + 1


@njit(cache=True, nogil=True, error_model="numpy")
def _rows_from_deposits(dep, c_lo, c_top, H, V, full, q, n_bins, ph, cum, rowbuf, row_out):
    """One slot's echo row from its fine-cell deposits ``dep[c_lo..c_top]`` (zero elsewhere; zeroed
    here for the next beam): ``echo_rows``' linear map (``H`` taps around each deposit's bin, a
    step of ``full`` from ``D + 1`` bins after it on, ``V`` at the row's end) over the bins it
    reaches, into ``row_out`` (float32, written whole). ``ph`` ``(q, n_bins + 2 D)`` zeros
    (left zero), ``cum`` ``(n_bins + D + 2,)`` and ``rowbuf`` ``(n_bins,)`` scratch. Returns False
    when no deposit is inside the row (written as zeros)."""
    D = (H.shape[1] - 1) // 2
    nt = 2 * D + 1
    n_cells = n_bins * q
    c_hi = min(c_top, n_cells - 1)  # the cells past the end are cut
    if c_hi < c_lo:
        row_out[:] = 0.0
        if c_top >= c_lo:
            dep[c_lo:c_top + 1] = 0.0
        return False
    lo = c_lo // q
    hi = c_hi // q
    # the deposits by phase, bins offset by D (zero margins for the taps), and their running
    # sum over bins, ``cum[b]`` for the bins up to ``b - D - 1`` (what the steps add up to)
    tot = 0.0
    if q == 2:  # the default oversampling: two phases, no integer division
        p0r = ph[0]
        p1r = ph[1]
        for bq in range(lo, hi + 1):
            v0 = dep[2 * bq]
            v1 = dep[2 * bq + 1]
            p0r[D + bq] = v0
            p1r[D + bq] = v1
            tot += v0 + v1
            cum[D + 1 + bq] = tot
    else:
        for bq in range(lo, hi + 1):
            g = 0.0
            for h in range(q):
                v = dep[bq * q + h]
                ph[h, D + bq] = v
                g += v
            tot += g
            cum[D + 1 + bq] = tot
    dep[c_lo:c_top + 1] = 0.0
    # the steps (bins e1 on), then the taps: row[b] += sum_{h, m} H[h, m + D] ph[h, D + b - m]
    r0 = max(lo - D, 0)
    r1 = min(hi + D + 1, n_bins)
    e1 = min(lo + D + 1, n_bins)
    n = r1 - r0
    rb = rowbuf[:n]
    rb[:e1 - r0] = 0.0
    cs = cum[e1:r1]
    rs = rb[e1 - r0:]
    for t in range(r1 - e1):
        rs[t] = full * cs[t]
    if q == 2:  # two taps of both phases per pass over the row (fewer loads and stores of it)
        p0r = ph[0]
        p1r = ph[1]
        mm = 0
        while mm + 1 < nt:
            ha0 = H[0, mm]
            ha1 = H[1, mm]
            hb0 = H[0, mm + 1]
            hb1 = H[1, mm + 1]
            o = r0 + 2 * D - mm  # D + (r0 + t) - (mm - D)
            sa0 = p0r[o:o + n]
            sa1 = p1r[o:o + n]
            sb0 = p0r[o - 1:o - 1 + n]
            sb1 = p1r[o - 1:o - 1 + n]
            for t in range(n):
                rb[t] += (ha0 * sa0[t] + ha1 * sa1[t]) + (hb0 * sb0[t] + hb1 * sb1[t])
            mm += 2
        if mm < nt:
            ha0 = H[0, mm]
            ha1 = H[1, mm]
            o = r0 + 2 * D - mm
            sa0 = p0r[o:o + n]
            sa1 = p1r[o:o + n]
            for t in range(n):
                rb[t] += ha0 * sa0[t] + ha1 * sa1[t]
    else:
        for h in range(q):
            for mm in range(nt):
                hv = H[h, mm]
                o = r0 + 2 * D - mm
                src = ph[h, o:o + n]
                for t in range(n):
                    rb[t] += hv * src[t]
    row_out[:r0] = 0.0
    ro = row_out[r0:r1]
    for t in range(n):
        ro[t] = rb[t]
    e2 = min(hi + D + 2, n_bins)
    for bb in range(r1, e2):
        row_out[bb] = full * cum[bb]
    row_out[e2:] = full * tot
    # fine cells past the end do not exist: V removes what the steps put there
    for tv in range(V.size):
        bb = n_bins - V.size + tv
        if bb >= 0:
            row_out[bb] -= tot * V[tv]
    ph[:, D + lo:D + hi + 1] = 0.0
    return True



@njit(cache=True, nogil=True, error_model="numpy")
def aperture_words(body, lo, hi, energy, a, b, half_step, cls, bin_width, max_sub, sub_bins, K, J, word, counts):
    """The per-ray words of :func:`aperture_echo_rows`, written **beam-major** (``word[j K + k]`` for the
    grid's ray ``i = k J + j``, read here in the grid's order): ``Sn | refined << 8 | body << 16``, with
    ``Sn`` the ray's sub-cells (``_numba_kernels.subcell_counts``: 0 for a miss, then the word is 0)
    and ``refined`` 1 where ``a[i]`` or ``b[i]`` is not ``half_step`` (a refined edge's cell). Also
    ``formation._class_slots_numba``'s counts: ``counts[cls[body]]`` += ``Sn`` over the lit rays
    (``energy > 0``; body -1 reads ``cls``' last entry), as ``class_counts`` with the sub-cell counts as
    weights. Returns the largest ``Sn`` (1 at least). ``max_sub`` must be below 256."""
    n_cls = cls.size
    top = 1
    for k in range(K):
        for j in range(J):
            i = k * J + j
            bd = body[i]
            s = 0
            if bd >= 0:
                s = int(np.ceil((hi[i] - lo[i]) / bin_width / sub_bins))
                s = min(max(s, 1), max_sub)
                top = max(top, s)
            if energy[i] > 0:
                counts[cls[bd if bd >= 0 else n_cls + bd]] += s
            w = np.int64(0)
            if s > 0:
                refined = 0 if (a[i] == half_step and b[i] == half_step) else 1
                w = np.int64(s) | (np.int64(refined) << 8) | (np.int64(bd) << 16)
            word[j * K + k] = w
    return top


@njit(cache=True, nogil=True, error_model="numpy")
def class_counts(body, energy, weight, cls, counts, ray_cls):
    """``formation._class_slots``'s first pass: ``ray_cls[i] = cls[body[i]]`` (body -1 reads the last
    entry) and ``counts[c]`` += ``weight[i]`` over the lit rays (``energy > 0``) of class ``c``."""
    n_cls = cls.size
    for i in range(body.size):
        b = body[i]
        c = cls[b if b >= 0 else n_cls + b]
        ray_cls[i] = c
        if energy[i] > 0:
            counts[c] += weight[i]


@njit(cache=True, nogil=True, error_model="numpy")
def class_slots(ray_cls, table, slot):
    """``slot[i] = table[ray_cls[i]]`` (``formation._class_slots``'s second pass)."""
    for i in range(ray_cls.size):
        slot[i] = table[ray_cls[i]]
