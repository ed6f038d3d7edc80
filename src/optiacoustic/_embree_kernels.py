"""Embree's ``rtcIntersect1`` called from numba kernels, skipping back faces in the traversal.

embreex casts a batch of rays and returns the closest hit of each; it has no way to ask for
the closest *front-facing* hit. The Embree it bundles exports ``rtcIntersect1`` and takes an
argument filter function (``RTCIntersectArguments.filter``, a C callback Embree calls for each
candidate hit during traversal, which may reject it so that traversal goes on). Here:

- :func:`_reject_back_faces` is that filter, a numba ``cfunc`` with Embree's
  ``RTCFilterFunctionN`` signature: it rejects a hit whose geometric normal faces away from
  the ray (``dot(ray direction, Ng) >= 0``; with the same ``Ng`` as ``embreex`` returns and the
  same rule as the shadow's two-cast path, where a hit with ``n . d < 0`` is front-facing);
- :func:`intersect_front` is an inlined numba helper that fills one ``RTCRayHit`` (80 bytes,
  16-byte aligned; 96 bytes are reserved per ray in case the library also writes
  ``instPrimID``) and calls ``rtcIntersect1`` through its address, with an
  ``RTCIntersectArguments`` built by hand (``rtcInitIntersectArguments`` is inline in Embree's
  header): flags ``RTC_RAY_QUERY_FLAG_INVOKE_ARGUMENT_FILTER``, feature mask triangles +
  argument filter + 32-bit ray mask, no context (Embree makes its default one), the filter.

The argument filter only runs in scenes committed with ``RTC_SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS``
(:func:`optiacoustic._embree_upload.enable_argument_filter`, called by the ray caster before
its commit). Struct layouts are not taken on trust: :func:`direct_path` first casts probe rays
at a two-triangle scene of its own and checks distances, ids, barycentrics, normals and the
filter's effect; where anything differs (another Embree build, a missing symbol) it returns
None and callers use embreex's batched cast instead.

This module imports numba and compiles (or loads from the on-disk cache) on import: only
kernels import it, never ``import optiacoustic``. Struct layouts are from Embree 4's
``rtcore_ray.h``, ``rtcore_scene.h`` and ``rtcore_common.h``.
"""

from __future__ import annotations

import functools
import threading

import numpy as np
from llvmlite import ir
from numba import carray, cfunc, njit, types
from numba.extending import intrinsic

from . import _embree_upload
from ._embree_upload import SELF_GAP

__all__ = ["direct_path", "intersect_front", "new_rayhit_scratch", "self_gap", "DirectPath", "SELF_GAP"]

_INVALID_ID = np.uint32(0xFFFFFFFF)
_RAYHIT_FLOATS = 24  # 96 bytes reserved per RTCRayHit (80 used)
_RAY_QUERY_FLAG_INVOKE_ARGUMENT_FILTER = 1 << 1
_FEATURE_TRIANGLE = 1 << 1
_FEATURE_FILTER_FUNCTION_IN_ARGUMENTS = 1 << 24
_FEATURE_32_BIT_RAY_MASK = 1 << 28


