"""The one ray caster: Embree (through embreex) behind a numpy interface.

Rays in, per ray: distance, body id, triangle id, smooth (interpolated) shading normal
and hit point out; misses come back with distance ``inf``, ids ``-1`` and NaN vectors.
Rays are split across threads (embreex releases the GIL), so two cores give close to
twice the rays of one. Nothing else in the project imports embreex.
"""

from __future__ import annotations

import os
import threading
import weakref
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._validate import as_array
from .scene import Scene, SceneError

__all__ = ["RayCaster", "Hits", "caster_for", "default_threads", "widen_hits"]

_MISS_DIST = np.float32(1e30)
# m: Embree computes in float32, which resolves 1 mm at 1e4 m (6 cm at 1e6 m). A scene moved by
# (T, T, 0) with its sensors renders the same to 5e-4 at T = 1e3 m and 0.3 % at 1e4 m, but at
# 3e4 m its camera image differs by 15 % (shadow rays start on the wrong side of surfaces) and
# at 1e5 m the depth by up to 0.1 m: beyond this, refused rather than silently wrong
MAX_COORDINATE = 1e4


# the probe rays of RayCaster.enclosing_body: the axes and the diagonals
_PROBE_DIRS = np.concatenate([np.vstack([np.eye(3), -np.eye(3)]),
                              np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) / np.sqrt(3)])
_PROBE_DIRS32 = np.ascontiguousarray(_PROBE_DIRS, np.float32)


