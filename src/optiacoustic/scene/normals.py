"""Vertex shading normals of a triangle mesh, with sharp edges kept sharp (vectorised).

Faces that share an edge are smoothed together when their normals differ by less than a
crease angle; vertices are duplicated where patches meet at a sharper edge, so that
interpolating vertex normals across a triangle shades curved parts smoothly and flat
parts flatly. This replaces ``trimesh.graph.smooth_shade`` + ``vertex_normals`` (about
7 us per triangle) with a few sorts and ``bincount`` s (well under 1 us per triangle).
Unlike trimesh, large coplanar facets get no special treatment: they are smoothed with
neighbours across edges under the crease angle, like any other faces.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["smooth_shading", "merge_vertices"]


@functools.lru_cache(maxsize=1)
def _pool():
    """Two worker threads for the large arrays of a mesh build (numpy releases the GIL)."""
    from concurrent.futures import ThreadPoolExecutor

    return ThreadPoolExecutor(max_workers=2, thread_name_prefix="oas-normals")


def _face_normals(V: np.ndarray, F: np.ndarray):
    """Area-weighted face normals ``(F, 3)`` (twice the area long) and their unit vectors."""
    a = V[F[:, 0]]
    e1 = V[F[:, 1]]
    e1 -= a
    e2 = V[F[:, 2]]
    e2 -= a
    fn = a  # reused: np.cross is 3x slower than the three components
    fn[:, 0] = e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1]
    fn[:, 1] = e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2]
    fn[:, 2] = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    area2 = np.sqrt(np.einsum("ij,ij->i", fn, fn))
    return fn, fn / np.where(area2 > 0, area2, 1.0)[:, None]


def _face_adjacency(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of faces ``(a, b)`` sharing an edge (consecutive ones around non-manifold edges)."""
    f = faces.astype(np.int64, copy=False)
    g = f[:, [1, 2, 0]]  # each corner's next corner: edges (f, g)
    lo = np.minimum(f, g).ravel()
    span = np.maximum(f, g, out=g).ravel()  # in place: few large temporaries
    span -= lo
    n = lo.size
    D = int(span.max()) + 1 if n else 1
    bits = max(int(n).bit_length(), 1)
    if n_vertices * D < 2 ** (62 - bits):
        # edge key and corner index packed in one int64: a plain sort (SIMD) instead of
        # an argsort, about 8x cheaper; meshes with vertex locality (grids, scans) fit
        packed = lo
        packed *= D
        packed += span
        packed <<= bits
        packed |= np.arange(n)
        packed.sort()
        order = np.bitwise_and(packed, (1 << bits) - 1, out=span)  # in place: span is spent
        ks = np.right_shift(packed, bits, out=packed)
    else:
        key = lo * D + span
        order = np.argsort(key)
        ks = key[order]
    same = np.flatnonzero(ks[1:] == ks[:-1])
    fa, fb = order[same], order[same + 1]
    fa //= 3
    fb //= 3
    return fa, fb


