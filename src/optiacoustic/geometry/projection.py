"""Projections through an opti-acoustic rig: camera points to pixels and to sonar measurements, and back.

Frames (DESIGN.md): camera frame OpenCV (X right, Y down, Z forward); sonar frame X right,
Y forward, Z up; rig ``P_s = R P_o + t`` with ``R = R_sonar_from_camera`` and ``t`` the camera
centre in the sonar frame. Sonar measurements are range ``r = |P_s|`` (m), azimuth
``theta = atan2(X_s, Y_s)`` and elevation ``phi = atan2(Z_s, hypot(X_s, Y_s))`` (rad).

"Depth" is always the camera-frame ``Z`` of a point (not the distance along the ray), so a
pixel ``(u, v)`` with depth ``Z`` is the point ``Z * (x, y, 1)`` with ``(x, y)`` the undistorted
normalised coordinates of the pixel. Pixels are image pixels; when the camera has lens
distortion they are undistorted through :meth:`PinholeCamera.normalized`.

Nothing here imports the simulators.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array
from ..frames import SonarProjection, project_to_sonar, sonar_from_spherical
from ..rig import Rig

__all__ = [
    "PixelProjection",
    "RigProjection",
    "PixelRays",
    "to_pixels",
    "to_sonar",
    "project",
    "camera_from_pixels",
    "camera_from_sonar",
    "pixel_rays_in_sonar",
    "normalized_coordinates",
    "ideal_pixels",
    "cos_sin_roots",
]


def cos_sin_roots(a, b, c) -> np.ndarray:
    """Both solutions ``phi`` of ``a cos(phi) + b sin(phi) = c``, shape ``(2,) + broadcast``.

    With ``a = n . (sin theta, cos theta, 0)``, ``b = n_z`` and ``c = d / r`` these are the
    elevations where a sonar measurement's arc ``r (cos phi sin theta, cos phi cos theta,
    sin phi)`` meets the plane ``n . P = d`` (thesis eqs. 6.15-6.16, corrected in
    docs/derivations.md): ``phi = atan2(b, a) +- arccos(c / hypot(a, b))``, wrapped to
    ``[-pi, pi)``. NaN where there is none (``|c| > hypot(a, b)``, or ``a = b = 0``).
    """
    a, b, c = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float), np.asarray(c, float))
    rho = np.hypot(a, b)
    psi = np.arctan2(b, a)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.arccos(c / rho)
    roots = np.stack([psi + q, psi - q])
    return (roots + np.pi) % (2 * np.pi) - np.pi


def _check_rig(rig) -> Rig:
    if not isinstance(rig, Rig):
        raise ValueError(f"rig: expected an optiacoustic.Rig, got {type(rig).__name__}")
    return rig


def _sonar_window(rig: Rig) -> dict:
    """Apertures and range window of the rig's sonar (no limits when it has none)."""
    s = rig.sonar
    if s is None:
        return dict(fov_azimuth=np.pi, fov_elevation=np.pi, range_min=0.0, range_max=np.inf)
    return dict(fov_azimuth=float(s.fov_azimuth), fov_elevation=float(s.fov_elevation),
                range_min=float(s.range_min), range_max=float(s.range_max))


