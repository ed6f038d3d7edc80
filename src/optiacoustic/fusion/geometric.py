"""Geometric sonar-to-optical mappings: what the RBF learns, written with the rig and planes.

A sonar measurement ``(r, theta)`` fixes a 3D point up to its elevation ``phi``. On a known
plane ``n . P_s = d`` (sonar frame) the elevation solves ``r (A cos phi + B sin phi) = d`` with
``A = n_x sin theta + n_y cos theta`` and ``B = n_z``: two roots ``phi = alpha +- arccos(d / (r C))``,
``C = hypot(A, B)``, ``alpha = atan2(B, A)``; the one inside the elevation aperture is kept
(docs/derivations.md (ch. 7)). The point then goes through the rig into the camera.

* :class:`PlaneMapping`: one plane for the whole scene (given, or the least-squares plane of
  the training matches reconstructed in 3D).
* :class:`PiecewisePlanarMapping`: one plane per triangle of the Delaunay triangulation of the
  training features in the fan plane (the thesis's future work for non-planar scenes).

Frames: sonar X right, Y forward, Z up; camera OpenCV; rig ``P_s = R P_o + t``.
Nothing here imports the simulators.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from .._validate import as_array, as_positive
from ..frames import Pose, polar_from_fan, sonar_from_spherical
from ..geometry.projection import cos_sin_roots
from ..rig import Rig
from ._checks import check_matches, query_points

__all__ = [
    "SonarPlane",
    "ElevationSolution",
    "plane_elevation",
    "GeometricMap",
    "reconstruct_matches",
    "PlaneMapping",
    "PiecewisePlanarMapping",
]


def _check_rig(rig) -> Rig:
    if not isinstance(rig, Rig):
        raise ValueError(f"rig: expected an optiacoustic.Rig, got {type(rig).__name__}")
    return rig


# --------------------------------------------------------------------------- planes
@dataclass(frozen=True, eq=False)
class SonarPlane:
    """A plane ``normal . P_s = offset`` in the sonar frame.

    Attributes
    ----------
    normal : ndarray, shape (3,)
        Unit normal (sonar frame), oriented so that ``offset >= 0``.
    offset : float
        Distance from the sonar's centre to the plane (m).
    """

    normal: np.ndarray
    offset: float

    def __post_init__(self):
        n = as_array(self.normal, "SonarPlane.normal", (3,))
        d = float(as_array(self.offset, "SonarPlane.offset", ()))
        norm = float(np.linalg.norm(n))
        if norm < 1e-12:
            raise ValueError("SonarPlane.normal: must be a non-zero vector")
        n, d = n / norm, d / norm
        if d < 0:
            n, d = -n, -d
        n.setflags(write=False)
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "offset", d)

    @classmethod
    def from_points(cls, points_sonar) -> "SonarPlane":
        """The least-squares (total, orthogonal-distance) plane of sonar-frame points ``(N, 3)``.

        Raises
        ------
        ValueError
            Fewer than 3 points, NaN, or all points on one line.
        """
        p = as_array(points_sonar, "points_sonar", (None, 3))
        if len(p) < 3:
            raise ValueError(f"points_sonar: need at least 3 points for a plane, got {len(p)}")
        c = p.mean(axis=0)
        _, s, vt = np.linalg.svd(p - c)
        if s[1] <= 1e-9 * max(s[0], 1e-300):
            raise ValueError(f"points_sonar: the {len(p)} points are collinear; no plane through them")
        n = vt[2]
        return cls(n, float(n @ c))

    @classmethod
    def from_world(cls, normal_world, offset_world: float, sonar_pose: Pose) -> "SonarPlane":
        """The world plane ``normal_world . P_w = offset_world`` in the frame of a sonar at ``sonar_pose``.

        ``P_w = R P_s + t`` gives ``(R^T n) . P_s = d - n . t``.
        """
        if not isinstance(sonar_pose, Pose):
            raise ValueError(f"sonar_pose: expected a Pose, got {type(sonar_pose).__name__}")
        n = as_array(normal_world, "normal_world", (3,))
        d = float(as_array(offset_world, "offset_world", ()))
        norm = float(np.linalg.norm(n))
        if norm < 1e-12:
            raise ValueError("normal_world: must be a non-zero vector")
        n, d = n / norm, d / norm
        return cls(sonar_pose.R.T @ n, d - float(n @ sonar_pose.t))

    def signed_distance(self, points_sonar) -> np.ndarray:
        """``normal . P - offset`` (m) of sonar-frame points ``(..., 3)``."""
        p = as_array(points_sonar, "points_sonar", ("...", 3), finite=False)
        return p @ self.normal - self.offset


@dataclass(frozen=True, eq=False)
class ElevationSolution:
    """Elevations that put sonar measurements on planes.

    Attributes
    ----------
    elevations : ndarray, shape (...)
        Elevation (rad) of the chosen root; NaN where ``valid`` is False.
    valid : ndarray of bool, shape (...)
        A root exists inside the elevation aperture.
    ambiguous : ndarray of bool, shape (...)
        Both roots lie inside the aperture (the one nearer the reference was kept).
    """

    elevations: np.ndarray
    valid: np.ndarray
    ambiguous: np.ndarray


def _elevation_on_planes(normals, offsets, r, th, half, reference=0.0) -> ElevationSolution:
    """Vectorised root choice: ``normals (..., 3)``, ``offsets``, ``r``, ``th`` broadcast together."""
    A = normals[..., 0] * np.sin(th) + normals[..., 1] * np.cos(th)
    B = normals[..., 2] + 0.0 * A
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(r > 0, offsets / np.where(r > 0, r, 1.0), np.nan)
    roots = np.moveaxis(cos_sin_roots(A, B, c), 0, -1)  # the arc meets the plane (eq. 6.16)
    ok = np.isfinite(roots[..., 0]) & (np.hypot(A, B) > 1e-12)
    inside = ok[..., None] & (np.abs(roots) <= half + 1e-12)
    distinct = np.abs(roots[..., 0] - roots[..., 1]) > 1e-12
    both = inside[..., 0] & inside[..., 1] & distinct
    ref = np.broadcast_to(np.asarray(reference, float), roots.shape[:-1])
    first = inside[..., 0] & (~inside[..., 1] | (np.abs(roots[..., 0] - ref) <= np.abs(roots[..., 1] - ref)))
    phi = np.where(first, roots[..., 0], roots[..., 1])
    valid = inside.any(axis=-1)
    return ElevationSolution(np.where(valid, phi, np.nan), valid, both)


def plane_elevation(plane: SonarPlane, ranges, azimuths, *, fov_elevation: float = np.pi) -> ElevationSolution:
    """The elevation at which a sonar measurement ``(r, theta)`` lies on ``plane``.

    Solves ``plane.normal . P_s(r, theta, phi) = plane.offset`` for ``phi``; of the two roots
    the one inside ``|phi| <= fov_elevation / 2`` is returned, the one nearer the boresight
    (``phi = 0``) when both are (flagged ``ambiguous``).

    Parameters
    ----------
    plane : SonarPlane
        In the sonar frame.
    ranges, azimuths : array_like, broadcastable
        Range (m) and azimuth (rad).
    fov_elevation : float
        Full elevation aperture (rad); pi accepts any elevation.

    Returns
    -------
    ElevationSolution
        NaN and ``valid = False`` where the range-azimuth arc misses the plane inside the
        aperture.
    """
    if not isinstance(plane, SonarPlane):
        raise ValueError(f"plane: expected a SonarPlane, got {type(plane).__name__}")
    r = as_array(ranges, "ranges", finite=False)
    th = as_array(azimuths, "azimuths", finite=False)
    try:
        r, th = np.broadcast_arrays(r, th)
    except ValueError:
        raise ValueError(f"ranges {r.shape} and azimuths {th.shape} do not broadcast together") from None
    half = min(as_positive(fov_elevation, "fov_elevation") / 2, np.pi / 2)
    return _elevation_on_planes(plane.normal, plane.offset, r, th, half)


# --------------------------------------------------------------------------- mapping results
@dataclass(frozen=True, eq=False)
class GeometricMap:
    """Sonar features mapped through a plane into the camera.

    Attributes
    ----------
    pixels : ndarray, shape (..., 2)
        Optical pixels ``(u, v)``; NaN where ``valid`` is False.
    valid : ndarray of bool, shape (...)
        A root inside the elevation aperture, in front of the camera.
    elevations : ndarray, shape (...)
        The chosen elevation (rad).
    points_sonar : ndarray, shape (..., 3)
        The 3D point on the plane (sonar frame, m).
    ambiguous : ndarray of bool, shape (...)
        Both elevation roots were inside the aperture.
    message : str
        How many points are valid, and why the others are not.
    """

    pixels: np.ndarray
    valid: np.ndarray
    elevations: np.ndarray
    points_sonar: np.ndarray
    ambiguous: np.ndarray
    message: str = ""

    def __bool__(self) -> bool:
        return bool(np.any(self.valid))


def _project(rig: Rig, flat, ok, shape, normals, offsets, reference=0.0) -> GeometricMap:
    r, th = polar_from_fan(flat[:, 0], flat[:, 1])
    sol = _elevation_on_planes(normals, offsets, r, th, min(rig.fov_elevation / 2, np.pi / 2), reference)
    el_ok = sol.valid & ok
    p_s = sonar_from_spherical(r, th, np.where(el_ok, sol.elevations, np.nan))
    px = rig.camera.project(rig.camera_from_sonar(p_s))
    valid = el_ok & np.all(np.isfinite(px), axis=-1)
    n, n_el = len(flat), int((sol.valid & ok).sum())
    msg = (f"{int(valid.sum())} of {n} points mapped; {int((~ok).sum())} not finite, "
           f"{int(ok.sum()) - n_el} with no elevation on the plane inside the aperture, "
           f"{n_el - int(valid.sum())} behind the camera")
    px = np.where(valid[:, None], px, np.nan)
    p_s = np.where(valid[:, None], p_s, np.nan)
    el = np.where(valid, sol.elevations, np.nan)
    return GeometricMap(px.reshape(shape + (2,)), valid.reshape(shape), el.reshape(shape), p_s.reshape(shape + (3,)),
                        (sol.ambiguous & valid).reshape(shape), msg)


def reconstruct_matches(rig: Rig, sonar_xy, pixels) -> np.ndarray:
    """3D points of matches (closed-form range solution, thesis ch. 5), in the sonar frame.

    Each pixel's ray is intersected with the sphere of the sonar range
    (:func:`optiacoustic.geometry.reconstruct.range_solution`).

    Parameters
    ----------
    rig : Rig
    sonar_xy : array_like, shape (N, 2)
        Fan coordinates (m).
    pixels : array_like, shape (N, 2)
        Optical pixels.

    Returns
    -------
    ndarray, shape (N, 3)
        Sonar-frame points (m).

    Raises
    ------
    ValueError
        Bad shapes or NaN, or a match whose ray misses its range sphere (inconsistent match).
    """
    from ..geometry.reconstruct import range_solution

    _check_rig(rig)
    xy = as_array(sonar_xy, "sonar_xy", (None, 2))
    px = as_array(pixels, "pixels", (len(xy), 2))
    r, _ = polar_from_fan(xy[:, 0], xy[:, 1])
    sol = range_solution(rig, px, r)
    if not np.all(sol.valid):
        bad = np.flatnonzero(~sol.valid)
        raise ValueError(f"pixels: matches {bad[:10].tolist()} cannot be reconstructed ({sol.message})")
    return rig.sonar_from_camera(sol.points)


# --------------------------------------------------------------------------- one plane
@dataclass(frozen=True, eq=False)
class PlaneMapping:
    """Sonar fan coordinates to pixels through one plane and the rig.

    Attributes
    ----------
    rig : Rig
        Its sonar's elevation aperture selects the root (pi when it has no sonar).
    plane : SonarPlane
        In the sonar frame.
    """

    rig: Rig
    plane: SonarPlane

    def __post_init__(self):
        _check_rig(self.rig)
        if not isinstance(self.plane, SonarPlane):
            raise ValueError(f"plane: expected a SonarPlane, got {type(self.plane).__name__}")

    @classmethod
    def fit(cls, rig: Rig, sonar_xy, pixels) -> "PlaneMapping":
        """The dominant plane of the matches: reconstruct them in 3D, fit a least-squares plane.

        Raises
        ------
        ValueError
            Degenerate layouts (as :class:`~optiacoustic.fusion.RBFMapping`), matches that do
            not reconstruct, or 3D points on one line.
        """
        xy, px = check_matches(sonar_xy, pixels)
        return cls(rig, SonarPlane.from_points(reconstruct_matches(rig, xy, px)))

    def solve(self, sonar_xy) -> GeometricMap:
        """Map fan coordinates ``(..., 2)`` (m); NaN and ``valid = False`` where no root."""
        flat, ok, shape = query_points(sonar_xy)
        return _project(self.rig, flat, ok, shape, self.plane.normal, self.plane.offset)

    def __call__(self, sonar_xy) -> np.ndarray:
        """Optical pixels ``(..., 2)`` of fan coordinates ``(..., 2)``; NaN where unmapped."""
        return self.solve(sonar_xy).pixels


# --------------------------------------------------------------------------- piecewise planar
@dataclass(frozen=True, eq=False)
class PiecewisePlanarMapping:
    """One plane per Delaunay triangle of the training features in the fan plane.

    The training matches are reconstructed in 3D (:func:`reconstruct_matches`); the sonar
    features are triangulated (Delaunay) in the fan plane; each triangle carries the plane
    through its three 3D points. A query point is mapped through the plane of the triangle
    that contains it in the fan, or of the triangle with the nearest centroid when it lies
    outside them all (or in a triangle whose 3D points are collinear). Of two elevation roots
    in the aperture, the one nearer the triangle's mean elevation is kept. Training features
    map to their own pixels.

    Attributes
    ----------
    rig : Rig
    sonar_xy : ndarray, shape (N, 2)
        Training fan coordinates (m).
    points_sonar : ndarray, shape (N, 3)
        Their reconstructed 3D points (sonar frame, m).
    triangles : ndarray of int, shape (M, 3)
        Delaunay triangles (indices into ``sonar_xy``).
    normals, offsets : ndarray, shapes (M, 3) and (M,)
        Each triangle's plane (sonar frame); NaN for triangles with collinear 3D points.
    """

    rig: Rig
    sonar_xy: np.ndarray
    points_sonar: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    _delaunay: Delaunay
    _centroids: cKDTree
    _usable: np.ndarray
    _reference: np.ndarray

    @classmethod
    def fit(cls, rig: Rig, sonar_xy, pixels) -> "PiecewisePlanarMapping":
        """Reconstruct, triangulate and fit the triangles' planes.

        Raises
        ------
        ValueError
            Degenerate layouts (fewer than 3, duplicated, collinear features, NaN), matches
            that do not reconstruct, or no triangle with a 3D plane.
        """
        xy, px = check_matches(sonar_xy, pixels)
        xy = xy.copy()  # frozen below: never freeze the caller's array
        P = reconstruct_matches(_check_rig(rig), xy, px)
        try:
            tri = Delaunay(xy)
        except QhullError as exc:
            raise ValueError(f"sonar_xy: cannot triangulate the features ({str(exc).splitlines()[0]})") from None
        s = tri.simplices
        a, b, c = P[s[:, 0]], P[s[:, 1]], P[s[:, 2]]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n, axis=-1)
        edge2 = np.max([np.sum((b - a) ** 2, -1), np.sum((c - a) ** 2, -1), np.sum((c - b) ** 2, -1)], axis=0)
        usable = norm > 1e-9 * edge2
        if not usable.any():
            raise ValueError("sonar_xy: every triangle of features has collinear 3D points; no plane to map through")
        with np.errstate(invalid="ignore", divide="ignore"):
            n = np.where(usable[:, None], n / norm[:, None], np.nan)
        d = np.einsum("ij,ij->i", n, a)
        el = np.arctan2(P[:, 2], np.hypot(P[:, 0], P[:, 1]))
        ref = el[s].mean(axis=1)
        centroids = xy[s].mean(axis=1)
        kd = cKDTree(centroids[usable])
        for arr in (xy, P, s, n, d):
            arr.setflags(write=False)
        return cls(rig, xy, P, s, n, d, tri, kd, np.flatnonzero(usable), ref)

    def triangle_of(self, sonar_xy) -> np.ndarray:
        """Index of the triangle whose plane maps each query point ``(..., 2)``; -1 for NaN input."""
        flat, ok, shape = query_points(sonar_xy)
        k = np.full(len(flat), -1)
        if ok.any():
            q = flat[ok]
            s = self._delaunay.find_simplex(q)
            bad = (s < 0) | ~np.isfinite(self.offsets[np.maximum(s, 0)])
            if bad.any():
                s[bad] = self._usable[self._centroids.query(q[bad])[1]]
            k[ok] = s
        return k.reshape(shape)

    def solve(self, sonar_xy) -> GeometricMap:
        """Map fan coordinates ``(..., 2)`` (m) through their triangles' planes."""
        flat, ok, shape = query_points(sonar_xy)
        k = self.triangle_of(flat)
        kk = np.maximum(k, 0)
        return _project(self.rig, flat, ok, shape, self.normals[kk], self.offsets[kk], self._reference[kk])

    def __call__(self, sonar_xy) -> np.ndarray:
        """Optical pixels ``(..., 2)`` of fan coordinates ``(..., 2)``; NaN where unmapped."""
        return self.solve(sonar_xy).pixels
