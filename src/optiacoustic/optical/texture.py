"""Surface albedo: body colours and procedural textures (checker, grid).

A :class:`~optiacoustic.scene.Texture` is evaluated in its body's frame. The scene model
describes it in the body's x-y coordinates, which is what a plane (normal +Z) shows. So
that the faces of boxes and other solids also carry the pattern (the walls of
``perpendicular_planes`` are thin boxes standing in their x-z plane), each surface point
is projected along the body axis closest to its normal: x-y on faces facing +-Z (planes
exactly as documented), y-z on faces facing +-X, x-z on faces facing +-Y.
"""

from __future__ import annotations

import numpy as np

from ..scene import Scene

__all__ = ["surface_albedo", "apply_textures", "body_colors", "texture_mask"]


def texture_mask(texture, coords_uv: np.ndarray) -> np.ndarray:
    """Where ``texture`` shows its second colour, for 2D texture coordinates ``(N, 2)`` (m).

    ``checker``: squares of side ``size`` alternate, the square at the origin's +u +v
    corner has the first colour. ``grid``: lines of width ``line_width`` centred on every
    multiple of ``size`` along u and v.
    """
    uv = np.asarray(coords_uv, float)
    s = texture.size
    if texture.kind == "checker":
        k = np.floor(uv[:, 0] / s) + np.floor(uv[:, 1] / s)
        return (k.astype(np.int64) & 1).astype(bool)
    if texture.kind == "grid":
        # distance to the nearest line along each axis
        d = np.abs(uv - s * np.round(uv / s))
        return np.any(d < texture.line_width / 2, axis=-1)
    raise ValueError(f"texture.kind: expected 'checker' or 'grid', got {texture.kind!r}")


def body_colors(scene: Scene) -> np.ndarray:
    """Base colour of every body, ``(n_bodies + 1, 3)`` float32; the last row (open water) is 0."""
    return np.array([b.material.color for b in scene.bodies] + [(0.0, 0.0, 0.0)], np.float32)


def surface_albedo(scene: Scene, body_ids: np.ndarray, points_world: np.ndarray, normals_world: np.ndarray) -> np.ndarray:
    """Diffuse albedo (linear RGB in [0, 1]) at surface points.

    Parameters
    ----------
    scene : Scene
    body_ids : (N,) int
        Body hit by each point; ``-1`` (open water) gives 0.
    points_world, normals_world : (N, 3)
        Hit points (m) and unit normals, world frame.

    Returns
    -------
    (N, 3) float32
    """
    colors = body_colors(scene)
    ids = np.where(body_ids >= 0, body_ids, len(scene.bodies))
    return apply_textures(scene, body_ids, points_world, normals_world, colors[ids])


def apply_textures(scene: Scene, body_ids: np.ndarray, points_world: np.ndarray, normals_world: np.ndarray,
                   albedo: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Paint the textured bodies' second colour (times ``scale``) into ``albedo`` ``(N, 3)`` in place.

    ``albedo`` holds each point's base colour (times ``scale``); the other arguments are
    those of :func:`surface_albedo`. Returns ``albedo``.
    """
    bodies = scene.bodies
    # a loop over the few textured bodies, each vectorised over its pixels
    for i, b in enumerate(bodies):
        tex = b.material.texture
        if tex is None:
            continue
        sel = np.flatnonzero(body_ids == i)
        if sel.size == 0:
            continue
        p_body = np.einsum("ij,jk->ik", points_world[sel] - b.pose.t, b.pose.R)  # R^T (p - t), no BLAS
        n_body = np.einsum("ij,jk->ik", normals_world[sel], b.pose.R)
        axis = np.argmax(np.abs(n_body), axis=-1)
        # project along the dominant normal axis: (u, v) = the other two coordinates in order
        u_idx = np.where(axis == 0, 1, 0)
        v_idx = np.where(axis == 2, 1, 2)
        uv = np.stack([np.take_along_axis(p_body, u_idx[:, None], 1)[:, 0],
                       np.take_along_axis(p_body, v_idx[:, None], 1)[:, 0]], -1)
        second = texture_mask(tex, uv)
        albedo[sel[second]] = np.asarray(tex.color2, np.float32) * np.float32(scale)
    return albedo
