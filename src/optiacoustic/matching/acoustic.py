"""What the sonar image says about elevation: the seabed plane and the acoustic shadows.

A sonar measures range and azimuth, not elevation. Two things in its image do constrain
elevation, and both survive the change of modality because they are geometry:

* **The seabed.** Where the seabed enters the fan (the echo onset of each beam) it meets
  the lower edge of the elevation aperture; where it leaves it (the seabed echo's far end,
  :func:`far_edges`), the upper edge. The onsets of all beams, placed at elevation
  ``-fov_elevation / 2``, and the far edges, at ``+fov_elevation / 2``, are points of the
  seabed plane: a robust plane fit gives the seabed in the sonar frame, hence the seabed's
  elevation at every ``(r, theta)``. (The onsets alone lie on one cone and leave the plane's
  tilt towards the sonar loose: round i15n, docs/matching.md.)
* **Shadows.** Behind an object that stands on the seabed the beam is dark until the ray
  that grazes the object's top reaches the seabed. That ray's elevation is the seabed's
  elevation at the end of the shadow, so an echo at range ``r`` just in front of the
  shadow comes from an elevation between the seabed's at ``r`` and the grazing ray's.
  A bright return with no shadow behind it lies on (or barely above) the seabed.

:func:`elevation_bounds` gives, for each sonar feature, the elevation interval these allow.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from .._validate import as_array, as_positive
from ..frames import sonar_from_spherical
from ..geometry.projection import cos_sin_roots

__all__ = ["SeabedPlane", "fit_seabed", "far_edges", "moved_plane", "plane_error_probability", "seabed_elevation", "seabed_points", "elevation_maps", "elevation_bounds", "occluded", "seabed_view"]


def check_fov_elevation(value, name: str = "fov_elevation") -> float:
    """An elevation aperture (rad) finite in (0, pi); else a ValueError naming ``name`` (with a hint when the
    value looks like degrees)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected an elevation aperture in radians, got {value!r}") from None
    if not (np.isfinite(v) and 0 < v < np.pi):
        hint = (f" (degrees? np.deg2rad({v:g}) = {np.deg2rad(v):.4g} rad)" if np.isfinite(v) and v >= np.pi
                and v < 180 else "")
        raise ValueError(f"{name}: expected an elevation aperture in radians, finite and in (0, pi), got {v!r}{hint}")
    return v


def check_sigma(name: str, value) -> float:
    """``value`` as a float when it is a finite number >= 0 (a standard deviation); else a ValueError naming
    ``name`` (a field, an argument or a command-line flag)."""
    if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value >= 0):
        raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
    return float(value)


