"""Vectorised triangle upload into an embreex scene (Embree 4's C API through ctypes).

``embreex.mesh_construction.TriangleMesh`` fills Embree's vertex and index buffers one
element at a time through Python indexing, which costs more than Embree's BVH build
(about 0.6 us per triangle). Here the same buffers are asked of Embree with the same
calls (``rtcNewGeometry``, ``rtcSetNewGeometryBuffer``, ``rtcCommitGeometry``,
``rtcAttachGeometry``) and filled by one numpy copy each, in the library embreex itself
loaded. Embree then holds exactly what ``TriangleMesh`` would have given it.

The scene handle is read from the ``EmbreeScene`` object, whose layout is checked first
(its public ``is_committed`` field must sit where the handle's neighbour should be);
where anything does not match (another embreex build, a platform without the bundled
library), :func:`upload_triangles` returns ``False`` and the caller uses ``TriangleMesh``.
Only :mod:`optiacoustic.raycast` and the direct-call kernels (:mod:`optiacoustic._embree_kernels`)
use this module; it also holds :data:`SELF_GAP`, shared by those kernels and the numpy reference
of the sonar's shadow (importing it loads no library).
"""

from __future__ import annotations

import ctypes
import functools
import glob
import os
import sys
import threading

import numpy as np

__all__ = ["SELF_GAP", "upload_triangles", "enable_argument_filter", "library_key", "library_at", "function_address",
           "probe_scene"]

_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX = 0
_BUFFER_TYPE_VERTEX = 1
_FORMAT_UINT3 = 0x5003
_FORMAT_FLOAT3 = 0x9003
_SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS = 1 << 3
_HEAD = 2 * ctypes.sizeof(ctypes.c_void_p)  # PyObject_HEAD: reference count and type
_LOCK = threading.Lock()

# A continuation ray that starts on a surface (float32 origin just beyond its hit) may meet that same
# surface again through rounding at grazing incidence (measured up to 6e-6 m at 4-7 m from the world
# origin in thesis scene 1, cos(incidence) about 0.05): a front face of the body it starts on closer
# than SELF_GAP x the origin's largest coordinate (at least SELF_GAP m) is taken for that surface.
SELF_GAP = 2e-5


@functools.lru_cache(maxsize=4)
def _library(package_dir: str):
    """Embree as embreex loaded it (the wheel's bundled copy next to ``package_dir``), with typed entry
    points; None if not found."""
    try:
        root = os.path.dirname(package_dir)
        found = sorted(glob.glob(os.path.join(root, "embreex.libs", "libembree4*.so*")))
        if len(found) != 1:
            return None
        lib = ctypes.CDLL(found[0])
        vp, u32 = ctypes.c_void_p, ctypes.c_uint32
        sig = {
            "rtcGetSceneDevice": (vp, [vp]),
            "rtcReleaseDevice": (None, [vp]),
            "rtcGetDeviceError": (ctypes.c_int, [vp]),
            "rtcNewGeometry": (vp, [vp, ctypes.c_int]),
            "rtcSetNewGeometryBuffer": (vp, [vp, ctypes.c_int, u32, ctypes.c_int, ctypes.c_size_t, ctypes.c_size_t]),
            "rtcCommitGeometry": (None, [vp]),
            "rtcAttachGeometry": (u32, [vp, vp]),
            "rtcReleaseGeometry": (None, [vp]),
            "rtcNewDevice": (vp, [ctypes.c_char_p]),
            "rtcNewScene": (vp, [vp]),
            "rtcGetSceneFlags": (ctypes.c_int, [vp]),
            "rtcSetSceneFlags": (None, [vp, ctypes.c_int]),
            "rtcCommitScene": (None, [vp]),
            "rtcReleaseScene": (None, [vp]),
        }
        for name, (res, args) in sig.items():
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
        return lib
    except (OSError, AttributeError):
        return None


def library_key(scene) -> str | None:
    """The folder of the embreex package that made ``scene`` (its library's key), or None."""
    module = sys.modules.get(type(scene).__module__)
    path = getattr(module, "__file__", None)
    return os.path.dirname(os.path.abspath(path)) if path else None


def library_at(key: str):
    """Embree as the embreex package in folder ``key`` loaded it (typed ctypes entry points), or None."""
    return _library(key)


def _library_of(scene):
    """The Embree library of the embreex package that made ``scene`` (no import of embreex here)."""
    key = library_key(scene)
    return _library(key) if key else None


def function_address(lib, name: str) -> int | None:
    """Address of the exported function ``name`` of ``lib`` (for compiled callers), or None."""
    try:
        return ctypes.cast(getattr(lib, name), ctypes.c_void_p).value
    except AttributeError:
        return None