def widen_hits(tfar32: np.ndarray, normal32: np.ndarray, miss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Embree's float32 output as the public float64 arrays: distance (inf on a miss) and unit
    normal (NaN on a miss); ``miss`` is ``geometry id < 0``."""
    distance = tfar32.astype(np.float64)
    distance[miss] = np.inf
    normal = normal32.astype(np.float64)
    normal[miss] = np.nan
    return distance, normal


def default_threads() -> int:
    """Threads used for casting: ``OAS_THREADS`` if set, else the number of usable cores.

    Raises
    ------
    ValueError
        When ``OAS_THREADS`` is set to anything but a whole number of 1 or more (naming the variable
        and the value: a typo must not silently become one thread or a traceback from ``int``).
    """
    env = os.environ.get("OAS_THREADS", "").strip()
    if env:
        if not (env.isascii() and env.isdigit()) or int(env) < 1:
            raise ValueError(f"OAS_THREADS: expected a whole number of threads, 1 or more, got {env!r}")
        return int(env)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _release_freed_memory() -> None:
    """Hand the heap memory freed by a large build back to the system (glibc only; else nothing).

    Building a large mesh frees hundreds of MB of temporaries that glibc keeps mapped
    (resident) for reuse; ``malloc_trim`` returns them, so a process's resident set is
    what the scene holds, not what its build once needed.
    """
    try:
        import ctypes

        ctypes.CDLL(None).malloc_trim(0)
    except (AttributeError, OSError):  # pragma: no cover - not glibc
        pass


_POOL: ThreadPoolExecutor | None = None
_POOL_LOCK = threading.Lock()


def _pool(n: int) -> ThreadPoolExecutor:
    global _POOL
    with _POOL_LOCK:
        if _POOL is None or _POOL._max_workers < n:  # noqa: SLF001 - sizing our own pool
            _POOL = ThreadPoolExecutor(max_workers=n, thread_name_prefix="oas-raycast")
        return _POOL


class Hits:
    """What each ray hit. Every array has the rays' leading shape.

    Attributes
    ----------
    distance : ndarray
        Distance from the origin along the unit direction (m); ``inf`` on a miss.
    body : ndarray of int32
        Index of the body in ``scene.bodies``; ``-1`` on a miss.
    triangle : ndarray of int32
        Triangle index within that body's surface; ``-1`` on a miss.
    normal : ndarray, (..., 3)
        Unit normal at the hit in the world frame, NaN on a miss: the shading normal
        interpolated from the vertex normals (``smooth=True``) or the triangle's
        geometric normal. Outward for closed bodies; for planes, the side of +Z.
    point : ndarray, (..., 3)
        World hit point (m); NaN on a miss (computed on first access).
    """

    __slots__ = ("distance", "body", "triangle", "normal", "_origins", "_directions", "_point")

    def __init__(self, distance, body, triangle, normal, origins, directions):
        self.distance = distance
        self.body = body
        self.triangle = triangle
        self.normal = normal
        self._origins = origins
        self._directions = directions
        self._point = None

    @property
    def hit(self) -> np.ndarray:
        """Boolean mask of rays that hit something."""
        return self.body >= 0

    @property
    def point(self) -> np.ndarray:
        if self._point is None:
            with np.errstate(invalid="ignore"):
                p = self._origins + self._directions * self.distance[..., None]
            p[self.body < 0] = np.nan
            self._point = p
        return self._point


class RayCaster:
    """Casts rays against a :class:`~optiacoustic.scene.Scene`.

    Build one per scene and reuse it: building the acceleration structure costs more
    than casting a frame.

    Parameters
    ----------
    scene : Scene
    threads : int, optional
        Worker threads, 1 or more (default :func:`default_threads`).
    """

    def __init__(self, scene: Scene, *, threads: int | None = None):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        if not isinstance(scene, Scene):
            raise TypeError(f"RayCaster needs a Scene, got {type(scene).__name__}")
        self.scene = scene
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer))
                                    or threads < 1):
            raise ValueError(f"RayCaster: threads must be a whole number, 1 or more (or None for the default), "
                             f"got {threads!r}")
        self.threads = int(threads) if threads is not None else default_threads()
        surfaces = scene.surfaces()
        for b, s in zip(scene.bodies, surfaces):
            # Embree works in float32: a size that overflows it (or loses all precision) hits nothing silently
            reach = float(np.max(np.abs(s.vertices))) if s.vertices.size else 0.0
            if not np.isfinite(reach) or reach > MAX_COORDINATE:
                raise SceneError(f"body '{b.name}': its surface reaches {reach:.3g} m from the origin; the ray caster "
                                 f"computes in float32 and accepts coordinates up to {MAX_COORDINATE:g} m (1 mm "
                                 f"resolution there): give the scene in local coordinates, with the origin near "
                                 f"the sensors (for UTM or geodetic positions, subtract a reference point)")
        from ._embree_upload import enable_argument_filter, upload_triangles

        self._embree = rtcore_scene.EmbreeScene()
        # before the commit: lets direct rtcIntersect1 calls skip back faces in one traversal
        # (front_hits); None where embreex's scene cannot be reached (then only embreex casts)
        self._rtc_scene = enable_argument_filter(self._embree)
        self._front_hits = False  # not looked up yet
        for i, s in enumerate(surfaces):
            # Embree copies both into its own buffers: the float32 vertices are a temporary.
            # One numpy copy per buffer; TriangleMesh (element by element) where that is not possible
            v32, f32 = s.vertices.astype(np.float32), s.faces.astype(np.int32, copy=False)
            gid = upload_triangles(self._embree, v32, f32)
            if gid is None:
                TriangleMesh(self._embree, v32, f32)
            elif gid != i:  # pragma: no cover - Embree numbers a new scene's geometries 0, 1, ...
                raise RuntimeError(f"Embree gave body {i} the geometry id {gid}")
        # per-triangle corner normals of all bodies, concatenated; geomID i is body i
        self._tri_offset = np.cumsum([0] + [s.n_faces for s in surfaces]).astype(np.int64)
        self._corner_normals_f32 = None  # built on the first smooth cast (36 bytes per triangle)
        self._lock = threading.Lock()
        # commit now, single-threaded, so that concurrent casts never race on it
        self._embree.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))
        if self._tri_offset[-1] >= 100_000:
            _release_freed_memory()

    # ------------------------------------------------------------------ internals
    @property
    def _corner_normals(self) -> np.ndarray:
        """Per-triangle corner normals of all bodies, ``(n_triangles, 3, 3)`` float32 (lazy)."""
        if self._corner_normals_f32 is None:
            with self._lock:
                if self._corner_normals_f32 is None:
                    surfaces = self.scene.surfaces()
                    out = np.empty((int(self._tri_offset[-1]), 3, 3), np.float32)
                    for s, a, b in zip(surfaces, self._tri_offset[:-1], self._tri_offset[1:]):
                        # gathered from float32 normals: no float64 (n, 3, 3) temporary (72 bytes/triangle)
                        np.take(s.normals.astype(np.float32), s.faces, axis=0, out=out[a:b])
                    self._corner_normals_f32 = out
        return self._corner_normals_f32

    def _run_chunks(self, origins: np.ndarray, directions: np.ndarray, dists: np.ndarray, query: str, output: bool,
                    copy: bool = True, split: bool = True):
        n = len(origins)
        # from 4096 rays on, split: the sonar's shadow continuation rays (~10 000 a round, starting on a
        # surface, two to four primary rays each) gain; its ~4 000 edge sub-rays run on one thread while
        # the noise is drawn on the other (measured faster than splitting them too)
        n_chunks = 1 if n < 4096 or self.threads == 1 or not split else 2 * self.threads
        bounds = [n * k // n_chunks for k in range(n_chunks + 1)]  # (np.linspace: ~15 us a call)

        def job(k):
            a, b = bounds[k], bounds[k + 1]
            dd = dists[a:b].copy() if copy else dists[a:b]  # Embree writes its hits' distances there
            return self._embree.run(origins[a:b], directions[a:b], dists=dd, query=query, output=output)

        if n_chunks == 1:
            return [job(0)]
        return list(_pool(self.threads).map(job, range(n_chunks)))

    @staticmethod
    def _prepare(origins, directions, max_distance):
        d = as_array(directions, "directions", ("...", 3))
        o = as_array(origins, "origins", ("...", 3))
        md = np.asarray(max_distance, float)
        shape = d.shape[:-1]
        if o.shape != d.shape or md.ndim:
            try:
                shape = np.broadcast_shapes(o.shape[:-1], d.shape[:-1], md.shape)
            except ValueError:
                raise ValueError(
                    f"origins {np.shape(origins)}, directions {np.shape(directions)} and max_distance "
                    f"{md.shape} do not broadcast together"
                ) from None
        d = np.broadcast_to(d, shape + (3,)).reshape(-1, 3)
        o = np.broadcast_to(o, shape + (3,)).reshape(-1, 3)
        n2 = np.einsum("ij,ij->i", d, d)
        lo2, hi2 = (n2.min(), n2.max()) if n2.size else (1.0, 1.0)
        if lo2 == 0:
            raise ValueError("directions: zero-length direction vector")
        if lo2 < 1.0 - 1e-6 or hi2 > 1.0 + 1e-6:
            d = d / np.sqrt(n2)[:, None]
        if np.any(np.isnan(md)) or np.any(md <= 0):
            raise ValueError("max_distance: must be > 0")
        dists = np.minimum(np.broadcast_to(md, shape).reshape(-1), _MISS_DIST).astype(np.float32)
        o32 = np.empty(d.shape, np.float32)
        o32[...] = o  # broadcast assignment: much cheaper than a strided copy of a broadcast view
        d32 = np.empty(d.shape, np.float32)
        d32[...] = d
        return shape, o32, d32, d, o, dists

    # ------------------------------------------------------------------ queries
    def cast(self, origins, directions, *, max_distance=np.inf, smooth: bool = True) -> Hits:
        """Closest hit of each ray.

        Parameters
        ----------
        origins : array_like, (..., 3) or (3,)
            Ray origins in the world frame (m); broadcast against ``directions``.
        directions : array_like, (..., 3)
            Ray directions in the world frame (normalised here).
        max_distance : float or array_like, optional
            Hits beyond this distance (m) count as misses.
        smooth : bool
            Interpolated shading normals (default) or the triangles' geometric normals
            (cheaper, enough for visibility tests).

        Returns
        -------
        Hits
        """
        shape, o32, d32, d64, o64, dists = self._prepare(origins, directions, max_distance)
        tfar, geom, prim, nrm = self.cast_raw(o32, d32, dists, smooth=smooth)
        miss = geom < 0
        distance, nrm = widen_hits(tfar, nrm, miss)
        prim = np.where(miss, -1, prim).astype(np.int32)
        return Hits(
            distance.reshape(shape),
            geom.astype(np.int32, copy=False).reshape(shape),
            prim.reshape(shape),
            nrm.reshape(shape + (3,)),
            np.broadcast_to(o64, (len(geom), 3)).reshape(shape + (3,)),
            d64.reshape(shape + (3,)),
        )

    def cast_raw(self, origins32: np.ndarray, directions32: np.ndarray, max_distance32: np.ndarray | None = None,
                 *, smooth: bool = True):
        """Closest hit with no validation and no widening: the simulators' inner path.

        Parameters
        ----------
        origins32, directions32 : ndarray (N, 3) float32, C-contiguous
            World origins (m) and *unit* directions.
        max_distance32 : ndarray (N,) float32, optional
            Far limit of each ray (m); default unlimited. Overwritten.
        smooth : bool
            Interpolated vertex normals, else the triangle's geometric normal.

        Returns
        -------
        distance : ndarray (N,) float32
            ``>= max_distance`` (or 1e30) on a miss.
        body : ndarray (N,) int32
            ``-1`` on a miss.
        triangle : ndarray (N,) int32
            Undefined on a miss.
        normal : ndarray (N, 3) float32
            Unit normal (world); undefined on a miss. :meth:`cast` is this, validated
            and widened to float64, bit for bit.
        """
        tfar, geom, prim, u, v, ng = self.intersect_raw(origins32, directions32, max_distance32, normals=not smooth)
        if smooth:
            gi = self._tri_offset[np.maximum(geom, 0)] + np.maximum(prim, 0)
            cn = self._corner_normals[gi]  # (n, 3, 3) float32
            w = np.empty((len(u), 3), np.float32)  # barycentric weights of the three corners
            w[:, 1] = u
            w[:, 2] = v
            w[:, 0] = 1.0 - u - v
            nrm = np.einsum("nk,nkj->nj", w, cn)
        else:
            nrm = ng
        nrm /= np.sqrt(np.einsum("ij,ij->i", nrm, nrm))[:, None] + np.float32(1e-30)
        return tfar, geom, prim, nrm

    def intersect_raw(self, origins32: np.ndarray, directions32: np.ndarray, max_distance32: np.ndarray | None = None,
                      *, normals: bool = True, split: bool = True):
        """Embree's closest-hit output as it comes, over the worker threads: the lowest-level query.

        Parameters as :meth:`cast_raw`; ``split=False`` casts every ray on the calling thread (for
        callers that already run one batch per thread). Returns ``(distance, body, triangle, u, v, Ng)``:
        ``(N,)`` float32 distance (``>= max_distance`` on a miss), ``(N,)`` int32 body
        (``-1`` on a miss) and triangle, ``(N,)`` float32 barycentric ``u, v`` of the hit
        (corners 1 and 2), and the unnormalised geometric normal ``(N, 3)`` float32 (``None``
        without ``normals``). Smooth normals are ``(1 - u - v) n0 + u n1 + v n2`` of
        :attr:`corner_normals` row ``triangle_offset[body] + triangle``.
        """
        n = len(origins32)
        dists = np.full(n, _MISS_DIST, np.float32) if max_distance32 is None else max_distance32
        outs = self._run_chunks(origins32, directions32, dists, "INTERSECT", True, copy=False, split=split)
        cat = (lambda k: outs[0][k]) if len(outs) == 1 else (lambda k: np.concatenate([r[k] for r in outs]))
        return cat("tfar"), cat("geomID"), cat("primID"), cat("u"), cat("v"), cat("Ng") if normals else None

    def intersect_each(self, origins32: np.ndarray, directions32: np.ndarray, max_distance32: np.ndarray, each) -> None:
        """:meth:`intersect_raw` in the same chunks over the worker threads, each chunk's output handed to
        ``each(a, b, distance, body, triangle, u, v)`` (rays ``a..b``; the arrays as :meth:`intersect_raw`
        returns them, of that chunk only) on the thread that cast it, as soon as it is cast: the caller's
        per-ray work runs beside the other chunks' casts, with no concatenated copy of the output.
        ``max_distance32`` is overwritten (as by :meth:`intersect_raw`)."""
        n = len(origins32)
        n_chunks = 1 if n < 4096 or self.threads == 1 else 2 * self.threads
        bounds = [n * k // n_chunks for k in range(n_chunks + 1)]  # (np.linspace: ~15 us a call)

        def job(k):
            a, b = int(bounds[k]), int(bounds[k + 1])
            out = self._embree.run(origins32[a:b], directions32[a:b], dists=max_distance32[a:b], query="INTERSECT",
                                   output=True)
            each(a, b, out["tfar"], out["geomID"], out["primID"], out["u"], out["v"])

        if n_chunks == 1:
            job(0)
            return
        for _ in _pool(self.threads).map(job, range(n_chunks)):
            pass

    def front_hits(self):
        """The direct ``rtcIntersect1`` path with a back-face filter on this scene, for numba kernels
        (:func:`optiacoustic._embree_kernels.direct_path`: integer addresses ``fn``, ``scene``,
        ``args``), or None where Embree's library, the scene handle or the struct layouts do not
        check out (then kernels use :meth:`intersect_raw`; an exception on the way is kept in
        ``front_hits_error``). Looked up once; imports numba."""
        if self._front_hits is False:
            with self._lock:
                if self._front_hits is False:
                    got = None
                    if self._rtc_scene:
                        try:
                            from ._embree_kernels import direct_path

                            got = direct_path(self._embree, self._rtc_scene)
                        except Exception as exc:  # pragma: no cover - numba or llvmlite cannot build the filter
                            self.front_hits_error = f"{type(exc).__name__}: {exc}"
                    self._front_hits = got
        return self._front_hits

    @property
    def corner_normals(self) -> np.ndarray:
        """Per-triangle corner normals of all bodies, ``(n_triangles, 3, 3)`` float32 (read-only use)."""
        return self._corner_normals

    @property
    def triangle_offset(self) -> np.ndarray:
        """Row of each body's first triangle in :attr:`corner_normals`, ``(n_bodies + 1,)`` int64."""
        return self._tri_offset

    def occluded_raw(self, origins32: np.ndarray, directions32: np.ndarray, max_distance32: np.ndarray) -> np.ndarray:
        """:meth:`occluded` with no validation: float32 ``(N, 3)`` unit directions, ``(N,)`` limits."""
        outs = self._run_chunks(origins32, directions32, max_distance32, "OCCLUDED", False, copy=False)
        return (outs[0] if len(outs) == 1 else np.concatenate(outs)) != -1

    def bare_intersect(self, origins32: np.ndarray, directions32: np.ndarray) -> None:
        """Raw closest-hit query over the worker threads, with no conversion or post-processing.

        For benchmarks: the floor under which no caster on this scene can go.
        ``origins32``/``directions32`` are contiguous float32 ``(N, 3)`` arrays.
        """
        dists = np.full(len(origins32), _MISS_DIST, np.float32)
        self._run_chunks(origins32, directions32, dists, "INTERSECT", True)

    def enclosing_body(self, point) -> int:
        """Id of a closed body that contains ``point`` (m, world), else -1.

        Fourteen probe rays (axes and diagonals): the point is inside a body when at least ten
        of them hit the back of one of its faces (a few may first meet a body it rests on,
        such as the seabed under a box). An open surface (a plane) never encloses a point.
        """
        p = as_array(point, "point", (3,)).astype(np.float32)
        o32 = np.ascontiguousarray(np.broadcast_to(p, _PROBE_DIRS32.shape))
        _, body, _, _, _, ng = self.intersect_raw(o32, _PROBE_DIRS32, split=False)  # 14 rays: ~20 us
        hit = body >= 0
        # the back of a face: the ray runs along its geometric normal
        back = hit & (np.einsum("ij,ij->i", _PROBE_DIRS32, np.where(hit[:, None], ng, 0.0)) > 0)
        if back.sum() < 10:
            return -1
        ids, counts = np.unique(body[back], return_counts=True)
        return int(ids[np.argmax(counts)]) if counts.max() >= 10 else -1

    def occluded(self, origins, directions, max_distance) -> np.ndarray:
        """True where something lies along the ray closer than ``max_distance`` (shadow rays)."""
        shape, o32, d32, _, _, dists = self._prepare(origins, directions, max_distance)
        outs = self._run_chunks(o32, d32, dists, "OCCLUDED", False)
        return (np.concatenate(outs) != -1).reshape(shape)

    def distance(self, origins, directions, *, max_distance=np.inf) -> np.ndarray:
        """Distance to the closest hit only (``inf`` on a miss): the cheapest query."""
        shape, o32, d32, _, _, dists = self._prepare(origins, directions, max_distance)
        outs = self._run_chunks(o32, d32, dists, "DISTANCE", False)
        t = np.concatenate(outs).astype(float)
        return np.where(t >= np.minimum(dists, _MISS_DIST) * (1 - 1e-7), np.inf, t).reshape(shape)


# --------------------------------------------------------------------------- per-scene cache
_CASTERS: "weakref.WeakKeyDictionary[Scene, RayCaster]" = weakref.WeakKeyDictionary()
_CASTERS_LOCK = threading.Lock()


def caster_for(scene: Scene) -> RayCaster:
    """The ray caster of ``scene``, built on first use and kept while the scene lives.

    Every simulator (sonar, camera, a rig of both) takes its caster from here, so one
    scene's acceleration structure is built once per process.
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene: expected a Scene, got {type(scene).__name__}")
    with _CASTERS_LOCK:
        c = _CASTERS.get(scene)
        if c is None:
            c = _CASTERS[scene] = RayCaster(scene)
    return c