def normalized_coordinates(rig: Rig, pixels, name: str = "pixels") -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised coordinates ``(x, y) = (X/Z, Y/Z)`` of pixels.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Image pixels ``(u, v)`` (distorted when the camera has distortion).
    name : str
        Argument name used in error messages.

    Returns
    -------
    x, y : ndarray, shape (...)
        Normalised camera coordinates (dimensionless).
    """
    cam = _check_rig(rig).camera
    uv = as_array(pixels, name, ("...", 2))
    if cam.has_distortion:
        xn = cam.normalized(uv)
        return xn[..., 0], xn[..., 1]
    return (uv[..., 0] - cam.cx) / cam.fx, (uv[..., 1] - cam.cy) / cam.fy


def ideal_pixels(rig: Rig, pixels) -> np.ndarray:
    """Undistorted ("ideal") pixels ``K (x, y, 1)`` of image pixels ``(..., 2)``.

    Identity for a camera without distortion. The conics of :mod:`.epipolar` and the
    residuals of :func:`.reconstruct.refine` live in these coordinates.
    """
    cam = _check_rig(rig).camera
    x, y = normalized_coordinates(rig, pixels)
    return np.stack([cam.fx * x + cam.cx, cam.fy * y + cam.cy], -1)


# --------------------------------------------------------------------------- forward
@dataclass(frozen=True, eq=False)
class PixelProjection:
    """Pixels of camera-frame points.

    Attributes
    ----------
    pixels : ndarray, shape (..., 2)
        ``(u, v)`` image pixels (with the camera's distortion); NaN behind the camera.
    in_front : ndarray of bool, shape (...)
        ``Z > 0``.
    in_image : ndarray of bool, shape (...)
        In front and inside the image.
    """

    pixels: np.ndarray
    in_front: np.ndarray
    in_image: np.ndarray


@dataclass(frozen=True, eq=False)
class RigProjection:
    """What both sensors of a rig measure of camera-frame points.

    Attributes
    ----------
    pixels : ndarray, shape (..., 2)
        Image pixels; NaN behind the camera.
    ranges, azimuths, elevations : ndarray, shape (...)
        Sonar measurements (m, rad, rad); given for every point (NaN only at the sonar's centre).
    in_front, in_image : ndarray of bool, shape (...)
        Camera masks (see :class:`PixelProjection`).
    in_fan : ndarray of bool, shape (...)
        Inside the sonar's azimuth and elevation apertures and range window (the rig's
        ``sonar``; no limits but ``|theta| <= pi/2`` without one).
    """

    pixels: np.ndarray
    ranges: np.ndarray
    azimuths: np.ndarray
    elevations: np.ndarray
    in_front: np.ndarray
    in_image: np.ndarray
    in_fan: np.ndarray

    @property
    def visible(self) -> np.ndarray:
        """Seen by both sensors: ``in_image & in_fan``, shape (...)."""
        return self.in_image & self.in_fan


def to_pixels(rig: Rig, points_camera) -> PixelProjection:
    """Project camera-frame points into the image.

    Parameters
    ----------
    rig : Rig
    points_camera : array_like, shape (3,) or (..., 3)
        Points in the camera frame (m). NaN entries give NaN pixels.

    Returns
    -------
    PixelProjection
    """
    cam = _check_rig(rig).camera
    p = as_array(points_camera, "points_camera", ("...", 3), finite=False)
    uv = cam.project(p)
    uv[~np.isfinite(p).all(-1)] = np.nan  # a point with any NaN coordinate has no pixel (as documented)
    with np.errstate(invalid="ignore"):
        front = p[..., 2] > 0
    return PixelProjection(uv, front, front & cam.in_image(uv))


def to_sonar(rig: Rig, points_camera) -> SonarProjection:
    """Sonar measurements of camera-frame points, with the rig's sonar fan as mask.

    Parameters
    ----------
    rig : Rig
    points_camera : array_like, shape (3,) or (..., 3)
        Points in the camera frame (m).

    Returns
    -------
    SonarProjection
        ``ranges`` (m), ``azimuths``, ``elevations`` (rad) and ``in_fan``, shape (...).
    """
    p_s = _check_rig(rig).sonar_from_camera(points_camera)
    return project_to_sonar(p_s, **_sonar_window(rig))


def project(rig: Rig, points_camera) -> RigProjection:
    """Pixels and sonar measurements of camera-frame points, with visibility masks.

    Parameters
    ----------
    rig : Rig
    points_camera : array_like, shape (3,) or (..., 3)
        Points in the camera frame (m).

    Returns
    -------
    RigProjection
    """
    pix = to_pixels(rig, points_camera)
    son = to_sonar(rig, points_camera)
    return RigProjection(pix.pixels, son.ranges, son.azimuths, son.elevations, pix.in_front, pix.in_image, son.in_fan)


# --------------------------------------------------------------------------- backward
def camera_from_pixels(rig: Rig, pixels, depths) -> np.ndarray:
    """Back-project pixels with known depths: ``P_o = Z (x, y, 1)``.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Image pixels.
    depths : array_like, shape broadcastable with ``pixels[..., 0]``
        Camera-frame ``Z`` (m), > 0 for points in front of the camera.

    Returns
    -------
    ndarray, shape (..., 3)
        Camera-frame points (m).
    """
    x, y = normalized_coordinates(rig, pixels)
    z = as_array(depths, "depths")
    x, z, y = _bc(("pixels", x), ("depths", z), ("pixels", y))
    return np.stack([z * x, z * y, z], -1)


def _bc(*named):
    try:
        return np.broadcast_arrays(*(a for _, a in named))
    except ValueError:
        shapes = ", ".join(f"{n}{np.shape(a)}" for n, a in named)
        raise ValueError(f"shapes do not broadcast together: {shapes}") from None


def camera_from_sonar(rig: Rig, ranges, azimuths, elevations) -> np.ndarray:
    """Back-project sonar measurements: ``P_o = R^T (P_s(r, theta, phi) - t)``.

    Parameters
    ----------
    rig : Rig
    ranges, azimuths, elevations : array_like, broadcastable
        Range (m), azimuth and elevation (rad) in the sonar frame.

    Returns
    -------
    ndarray, shape broadcast + (3,)
        Camera-frame points (m).
    """
    r = as_array(ranges, "ranges")
    th = as_array(azimuths, "azimuths")
    ph = as_array(elevations, "elevations")
    r, th, ph = _bc(("ranges", r), ("azimuths", th), ("elevations", ph))
    return _check_rig(rig).camera_from_sonar(sonar_from_spherical(r, th, ph))


@dataclass(frozen=True, eq=False)
class PixelRays:
    """Viewing rays of pixels expressed in the sonar frame: ``P_s(Z) = origin + Z * directions``.

    Attributes
    ----------
    origin : ndarray, shape (3,)
        The camera centre in the sonar frame (m), ``t``.
    directions : ndarray, shape (..., 3)
        ``R (x, y, 1)``: scaled so that the parameter ``Z`` is the camera-frame depth (m).
    """

    origin: np.ndarray
    directions: np.ndarray

    @property
    def unit_directions(self) -> np.ndarray:
        """Unit viewing directions in the sonar frame, shape (..., 3)."""
        return self.directions / np.linalg.norm(self.directions, axis=-1, keepdims=True)

    def at_depth(self, depths) -> np.ndarray:
        """Sonar-frame points at camera depths ``Z`` (m), shape broadcast + (3,)."""
        z = np.asarray(depths, float)
        return self.origin + z[..., None] * self.directions


def pixel_rays_in_sonar(rig: Rig, pixels) -> PixelRays:
    """The viewing rays of pixels in the sonar frame.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (..., 2)
        Image pixels.

    Returns
    -------
    PixelRays
        ``origin = t`` and ``directions = R (x, y, 1)``, shape (..., 3).
    """
    x, y = normalized_coordinates(rig, pixels)
    q = np.stack([x, y, np.ones_like(x)], -1)
    return PixelRays(np.array(rig.t), q @ rig.R.T)