def enable_argument_filter(scene) -> int | None:
    """Let queries on the uncommitted embreex ``scene`` run argument filter functions
    (``RTC_SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS``, which must be set before the commit); its
    ``RTCScene`` handle, or None where that is not possible (then nothing was changed)."""
    lib = _library_of(scene)
    if lib is None or scene.is_committed:
        return None
    with _LOCK:
        handle = _scene_handle(scene)
        if handle is None:
            return None
        flags = lib.rtcGetSceneFlags(handle)
        lib.rtcSetSceneFlags(handle, flags | _SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS)
        return handle


def probe_scene(lib, meshes):
    """A committed scene of its own (argument filters enabled) holding ``meshes``, a list of
    ``(vertices32 (V, 3), faces32 (F, 3))``, one geometry each (ids 0, 1, ...), on a device of its
    own: ``(RTCScene address, release)``, or None when Embree refuses."""
    device = lib.rtcNewDevice(None)
    if not device:
        return None
    scene = lib.rtcNewScene(device)
    if not scene:
        lib.rtcReleaseDevice(device)
        return None

    def release():
        lib.rtcReleaseScene(scene)
        lib.rtcReleaseDevice(device)

    lib.rtcSetSceneFlags(scene, _SCENE_FLAG_FILTER_FUNCTION_IN_ARGUMENTS)
    for i, (v32, f32) in enumerate(meshes):
        if _attach(lib, device, scene, np.asarray(v32, np.float32), np.asarray(f32, np.int32)) != i:
            release()
            return None
    lib.rtcCommitScene(scene)
    if lib.rtcGetDeviceError(device) != 0:
        release()
        return None
    return scene, release


def _attach(lib, device, handle, vertices32, faces32) -> int | None:
    """One triangle geometry with these buffers, attached to ``handle``: its id, or None."""
    geom = lib.rtcNewGeometry(device, _GEOMETRY_TYPE_TRIANGLE)
    if not geom:
        return None
    nv, nf = len(vertices32), len(faces32)
    # the vertex layout TriangleMesh uses: x, y, z and one padding float (16 bytes)
    vptr = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, 16, nv)
    fptr = lib.rtcSetNewGeometryBuffer(geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, 12, nf)
    if not vptr or not fptr:
        lib.rtcReleaseGeometry(geom)
        return None
    vbuf = np.ctypeslib.as_array(ctypes.cast(vptr, ctypes.POINTER(ctypes.c_float)), shape=(nv, 4))
    vbuf[:, :3] = vertices32
    vbuf[:, 3] = 0.0
    fbuf = np.ctypeslib.as_array(ctypes.cast(fptr, ctypes.POINTER(ctypes.c_uint32)), shape=(nf, 3))
    fbuf[...] = faces32
    lib.rtcCommitGeometry(geom)
    gid = lib.rtcAttachGeometry(handle, geom)
    lib.rtcReleaseGeometry(geom)
    return int(gid)


def _scene_handle(scene) -> int | None:
    """The ``RTCScene`` inside an ``embreex.rtcore_scene.EmbreeScene``, or None if its layout is not the known one.

    The known layout: ``RTCScene scene_i`` right after the object head, then ``int
    is_committed`` (public, so it can be written from Python and looked for in memory).
    """
    if type(scene).__basicsize__ != _HEAD + 3 * ctypes.sizeof(ctypes.c_void_p):
        return None
    old = scene.is_committed
    try:
        for probe in (0x5A17C0DE, 0x2B3C4D5E):
            scene.is_committed = probe
            if ctypes.c_int.from_address(id(scene) + _HEAD + ctypes.sizeof(ctypes.c_void_p)).value != probe:
                return None
    finally:
        scene.is_committed = old
    handle = ctypes.c_void_p.from_address(id(scene) + _HEAD).value
    return handle or None


def upload_triangles(scene, vertices32: np.ndarray, faces32: np.ndarray) -> int | None:
    """Add a triangle mesh to an uncommitted embreex scene; its geometry id, or None when not possible.

    Parameters
    ----------
    scene : embreex.rtcore_scene.EmbreeScene
        Not yet committed (no query run on it).
    vertices32 : ndarray (V, 3) float32
    faces32 : ndarray (F, 3) int32, indices into ``vertices32``
    """
    lib = _library_of(scene)
    if lib is None or scene.is_committed:
        return None
    with _LOCK:
        handle = _scene_handle(scene)
        if handle is None:
            return None
        device = lib.rtcGetSceneDevice(handle)
        if not device:
            return None
        try:
            gid = _attach(lib, device, handle, vertices32, faces32)
            if gid is None:
                return None
            if lib.rtcGetDeviceError(device) != 0:
                raise RuntimeError("Embree reported an error while uploading a triangle mesh")
            return gid
        finally:
            lib.rtcReleaseDevice(device)