@dataclass(frozen=True, eq=False)
class SeabedPlane:
    """The plane ``normal . P_s = offset`` of the seabed in the sonar frame (unit normal, pointing up).

    "Up" is the world's up, towards the water: the side of the plane the sonar is on, so that
    :meth:`height` is positive in the water (``offset < 0``). It is not re-oriented here (a sonar
    mounted upside down has a normal with a negative sonar-frame z); :func:`.match.match` refuses a
    ``seabed=`` with the sonar under it (``offset >= 0``: most often the normal given pointing down,
    ``(-n, -d)``). A normal of the wrong shape, not finite, or not of unit length (which offset was
    meant would be a guess) is refused with a ValueError naming ``SeabedPlane.normal``; so is a
    non-finite ``offset``. The all-NaN normal is the falsy "no plane" (with its ``message``).

    Attributes
    ----------
    normal : ndarray, shape (3,)
    offset : float
        (m); the sonar's height above the seabed is ``-offset``.
    rms : float
        Residual of the fit (m).
    n_beams : int
        Beams whose onset supported the fit.
    message : str
        Why no plane was found (the object is then falsy).
    flat_rms : float
        (m) What ``rms`` is for a flat seabed: the onsets' placement within their range bin (about
        uniform, so the median absolute height residual is a quarter of a bin times ``|n . d|`` along the
        near edge's rays). NaN for a plane not fitted to a sonar image.
    sigma_offset : float
        (m) Standard deviation of ``offset`` declared by whoever gave the plane (a navigation plane:
        the altimeter's or DVL's error); 0 for a fitted plane, whose own error the matcher's scores
        were calibrated with.
    sigma_tilt : float
        (rad) Standard deviation of the normal's tilt about each horizontal axis (the attitude's
        roll and pitch error), pivoting about the sonar; 0 likewise.
    """

    normal: np.ndarray
    offset: float
    rms: float
    n_beams: int
    message: str = ""
    flat_rms: float = float("nan")
    sigma_offset: float = 0.0
    sigma_tilt: float = 0.0

    def __post_init__(self):
        for name in ("sigma_offset", "sigma_tilt"):
            check_sigma(f"SeabedPlane.{name}", getattr(self, name))
        n = as_array(self.normal, "SeabedPlane.normal", (3,), finite=False)
        if np.all(np.isnan(n)):  # "no plane" (falsy)
            object.__setattr__(self, "normal", n)
            return
        if not np.all(np.isfinite(n)):
            raise ValueError(f"SeabedPlane.normal: the seabed's normal must be finite, got {n.tolist()}")
        norm = float(np.linalg.norm(n))
        if abs(norm - 1.0) > 1e-6:
            raise ValueError(f"SeabedPlane.normal: the seabed's normal must be a unit vector, got {n.tolist()} "
                             f"(length {norm:.6g}); divide both the normal and the offset by its length")
        try:
            d = float(self.offset)
        except (TypeError, ValueError):
            raise ValueError(f"SeabedPlane.offset: expected a number (m), got {self.offset!r}") from None
        if not np.isfinite(d):
            raise ValueError(f"SeabedPlane.offset: the seabed's offset must be finite, got {d!r}")
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "offset", d)

    @property
    def uncertain(self) -> bool:
        """Whether the plane comes with a declared error (``sigma_offset`` or ``sigma_tilt`` above 0)."""
        return self.sigma_offset > 0 or self.sigma_tilt > 0

    def offset_sigma_at(self, points_sonar) -> np.ndarray:
        """(m) Standard deviation of the plane's height at sonar-frame points ``(..., 3)`` from the declared
        errors: ``sqrt(sigma_offset^2 + sigma_tilt^2 |P_par|^2)``, ``P_par`` the point's component along the
        plane (a tilt ``eps`` about a horizontal axis ``a`` moves the normal by ``eps a x n``, and the height
        of ``P`` by ``eps (a x n) . P``, whose variance over both axes is ``sigma_tilt^2 |P_par|^2``)."""
        P = np.asarray(points_sonar, float)
        par = P - (P @ self.normal)[..., None] * self.normal
        return np.sqrt(self.sigma_offset ** 2 + self.sigma_tilt ** 2 * np.einsum("...i,...i->...", par, par))

    def __bool__(self) -> bool:
        return bool(np.all(np.isfinite(self.normal)))

    @property
    def relief_ratio(self) -> float:
        """``rms / flat_rms``: about 1 on a flat seabed (0.9-1.2 on 52 seeded flat scenes), more where the
        seabed has relief (1.6-3.7 at 1 cm RMS) or objects break the near edge; NaN when unknown."""
        return float(self.rms / self.flat_rms) if self.flat_rms > 0 else float("nan")

    @property
    def relief_sigma(self) -> float:
        """(m) The seabed's height spread about the plane that the fit's residual implies beyond a flat
        seabed's: ``sqrt(rms^2 - flat_rms^2) / 0.6745`` (``rms`` and ``flat_rms`` are median absolute
        residuals, and a normal height's is 0.6745 of its standard deviation; the flat part, the onsets'
        placement in their bins, adds in quadrature). On relief_scene's heightfields of 1 and 2 cm RMS it
        gave 0.6-1.6 and 0.7-2.7 cm (12 scenes each). 0 where the residual is no more than a flat
        seabed's; NaN when ``flat_rms`` is unknown."""
        if not self.flat_rms > 0:
            return float("nan")
        return float(np.sqrt(max(self.rms ** 2 - self.flat_rms ** 2, 0.0)) / 0.6745)

    def height(self, points_sonar) -> np.ndarray:
        """Signed height (m) of sonar-frame points ``(..., 3)`` above the plane."""
        return np.asarray(points_sonar, float) @ self.normal - self.offset

    @classmethod
    def from_pose(cls, sonar_pose, seabed_z: float = 0.0, *, sigma_height: float = 0.0,
                  sigma_tilt: float = 0.0) -> "SeabedPlane":
        """The horizontal seabed ``z_world = seabed_z`` in the sonar frame, from the sonar's pose in the world.

        What a vehicle's navigation gives: attitude (roll, pitch, heading; only roll and pitch matter)
        and altitude above the seabed (``sonar_pose.t[2] - seabed_z``, the altimeter's or DVL's
        range corrected for the sonar's mounting). With ``P_world = R P_sonar + t``, the plane
        ``e_z . P_world = seabed_z`` is ``(R^T e_z) . P_sonar = seabed_z - t_z``.

        Parameters
        ----------
        sonar_pose : Pose
            The sonar's pose (``.R``, ``.t``: ``P_world = R P_sonar + t``, world z up).
        seabed_z : float
            The seabed's height in the world (m).
        sigma_height : float
            (m) Standard deviation of the altitude (``sigma_offset``). The matcher needs the plane to
            about a centimetre: with more, the seabed points it places on the plane are wrong more
            often, and it lowers their scores by that chance (:func:`plane_error_probability`).
        sigma_tilt : float
            (rad) Standard deviation of roll and pitch (``sigma_tilt``).
        """
        R = np.asarray(getattr(sonar_pose, "R", None), float)
        t = np.asarray(getattr(sonar_pose, "t", None), float)
        if R.shape != (3, 3) or t.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise ValueError(f"sonar_pose: expected a Pose (R (3, 3), t (3,), finite), got {type(sonar_pose).__name__}")
        if not np.isfinite(seabed_z):
            raise ValueError(f"seabed_z: expected a finite height (m), got {seabed_z!r}")
        sigma_height, sigma_tilt = check_sigma("sigma_height", sigma_height), check_sigma("sigma_tilt", sigma_tilt)
        n = R.T @ np.array([0.0, 0.0, 1.0])
        return cls(n / np.linalg.norm(n), float(seabed_z - t[2]), 0.0, 0, "",
                   sigma_offset=sigma_height, sigma_tilt=sigma_tilt)

    @classmethod
    def from_attitude(cls, altitude: float, pitch_deg: float = 0.0, roll_deg: float = 0.0, *,
                      sigma_height: float = 0.0, sigma_tilt: float = 0.0) -> "SeabedPlane":
        """The flat seabed seen from a sonar at ``altitude`` (m) above it, its boresight pitched down by
        ``pitch_deg`` and rolled by ``roll_deg`` (right side down), as a vehicle's altimeter and attitude
        sensor give them with the sonar's mounting added. The sonar's world rotation is a roll about its
        forward axis after a pitch about its right axis; the rest as :meth:`from_pose`. Straight ahead the
        boresight meets the seabed at the slant range ``altitude / sin(pitch)``."""
        from ..frames import Pose, rotation_from_euler_xyz

        for name, v in (("altitude", altitude), ("pitch_deg", pitch_deg), ("roll_deg", roll_deg)):
            if not (isinstance(v, (int, float, np.floating, np.integer)) and np.isfinite(v)):
                raise ValueError(f"{name}: expected a finite number, got {v!r}")
        if altitude <= 0:
            raise ValueError(f"altitude: the sonar must be above the seabed (m > 0), got {altitude!r}")
        R = rotation_from_euler_xyz(np.deg2rad([-float(pitch_deg), float(roll_deg), 0.0]))
        return cls.from_pose(Pose(R, np.array([0.0, 0.0, float(altitude)])), 0.0, sigma_height=sigma_height,
                             sigma_tilt=sigma_tilt)


