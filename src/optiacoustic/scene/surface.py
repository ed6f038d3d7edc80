"""Triangle surfaces with per-vertex shading normals.

A :class:`Surface` is what every shape tessellates to and what the ray caster consumes.
Vertices are duplicated along sharp edges (box edges, cylinder rims) so that
interpolating the per-vertex normals across a triangle gives smooth shading on curved
parts and flat shading on flat ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..frames import Pose

__all__ = ["Surface", "parametric_grid"]


@dataclass(frozen=True, eq=False)
class Surface:
    """A triangle mesh in some frame.

    Attributes
    ----------
    vertices : ndarray, shape (V, 3)
        Vertex positions (m).
    faces : ndarray, shape (F, 3), int
        Vertex indices of each triangle.
    normals : ndarray, shape (V, 3)
        Unit shading normals at the vertices (outward for closed bodies).
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray

    def __post_init__(self):
        v = np.ascontiguousarray(self.vertices, dtype=float)
        f = np.ascontiguousarray(self.faces, dtype=np.int32)
        n = np.ascontiguousarray(self.normals, dtype=float)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
            raise ValueError(f"Surface.vertices: expected shape (V>=3, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 1:
            raise ValueError(f"Surface.faces: expected shape (F>=1, 3), got {f.shape}")
        if n.shape != v.shape:
            raise ValueError(f"Surface.normals: expected shape {v.shape}, got {n.shape}")
        if f.min() < 0 or f.max() >= len(v):
            raise ValueError("Surface.faces: vertex index out of range")
        if not (np.all(np.isfinite(v)) and np.all(np.isfinite(n))):
            raise ValueError("Surface: vertices and normals must be finite")
        norm = np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
        if not np.all(np.abs(norm - 1.0) < 1e-12):  # most callers give unit normals: no copy then
            n = n / np.where(norm > 0, norm, 1.0)
        for name, arr in (("vertices", v), ("faces", f), ("normals", n)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def transformed(self, pose: Pose, scale: float | np.ndarray = 1.0) -> "Surface":
        """The surface scaled (in its own frame, per axis allowed) then moved by ``pose``.

        Normals transform with the inverse-transpose of the scale, then the rotation.
        """
        s = np.broadcast_to(np.asarray(scale, float), (3,))
        if np.all(s == 1.0) and np.array_equal(pose.R, np.eye(3)) and not np.any(pose.t):
            return self  # immutable: the identity needs no copy (large meshes)
        v = pose.to_world(self.vertices * s)
        n = self.normals / s
        n = n / np.linalg.norm(n, axis=1, keepdims=True)
        return Surface(v, self.faces, n @ pose.R.T)

    def area(self) -> float:
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())

    @staticmethod
    def concatenate(parts: list["Surface"]) -> "Surface":
        offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
        return Surface(
            np.concatenate([p.vertices for p in parts]),
            np.concatenate([p.faces + o for p, o in zip(parts, offsets)]),
            np.concatenate([p.normals for p in parts]),
        )


def parametric_grid(func, u_range, v_range, nu: int, nv: int, *, wrap_u=False, wrap_v=False) -> Surface:
    """Tessellate a parametric surface ``func(u, v) -> (..., 3)`` on a ``nu x nv`` grid.

    Normals are the normalised cross product of the analytic-by-central-difference
    partial derivatives, which is smooth wherever the parametrisation is.
    """
    u = np.linspace(*u_range, nu, endpoint=not wrap_u)
    v = np.linspace(*v_range, nv, endpoint=not wrap_v)
    U, V = np.meshgrid(u, v, indexing="ij")
    P = func(U, V)
    hu = 1e-5 * (u_range[1] - u_range[0])
    hv = 1e-5 * (v_range[1] - v_range[0])
    Pu = (func(U + hu, V) - func(U - hu, V)) / (2 * hu)
    Pv = (func(U, V + hv) - func(U, V - hv)) / (2 * hv)
    N = np.cross(Pu, Pv)
    ln = np.linalg.norm(N, axis=-1, keepdims=True)
    # Singular points of the parametrisation (poles) take the mean of their neighbours' normals.
    N = np.where(ln > 1e-12, N / np.where(ln > 0, ln, 1), 0.0)
    iu = np.arange(nu if wrap_u else nu - 1)
    iv = np.arange(nv if wrap_v else nv - 1)
    I, J = np.meshgrid(iu, iv, indexing="ij")
    idx = lambda i, j: (i % nu) * nv + (j % nv)  # noqa: E731
    a, b, c, d = idx(I, J), idx(I + 1, J), idx(I + 1, J + 1), idx(I, J + 1)
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    verts = P.reshape(-1, 3)
    normals = N.reshape(-1, 3)
    zero = np.linalg.norm(normals, axis=1) == 0
    if zero.any():
        acc = np.zeros_like(normals)
        fn = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
        for k in range(3):
            np.add.at(acc, faces[:, k], fn)
        normals[zero] = acc[zero]
    return Surface(verts, faces, normals)
