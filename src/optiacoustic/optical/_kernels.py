"""Compiled per-pixel shading of the camera frame (numba, cached on disk).

The numpy path of :mod:`.render` is the reference: these kernels do the same float32
arithmetic in one pass per stage instead of a dozen whole-image temporaries, and the
tests compare the two. This module imports numba, so only :mod:`.render` imports it,
lazily, when a frame is rendered (``import optiacoustic`` and ``oas --help`` stay free
of it). Set ``OAS_KERNELS=numpy`` to render with the reference path.

Per pixel ``i`` (rays in world frame, float32):

* :func:`surface` turns Embree's raw closest hits (distance, body, triangle,
  barycentric ``u, v``) into the hit point, the interpolated vertex normal turned to face
  the camera, and the depth (``inf`` on a miss);
* :func:`shadow_rays` gives each lamp's shadow ray (origin 1 mm off the surface, unit
  direction, length; length 0 where the surface faces away, which Embree rejects);
* :func:`add_lamp` adds one lamp's irradiance (clear, narrow-beam through water, and
  forward-scattered on the lamp leg) where its shadow ray was not blocked;
* :func:`compose` forms the image stages from albedo, irradiance and camera range;
* :func:`range_span` and :func:`bin_layers` share each pixel's forward-scattered light
  between range layers on the reduced grid of the blur;
* :func:`veil` looks each pixel's backscatter up in the coarse slice tables.

Every kernel works on any contiguous run of pixels, so the caller may split an image in
two and run the halves on two threads (``nogil``). No bounds are checked here: the
callers in :mod:`.render` pass arrays of matching lengths.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_F = np.float32
_ZERO = _F(0.0)
_ONE = _F(1.0)
_EPS_N = _F(1e-30)
_EPS_R = _F(1e-12)


@njit(cache=True, nogil=True)
def rotate_rays(d_cam, R, t, o_out, d_out):  # pragma: no cover - compiled
    """World rays of the pixels: ``d_out = d_cam R^T`` and ``o_out = t`` (float32, ``(N, 3)``)."""
    n = d_cam.shape[0]
    for i in range(n):
        x, y, z = d_cam[i, 0], d_cam[i, 1], d_cam[i, 2]
        for j in range(3):
            d_out[i, j] = x * R[j, 0] + y * R[j, 1] + z * R[j, 2]
            o_out[i, j] = t[j]


@njit(cache=True, nogil=True)
def surface(o, d, tfar, geom, prim, u, v, tri_offset, corner_normals, colors_pi,
            p_out, n_out, depth_out, body_out, rho_out):  # pragma: no cover - compiled
    """Hit points ``p_out``, camera-facing unit normals ``n_out`` (0 on a miss), ``depth_out``
    (``inf`` on a miss), ``body_out`` (-1 on a miss) and the body's colour over pi
    ``rho_out`` (``colors_pi`` ``(n_bodies, 3)``; 0 on a miss); returns the hit count."""
    n = tfar.shape[0]
    hits = 0
    for i in range(n):
        g = geom[i]
        if g < 0:
            body_out[i] = -1
            depth_out[i] = np.inf
            for k in range(3):
                p_out[i, k] = _ZERO
                n_out[i, k] = _ZERO
                rho_out[i, k] = _ZERO
            continue
        hits += 1
        body_out[i] = g
        for k in range(3):
            rho_out[i, k] = colors_pi[g, k]
        t = tfar[i]
        depth_out[i] = t
        tri = tri_offset[g] + prim[i]
        w1 = u[i]
        w2 = v[i]
        w0 = _ONE - w1 - w2
        nx = w0 * corner_normals[tri, 0, 0] + w1 * corner_normals[tri, 1, 0] + w2 * corner_normals[tri, 2, 0]
        ny = w0 * corner_normals[tri, 0, 1] + w1 * corner_normals[tri, 1, 1] + w2 * corner_normals[tri, 2, 1]
        nz = w0 * corner_normals[tri, 0, 2] + w1 * corner_normals[tri, 1, 2] + w2 * corner_normals[tri, 2, 2]
        ln = np.sqrt(nx * nx + ny * ny + nz * nz) + _EPS_N
        nx /= ln
        ny /= ln
        nz /= ln
        dx, dy, dz = d[i, 0], d[i, 1], d[i, 2]
        if nx * dx + ny * dy + nz * dz > _ZERO:  # shade the side facing the camera
            nx, ny, nz = -nx, -ny, -nz
        n_out[i, 0], n_out[i, 1], n_out[i, 2] = nx, ny, nz
        p_out[i, 0] = o[i, 0] + dx * t
        p_out[i, 1] = o[i, 1] + dy * t
        p_out[i, 2] = o[i, 2] + dz * t
    return hits


@njit(cache=True, nogil=True)
def shadow_rays(p, nrm, body, light, eps, o_out, dir_out, lim_out, cosg_out, rs_out):  # pragma: no cover - compiled
    """Shadow rays from every hit point to one lamp at ``light`` (3,) (world, m).

    ``cosg_out``: cosine between normal and the direction to the lamp (0 where unlit or on
    a miss); ``rs_out``: distance to the lamp; ``lim_out``: the ray's length, 0 (rejected
    by Embree) where the point faces away or there is no surface."""
    n = p.shape[0]
    lx, ly, lz = light[0], light[1], light[2]
    two_eps = _F(2.0) * eps
    for i in range(n):
        vx = lx - p[i, 0]
        vy = ly - p[i, 1]
        vz = lz - p[i, 2]
        rs = np.sqrt(vx * vx + vy * vy + vz * vz)
        inv = max(rs, _EPS_R)
        vx /= inv
        vy /= inv
        vz /= inv
        nx, ny, nz = nrm[i, 0], nrm[i, 1], nrm[i, 2]
        cg = nx * vx + ny * vy + nz * vz
        o_out[i, 0] = p[i, 0] + eps * nx
        o_out[i, 1] = p[i, 1] + eps * ny
        o_out[i, 2] = p[i, 2] + eps * nz
        dir_out[i, 0], dir_out[i, 1], dir_out[i, 2] = vx, vy, vz
        rs_out[i] = rs
        if cg > _ZERO and body[i] >= 0:
            cosg_out[i] = cg
            lim_out[i] = max(rs - two_eps, _F(1e-6))
        else:
            cosg_out[i] = _ZERO
            lim_out[i] = _ZERO


@njit(cache=True, nogil=True)
def add_lamp(cosg, rs, ldir, blocked, intensity, axis, exponent, spot, c, G, lamp_fs,
             irr_clear, irr_water, irr_fwd):  # pragma: no cover - compiled
    """Add one lamp's irradiance ``I s cos(gamma) / R_s^2`` (clear), times ``e^{-c R_s}``
    (water) and ``e^{-G R_s}`` (forward scatter, when ``lamp_fs``), where not ``blocked``.
    ``spot``: 0 no cone, 1 linear cosine falloff, 2 ``cos^exponent``."""
    n = cosg.shape[0]
    for i in range(n):
        cg = cosg[i]
        if cg <= _ZERO or blocked[i]:
            continue
        r = rs[i]
        e = cg / max(r * r, _EPS_R)
        if spot != 0:
            ca = -(ldir[i, 0] * axis[0] + ldir[i, 1] * axis[1] + ldir[i, 2] * axis[2])
            if ca <= _ZERO:
                continue
            e *= ca if spot == 1 else ca ** exponent
        for k in range(3):
            ek = e * intensity[k]
            irr_clear[i, k] += ek
            irr_water[i, k] += ek * np.exp(-r * c[k])
            if lamp_fs:
                irr_fwd[i, k] += ek * np.exp(-r * G[k])


@njit(cache=True, nogil=True)
def compose(rho_pi, irr_clear, irr_water, irr_fwd, depth, c, G, lamp_fs,
            clear_out, att_out, fs_src_out, fwd_out):  # pragma: no cover - compiled
    """Image stages per pixel: ``clear = rho/pi E_clear``; ``att = rho/pi E_water e^{-c R_c}``;
    with lamp forward scatter, the blur source ``rho/pi E_fwd max(e^{-G R_c} - e^{-c R_c}, 0)``
    and the unblurred forward image ``rho/pi (E_fwd - E_water) e^{-c R_c} + att``
    (else ``fwd = att`` and no source). Misses (``depth`` inf) are 0."""
    n = depth.shape[0]
    for i in range(n):
        r = depth[i]
        if not r < np.inf:
            for k in range(3):
                clear_out[i, k] = _ZERO
                att_out[i, k] = _ZERO
                fs_src_out[i, k] = _ZERO
                fwd_out[i, k] = _ZERO
            continue
        if irr_clear[i, 0] == 0 and irr_clear[i, 1] == 0 and irr_clear[i, 2] == 0:
            for k in range(3):  # unlit or shadowed (the clear irradiance bounds the others): black, no exp
                clear_out[i, k] = _ZERO
                att_out[i, k] = _ZERO
                fs_src_out[i, k] = _ZERO
                fwd_out[i, k] = _ZERO
            continue
        for k in range(3):
            rho = rho_pi[i, k]
            tc = np.exp(-r * c[k])
            surf = rho * irr_water[i, k]
            att = surf * tc
            clear_out[i, k] = rho * irr_clear[i, k]
            att_out[i, k] = att
            if lamp_fs:
                sf = rho * irr_fwd[i, k]
                fs_src_out[i, k] = sf * max(np.exp(-r * G[k]) - tc, _ZERO)
                fwd_out[i, k] = (sf - surf) * tc + att
            else:
                fs_src_out[i, k] = _ZERO
                fwd_out[i, k] = att


@njit(cache=True, nogil=True)
def range_span(src, depth):  # pragma: no cover - compiled
    """Nearest and farthest range of the pixels that have a surface and light to blur:
    ``(r_lo, r_hi, count)``."""
    lo, hi, cnt = np.inf, -np.inf, 0
    for i in range(depth.shape[0]):
        d = depth[i]
        if d < np.inf and (src[i, 0] > 0 or src[i, 1] > 0 or src[i, 2] > 0):
            cnt += 1
            lo = min(lo, d)
            hi = max(hi, d)
    return lo, hi, cnt


@njit(cache=True, nogil=True)
def bin_layers(src, depth, W, q, w, r_lo, scale, n_layers, small):  # pragma: no cover - compiled
    """Box sums of each range layer's share of ``src`` ``(H*W, 3)`` on the ``q``-reduced grid.

    A pixel of range ``d`` sits at ``t = ln(d / r_lo) * scale`` layers; it gives ``1 - f``
    of its light to layer ``k = clip(floor(t), 0, n_layers - 2)`` and ``f = t - k`` to
    ``k + 1``. ``small`` ``(n_layers, h, w, 3)`` float64 is added to."""
    n = depth.shape[0]
    for i in range(n):
        a, b, c = src[i, 0], src[i, 1], src[i, 2]
        d = depth[i]
        hit = d < np.inf and (a > 0 or b > 0 or c > 0)
        row = (i // W) // q
        col = (i % W) // q
        if n_layers == 1:
            small[0, row, col, 0] += a
            small[0, row, col, 1] += b
            small[0, row, col, 2] += c
            continue
        # float32 log: the split between two layers is linear, so its rounding moves light by ~1e-7
        t = np.float64(np.log(np.float32((d if hit else r_lo) / r_lo))) * scale
        k = min(max(np.floor(t), 0.0), n_layers - 2.0)
        f = np.float32(t - k)
        ki = int(k)
        g = np.float32(1.0) - f
        small[ki, row, col, 0] += a * g
        small[ki, row, col, 1] += b * g
        small[ki, row, col, 2] += c * g
        small[ki + 1, row, col, 0] += a * f
        small[ki + 1, row, col, 1] += b * f
        small[ki + 1, row, col, 2] += c * f


@njit(cache=True, nogil=True)
def veil(table, depth, cz, s, W, out):  # pragma: no cover - compiled
    """Each pixel's backscatter up to its own surface, from the coarse slice tables.

    ``table`` ``(N + 1, hc, wc, 3)`` float32 holds the veil accumulated up to each slice
    boundary on a coarse grid spanning the image corner to corner; ``depth`` ``(H*W,)``
    is each pixel's range (``inf``: open water), ``cz`` its ray's cosine to the optical
    axis, ``s`` the slice scale. The pixel's depth falls at fractional boundary
    ``q = N z / (s + z)``; the veil is the bilinear value at the pixel on boundaries
    ``floor(q)`` and ``floor(q) + 1``, blended by the fraction. The bilinear lookup is
    the one ``cv2.remap`` (OpenCV 5) does on the numpy path, at float32 positions, so both
    paths agree to rounding. Returns the count of invalid depths
    (NaN or negative); ``out`` ``(H*W, 3)`` float32 is written.
    """
    n = table.shape[0] - 1
    hc, wc = table.shape[1], table.shape[2]
    npx = depth.shape[0]
    H = npx // W
    step2 = np.float32(wc + 2)
    bad = 0
    for i in range(H):
        Y = np.float32(i * (hc - 1) / max(H - 1, 1))
        y0 = min(int(np.floor(Y)), hc - 1)
        fy = Y - np.float32(y0)
        y1 = min(y0 + 1, hc - 1)
        for j in range(W):
            idx = i * W + j
            dd = np.float64(depth[idx])
            if not dd >= 0.0:
                bad += 1
                for k in range(3):
                    out[idx, k] = np.nan
                continue
            zD = dd * cz[idx]
            u = zD / (s + zD) if zD < np.inf else 1.0
            q = u * n
            k0 = min(np.floor(q), n - 1.0)
            frac = np.float32(q - k0)
            ki = int(k0)
            base = k0 * (wc + 2) + 1 + j * (wc - 1) / max(W - 1, 1)
            x_lo = np.float32(base)
            for half in range(2):
                X = x_lo if half == 0 else x_lo + step2
                x0 = np.floor(X)
                fx = X - x0
                pc = int(x0) - (ki + half) * (wc + 2)  # column in the padded tile of this slice
                c0 = min(max(pc - 1, 0), wc - 1)
                c1 = min(max(pc, 0), wc - 1)
                t = table[ki + half]
                for k in range(3):
                    top = t[y0, c0, k] + fx * (t[y0, c1, k] - t[y0, c0, k])
                    bot = t[y1, c0, k] + fx * (t[y1, c1, k] - t[y1, c0, k])
                    v = top + fy * (bot - top)
                    if half == 0:
                        out[idx, k] = v
                    else:
                        lo = out[idx, k]
                        out[idx, k] = lo + frac * (v - lo)
    return bad