#: Where the seabed edge lies after the centre of the first bin above the onset threshold (bins).
ONSET_OFFSET_BINS = 0.55

_NO_PLANE = dict(normal=np.full(3, np.nan), offset=np.nan, rms=np.nan)


def _smoothed(image):
    return ndi.uniform_filter(np.asarray(image, np.float64), (9, 3), mode="nearest")


def _near_edges(sm, ranges, onset_fraction):
    """Per beam, the range (m) where the seabed enters the fan at the aperture's lower edge, and whether found."""
    r = np.asarray(ranges, float)
    # The beam's typical seabed echo: its upper quartile (the lit seabed fills a good part of
    # the beam; the median may fall on the dark ranges before and after it).
    level = np.percentile(sm, 75, axis=0)
    above = sm > onset_fraction * level[None, :]
    onset = np.argmax(above, axis=0)
    # An onset at the first bins means the seabed was already in the aperture there: no edge.
    ok = above.any(0) & (onset > 3) & (onset < r.size - 3) & np.isfinite(level)
    # The first bin above the threshold is the one the edge enters: its centre lies on
    # average ONSET_OFFSET_BINS before the edge (measured on training scenes 5000-5002
    # against the true seabed: 0.55 bins, interquartile 0.3-0.85).
    dr = float(np.median(np.diff(r))) if r.size > 1 else 0.0
    return r[onset] + ONSET_OFFSET_BINS * dr, ok


def far_edges(image, ranges, *, window_bins: int = 20, n_beams: int = 5, min_step_db: float = 6.0,
              tail_bins: int = 30, refine: bool = True):
    """Per beam, the range (m) where the seabed leaves the fan at the aperture's upper edge (round i15n).

    Beyond the range where the upper edge of the elevation aperture meets the seabed, no seabed
    echo returns: the beam drops to its noise for good. That last down-step of the log echo
    (speckle is multiplicative, so additive in the log) is found as the largest difference between
    the mean log echo over ``window_bins`` before and after a bin boundary, among boundaries after
    which the beam stays within a factor e of its last ``tail_bins``' level (the noise), and placed
    to a fraction of a bin by a parabola through that difference. Echoes are averaged over
    ``n_beams`` neighbouring beams first (the far edge is weak: a few times the noise).

    Returns
    -------
    ranges : ndarray, shape (n_beams,)
        The far edge's range (m); meaningless where not found.
    found : ndarray of bool, shape (n_beams,)
        A step of at least ``min_step_db`` was found (not where the seabed runs past the range window
        or the noise is too high; objects' shadows that run to the end give false edges, which
        :func:`fit_seabed` gates out).
    """
    r = np.asarray(ranges, float)
    sm = ndi.uniform_filter(np.asarray(image, np.float64), (1, n_beams), mode="nearest")
    n, J = sm.shape
    M = int(window_bins)
    if n < 2 * M + 3:
        return np.full(J, np.nan), np.zeros(J, bool)
    dr = float(np.median(np.diff(r)))
    log_e = np.log(np.maximum(sm, 1e-30))
    floor = np.log(np.maximum(np.median(sm[-tail_bins:], axis=0), 1e-30))
    c = np.vstack([np.zeros(J), np.cumsum(log_e, axis=0)])
    k = np.arange(M, n - M + 1)  # boundary between bins k - 1 and k
    before = (c[k] - c[k - M]) / M
    after = (c[k + M] - c[k]) / M
    stays_dark = np.maximum.accumulate(after[::-1], axis=0)[::-1] < floor[None, :] + 1.0
    step = before - after
    cand = (step > min_step_db / 10.0 * np.log(10.0)) & stays_dark
    i = np.argmax(np.where(cand, step, -np.inf), axis=0)
    i0 = np.clip(i, 1, k.size - 2)
    jj = np.arange(J)
    y0, y1, y2 = step[i0 - 1, jj], step[i0, jj], step[i0 + 1, jj]
    den = y0 - 2.0 * y1 + y2
    safe = np.where(den < 0, den, -1.0)
    d = np.clip(np.where(den < 0, 0.5 * (y0 - y2) / safe, 0.0), -1.0, 1.0)
    edge = r[0] + (k[i0] + d - 0.5) * dr
    found = cand.any(0) & (i > 0) & (i < k.size - 1)
    if refine:
        edge = _refine_far_edge(sm, r, edge)
    return edge, found