def smooth_shading(vertices, faces, crease_angle: float):
    """Split vertices along creases and give each an area-weighted normal.

    Parameters
    ----------
    vertices : ndarray (V, 3)
        Vertex positions (m), any frame.
    faces : ndarray (F, 3) of int
        Vertex indices of each triangle (counter-clockwise seen from outside).
    crease_angle : float
        Faces sharing an edge are smoothed together when their normals differ by less
        than this angle (rad); 0 gives flat shading (every triangle its own normal).

    Returns
    -------
    vertices : ndarray (V', 3)
        The input vertices followed by the duplicates made along creases.
    faces : ndarray (F, 3) of int32
        Re-indexed faces.
    normals : ndarray (V', 3)
        Unit vertex normals, each the area-weighted mean of the normals of the faces of
        its smoothing patch around that vertex.
    """
    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    nv, nf = len(V), len(F)
    # face normals on a second thread while this one finds the edge neighbours (numpy
    # releases the GIL; a large mesh's build has the other core free at this point)
    side = _pool().submit(_face_normals, V, F) if crease_angle > 0 and nf >= 200_000 else None
    if crease_angle > 0:
        fa, fb = _face_adjacency(F, nv)
    fn, unit = side.result() if side is not None else _face_normals(V, F)
    if crease_angle > 0:
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        smooth = np.einsum("ij,ij->i", unit[fa], unit[fb]) > np.cos(crease_angle)
        g = coo_matrix((np.ones(int(smooth.sum()), np.int8), (fa[smooth], fb[smooth])), shape=(nf, nf))
        _, patch = connected_components(g, directed=False)
    else:
        patch = np.arange(nf)
    # a corner keeps its vertex when its patch is the one that vertex's first user set;
    # the other corners (along creases only) get one new vertex per (patch, vertex)
    corner_patch = np.repeat(patch, 3)
    corner_v = F.ravel()
    owner = np.full(nv, -1, np.int64)
    owner[corner_v[::-1]] = corner_patch[::-1]  # the first corner's patch wins
    other = np.flatnonzero(corner_patch != owner[corner_v])
    new_f = corner_v.copy()
    if other.size:
        key = corner_patch[other] * nv + corner_v[other]
        uniq, inv = np.unique(key, return_inverse=True)
        new_f[other] = nv + inv
        V = np.concatenate([V, V[uniq % nv]])
    n_out = len(V)
    new_f = new_f.reshape(nf, 3)
    N = np.empty((n_out, 3))
    corners = [np.ascontiguousarray(new_f[:, k]) for k in range(3)]  # one copy each, not one per channel

    def channel(j):
        w = np.ascontiguousarray(fn[:, j])
        N[:, j] = sum(np.bincount(c, weights=w, minlength=n_out) for c in corners)

    if nf >= 200_000:
        list(_pool().map(channel, range(3)))
    else:
        for j in range(3):
            channel(j)
    ln = np.sqrt(np.einsum("ij,ij->i", N, N))
    # unused vertices (and degenerate patches) get an arbitrary unit normal
    N = np.where(ln[:, None] > 0, N / np.where(ln > 0, ln, 1.0)[:, None], [0.0, 0.0, 1.0])
    return V, new_f.astype(np.int32), N


def merge_vertices(vertices, faces, digits: int = 8):
    """Merge vertices at the same position and drop the ones no face uses.

    Positions are compared after rounding to ``digits`` decimals (trimesh's merge
    tolerance), or to ``max|coordinate| / 2**60`` where that is coarser (coordinates above
    about 1e10 in the file's units, e.g. a mesh in nanometres: rounded to 1e-8 they
    overflowed the int64 key and distinct triangles merged); unlike trimesh, vertices are merged by position alone (normals and UVs in
    the file do not keep them apart: shading normals are computed here). The kept vertices
    stay in the order of their first use in the file's vertex list.

    Returns ``(vertices (V', 3) float64, faces (F, 3) int64)``; the input arrays
    themselves when nothing is to merge or drop.
    """
    V = np.asarray(vertices, float)
    F = np.asarray(faces, np.int64)
    used = np.zeros(len(V), bool)
    used[F.ravel()] = True
    idx = np.flatnonzero(used)
    Vu = V[idx]
    extent = float(np.abs(Vu).max()) if Vu.size else 0.0
    # the rounding step: 10^-digits, or coarser where the coordinates would overflow an int64 key
    # (2^60 steps span the mesh: still far finer than float64 resolves at that size)
    step = max(10.0 ** -digits, extent / 2.0 ** 60)
    q = np.round(Vu / step).astype(np.int64)
    # one 64-bit hash per position, sorted stably, then checked exactly against the positions
    h = q[:, 0] * np.int64(-7046029254386353131) ^ q[:, 1] * np.int64(-4417276706812531889) ^ q[:, 2] * np.int64(
        1609587929392839161)
    order = np.argsort(h, kind="stable")
    hs = h[order]
    start = np.empty(len(hs), bool)
    start[:1] = True
    np.not_equal(hs[1:], hs[:-1], out=start[1:])
    if start.all() and len(idx) == len(V):
        return V, F  # nothing to merge, nothing unused
    first = order[start][np.cumsum(start) - 1]  # each sorted entry's group representative (its first use)
    rep = np.empty(len(idx), np.int64)
    rep[order] = first
    if not np.array_equal(q[rep], q):  # a hash collision (never seen): exact grouping instead
        _, inv = np.unique(q, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        first_of = np.full(inv.max() + 1, len(idx), np.int64)
        np.minimum.at(first_of, inv, np.arange(len(idx)))
        rep = first_of[inv]
    keep = rep == np.arange(len(idx))
    new_id = np.cumsum(keep) - 1
    remap = np.full(len(V), -1, np.int64)
    remap[idx] = new_id[rep]
    return V[idx[keep]], remap[F]
