"""The analytic echo of a flat seabed ``z = 0`` seen by a sonar at height ``h``, pitched and rolled.

The sonar's body-to-world rotation is ``R = rot_x(-pitch) @ rot_y(roll)`` (pitch > 0
looks down, roll > 0 dips the starboard side); the world's up axis in the sonar frame is
``n = R^T e_z``. A beam at azimuth ``theta`` meets the seabed at range ``r`` at the
elevation ``phi`` solving

    cos(phi) A + sin(phi) B = -h / r,   A = n_x sin(theta) + n_y cos(theta),  B = n_z,

i.e. ``phi = beta +- arccos(-h / (r S))`` with ``S = hypot(A, B)``, ``beta = atan2(B, A)``.
The Lambertian echo per metre of range of that beam (the simulator's unit, ideal TVG) is

    E(r) = sum over roots  W(phi) rho cos(alpha) |dphi/dr|,
    cos(alpha) = h / r,  |dphi/dr| = h / (r^2 S |sin(phi - beta)|),

``W = F^4`` the two-way elevation pattern (docs/physics.md, "Fitting a sensor profile").
"""

from __future__ import annotations

import numpy as np

from ..frames import Pose, rot_x, rot_y

__all__ = ["seabed_rotation", "seabed_pose", "flat_seabed_echo"]


def seabed_rotation(pitch: float, roll: float) -> np.ndarray:
    """Body-to-world rotation of a sonar pitched down by ``pitch`` and rolled by ``roll`` (rad)."""
    return rot_x(-float(pitch)) @ rot_y(float(roll))


def seabed_pose(height: float, pitch: float, roll: float) -> Pose:
    """The sonar's pose at ``(0, 0, height)`` over the seabed ``z = 0``, looking along +Y."""
    return Pose(seabed_rotation(pitch, roll), np.array([0.0, 0.0, float(height)]))


def flat_seabed_echo(ranges, azimuths, height: float, pitch: float, roll: float, pattern,
                     reflectivity: float = 1.0, max_elevation: float | None = None) -> np.ndarray:
    """Noise-free echo per metre of range ``(n_bins, n_beams)`` of the seabed, ideal TVG.

    Parameters
    ----------
    ranges : (n_bins,) m;  azimuths : (n_beams,) rad
    height, pitch, roll : the sonar's height (m) and attitude (rad)
    pattern : BeamPattern
        One-way elevation pattern; the echo is weighted by its two-way power ``F^4``.
    max_elevation : float, optional
        Ignore returns beyond this elevation (rad); default the pattern's second null.
    """
    r = np.asarray(ranges, float)[:, None]
    th = np.asarray(azimuths, float)[None, :]
    n = seabed_rotation(pitch, roll).T @ np.array([0.0, 0.0, 1.0])
    A = n[0] * np.sin(th) + n[1] * np.cos(th)
    B = n[2]
    S = np.hypot(A, B)
    beta = np.arctan2(B, A)
    lim = pattern.null_angle(2) if max_elevation is None else max_elevation
    with np.errstate(invalid="ignore", divide="ignore"):
        c = -height / (r * S)
        ok = np.abs(c) < 1.0
        gam = np.arccos(np.clip(c, -1.0, 1.0))
        out = np.zeros(np.broadcast(r, th).shape)
        for sign in (1.0, -1.0):
            phi = beta + sign * gam
            phi = (phi + np.pi) % (2 * np.pi) - np.pi
            sin_term = np.abs(np.sin(gam))
            dphi = height / (r * r * S * np.maximum(sin_term, 1e-9))
            w = np.where(ok & (np.abs(phi) <= lim), pattern.two_way(phi), 0.0)
            out += w * reflectivity * (height / r) * dphi
    return out