def _refine_far_edge(sm, r, edge, *, pre: int = 4, post: int = 4, level_bins: int = 12):
    """The far edge to a fraction of a bin in the linear echo: the lit share of the bins around it.

    In the log the blurred step's middle sits where the echo reaches the noise, about half a bin
    after the edge (measured against the true seabed, round i15n). In the linear echo a step from the
    seabed's level ``a`` to the noise ``b``, blurred by any filter that keeps its area, puts
    ``sum((E - b) / (a - b))`` bins of seabed in a window around it: the edge, unbiased under
    multiplicative speckle (linear in the echo).
    """
    n, J = sm.shape
    dr = float(np.median(np.diff(r)))
    jj = np.arange(J)
    kb = np.clip(np.round((edge - r[0]) / dr + 0.5).astype(int), pre + level_bins, n - post - level_bins)
    a = sm[kb[None, :] - pre - level_bins + np.arange(level_bins)[:, None], jj].mean(0)
    b = sm[kb[None, :] + post + np.arange(level_bins)[:, None], jj].mean(0)
    w = sm[kb[None, :] - pre + np.arange(pre + post)[:, None], jj]
    lit = ((w - b[None, :]) / np.maximum(a - b, 1e-30)[None, :]).sum(0)
    return r[0] + (kb - pre - 0.5) * dr + lit * dr