# ----------------------------------------------------------------------------- raw memory in numba
@intrinsic
def _f32_ptr(typingctx, addr):
    """``float*`` from an integer address."""
    sig = types.CPointer(types.float32)(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

    return sig, codegen


@intrinsic
def _i32_ptr(typingctx, addr):
    """``int*`` from an integer address."""
    sig = types.CPointer(types.int32)(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

    return sig, codegen


@intrinsic
def _u32_ptr(typingctx, addr):
    """``unsigned int*`` from an integer address."""
    sig = types.CPointer(types.uint32)(types.int64)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

    return sig, codegen


@intrinsic
def _call_intersect1(typingctx, fn, scene, rayhit, args):
    """``((void (*)(void*, void*, void*)) fn)(scene, rayhit, args)``: all four are integer addresses."""
    sig = types.void(types.int64, types.int64, types.int64, types.int64)

    def codegen(context, builder, signature, llargs):
        vp = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [vp, vp, vp])
        f = builder.inttoptr(llargs[0], fnty.as_pointer())
        builder.call(f, [builder.inttoptr(a, vp) for a in llargs[1:]])
        return context.get_dummy_value()

    return sig, codegen


# ----------------------------------------------------------------------------- the filter
@njit(cache=True, nogil=True, inline="always")
def self_gap(ox, oy, oz):
    """How far (m) beyond a continuation ray's float32 origin a front face of the body it starts on
    is taken for the surface it starts on (float32 rounding at grazing incidence: measured up to
    6e-6 m at 4-7 m from the world origin in thesis scene 1): ``SELF_GAP`` times the origin's largest
    coordinate, at least ``SELF_GAP`` m."""
    return SELF_GAP * max(abs(ox), abs(oy), abs(oz), 1.0)


@cfunc(types.void(types.CPointer(types.int64)), cache=True, nopython=True)
def _reject_back_faces(fargs):
    """``RTCFilterFunctionN``: ``fargs`` is ``RTCFilterFunctionNArguments`` read as 64-bit words
    (``int* valid``, ``void* geometryUserPtr``, ``RTCRayQueryContext* context``, ``RTCRayN* ray``,
    ``RTCHitN* hit``, ``unsigned int N``). Rays and hits are in SoA layout for ``N`` rays: ray
    origin at floats ``0 .. 2N``, direction ``4N .. 6N``, ``tfar`` (the candidate's distance)
    ``8N``, ``id`` ``10N``; hit ``Ng`` at ``0 .. 2N``, ``geomID`` ``6N``. Rejects back faces, and
    front faces of geometry ``id`` (the body the ray starts on) closer than :func:`self_gap`."""
    n = np.int64(fargs[5] & 0xFFFFFFFF)
    valid = carray(_i32_ptr(fargs[0]), (n,))
    ray = carray(_f32_ptr(fargs[3]), (11 * n,))
    rayu = carray(_u32_ptr(fargs[3]), (11 * n,))
    hit = carray(_f32_ptr(fargs[4]), (3 * n,))
    hitu = carray(_u32_ptr(fargs[4]), (7 * n,))
    for i in range(n):
        if valid[i] == 0:
            continue
        d = ray[4 * n + i] * hit[i] + ray[5 * n + i] * hit[n + i] + ray[6 * n + i] * hit[2 * n + i]
        if not d < 0:  # back-facing (or edge-on, or NaN): not a surface the ray meets from the front
            valid[i] = 0
        elif hitu[6 * n + i] == rayu[10 * n + i] and ray[8 * n + i] <= self_gap(ray[i], ray[n + i], ray[2 * n + i]):
            valid[i] = 0  # the surface the ray starts on, met again through float32 rounding


# ----------------------------------------------------------------------------- one ray
@njit(cache=True, nogil=True)
def new_rayhit_scratch():
    """A per-call scratch for one ``RTCRayHit``: ``(float32 view, uint32 view, address)``, 16-byte aligned."""
    raw = np.empty(_RAYHIT_FLOATS + 4, np.float32)
    off = ((16 - (raw.ctypes.data & 15)) & 15) // 4
    f = raw[off:off + _RAYHIT_FLOATS]
    return f, f.view(np.uint32), f.ctypes.data


@njit(cache=True, nogil=True, inline="always")
def intersect_front(fn, scene, args, f, u, addr, ox, oy, oz, dx, dy, dz, tfar, first):
    """Closest front-facing hit of one ray (float32 origin and unit direction, limit ``tfar``) that
    starts on geometry ``first`` (``-1``: none; its front faces within :func:`self_gap` are skipped) through
    ``rtcIntersect1`` at address ``fn`` with the back-face filter in ``args``; ``f``, ``u``, ``addr``
    from :func:`new_rayhit_scratch`. Returns ``(distance, geomID as int64 (-1 on a miss), Ng_x, Ng_y,
    Ng_z)``: Embree's unnormalised float32 geometric normal, as embreex gives it."""
    f[0] = ox
    f[1] = oy
    f[2] = oz
    f[3] = 0.0  # tnear
    f[4] = dx
    f[5] = dy
    f[6] = dz
    f[7] = 0.0  # time
    f[8] = tfar
    u[9] = _INVALID_ID  # mask: every geometry
    u[10] = np.uint32(first) if first >= 0 else _INVALID_ID  # id: the geometry the ray starts on
    u[11] = 0  # flags
    # the hit: Ng at floats 12-14, u, v at 15-16, primID, geomID, instID[0] at words 17-19
    u[17] = _INVALID_ID
    u[18] = _INVALID_ID
    u[19] = _INVALID_ID
    _call_intersect1(fn, scene, addr, args)
    g = u[18]
    if g == _INVALID_ID:
        return f[8], np.int64(-1), np.float32(0.0), np.float32(0.0), np.float32(0.0)
    return f[8], np.int64(g), f[12], f[13], f[14]


@njit(cache=True, nogil=True)
def _probe_cast(fn, scene, args, o, d, tfar, first, out_t, out_g, out_n, out_uv, out_prim):
    """Cast ``o``/``d`` (float32 (n, 3)) starting on geometries ``first`` (int64, -1: none), keeping
    primID and u, v too (the layout probe)."""
    f, u, addr = new_rayhit_scratch()
    for k in range(o.shape[0]):
        t, g, n0, n1, n2 = intersect_front(fn, scene, args, f, u, addr, o[k, 0], o[k, 1], o[k, 2],
                                           d[k, 0], d[k, 1], d[k, 2], tfar, first[k])
        out_t[k] = t
        out_g[k] = g
        out_n[k, 0], out_n[k, 1], out_n[k, 2] = n0, n1, n2
        out_uv[k, 0], out_uv[k, 1] = f[15], f[16]
        out_prim[k] = np.int64(u[17]) if g >= 0 else -1


# ----------------------------------------------------------------------------- arguments and checks
def _arguments(filter_address: int, with_filter: bool) -> np.ndarray:
    """An ``RTCIntersectArguments`` (flags, feature_mask, context, filter, intersect,
    minWidthDistanceFactor) in a 64-byte zeroed, 16-byte aligned buffer (kept alive by the caller)."""
    raw = np.zeros(80, np.uint8)
    off = (-raw.ctypes.data) % 16
    buf = raw[off:off + 64]
    words32 = buf.view(np.uint32)
    words64 = buf.view(np.uint64)
    words32[0] = _RAY_QUERY_FLAG_INVOKE_ARGUMENT_FILTER if with_filter else 0
    words32[1] = _FEATURE_TRIANGLE | _FEATURE_FILTER_FUNCTION_IN_ARGUMENTS | _FEATURE_32_BIT_RAY_MASK
    words64[1] = 0  # context: Embree's default
    words64[2] = filter_address if with_filter else 0
    words64[3] = 0  # user geometry callback: none
    return buf


class DirectPath:
    """What a kernel needs to call ``rtcIntersect1`` with the back-face filter on one scene:
    integer addresses ``fn`` (``rtcIntersect1``), ``scene`` (``RTCScene``), ``args``
    (``RTCIntersectArguments``). Holds the arguments' buffer alive."""

    __slots__ = ("fn", "scene", "args", "_keep")

    def __init__(self, fn: int, scene: int, args_buf: np.ndarray):
        self.fn, self.scene, self._keep = int(fn), int(scene), args_buf
        self.args = int(args_buf.ctypes.data)


_CHECK_LOCK = threading.Lock()


@functools.lru_cache(maxsize=4)
def _layout_checks_out(lib_key: str) -> tuple | None:
    """Cast probe rays at a two-triangle scene of our own and compare with what Embree's documented
    layouts imply; ``(fn, args_buffer)`` when they all agree, else None. Once per library."""
    lib = _embree_upload.library_at(lib_key)
    if lib is None:
        return None
    fn = _embree_upload.function_address(lib, "rtcIntersect1")
    if not fn:
        return None
    # two parallel triangles over the same footprint, z = 0 (geometry 0) and z = -1 (1), wound so that each
    # faces away from the ray that meets it first (right-handed: Ng = (v1 - v0) x (v2 - v0), -z and +z)
    upper = (np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0]], np.float32), np.array([[0, 1, 2]], np.int32))
    lower = (np.array([[0, 0, -1], [1, 0, -1], [0, 1, -1]], np.float32), np.array([[0, 1, 2]], np.int32))
    probe = _embree_upload.probe_scene(lib, [upper, lower])
    if probe is None:
        return None
    scene, release = probe
    try:
        filt = _arguments(_reject_back_faces.address, True)
        plain = _arguments(0, False)
        # down from z = 1 (meets z = 0 at 1, z = -1 at 2), up from z = -2 (z = -1 at 1, z = 0 at 2), a ray
        # beside both triangles (x + y > 1), and two rays down from 8 um above the lower triangle (its front
        # face), one of them starting on it (geometry 1: that face is within the self gap, 20 um)
        o = np.array([[0.25, 0.125, 1.0], [0.25, 0.125, -2.0], [0.5, 0.75, 1.0], [0.25, 0.125, -1.0 + 8e-6],
                      [0.25, 0.125, -1.0 + 8e-6]], np.float32)
        d = np.array([[0, 0, -1], [0, 0, 1], [0, 0, -1], [0, 0, -1], [0, 0, -1]], np.float32)
        first = np.array([-1, -1, -1, -1, 1], np.int64)
        res = {}
        for name, a in (("plain", plain), ("filter", filt)):
            k = len(o)
            t, g = np.empty(k, np.float32), np.empty(k, np.int64)
            nrm, uv, prim = np.empty((k, 3), np.float32), np.empty((k, 2), np.float32), np.empty(k, np.int64)
            _probe_cast(fn, scene, int(a.ctypes.data), o, d, np.float32(10.0), first, t, g, nrm, uv, prim)
            res[name] = (t, g, nrm, uv, prim)
        t, g, nrm, uv, prim = res["plain"]
        # distances as Embree's float32 arithmetic gives them: within a few ulp of 1 and 2
        near = lambda x, y: abs(float(x) - y) <= 1e-6 * y  # noqa: E731
        if not (near(t[0], 1.0) and g[0] == 0 and prim[0] == 0 and near(t[1], 1.0) and g[1] == 1 and prim[1] == 0
                and g[2] == -1 and t[2] == 10.0):
            return None
        # barycentrics of (0.25, 0.125) in the upper triangle: u (corner 1 at y = 1) = y, v (corner 2) = x
        if not (abs(uv[0, 0] - 0.125) < 1e-6 and abs(uv[0, 1] - 0.25) < 1e-6):
            return None
        # the normals embreex reports (the shadow's two-cast path reads them): -z for the upper, +z for
        # the lower triangle, so that both rays meet a back face first
        if not (nrm[0, 0] == 0 and nrm[0, 1] == 0 and nrm[0, 2] < 0 and nrm[1, 0] == 0 and nrm[1, 1] == 0
                and nrm[1, 2] > 0):
            return None
        # with the filter both skip it and meet the other triangle from the front, at 2
        tf, gf, nf, _, _ = res["filter"]
        if not (near(tf[0], 2.0) and gf[0] == 1 and nf[0, 2] > 0 and near(tf[1], 2.0) and gf[1] == 0 and nf[1, 2] < 0):
            return None
        if not (gf[2] == -1 and tf[2] == 10.0):
            return None
        # the ray id carries the geometry the ray starts on: its front face that close is skipped
        if not (gf[3] == 1 and 0 < tf[3] < 2e-5 and gf[4] == -1 and tf[4] == 10.0):
            return None
        return fn, filt
    finally:
        release()


def direct_path(embree_scene, scene_handle: int | None) -> DirectPath | None:
    """The direct ``rtcIntersect1`` path with the back-face filter for an embreex scene whose
    ``RTCScene`` is ``scene_handle`` (committed with argument filters enabled), or None where the
    library, the handle or the struct layouts do not check out."""
    if not scene_handle:
        return None
    key = _embree_upload.library_key(embree_scene)
    if key is None:
        return None
    with _CHECK_LOCK:
        got = _layout_checks_out(key)
    if got is None:
        return None
    fn, args = got
    return DirectPath(fn, scene_handle, args)
