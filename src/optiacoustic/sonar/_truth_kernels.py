"""numba kernels of the sonar's ground truth (imported only through :func:`._kernels.truth_kernels`, on first use).

Kept apart from :mod:`._numba_kernels` (echo, noise, aperture sub-cells) so that work on the
two does not collide. Each kernel computes exactly what its numpy reference in ``formation.py``
computes on a simulated frame's rays (same float32/float64 operations per ray, so the same
bits; ``tests/sonar/test_truth_kernels.py`` compares them).
They release the GIL and are cached on disk like the others.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def truth_maps_direct(beam, lo_m, hi_m, energy, body, el_lo, el_hi, range_min, inv_bin, n_bins, n_beams,
                      body_map, el_min, el_max, weight, j0, j1):
    """Per cell the body of the strongest single contribution and the elevation span that echoes
    (``formation._truth_maps``), written straight into the maps: beams ``j0..j1`` only (their
    columns; rays of other beams are skipped, so that beam ranges can run on several threads).

    ``body_map`` (int16), ``el_min``, ``el_max`` (float32) are ``(n_bins, n_beams)`` outputs;
    ``weight`` ``(n_bins, n_beams)`` float32 is scratch (a cell's strongest weight). The maps start
    as "no echo" (-1, NaN, NaN) by contiguous fills, which vectorise, and need no final pass: an
    unset span is NaN, so a ray's ``lo`` replaces it when ``lo < cur`` or ``cur`` is NaN.

    This equals the reference (the ray-order ``_numba_kernels.truth_maps`` and the numpy path of
    ``formation._truth_maps``) bit for bit whenever every lit ray's elevation span is finite (a
    cell's result does not depend on the order of its rays: the strongest weight wins, ties go to
    the larger body id; the span is a min and a max). It returns the number of lit rays with a
    non-finite span or a body id beyond int16; the caller falls back to the reference when that
    is not 0.
    """
    wf, bf, e0f, e1f = weight.reshape(-1), body_map.reshape(-1), el_min.reshape(-1), el_max.reshape(-1)
    nan = np.float32(np.nan)
    for bb in range(n_bins):
        c0 = bb * n_beams + j0
        c1 = c0 + (j1 - j0)
        wf[c0:c1] = 0.0
        bf[c0:c1] = -1
        e0f[c0:c1] = nan
        e1f[c0:c1] = nan
    odd = 0
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
        if not (np.isfinite(lo_e) and np.isfinite(hi_e)) or body[i] > 32767:
            odd += 1
        g = np.int16(body[i])
        for bb in range(b0, b1 + 1):
            w = dens * max(min(x1, np.float32(bb + 1)) - max(x0, np.float32(bb)), np.float32(0.0))
            cw = weight[bb, j]
            if w > cw or (w == cw and g > body_map[bb, j]):
                weight[bb, j] = w
                body_map[bb, j] = g
            cur = el_min[bb, j]
            if lo_e < cur or cur != cur:
                el_min[bb, j] = lo_e
            cur = el_max[bb, j]
            if hi_e > cur or cur != cur:
                el_max[bb, j] = hi_e
    return odd


@njit(cache=True, nogil=True)
def truth_maps_grid(beam, lo_m, hi_m, energy, body, el_lo, el_hi, range_min, inv_bin, n_bins, n_beams,
                    body_map, el_min, el_max, weight, j0, j1):
    """:func:`truth_maps_direct` for the frame's ray grid (ray ``k * n_beams + j`` is of beam ``j``),
    reading only the rays of beams ``j0..j1`` (row by row, in the same order as
    :func:`truth_maps_direct` takes them): a range of beams costs its own rays, so that the beams can go
    in many small chunks over the threads. Returns what :func:`truth_maps_direct` returns, or -1 (and the
    maps unfinished) when ``beam`` is not the grid's beam index.

    The clearing and the per-ray body are :func:`truth_maps_direct`'s, written out again on purpose:
    as shared helpers (numba ``inline="always"`` or plain calls) the truth maps of thesis scene 1 took
    4.9-5.1 ms of CPU instead of 2.6-2.7 ms (one thread, same bits; measured 2026-11-23). A change to
    one must be made to the other; ``tests/sonar/test_truth_kernels.py`` compares both with the
    reference."""
    wf, bf, e0f, e1f = weight.reshape(-1), body_map.reshape(-1), el_min.reshape(-1), el_max.reshape(-1)
    nan = np.float32(np.nan)
    for bb in range(n_bins):
        c0 = bb * n_beams + j0
        c1 = c0 + (j1 - j0)
        wf[c0:c1] = 0.0
        bf[c0:c1] = -1
        e0f[c0:c1] = nan
        e1f[c0:c1] = nan
    if beam.size % n_beams != 0:
        return -1
    odd = 0
    for k in range(beam.size // n_beams):
        for j in range(j0, j1):
            i = k * n_beams + j
            if beam[i] != j:
                return -1
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
            if not (np.isfinite(lo_e) and np.isfinite(hi_e)) or body[i] > 32767:
                odd += 1
            g = np.int16(body[i])
            for bb in range(b0, b1 + 1):
                w = dens * max(min(x1, np.float32(bb + 1)) - max(x0, np.float32(bb)), np.float32(0.0))
                cw = weight[bb, j]
                if w > cw or (w == cw and g > body_map[bb, j]):
                    weight[bb, j] = w
                    body_map[bb, j] = g
                cur = el_min[bb, j]
                if lo_e < cur or cur != cur:
                    el_min[bb, j] = lo_e
                cur = el_max[bb, j]
                if hi_e > cur or cur != cur:
                    el_max[bb, j] = hi_e
    return odd