def _plane_ranges(p, D):
    """Range at which rays ``D`` meet the plane ``z = p0 x + p1 y + p2`` (sonar frame)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return p[2] / (D[:, 2] - p[0] * D[:, 0] - p[1] * D[:, 1])


def _fit_both_edges(p, image, r, th, ro, D_near, half, min_beams, far_gate_m):
    """Refit the plane ``z = p0 x + p1 y + p2`` to the onsets ``(ro, to)`` and the far edges together.

    ``D_near``: the onsets' ray directions (unit, at the aperture's lower edge).
    Residuals in range along each ray (near and far edges alike) with a Cauchy loss: the onsets
    of objects and the far edges that are the end of an object's shadow weigh little. The onsets'
    plane is refitted so first (the z-fit's soft loss lets objects' onsets drag it along the loose
    tilt: 8.5 deg off on varied scene 8022, round i15n), then the far edges within ``far_gate_m`` of
    where it puts them join.
    """
    from scipy.optimize import least_squares

    p = least_squares(lambda q: ro - _plane_ranges(q, D_near), p, loss="cauchy", f_scale=0.05).x
    r_far, found = far_edges(image, r)
    D_far = sonar_from_spherical(1.0, th, half)
    expected = _plane_ranges(p, D_far)
    use = found & np.isfinite(expected) & (expected > 0) & (np.abs(r_far - expected) < far_gate_m)
    if use.sum() < min_beams:
        return p
    D = np.concatenate([D_near, D_far[use]])
    r_obs = np.concatenate([ro, r_far[use]])
    return least_squares(lambda q: r_obs - _plane_ranges(q, D), p, loss="cauchy", f_scale=0.05).x


def fit_seabed(image, ranges, azimuths, fov_elevation: float, *, min_beams: int = 20,
               onset_fraction: float = 0.3, far_edge: bool = True, far_gate_m: float = 1.5) -> SeabedPlane:
    """Fit the seabed plane to where the seabed enters and leaves the beams (robust, ``scipy.optimize.least_squares``).

    Parameters
    ----------
    image : array_like, shape (n_bins, n_beams)
        Linear intensity.
    ranges, azimuths : array_like
        Bin centres (m), beam centres (rad).
    fov_elevation : float
        Elevation aperture (rad).
    min_beams : int
        Fewer onsets than this: no plane (at least 3).
    onset_fraction : float
        The onset is the first bin above this fraction of the beam's typical seabed echo: its upper
        quartile (75th percentile) after smoothing across three beams.
    far_edge : bool
        Also use where the seabed leaves the fan at the aperture's upper edge (:func:`far_edges`;
        round i15n). The onsets alone lie on one cone (elevation ``-fov_elevation / 2``), which
        leaves the plane's tilt towards the sonar poorly fixed: an onset error of 0.1 bin growing
        from the middle beams to the outer ones tilts it by 0.1 deg. The far edges, on the other
        cone, fix it. The onsets' plane is refitted then in range with a Cauchy loss
        (``far_edge=False`` keeps round i15k's plane).
    far_gate_m : float
        Far edges more than this (m) from where the onsets' plane puts them are not used
        (shadows that run past the lit seabed).

    Returns
    -------
    SeabedPlane
        Falsy with a message when the onsets do not support a plane (no seabed in view, the
        seabed already inside the aperture at the nearest range, or a poor fit).

    Raises
    ------
    ValueError
        Naming the argument: an image not of shape ``(ranges.size, azimuths.size)`` or not finite,
        ranges or azimuths not finite and strictly increasing, ``fov_elevation`` not in (0, pi) rad,
        ``min_beams`` below 3, ``onset_fraction`` or ``far_gate_m`` not > 0.
    """
    from scipy.optimize import least_squares

    from .sonar_features import check_axes, check_count

    r, th = check_axes(ranges, azimuths)
    img = as_array(image, "image", (r.size, th.size), dtype=np.float64)
    fov_elevation = check_fov_elevation(fov_elevation)
    min_beams = check_count("min_beams", min_beams, 3)
    as_positive(onset_fraction, "onset_fraction")
    as_positive(far_gate_m, "far_gate_m")
    image = img
    # No smoothing along range (a window crosses the threshold before the step), three beams
    # across against speckle.
    sm = ndi.uniform_filter(img, (1, 3), mode="nearest")
    r_near, ok = _near_edges(sm, r, onset_fraction)
    if ok.sum() < min_beams:
        return SeabedPlane(**_NO_PLANE, n_beams=int(ok.sum()),
                           message=f"seabed: only {int(ok.sum())} beams show an echo onset (need {min_beams})")
    half = fov_elevation / 2
    ro, to = r_near[ok], th[ok]
    D_near = np.atleast_2d(sonar_from_spherical(1.0, to, -half))  # the onsets' rays, at the lower edge
    P = ro[:, None] * D_near

    # z = a x + b y + c, robust to onsets that are objects rather than seabed.
    def res(p):
        return P[:, 2] - (p[0] * P[:, 0] + p[1] * P[:, 1] + p[2])

    p = least_squares(res, np.array([0.0, 0.0, float(np.median(P[:, 2]))]), loss="soft_l1", f_scale=0.05).x
    if far_edge:
        p = _fit_both_edges(p, image, r, th, ro, D_near, half, min_beams, far_gate_m)
    a, b, c = p
    n = np.array([-a, -b, 1.0])
    norm = np.linalg.norm(n)
    resid = res(p) / norm
    rms = float(np.sqrt(np.median(resid ** 2)))
    if not np.isfinite(rms) or rms > 0.15:
        return SeabedPlane(**_NO_PLANE, n_beams=int(ok.sum()), message=f"seabed: onsets do not lie on a plane "
                           f"(median residual {rms:.2f} m)")
    dr = float(np.median(np.diff(r))) if r.size > 1 else float("nan")
    flat_rms = dr / 4.0 * float(np.median(np.abs(D_near @ (n / norm))))
    return SeabedPlane(n / norm, float(c / norm), rms, int(ok.sum()), flat_rms=flat_rms)


def moved_plane(rig, plane: SeabedPlane, R_o, t_o) -> SeabedPlane:
    """The seabed plane of view 1 in the sonar frame of view 2, after the rig moved by ``(R_o, t_o)``.

    ``P_camera2 = R_o P_camera1 + t_o`` and ``P_sonar = R P_camera + t`` (the rig) give
    ``P_sonar2 = M P_sonar1 + u`` with ``M = R R_o R^T``, ``u = t + R t_o - M t``; the plane
    ``n . P_sonar1 = d`` becomes ``(M n) . P_sonar2 = d + (M n) . u``.
    """
    R, t = np.asarray(rig.R, float), np.asarray(rig.t, float)
    M = R @ np.asarray(R_o, float) @ R.T
    u = t + R @ np.asarray(t_o, float) - M @ t
    n2 = M @ plane.normal
    # the declared errors carried over as they are (the tilt's pivot then sits at the second sonar: over
    # the decimetres a rig moves between views, a difference of sigma_tilt x the move)
    return SeabedPlane(n2, float(plane.offset + n2 @ u), plane.rms, plane.n_beams, plane.message,
                       sigma_offset=plane.sigma_offset, sigma_tilt=plane.sigma_tilt)


def seabed_elevation(plane: SeabedPlane, ranges, azimuths) -> np.ndarray:
    """Elevation (rad) at which the arc ``(r, theta)`` meets the seabed; NaN where it does not.

    Of the two crossings the one nearer to the horizontal (``|phi| < pi/2``, below the
    sonar's horizon for a sonar above the seabed) is returned. A range that is not finite
    and > 0 has no arc: NaN there too.
    """
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    r = np.where(np.isfinite(r) & (r > 0), r, np.nan)
    n = plane.normal
    a = n[0] * np.sin(th) + n[1] * np.cos(th)
    with np.errstate(invalid="ignore", divide="ignore"):
        roots = cos_sin_roots(a, n[2], plane.offset / r)
    good = np.abs(roots) < np.pi / 2
    return np.where(good[0], roots[0], np.where(good[1], roots[1], np.nan))


def seabed_points(rig, plane: SeabedPlane, ranges, azimuths, fov_elevation: float):
    """Where each feature's arc meets the seabed plane, in the camera image (the *seabed point*).

    An echo with no shadow behind it comes from the seabed itself (or from something barely above
    it), so its point is the arc ``r (cos phi sin theta, cos phi cos theta, sin phi)`` at the
    seabed's elevation :func:`seabed_elevation`. Closed form, vectorised over features.

    Parameters
    ----------
    rig : Rig
        With the sonar attached.
    plane : SeabedPlane
        The seabed in the sonar frame (:func:`fit_seabed`).
    ranges, azimuths : array_like, shape (N,)
        Sonar features (m, rad).
    fov_elevation : float
        The sonar's elevation aperture (rad): a point outside it is not found.

    Returns
    -------
    elevations : ndarray, shape (N,)
        Sonar-frame elevation (rad); NaN where not found.
    pixels : ndarray, shape (N, 2)
        Camera pixels ``(u, v)``; NaN where not found.
    found : ndarray of bool, shape (N,)
        The arc meets the seabed inside the aperture, in front of the camera and inside its image.
    """
    r = np.asarray(ranges, float).reshape(-1)
    th = np.asarray(azimuths, float).reshape(-1)
    if r.size != th.size:
        raise ValueError(f"seabed_points: ranges and azimuths must have one length, got {r.size} and {th.size}")
    N = r.size
    if N == 0 or not plane:
        return np.full(N, np.nan), np.full((N, 2), np.nan), np.zeros(N, bool)
    phi = seabed_elevation(plane, r, th)
    ok = np.isfinite(phi) & (np.abs(np.nan_to_num(phi, nan=np.inf)) <= fov_elevation / 2)
    Pc = rig.camera_from_sonar(sonar_from_spherical(r, th, np.nan_to_num(phi)))
    px = rig.camera.project(Pc)
    found = ok & (Pc[:, 2] > 0) & rig.camera.in_image(px)
    return np.where(found, phi, np.nan), np.where(found[:, None], px, np.nan), found


def plane_error_probability(rig, plane: SeabedPlane, points_sonar, bin_width: float, beam_width: float) -> np.ndarray:
    """Probability that the plane's declared error keeps a point placed on it a right match (``(N,)``).

    A seabed point ``P`` (sonar frame, on the plane ``n . P = d``) is matched to the pixel that sees
    it. If the true seabed lies ``delta`` higher there, that pixel's ray ``C + s (P - C)`` (``C`` the
    camera centre, ``rig.t``) meets it at ``Q = P + delta (P - C) / (n . (P - C))``, whose range
    and azimuth differ from ``P``'s by ``delta g_r`` and ``delta g_theta`` to first order, with
    ``g_r = rhat . v / (n . v)``, ``g_theta = (P_y v_x - P_x v_y) / ((P_x^2 + P_y^2) (n . v))`` and
    ``v = P - C`` (docs/derivations.md, "A seabed point under an uncertain plane"). The match stays
    right (``matching.truth.correct``: within one bin and one beam) while ``|delta| <= tau``,
    ``tau = min(bin / |g_r|, beam / |g_theta|)``; with ``delta ~ N(0, s^2)``, ``s`` the plane's
    height error at ``P`` (:meth:`SeabedPlane.offset_sigma_at`), that is ``erf(tau / (sqrt(2) s))``.
    1 where the plane declares no error; 0 where ``n . v`` is 0 (the pixel's ray along the plane).
    At grazing views ``|g_r|`` is 3-5, so an altitude known to 1 cm leaves a seabed point right only
    about half the time at 2.5 cm bins.
    """
    from scipy.special import erf

    P = np.asarray(points_sonar, float).reshape(-1, 3)
    if not plane.uncertain:
        return np.ones(len(P))
    v = P - np.asarray(rig.t, float)
    nv = v @ plane.normal
    r = np.linalg.norm(P, axis=1)
    rho2 = P[:, 0] ** 2 + P[:, 1] ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        g_r = np.einsum("ij,ij->i", P, v) / (r * nv)
        g_t = (P[:, 1] * v[:, 0] - P[:, 0] * v[:, 1]) / (rho2 * nv)
        tau = np.minimum(bin_width / np.abs(g_r), beam_width / np.abs(g_t))
        s = plane.offset_sigma_at(P)
        p = erf(tau / (np.sqrt(2.0) * s))
    return np.where(np.isfinite(p), p, np.where(nv == 0, 0.0, 1.0))


def _seabed_level(sm):
    """The seabed's echo level per range (median over beams), and where the seabed is lit at all."""
    level = ndi.uniform_filter1d(np.median(sm, axis=1), 15, mode="nearest")
    floor = max(float(np.min(level)), 1e-30)
    return level, level > 10.0 * floor


def _next_index(mask):
    """For every cell, the row of the next True cell at or below it in its column (``n_rows`` if none)."""
    n = mask.shape[0]
    idx = np.where(mask, np.arange(n)[:, None], n)
    return np.minimum.accumulate(idx[::-1], axis=0)[::-1]


def elevation_maps(image, ranges, azimuths, plane: SeabedPlane, fov_elevation: float, *,
                   dark_fraction: float = 0.2, min_shadow_bins: int = 6, search_m: float = 1.0, cells=None):
    """Elevation interval ``[low, high]`` (rad) of an echo in every cell, from the seabed and the shadows.

    Parameters
    ----------
    image : array_like, shape (n_bins, n_beams)
    ranges, azimuths : array_like
        Bin and beam centres (m, rad).
    plane : SeabedPlane
        Without a plane, the interval is the aperture.
    fov_elevation : float
    dark_fraction : float
        A shadow cell is below this fraction of the seabed's echo level at its range.
    min_shadow_bins : int
        Shortest run of dark cells taken for a shadow.
    search_m : float
        How far beyond the cell (m) the shadow may start.
    cells : array_like of bool, shape (n_bins, n_beams), optional
        Compute the interval only there (the rest keeps the aperture): the elevations are
        the costly part.

    Returns
    -------
    low, high : ndarray, shape (n_bins, n_beams)
        ``low`` is the seabed's elevation at the cell's range; ``high`` the elevation of the
        ray grazing the end of the shadow that follows the cell, the seabed's when no shadow
        follows (an echo with no shadow behind it is on the seabed), and the aperture's top
        when the shadow runs past the lit seabed.
    shadowed : ndarray of bool, shape (n_bins, n_beams)
        A shadow follows the cell.
    """
    sm = _smoothed(image)
    n_bins, n_beams = sm.shape
    half = fov_elevation / 2
    low = np.full(sm.shape, -half)
    high = np.full(sm.shape, half)
    shadowed = np.zeros(sm.shape, bool)
    if not plane:
        return low, high, shadowed
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    # Echo falls with range and the noise floor rises with it, so "dark" is judged against
    # the seabed's level at each range; where the seabed is not lit there is no shadow to see.
    level, lit_range = _seabed_level(sm)
    dark = (sm < dark_fraction * level[:, None]) & lit_range[:, None]
    # Speckle and the range-amplified noise floor light isolated cells inside a shadow.
    dark = ndi.binary_closing(dark, structure=np.ones((7, 1), bool), border_value=1) & lit_range[:, None]
    unlit = np.broadcast_to(~lit_range[:, None], sm.shape)
    dr = float(np.median(np.diff(r))) if r.size > 1 else 1.0
    n_search = max(1, int(round(search_m / dr)))
    rows = np.arange(n_bins)[:, None]
    cols = np.broadcast_to(np.arange(n_beams)[None, :], sm.shape)
    # Next dark (or unlit) cell, then the first lit seabed cell after it: the shadow's end.
    start = _next_index(dark | unlit)
    lit = ~dark & ~unlit
    next_lit = _next_index(lit)
    end = next_lit[np.minimum(start, n_bins - 1), cols]
    end = np.where(start >= n_bins, n_bins, end)
    next_unlit = _next_index(unlit)
    first_unlit = next_unlit[np.minimum(start, n_bins - 1), cols]
    shadowed = (start - rows <= n_search) & (end - start >= min_shadow_bins) & (start < n_bins)
    runs_out = shadowed & (first_unlit <= end)
    sel = np.ones(sm.shape, bool) if cells is None else np.asarray(cells, bool)
    bi, ki = np.nonzero(sel)
    e = np.minimum(end[bi, ki], n_bins - 1)
    phi_end = seabed_elevation(plane, r[e], th[ki])
    phi_sb = seabed_elevation(plane, r[bi], th[ki])
    sh, ro = shadowed[bi, ki], runs_out[bi, ki]
    lo = np.where(np.isfinite(phi_sb), np.maximum(phi_sb, -half), -half)
    hi = np.where(sh & ~ro & np.isfinite(phi_end), np.minimum(phi_end, half), half)
    hi = np.where(~sh & np.isfinite(phi_sb), lo, hi)
    low[bi, ki] = lo
    high[bi, ki] = np.maximum(hi, lo)
    return low, high, shadowed


def elevation_bounds(image, ranges, azimuths, bins, beams, plane: SeabedPlane, fov_elevation: float, **kwargs):
    """:func:`elevation_maps` at the cells ``(bins, beams)`` of ``N`` features: ``low, high, shadowed``, shape (N,).

    ``bins`` and ``beams`` are integer cell indices inside the image (a ValueError naming them
    otherwise: no wrapping of negative indices, no truncation of fractional ones).
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image: expected shape (n_bins, n_beams), got {img.shape}")
    fov_elevation = check_fov_elevation(fov_elevation)
    idx = []
    for name, v, n in (("bins", bins, img.shape[0]), ("beams", beams, img.shape[1])):
        a = np.asarray(v)
        if a.dtype.kind not in "iu":
            a = as_array(a, name)
            if np.any(a != np.round(a)):
                raise ValueError(f"{name}: expected integer cell indices, got {a[a != np.round(a)][0]:g}")
        bad = (a < 0) | (a >= n)
        if np.any(bad):
            raise ValueError(f"{name}: expected indices in [0, {n - 1}] (the image has {n} {name}), "
                             f"got {int(a[bad].flat[0])}")
        idx.append(a.astype(int))
    if idx[0].shape != idx[1].shape:
        raise ValueError(f"bins and beams: expected one shape, got {idx[0].shape} and {idx[1].shape}")
    b, k = idx
    cells = np.zeros(np.shape(image), bool)
    cells[b, k] = True
    low, high, sh = elevation_maps(image, ranges, azimuths, plane, fov_elevation, cells=cells, **kwargs)
    return low[b, k], high[b, k], sh[b, k]


def occluded(rig, pixels, depths, detected, low, high, ranges, azimuths, *, margin: float = 0.5,
             tolerance: float = 0.01, n_samples: int = 48) -> np.ndarray:
    """Whether an echo the sonar sees lies on each pixel's ray before the given depth (no closer occluder).

    The ray from the camera centre to depth ``depths - margin`` (camera Z) is sampled; a
    sample occludes when its sonar cell holds a detected echo whose elevation interval
    (:func:`elevation_maps`) contains the sample's elevation. The margin spares the
    candidate's own object: its other cells along the ray lie within an object's depth.

    Parameters
    ----------
    rig : Rig
    pixels : array_like, shape (M, 2)
    depths : array_like, shape (M,)
        Camera-frame Z of the candidate points (m).
    detected, low, high : ndarray, shape (n_bins, n_beams)
        CFAR detections and their elevation intervals (rad).
    ranges, azimuths : array_like
        Bin and beam centres.
    margin : float
        Only echoes nearer than the candidate by this much (m, along the ray) count.
    tolerance : float
        Slack on the elevation intervals (rad).

    Returns
    -------
    ndarray of bool, shape (M,)
    """
    from ..frames import spherical_from_sonar
    from ..geometry.projection import pixel_rays_in_sonar

    px = np.asarray(pixels, float).reshape(-1, 2)
    z = np.asarray(depths, float).reshape(-1)
    if px.shape[0] == 0:
        return np.zeros(0, bool)
    rays = pixel_rays_in_sonar(rig, px)
    scale = np.linalg.norm(rays.directions, axis=-1)
    zmax = z - margin / scale
    f = np.linspace(0.02, 1.0, n_samples)
    zs = np.maximum(zmax, 0.0)[:, None] * f[None, :]
    Q = rays.origin + zs[..., None] * rays.directions[:, None, :]
    rq, tq, pq = spherical_from_sonar(Q)
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    dr = r[1] - r[0] if r.size > 1 else 1.0
    b = np.rint((rq - r[0]) / dr).astype(int)
    k = np.clip(np.searchsorted(th, tq), 1, th.size - 1)
    k = np.where(np.abs(th[k - 1] - tq) < np.abs(th[k] - tq), k - 1, k)
    inside = (b >= 0) & (b < r.size) & (tq >= th[0]) & (tq <= th[-1]) & (zmax[:, None] > 0)
    bb = np.clip(b, 0, r.size - 1)
    occ = inside & detected[bb, k] & (pq >= low[bb, k] - tolerance) & (pq <= high[bb, k] + tolerance)
    return occ.any(axis=1)


#: States of :func:`seabed_view`.
SEABED_UNKNOWN, SEABED_LIT, SEABED_SHADOWED = 0, 1, 2


def seabed_view(rig, plane: SeabedPlane, pixels, image, ranges, azimuths, *, dark_fraction: float = 0.2):
    """What the sonar says about the seabed point behind each camera pixel.

    Each pixel's ray meets the seabed plane at ``Q``. If the sonar's cell of ``Q`` is lit at
    the seabed's level, the sonar sees ``Q``; from a viewpoint a baseline away the camera
    sees it too, so the pixel shows the seabed at ``Q``'s depth. If the cell is dark while
    the seabed is lit at that range elsewhere, ``Q`` lies in an acoustic shadow: something
    stands between the sensors and ``Q``, and the pixel shows that occluder, nearer than ``Q``.

    Parameters
    ----------
    rig : Rig
    plane : SeabedPlane
    pixels : array_like, shape (M, 2)
    image, ranges, azimuths : the sonar image and its bin and beam centres.
    dark_fraction : float
        As in :func:`elevation_bounds`.

    Returns
    -------
    state : ndarray of int, shape (M,)
        ``SEABED_LIT`` (1), ``SEABED_SHADOWED`` (2) or ``SEABED_UNKNOWN`` (0: no plane, the ray
        misses the seabed, or ``Q`` is outside the sonar's lit seabed).
    depth : ndarray, shape (M,)
        Camera-frame Z of ``Q`` (m); NaN where the ray misses the seabed.
    """
    from ..frames import spherical_from_sonar
    from ..geometry.projection import pixel_rays_in_sonar

    px = np.asarray(pixels, float).reshape(-1, 2)
    M = len(px)
    state = np.zeros(M, int)
    depth = np.full(M, np.nan)
    if not plane or M == 0:
        return state, depth
    rays = pixel_rays_in_sonar(rig, px)
    n = plane.normal
    den = rays.directions @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (plane.offset - rays.origin @ n) / den
    hit = np.isfinite(z) & (z > 0)
    depth[hit] = z[hit]
    Q = rays.origin + np.where(hit, z, 0.0)[:, None] * rays.directions
    rq, tq, pq = spherical_from_sonar(Q)
    r = np.asarray(ranges, float)
    th = np.asarray(azimuths, float)
    sm = _smoothed(image)
    level, lit_range = _seabed_level(sm)
    inside = hit & (rq >= r[0]) & (rq <= r[-1]) & (tq >= th[0]) & (tq <= th[-1])
    b = np.clip(np.searchsorted(r, rq) , 0, r.size - 1)
    k = np.clip(np.searchsorted(th, tq), 0, th.size - 1)
    known = inside & lit_range[b]
    bright = sm[b, k] >= dark_fraction * level[b]
    state[known & bright] = SEABED_LIT
    state[known & ~bright] = SEABED_SHADOWED
    return state, depth
