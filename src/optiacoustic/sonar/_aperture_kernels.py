"""numba kernel of the aperture model's image formation (imported only through :mod:`._kernels`).

One pass per beam over the primary rays' grid forms, for the beams ``j0..j1``, what three passes
formed before (issue 10, cost): each hit ray's sub-cells (``formation._subdivide``, never stored),
their echo with the seabed/target split (``_numba_kernels.bucket_by_beam`` + ``echo_rows``) and
the seabed area per cell (``formation.cell_area``). The sub-cells of a beam are visited in the
order the materialised path buckets them (elevation sample, then sub-cell), with the same
formulas, so the sums are the same numbers; the tests compare it with the numpy reference
(``OAS_KERNELS=numpy``: materialised sub-cells, ``_form_image``, ``cell_area``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

_MIN_COS_FOOTPRINT = 0.02  # same clamp as formation._MIN_COS_FOOTPRINT


@njit(cache=True, nogil=True)
def aperture_echo_rows(rng, nd, ndd, a, b, half_step, refl, elevation, n_sub, K, J,
                       table_x0, table_dx, table_y, alpha_db, spreading, bin_width,
                       slot_of_ray, seabed_of_ray, dtheta, range_min, n_cells, H, V, full, q, n_bins,
                       want_area, j0, j1, out, area_out):
    """Echo rows (``(S, n_beams, n_bins)`` float32, as ``echo_rows``) and the seabed area
    (``(n_bins, n_beams)`` float32, the image layout, one cell per bin, no anti-aliasing, as
    ``cell_area``; beams ``j0..j1`` are its columns) of the
    aperture model's sub-cells, for beams ``j0..j1``, straight from the primary rays.

    Per ray ``i = j K + k`` (flat beam-major ``(J * K,)`` arrays: each beam's rays contiguous;
    ``half_step`` the cells' extents ``a``, ``b`` but at refined edges): ``n_sub[i]`` sub-cells
    (``subcell_counts``), each with the range, footprint, Lambert factor, two-way pattern weight
    and gain of ``_numba_kernels.subdivide``; a sub-cell of energy ``> 0`` deposits its box
    into slot 0 and its class's slot ``slot_of_ray[i]``; a seabed sub-cell
    (``seabed_of_ray[i]``) deposits its area ``r^2 cos(phi) dtheta_j dphi / max(cos, 0.05)`` into
    ``area_out`` (when ``want_area``).
    """
    S = out.shape[0]
    D = (H.shape[1] - 1) // 2
    row = np.zeros((S, n_bins))
    step = np.zeros((S, n_bins + 1))
    end = np.zeros(S)
    used = np.zeros(S, np.bool_)
    a_row = np.zeros(n_bins)
    a_step = np.zeros(n_bins + 1)
    a_used = False
    n_tab = table_y.size
    pad_w = 1e-4 * bin_width
    k_abs = -0.2 * np.log(10.0) * alpha_db
    scale = q / bin_width
    a_scale = 1.0 / bin_width
    # the trigonometry of a cell depends only on (a, b, S): most cells have the grid's (a, b)
    # (all but the refined edges), so it is tabulated per S for those (the same numbers)
    max_s = 1
    for i in range(n_sub.size):
        max_s = max(max_s, n_sub[i])
    # deposits at fine cells c (phase ph) and c + 1 of the default q = 2 in one pass over bins
    # bi - D .. bi + D + 1 (bi = c // 2): HA the first's taps, HB the second's (same bin at phase 0,
    # the next bin at phase 1); the sums differ from two passes by float64 rounding only
    pair = q == 2
    HA = np.zeros((2, 2 * D + 2))
    HB = np.zeros((2, 2 * D + 2))
    if pair:
        for m in range(2 * D + 1):
            HA[0, m] = H[0, m]
            HB[0, m] = H[1, m]
            HA[1, m] = H[1, m]
            HB[1, m + 1] = H[0, m]
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
    # one beam's sub-cells, formed in a first pass and deposited in a third: the exp and cos
    # between them run in a loop of their own (libm calls in the big loop spill its registers)
    cap = K * max_s
    c_r = np.empty(cap)
    c_lo = np.empty(cap)
    c_hi = np.empty(cap)
    c_c = np.empty(cap)
    c_el = np.empty(cap)
    c_d = np.empty(cap)
    c_e = np.empty(cap)
    c_cos = np.empty(cap)
    c_s = np.empty(cap, np.int64)
    c_sea = np.empty(cap, np.bool_)
    c_key = np.empty(cap, np.int64)
    # cos(elevation) of the sub-cells, remembered per (elevation sample, sub-cell): the grid's cells
    # (most) give the same elevation, bit for bit, in every beam, so libm is called once per value
    # (a hit only where the stored elevation is the same number: the same cos)
    memo_el = np.full(K * max_s, np.nan)
    memo_cos = np.empty(K * max_s)
    for j in range(j0, j1):
        dth = dtheta[j]
        nc = 0
        for k in range(K):
            i = k * J + j
            Sn = n_sub[i]
            if Sn == 0:
                continue
            if a[i] == a_g and b[i] == b_g:
                delta, ch, sh, cd, sd, ct0, st0 = (trig[Sn, 0], trig[Sn, 1], trig[Sn, 2], trig[Sn, 3], trig[Sn, 4],
                                                   trig[Sn, 5], trig[Sn, 6])
            else:
                delta = (a[i] + b[i]) / Sn
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
            s = slot_of_ray[i]
            seabed = want_area and seabed_of_ray[i]
            for kk in range(Sn):
                if kk > 0:
                    t = -a[i] + (kk + 0.5) * delta
                    ct, st = ct * cd - st * sd, st * cd + ct * sd
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
                f_lo = flo - pad
                f_hi = fhi + pad
                el = elevation[i] + t
                pos = (el - table_x0) / table_dx
                if pos <= 0.0:
                    w = table_y[0]
                elif pos >= n_tab - 1:
                    w = table_y[n_tab - 1]
                else:
                    jj = int(pos)
                    f = pos - jj
                    w = table_y[jj] + f * (table_y[jj + 1] - table_y[jj])
                c_r[nc] = r_mid
                c_lo[nc] = f_lo
                c_hi[nc] = f_hi
                c_c[nc] = c_mid
                c_el[nc] = el
                c_d[nc] = delta
                c_e[nc] = refl[i] * c_mid * delta * w
                c_s[nc] = s
                c_sea[nc] = seabed
                c_key[nc] = k * max_s + kk
                nc += 1
        if spreading:
            for ic in range(nc):
                r_mid = c_r[ic]
                c_e[ic] *= np.exp(k_abs * (r_mid - 1.0)) / (r_mid * r_mid)
        if want_area:
            for ic in range(nc):
                key = c_key[ic]
                el = c_el[ic]
                if memo_el[key] == el:
                    c_cos[ic] = memo_cos[key]
                else:
                    cv = np.cos(el)
                    memo_el[key] = el
                    memo_cos[key] = cv
                    c_cos[ic] = cv
        for ic in range(nc):
            r_mid = c_r[ic]
            f_lo = c_lo[ic]
            f_hi = c_hi[ic]
            c_mid = c_c[ic]
            el = c_el[ic]
            delta = c_d[ic]
            e = c_e[ic]
            s = c_s[ic]
            if e > 0:  # as bucket_by_beam: footprint in fine cells, density, clipped
                x0 = (f_lo - range_min) * scale
                x1 = (f_hi - range_min) * scale
                dens = e / (x1 - x0)
                x0 = min(max(x0, 0.0), n_cells)
                x1 = min(max(x1, 0.0), n_cells)
                p0 = int(x0)
                f0 = x0 - p0
                p1 = int(x1)
                f1 = x1 - p1
                ss = 0
                while True:  # slot 0 (the whole echo), then the class's slot when it has one
                    for c, va, vb in ((p0, dens - dens * f0, dens * f0), (p1, dens * f1 - dens, -dens * f1)):
                        # the deposits at fine cells c and c + 1 together: one pass over the bins both
                        # reach (2 D + 2 at most) when both are inside the row (the default q = 2)
                        if pair and c + 1 < n_cells:
                            bi = c >> 1
                            ph = c & 1
                            if D <= bi and bi + 1 < n_bins - D:
                                used[ss] = True
                                end[ss] += va
                                end[ss] += vb
                                for m in range(2 * D + 2):
                                    row[ss, bi - D + m] += va * HA[ph, m] + vb * HB[ph, m]
                                step[ss, bi + D + 1] += va * full  # bi + D + 1 < n_bins: bi + 1 < n_bins - D
                                sb = bi + ph + D + 1
                                if sb < n_bins:
                                    step[ss, sb] += vb * full
                                continue
                        for c1, v in ((c, va), (c + 1, vb)):
                            if c1 >= n_cells:  # only cells past the end, which are cut
                                continue
                            used[ss] = True
                            end[ss] += v
                            if q == 2:  # the default oversampling: no integer division
                                bi = c1 >> 1
                                ph = c1 & 1
                            else:
                                bi = c1 // q
                                ph = c1 - bi * q
                            if D <= bi < n_bins - D:
                                for m in range(2 * D + 1):
                                    row[ss, bi - D + m] += v * H[ph, m]
                            else:
                                for m in range(-D, D + 1):
                                    bb = bi + m
                                    if 0 <= bb < n_bins:
                                        row[ss, bb] += v * H[ph, m + D]
                            sb = bi + D + 1
                            if sb < n_bins:
                                step[ss, sb] += v * full
                    if ss != 0 or s <= 0:
                        break
                    ss = s
            if c_sea[ic]:
                el_lo = el - 0.5 * delta
                el_hi = el + 0.5 * delta
                ar = r_mid * r_mid * c_cos[ic] * dth * (el_hi - el_lo) / max(c_mid, 0.05)
                if ar > 0:
                    x0 = (f_lo - range_min) * a_scale
                    x1 = (f_hi - range_min) * a_scale
                    dens = ar / (x1 - x0)
                    x0 = min(max(x0, 0.0), n_bins)
                    x1 = min(max(x1, 0.0), n_bins)
                    p0 = int(x0)
                    f0 = x0 - p0
                    p1 = int(x1)
                    f1 = x1 - p1
                    a_used = True
                    for c, v in ((p0, dens - dens * f0), (p0 + 1, dens * f0), (p1, dens * f1 - dens),
                                 (p1 + 1, -dens * f1)):
                        if c < n_bins:  # one cell per bin, no anti-aliasing: echo_rows with D = 0
                            a_row[c] += v
                            if c + 1 < n_bins:
                                a_step[c + 1] += v
        for ss in range(S):
            if not used[ss]:
                out[ss, j, :] = 0.0
                continue
            acc = 0.0
            for bb in range(n_bins):
                acc += step[ss, bb]
                out[ss, j, bb] = row[ss, bb] + acc
            for tv in range(V.size):
                bb = n_bins - V.size + tv
                if bb >= 0:
                    out[ss, j, bb] -= end[ss] * V[tv]
            row[ss, :] = 0.0
            step[ss, :] = 0.0
            end[ss] = 0.0
            used[ss] = False
        if want_area:
            if not a_used:
                area_out[:, j] = 0.0
            else:
                acc = 0.0
                for bb in range(n_bins):
                    acc += a_step[bb]
                    area_out[bb, j] = a_row[bb] + acc
                a_row[:] = 0.0
                a_step[:] = 0.0
                a_used = False



@njit(cache=True, nogil=True)
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


@njit(cache=True, nogil=True)
def class_slots(ray_cls, table, slot):
    """``slot[i] = table[ray_cls[i]]`` (``formation._class_slots``'s second pass)."""
    for i in range(ray_cls.size):
        slot[i] = table[ray_cls[i]]
