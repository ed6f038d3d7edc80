"""Motion of an opti-acoustic rig from two views (thesis ch. 6), metric thanks to the sonar.

The rig moves between view 1 and view 2; the same scene point is ``P_o``, ``P'_o`` in the
camera frames and ``P_s``, ``P'_s`` in the sonar frames, with

* the rig ``P_s = R P_o + t`` (``R = R_sonar_from_camera``, ``t`` the camera centre in the
  sonar frame, known from calibration),
* the camera motion ``P'_o = R_o P_o + t_o`` (the unknown),
* the sonar motion ``P'_s = R_s P_s + t_s`` with ``R_s = R R_o R^T`` and
  ``t_s = (I - R_s) t + R t_o`` (eq. 6.5, corrected).

Optical features are matched between the two images, sonar features between the two sonar
images; the two modalities need not be matched to each other. :func:`estimate` runs:

1. the homography of the dominant plane from the optical matches (OpenCV USAC/MAGSAC);
2. its decomposition ``{R_o, t_o / d, n_o}`` (OpenCV), re-orthonormalised and filtered by
   visibility; the remaining *dual* solutions are told apart by the sonar matches, which
   only the true motion explains;
3. the scale ``d`` (the plane's distance) from a single sonar match on the plane: for each
   elevation ``phi`` of the match the plane fixes ``d``, and ``phi`` is the one that predicts
   the match in view 2 (eqs. 6.13-6.16, corrected); the match is the one most other sonar
   matches agree with;
4. maximum likelihood over all optical and sonar matches (eq. 6.17) by
   ``scipy.optimize.least_squares`` with the per-point positions on the plane eliminated
   (variable projection, :mod:`._bundle`), matches relabelled on/off the plane at every
   iteration;
5. more planes (sequential RANSAC on the matches left off the plane, :mod:`._planes`) and a
   joint maximum likelihood over all of them;

or, for non-planar scenes (``model="essential"``), the five-point essential matrix (OpenCV
USAC + ``recoverPose``), the scale from the sonar matches triangulated with the up-to-scale
motion, and the same maximum likelihood with free 3D points.

Derivations: ``docs/derivations.md (ch. 6, app. A-B)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from scipy.stats import chi2 as _chi2

from .._validate import as_array, as_azimuths, as_positive
from ..frames import orthonormalize
from ..rig import Rig
from . import _bundle as B
from ._planes import homography_sampson, sequential_ransac_plane
from .projection import cos_sin_roots
from .sonar_stereo import _closed_forms

__all__ = [
    "Plane",
    "MonocularSolution",
    "MotionStage",
    "MotionResult",
    "sonar_motion",
    "estimate",
]


# --------------------------------------------------------------------------- small types
@dataclass(frozen=True, eq=False)
class Plane:
    """A plane ``normal . P_o = distance`` in the camera frame of view 1.

    Attributes
    ----------
    normal : ndarray (3,)
        Unit normal pointing away from the camera (camera frame of view 1).
    distance : float
        Distance from the camera centre (m), > 0.
    """

    normal: np.ndarray
    distance: float

    @property
    def m(self) -> np.ndarray:
        """``normal / distance`` (1/m): the plane is ``m . P_o = 1``."""
        return self.normal / self.distance

    @classmethod
    def from_m(cls, m) -> "Plane":
        m = np.asarray(m, float)
        k = float(np.linalg.norm(m))
        return cls(m / k, 1.0 / k)

    def in_sonar(self, rig: Rig) -> tuple[np.ndarray, float]:
        """The plane in the sonar frame of view 1: ``n_s . P_s = d_s`` (eq. 6.7, corrected).

        ``n_s = R n_o`` and ``d_s = d_o + n_s . t``.
        """
        n_s = rig.R @ self.normal
        return n_s, float(self.distance + n_s @ rig.t)


@dataclass(frozen=True, eq=False)
class MonocularSolution:
    """One interpretation of the optical homography, without scale.

    Attributes
    ----------
    R_o : ndarray (3, 3)
        Camera rotation, ``P'_o = R_o P_o + t_o``.
    t_over_d : ndarray (3,)
        ``t_o / d``: translation in units of the plane's distance.
    normal : ndarray (3,)
        Plane normal (camera frame of view 1).
    """

    R_o: np.ndarray
    t_over_d: np.ndarray
    normal: np.ndarray


@dataclass(frozen=True, eq=False)
class MotionStage:
    """One estimate of the chain (``"initial"``, ``"planar"``, ``"clustered"``, ``"essential"``).

    Attributes
    ----------
    name : str
    R_o : ndarray (3, 3)
        Camera rotation.
    t_o : ndarray (3,)
        Camera translation (m), ``P'_o = R_o P_o + t_o``.
    planes : tuple of Plane
    labels_optical : ndarray of int (N_o,)
        Plane index of each optical match, -1 for outliers.
    labels_sonar : ndarray of int (M,)
        Plane index of each sonar match (0 for inliers of the essential model), -1 outliers.
    iterations : int
        Relabelling iterations of the maximum likelihood (0 for the initial estimate).
    cost : float
        Sum of the inliers' whitened squared residuals.
    points_optical : ndarray (N_o, 3)
        Every optical match triangulated with this motion (camera frame of view 1, m),
        computed on first access.
    points_sonar : ndarray (M, 3)
        Every sonar match triangulated with this motion (sonar frame of view 1, m).
    """

    name: str
    R_o: np.ndarray
    t_o: np.ndarray
    planes: tuple
    labels_optical: np.ndarray
    labels_sonar: np.ndarray
    iterations: int
    cost: float
    _triangulate: object = field(default=None, repr=False)

    @cached_property
    def _points(self):
        if self._triangulate is None:
            return np.zeros((self.labels_optical.size, 3)) * np.nan, np.zeros((self.labels_sonar.size, 3)) * np.nan
        return self._triangulate(self.R_o, self.t_o)

    @property
    def points_optical(self) -> np.ndarray:
        """Every optical match triangulated with this motion, (N_o, 3), camera frame of view 1 (m)."""
        return self._points[0]

    @property
    def points_sonar(self) -> np.ndarray:
        """Every sonar match triangulated with this motion, (M, 3), sonar frame of view 1 (m)."""
        return self._points[1]

    @property
    def n_outliers(self) -> int:
        """Matches (optical and sonar) labelled outliers."""
        return int(np.sum(self.labels_optical < 0) + np.sum(self.labels_sonar < 0))


@dataclass(frozen=True, eq=False)
class MotionResult:
    """Motion of the rig between two views.

    ``bool(result)`` is False when the data are degenerate; ``message`` says why and the
    arrays are NaN.

    Attributes
    ----------
    success : bool
    message : str
    model : str
        ``"homography"`` or ``"essential"``.
    R_o : ndarray (3, 3)
        Camera rotation, ``P'_o = R_o P_o + t_o``.
    t_o : ndarray (3,)
        Metric camera translation (m).
    planes : tuple of Plane
        The scene planes (camera frame of view 1); empty for the essential model.
    labels_optical, labels_sonar : ndarray of int
        Plane index of each match, -1 for outliers.
    covariance : ndarray (6 + 3k, 6 + 3k)
        First-order covariance of ``(w, t_o, m_1, ..., m_k)``: ``w`` (rad) the rotation error
        on the left (``R_true ~ exp(w) R_o``), ``t_o`` (m), ``m_j = n_j / d_j`` (1/m).
    stages : tuple of MotionStage
        Every estimate, first to last.
    monocular : tuple of MonocularSolution
        The visible interpretations of the optical homography (scale-free; usually two:
        the true and the dual one, which the camera alone cannot tell apart).
    scale_candidates : ndarray (M,)
        The scale (plane distance ``d``, m; ``|t_o|`` for the essential model) that each
        sonar match alone gives; NaN where it gives none.
    single_match : int
        Index of the sonar match the initial estimate uses.
    dual_support : tuple of int
        Sonar matches consistent with each monocular interpretation.
    chi2 : float
        Final cost (sum of whitened squared residuals of the inliers).
    dof : int
        Its degrees of freedom.
    rig : Rig
    ambiguous : bool
        The essential model on a (nearly) planar scene found two different motions that explain
        the matches equally well (see :func:`estimate`); the result is then falsy unless the
        homography model settled it.
    """

    success: bool
    message: str
    model: str
    R_o: np.ndarray
    t_o: np.ndarray
    planes: tuple
    labels_optical: np.ndarray
    labels_sonar: np.ndarray
    covariance: np.ndarray
    stages: tuple
    monocular: tuple
    scale_candidates: np.ndarray
    single_match: int
    dual_support: tuple
    chi2: float
    dof: int
    rig: Rig = field(repr=False)
    ambiguous: bool = False

    def __bool__(self) -> bool:
        return bool(self.success)

    def _require(self, what: str) -> None:
        # a failed estimate has no motion: say so instead of failing on its NaN internals
        if not self.success:
            raise ValueError(f"{what}: the motion estimation failed ({self.message}); there is no motion to use")

    # ------------------------------------------------------------------ views
    @property
    def inliers_optical(self) -> np.ndarray:
        return self.labels_optical >= 0

    @property
    def inliers_sonar(self) -> np.ndarray:
        return self.labels_sonar >= 0

    @property
    def R_s(self) -> np.ndarray:
        """Sonar rotation ``R R_o R^T``."""
        self._require("R_s")
        return sonar_motion(self.rig, self.R_o, self.t_o)[0]

    @property
    def t_s(self) -> np.ndarray:
        """Sonar translation ``(I - R_s) t + R t_o`` (m)."""
        self._require("t_s")
        return sonar_motion(self.rig, self.R_o, self.t_o)[1]

    @property
    def scale(self) -> float:
        """``|t_o|`` (m)."""
        return float(np.linalg.norm(self.t_o))

    @property
    def covariance_motion(self) -> np.ndarray:
        """Covariance (6, 6) of ``(w, t_o)``."""
        return self.covariance[:6, :6]

    @property
    def std_rotation(self) -> np.ndarray:
        """Standard deviations (rad) of the rotation error ``w``, (3,)."""
        return np.sqrt(np.abs(np.diag(self.covariance)[:3]))

    @property
    def std_translation(self) -> np.ndarray:
        """Standard deviations (m) of ``t_o``, (3,)."""
        return np.sqrt(np.abs(np.diag(self.covariance)[3:6]))

    def stage(self, name: str) -> MotionStage:
        """The stage called ``name``."""
        for s in self.stages:
            if s.name == name:
                return s
        raise KeyError(f"no stage {name!r}; stages are {[s.name for s in self.stages]}")

    def nees(self, R_o_true, t_o_true) -> float:
        """Normalised estimation error squared of ``(w, t_o)`` against a ground truth (6 dof)."""
        self._require("nees")
        e = np.concatenate([B.log_so3(np.asarray(R_o_true) @ self.R_o.T), np.asarray(t_o_true) - self.t_o])
        return float(e @ np.linalg.solve(self.covariance_motion, e))


def sonar_motion(rig: Rig, R_o, t_o) -> tuple[np.ndarray, np.ndarray]:
    """Sonar motion from camera motion (eq. 6.5, corrected).

    ``P'_s = R P'_o + t = R (R_o P_o + t_o) + t = R R_o R^T (P_s - t) + R t_o + t``, so
    ``R_s = R R_o R^T`` and ``t_s = (I - R_s) t + R t_o``.

    Parameters
    ----------
    rig : Rig
    R_o : array_like (3, 3)
        Camera rotation.
    t_o : array_like (3,)
        Camera translation (m).

    Returns
    -------
    R_s : ndarray (3, 3)
    t_s : ndarray (3,)
        Sonar translation (m).
    """
    R_o = as_array(R_o, "R_o", (3, 3))
    t_o = as_array(t_o, "t_o", (3,))
    R_s = rig.R @ R_o @ rig.R.T
    return R_s, (np.eye(3) - R_s) @ rig.t + rig.R @ t_o


# --------------------------------------------------------------------------- data
@dataclass
class _Data:
    rig: Rig
    K: tuple
    x1: np.ndarray  # normalised coordinates (N, 2)
    x2: np.ndarray
    u1: np.ndarray  # ideal pixels (N, 2)
    u2: np.ndarray
    r1: np.ndarray
    th1: np.ndarray
    r2: np.ndarray
    th2: np.ndarray
    sp: float
    sr: float
    sa: float
    fov: float
    min_inliers: float = 0.25

    @property
    def n_o(self) -> int:
        return self.x1.shape[0]

    @property
    def n_s(self) -> int:
        return self.r1.shape[0]

    @property
    def margin(self) -> float:
        # elevations slightly outside the aperture are accepted: noise, and beam edges
        return max(np.deg2rad(1.0), 0.1 * self.fov / 2)


def _pixels(rig, pixels, name):
    uv = as_array(pixels, name, (None, 2))
    cam = rig.camera
    xn = cam.normalized(uv) if cam.has_distortion else np.stack(
        [(uv[:, 0] - cam.cx) / cam.fx, (uv[:, 1] - cam.cy) / cam.fy], -1)
    ideal = np.stack([cam.fx * xn[:, 0] + cam.cx, cam.fy * xn[:, 1] + cam.cy], -1)
    return xn, ideal


def _sonar_pair(x, name):
    """``(ranges, azimuths)`` of the sonar matches ``x``: a pair of (M,) arrays, or an array of
    shape (2, M) (row 0 the ranges, row 1 the azimuths). An (M, 2) array is refused (its
    transpose is meant), and so is a (2, 2) array, which could be either."""
    if isinstance(x, np.ndarray) and x.ndim == 2:
        if x.shape == (2, 2):
            raise ValueError(f"{name}: a (2, 2) array is ambiguous (rows (ranges, azimuths) of 2 matches, or 2 "
                             f"matches of (range, azimuth)); pass a tuple (ranges, azimuths) of (M,) arrays")
        if x.shape[0] != 2:
            hint = f" (an (M, 2) array: pass {name}.T)" if x.shape[1] == 2 else ""
            raise ValueError(f"{name}: expected a pair (ranges, azimuths) of (M,) arrays or an array of shape "
                             f"(2, M), got shape {x.shape}{hint}")
        r, a = x[0], x[1]
    else:
        try:
            r, a = x
        except (TypeError, ValueError):
            raise ValueError(f"{name}: expected a pair (ranges, azimuths) of (M,) arrays or an array of shape "
                             f"(2, M)") from None
    r = as_array(r, f"{name} ranges", (None,))
    a = as_azimuths(as_array(a, f"{name} azimuths", (r.shape[0],)), f"{name} azimuths")
    if np.any(r <= 0):
        raise ValueError(f"{name} ranges: must be > 0")
    return r, a


def _data(rig, pixels_1, pixels_2, sonar_1, sonar_2, sigma_pixel, sigma_range, sigma_azimuth) -> _Data:
    if not isinstance(rig, Rig):
        raise ValueError(f"rig: expected an optiacoustic.Rig, got {type(rig).__name__}")
    x1, u1 = _pixels(rig, pixels_1, "pixels_1")
    x2, u2 = _pixels(rig, pixels_2, "pixels_2")
    if x1.shape != x2.shape:
        raise ValueError(f"pixels_1, pixels_2: must have the same shape, got {x1.shape} and {x2.shape}")
    r1, th1 = _sonar_pair(sonar_1, "sonar_1")
    r2, th2 = _sonar_pair(sonar_2, "sonar_2")
    if r1.shape != r2.shape:
        raise ValueError(f"sonar_1, sonar_2: must hold the same number of matches, got {r1.shape[0]} and {r2.shape[0]}")
    c = rig.camera
    return _Data(rig, (c.fx, c.fy, c.cx, c.cy), x1, x2, u1, u2, r1, th1, r2, th2,
                 as_positive(sigma_pixel, "sigma_pixel"), as_positive(sigma_range, "sigma_range"),
                 as_positive(sigma_azimuth, "sigma_azimuth"), float(min(rig.fov_elevation, np.pi - 1e-6)))


# --------------------------------------------------------------------------- OpenCV, wrapped
def _collinear(u, sigma) -> bool:
    """True when the points hug a line to within the noise (or are fewer than 3 distinct)."""
    if u.shape[0] < 3:
        return True
    c = u - u.mean(0)
    s = np.linalg.svd(c, compute_uv=False)
    return bool(s[1] / np.sqrt(u.shape[0]) < 2 * sigma)


def _subset(d: _Data, idx) -> _Data:
    """The optical matches ``idx`` of ``d`` (sonar matches kept)."""
    return _Data(d.rig, d.K, d.x1[idx], d.x2[idx], d.u1[idx], d.u2[idx], d.r1, d.th1, d.r2, d.th2,
                 d.sp, d.sr, d.sa, d.fov, d.min_inliers)


def _homography(d: _Data, threshold, confidence, max_iters):
    import cv2

    try:
        H, mask = cv2.findHomography(d.u1.astype(np.float64), d.u2.astype(np.float64), cv2.USAC_MAGSAC,
                                     float(threshold), maxIters=int(max_iters), confidence=float(confidence))
    except cv2.error as exc:  # degenerate samples reach OpenCV's asserts
        return None, None, f"OpenCV could not fit a homography ({str(exc).splitlines()[-1][:80]})"
    if H is None or mask is None or H.shape != (3, 3) or not np.all(np.isfinite(H)):
        return None, None, "no homography explains the optical matches (degenerate configuration)"
    mask = mask.ravel().astype(bool)
    sv = np.linalg.svd(H, compute_uv=False)
    if sv[-1] < 1e-9 * sv[0]:
        return None, None, "the optical homography is singular (plane seen edge-on or collinear points)"
    return H, mask, ""


def _decompose(d: _Data, H, inl) -> tuple[list[MonocularSolution], str]:
    """The visible interpretations of the homography ``H`` (OpenCV), or, where OpenCV reads it
    as a pure rotation, that rotation with ``t_o / d = 0`` and the plane's normal from the
    sonar matches (:func:`_rotation_only`); with an empty list, the reason."""
    import cv2

    fx, fy, cx, cy = d.K
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    try:
        num, Rs, ts, ns = cv2.decomposeHomographyMat(H, K)
        if num >= 1 and all(np.linalg.norm(np.asarray(t, float)) < 1e-12 for t in ts[:num]):
            # H is a rotation to OpenCV's tolerance (a hovering rig that turns, or a translation
            # of a few mm at metres): one solution, t = 0, n = 0, which the visibility filter
            # drops. The rotation is right; the sonar fixes the plane and the ML the translation.
            R0 = np.asarray(Rs[0], float)
            sol = _rotation_only(d, orthonormalize(R0)) if np.all(np.isfinite(R0)) else None
            if sol is None:
                return [], ("the optical homography is a pure rotation, and fewer than 3 sonar matches have an "
                            "elevation the sonar's own parallax fixes: the plane, hence the scale, is unobservable")
            return [sol], ""
        p1 = d.x1[inl].astype(np.float32).reshape(-1, 1, 2)
        p2 = d.x2[inl].astype(np.float32).reshape(-1, 1, 2)
        keep = cv2.filterHomographyDecompByVisibleRefpoints(Rs, ns, p1, p2)
    except cv2.error:
        return [], "OpenCV could not decompose the homography"
    if keep is None:
        return [], "the homography has no decomposition with the points in front of both views"
    out = []
    for i in np.asarray(keep).ravel():
        n = np.asarray(ns[i], float).ravel()
        t = np.asarray(ts[i], float).ravel()
        if not (np.all(np.isfinite(n)) and np.all(np.isfinite(t))) or np.linalg.norm(n) < 1e-12:
            continue
        out.append(MonocularSolution(orthonormalize(np.asarray(Rs[i], float)), t, n / np.linalg.norm(n)))
    return out, ("" if out else "the homography has no decomposition with the points in front of both views")


def _rotation_only(d: _Data, R_o):
    """The interpretation ``{R_o, 0, n}`` of a homography that is a pure rotation, or None.

    With ``t_o = 0`` the sonar still moves (``t_s = (I - R_s) t``, the lever arm): each sonar
    match's elevation is the one that predicts its view-2 measurements (grid + golden section
    over the aperture, plus the exact roots of the azimuth equation, as in
    :func:`_plane_scale` with ``t_o / d = 0``), and the plane through those points (total
    least squares, twice trimmed at 3 robust deviations) gives the normal. The distance is then
    the sonar's (:func:`_plane_scale`) and the translation the ML's."""
    if d.n_s < 3:
        return None
    R, t = d.rig.R, d.rig.t
    R_s = R @ R_o @ R.T
    a = (np.eye(3) - R_s) @ t

    def chi(phi):
        Q = _arc(d, phi) @ R_s.T + a
        az = B.wrap(np.arctan2(Q[..., 0], Q[..., 1]) - d.th2)
        return ((np.linalg.norm(Q, axis=-1) - d.r2) / d.sr) ** 2 + (az / d.sa) ** 2

    e2 = np.stack([np.cos(d.th2), -np.sin(d.th2), np.zeros(d.n_s)], -1)
    u = np.stack([np.sin(d.th1), np.cos(d.th1), np.zeros(d.n_s)], -1)
    g = e2 @ R_s
    roots = _trig_roots(d.r1 * np.einsum("mi,mi->m", g, u), d.r1 * g[:, 2], -(e2 @ a))
    phi, c = _phi_search(d, chi, extra=roots)
    X = (_arc(d, phi) - t) @ R  # camera frame of view 1
    thr = float(_chi2.ppf(0.99, 1))
    # a match whose chi-square does not vary across the aperture tells nothing of its elevation
    # (the rig has not moved at all: no parallax); one that varies little (the lever arm's few
    # mm of parallax at a cm of range noise) still counts: the ML's covariance then says how
    # poorly the plane is known
    half = d.fov / 2 + d.margin
    c_grid = chi(np.linspace(-half, half, 61)[:, None] * np.ones((1, d.n_s)))
    with np.errstate(invalid="ignore"):
        known = np.nanmax(np.where(np.isfinite(c_grid), c_grid, np.nan), 0) > c + 1e-6 * (1.0 + c)
    keep = np.isfinite(c) & (c < thr) & known & np.all(np.isfinite(X), 1)
    n = None
    for _ in range(3):
        if keep.sum() < 3:
            return None
        Xk = X[keep]
        cen = Xk.mean(0)
        _, sv, Vt = np.linalg.svd(Xk - cen, full_matrices=False)
        if sv[1] < 1e-9 * max(sv[0], 1e-300):  # the points are collinear: no plane
            return None
        n = Vt[2]
        dist = np.abs((X - cen) @ n)
        mad = 1.4826 * np.median(dist[keep])
        keep = keep & (dist <= max(3 * mad, 1e-9 * np.linalg.norm(cen)))
    if n @ cen < 0:
        n = -n
    if not (n @ cen > 0):  # the plane passes through the camera centre
        return None
    return MonocularSolution(R_o, np.zeros(3), n)


def _essential(d: _Data, threshold, confidence, max_iters):
    import cv2

    f = 0.5 * (d.K[0] + d.K[1])
    try:
        E, mask = cv2.findEssentialMat(d.x1.astype(np.float64), d.x2.astype(np.float64), np.eye(3),
                                       method=cv2.USAC_MAGSAC, prob=float(confidence),
                                       threshold=float(threshold) / f, maxIters=int(max_iters))
        if E is None or mask is None or E.shape[0] < 3 or not np.all(np.isfinite(E)):
            return None, None, None, "no essential matrix explains the optical matches"
        E = E[:3]
        _, R, t, mask2 = cv2.recoverPose(E, d.x1.astype(np.float64), d.x2.astype(np.float64), np.eye(3),
                                         mask=mask.copy())
    except cv2.error as exc:
        return None, None, None, f"OpenCV could not fit an essential matrix ({str(exc).splitlines()[-1][:80]})"
    inl = np.asarray(mask2).ravel() > 0
    if inl.sum() < 5 or not np.all(np.isfinite(R)) or not np.all(np.isfinite(t)):
        return None, None, None, "the essential matrix leaves fewer than 5 points in front of both views"
    t = np.asarray(t, float).ravel()
    return orthonormalize(np.asarray(R, float)), t / np.linalg.norm(t), inl, ""


# --------------------------------------------------------------------------- scale from the sonar
def _arc(d: _Data, phi, idx=slice(None)):
    """Sonar-frame points ``r (cos(phi) u + sin(phi) z)`` of the matches' arcs, ``phi (..., M)``."""
    r, th = d.r1[idx], d.th1[idx]
    cp, sp = np.cos(phi), np.sin(phi)
    return np.stack([r * cp * np.sin(th), r * cp * np.cos(th), r * sp], -1)


def _golden(f, lo, hi, iters=40):
    """Vectorised golden-section minimisation of ``f (M,) -> (M,)`` on ``[lo, hi]``."""
    g = (np.sqrt(5) - 1) / 2
    a, b = lo.astype(float).copy(), hi.astype(float).copy()
    c, e = b - g * (b - a), a + g * (b - a)
    fc, fe = f(c), f(e)
    for _ in range(iters):
        left = fc < fe  # the minimum is in [a, e]
        a = np.where(left, a, c)
        b = np.where(left, e, b)
        x_new = np.where(left, b - g * (b - a), a + g * (b - a))
        f_new = f(x_new)
        e, fe, c, fc = (np.where(left, c, x_new), np.where(left, fc, f_new),
                        np.where(left, x_new, e), np.where(left, f_new, fe))
    x = 0.5 * (a + b)
    return x, f(x)


def _phi_search(d: _Data, chi2_of_phi, extra=None, n_grid=61, golden=None):
    """Per-match elevation minimising ``chi2_of_phi (G, M) -> (G, M)``; returns ``(phi, chi2)``.

    ``golden``: ``(lo, hi) -> (phi, chi2)``, the golden-section refinement of ``chi2_of_phi`` in
    a compiled kernel (:func:`._kernels.golden_scale`), else :func:`_golden` runs it."""
    half = d.fov / 2 + d.margin
    grid = np.linspace(-half, half, n_grid)[:, None] * np.ones((1, d.n_s))
    c = chi2_of_phi(grid)
    k = np.argmin(np.where(np.isfinite(c), c, np.inf), 0)
    step = grid[1, 0] - grid[0, 0]
    phi0 = grid[k, np.arange(d.n_s)]
    lo, hi = np.maximum(phi0 - step, -half), np.minimum(phi0 + step, half)
    phi, cbest = golden(lo, hi) if golden is not None else _golden(lambda p: chi2_of_phi(p[None])[0], lo, hi)
    if extra is not None:  # analytic roots (exact on noise-free data)
        ce = chi2_of_phi(extra)
        ce = np.where(np.isfinite(ce) & (np.abs(extra) <= half), ce, np.inf)
        j = np.argmin(ce, 0)
        cj = ce[j, np.arange(d.n_s)]
        better = cj <= cbest
        phi = np.where(better, extra[j, np.arange(d.n_s)], phi)
        cbest = np.where(better, cj, cbest)
    return phi, np.where(np.isfinite(cbest), cbest, np.inf)


def _golden_kernel(d: _Data, essential, R_s, a, b, n_s=None, nst=0.0, bb=1.0, sign=1.0):
    """:func:`._kernels.golden_scale` for :func:`_phi_search` (None with ``OAS_KERNELS=numpy``)."""
    from .._kernel_switch import use_numba

    if not use_numba():
        return None
    from . import _kernels as Kn

    f = lambda x: np.ascontiguousarray(x, float)  # noqa: E731
    args = (f(d.r1), f(d.th1), f(d.r2), f(d.th2), float(d.sr), float(d.sa), f(R_s), f(a), f(b),
            f(np.zeros(3) if n_s is None else n_s), float(nst), float(bb), float(sign))

    def golden(lo, hi, iters=40):
        phi, chi = np.empty(d.n_s), np.empty(d.n_s)
        Kn.golden_scale(bool(essential), f(lo), f(hi), iters, *args, phi, chi)
        return phi, chi

    return golden


_trig_roots = cos_sin_roots  # both solutions of A cos(phi) + B sin(phi) = C, (2, ...); NaN where none


def _plane_scale(d: _Data, sol: MonocularSolution):
    """Scale ``d_o`` from each sonar match alone, for the interpretation ``sol`` (eqs. 6.13-6.16).

    The match's point is ``P_s = r w(phi)``; lying on the plane ``n_s . P_s = d_o + n_s . t``
    gives ``d_o(phi)``; view 2 predicts ``P'_s = R_s P_s + (I - R_s) t + d_o(phi) R tau``;
    ``phi`` minimises the whitened error of ``(r', theta')``.
    """
    R, t = d.rig.R, d.rig.t
    R_s = R @ sol.R_o @ R.T
    a = (np.eye(3) - R_s) @ t
    b = R @ sol.t_over_d
    n_s = R @ sol.normal
    nst = float(n_s @ t)

    def chi(phi):
        P = _arc(d, phi)
        do = P @ n_s - nst
        Q = P @ R_s.T + a + do[..., None] * b
        rq = np.linalg.norm(Q, axis=-1)
        aq = np.arctan2(Q[..., 0], Q[..., 1])
        c = ((rq - d.r2) / d.sr) ** 2 + (B.wrap(aq - d.th2) / d.sa) ** 2
        return np.where(do > 0, c, np.inf)

    # analytic roots of the azimuth equation e'.P'_s = 0 (the ratio of the rows of eq. 6.11)
    e2 = np.stack([np.cos(d.th2), -np.sin(d.th2), np.zeros(d.n_s)], -1)
    g = e2 @ R_s + (e2 @ b)[:, None] * n_s[None]
    u = np.stack([np.sin(d.th1), np.cos(d.th1), np.zeros(d.n_s)], -1)
    alpha = d.r1 * np.einsum("mi,mi->m", g, u)
    beta = d.r1 * g[:, 2]
    gamma = -(e2 @ a - nst * (e2 @ b))
    roots = _trig_roots(alpha, beta, gamma)
    golden = _golden_kernel(d, False, R_s, a, b, n_s=n_s, nst=nst)
    phi, c = _phi_search(d, chi, extra=roots, golden=golden)
    do = _arc(d, phi) @ n_s - nst
    return np.where(np.isfinite(c), do, np.nan), phi, c


def _plane_consensus(d: _Data, sol: MonocularSolution, d_cands):
    """Whitened error of every match if the plane were at each candidate distance, ``(C, M)``.

    With ``d_o`` known the plane fixes each match's elevation (eq. 6.16, two roots; the one
    inside the aperture that fits best), leaving two degrees of freedom.
    """
    R, t = d.rig.R, d.rig.t
    R_s = R @ sol.R_o @ R.T
    a = (np.eye(3) - R_s) @ t
    b = R @ sol.t_over_d
    n_s = R @ sol.normal
    nst = float(n_s @ t)
    u = np.stack([np.sin(d.th1), np.cos(d.th1), np.zeros(d.n_s)], -1)
    A = d.r1 * (u @ n_s)
    Bc = d.r1 * n_s[2]
    C = d_cands[:, None] + nst
    roots = _trig_roots(A[None], Bc[None], C)  # (2, C, M)
    half = d.fov / 2 + d.margin
    best = np.full(C.shape, np.inf)
    for k in range(2):
        phi = roots[k]
        ok = np.isfinite(phi) & (np.abs(phi) <= half)
        P = _arc(d, np.where(ok, phi, 0.0))
        Q = P @ R_s.T + a + d_cands[:, None, None] * b
        c = ((np.linalg.norm(Q, axis=-1) - d.r2) / d.sr) ** 2 + (B.wrap(np.arctan2(Q[..., 0], Q[..., 1]) - d.th2) / d.sa) ** 2
        best = np.minimum(best, np.where(ok, c, np.inf))
    return best


def _essential_scale(d: _Data, R_o, t_dir):
    """Scale ``s = |t_o|`` from each sonar match alone (five-point path).

    The match's point is ``P_s = r w(phi)``; view 2 sees ``P'_s = R_s P_s + (I - R_s) t + s R t_dir``.
    For each ``phi`` the range ``r'`` fixes ``s`` (a quadratic: two branches); ``phi`` is the
    one that predicts the azimuth ``theta'``.
    """
    R, t = d.rig.R, d.rig.t
    R_s = R @ R_o @ R.T
    a = (np.eye(3) - R_s) @ t
    b = R @ t_dir
    bb = float(b @ b)
    out_s = np.full((2, d.n_s), np.nan)
    out_c = np.full((2, d.n_s), np.inf)
    for branch, sign in enumerate((1.0, -1.0)):
        def s_of(phi, sign=sign):
            c = _arc(d, phi) @ R_s.T + a
            bc = c @ b
            disc = bc**2 - bb * (np.einsum("...i,...i->...", c, c) - d.r2**2)
            return (-bc + sign * np.sqrt(np.maximum(disc, 0.0))) / bb, c

        def chi(phi, s_of=s_of):
            s, c = s_of(phi)
            Q = c + s[..., None] * b
            e = ((np.linalg.norm(Q, axis=-1) - d.r2) / d.sr) ** 2 + (B.wrap(np.arctan2(Q[..., 0], Q[..., 1]) - d.th2) / d.sa) ** 2
            return np.where(s > 0, e, np.inf)

        phi, cb = _phi_search(d, chi, golden=_golden_kernel(d, True, R_s, a, b, bb=bb, sign=sign))
        out_s[branch] = s_of(phi[None])[0][0]
        out_c[branch] = cb
    k = np.argmin(out_c, 0)
    s = out_s[k, np.arange(d.n_s)]
    c = out_c[k, np.arange(d.n_s)]
    return np.where(np.isfinite(c), s, np.nan), c


def _essential_consensus(d: _Data, R_o, t_dir, s_cands):
    """Whitened range error of every match at each candidate scale (azimuth roots), ``(C, M)``."""
    R, t = d.rig.R, d.rig.t
    R_s = R @ R_o @ R.T
    a = (np.eye(3) - R_s) @ t
    b = R @ t_dir
    e2 = np.stack([np.cos(d.th2), -np.sin(d.th2), np.zeros(d.n_s)], -1)
    u = np.stack([np.sin(d.th1), np.cos(d.th1), np.zeros(d.n_s)], -1)
    g = e2 @ R_s
    alpha = d.r1 * np.einsum("mi,mi->m", g, u)
    beta = d.r1 * g[:, 2]
    gamma = -(e2 @ a)[None] - s_cands[:, None] * (e2 @ b)[None]
    roots = _trig_roots(alpha[None], beta[None], gamma)
    half = d.fov / 2 + d.margin
    best = np.full(gamma.shape, np.inf)
    for k in range(2):
        phi = roots[k]
        ok = np.isfinite(phi) & (np.abs(phi) <= half)
        P = _arc(d, np.where(ok, phi, 0.0))
        Q = P @ R_s.T + a + s_cands[:, None, None] * b
        ok &= Q[..., 1] > 0
        c = ((np.linalg.norm(Q, axis=-1) - d.r2) / d.sr) ** 2
        best = np.minimum(best, np.where(ok, c, np.inf))
    return best


def _pick_scale(cands, cand_chi, consensus, single_thr, thr):
    """The single match most others agree with: ``(index, support, mask, cost)`` or None."""
    valid = np.isfinite(cands) & (cands > 0) & (cand_chi < single_thr)
    if not valid.any():
        return None
    idx = np.flatnonzero(valid)
    cons = consensus(cands[idx])  # (C, M)
    inl = cons < thr
    support = inl.sum(1)
    cost = np.minimum(cons, thr).sum(1)
    j = np.lexsort((cost, -support))[0]
    return int(idx[j]), int(support[j]), inl[j], float(cost[j])


# --------------------------------------------------------------------------- ML problem
def _blocks(d: _Data, labels_o, labels_s, model, which="inliers"):
    """Blocks of the variable-projection problem; ``which="inliers"`` keeps labelled matches."""
    R, t = d.rig.R, d.rig.t
    I3, z3 = np.eye(3), np.zeros(3)
    cam_ch = (B.Channel("camera", False, I3, z3), B.Channel("camera", True, I3, z3))
    son_ch = (B.Channel("sonar", False, R, t), B.Channel("sonar", True, R, t))
    so = np.array([[d.sp, d.sp], [d.sp, d.sp]])
    ss = np.array([[d.sr, d.sa], [d.sr, d.sa]])
    io = np.flatnonzero(labels_o >= 0) if which == "inliers" else np.arange(d.n_o)
    is_ = np.flatnonzero(labels_s >= 0) if which == "inliers" else np.arange(d.n_s)
    meas_o = np.stack([d.u1[io], d.u2[io]], 1)
    meas_s = np.stack([np.stack([d.r1[is_], d.th1[is_]], -1), np.stack([d.r2[is_], d.th2[is_]], -1)], 1)
    if model == "plane":
        x1 = d.x1[io]

        def init_o(Rv, cv, planes, plane):
            return x1

        def init_s(Rv, cv, planes, plane):
            return _sonar_on_plane(d, is_, planes[plane])

        bo = B.Block(cam_ch, meas_o, so, "plane", init_o, np.maximum(labels_o[io], 0))
        bs = B.Block(son_ch, meas_s, ss, "plane", init_s, np.maximum(labels_s[is_], 0), multi_start=True)
    else:
        def init_o(Rv, cv, planes, plane):
            return _triangulate_optical(d.x1[io], d.x2[io], Rv, cv)

        def init_s(Rv, cv, planes, plane):
            return _triangulate_sonar(d, is_, Rv, cv)

        bo = B.Block(cam_ch, meas_o, so, "free", init_o, np.zeros(io.size, int))
        bs = B.Block(son_ch, meas_s, ss, "free", init_s, np.zeros(is_.size, int), multi_start=True)
    return bo, bs, io, is_


def _sonar_on_plane(d: _Data, idx, m, R=None, t=None):
    """Candidate normalised camera coordinates ``(n, 2, 2)`` of sonar matches put on their planes.

    The plane ``m`` (camera frame, ``(n, 3)``) in the sonar frame is ``n_s . P_s = d_s``
    (eq. 6.7); the match's arc ``r w(phi)`` meets it where
    ``r (n_s . u) cos(phi) + r n_sz sin(phi) = d_s`` (eq. 6.15): two roots (eq. 6.16). Both are
    returned (the caller keeps the one that fits the other measurements); where the arc
    misses the plane, its point closest to the plane.
    """
    R = d.rig.R if R is None else R
    t = d.rig.t if t is None else t
    k = np.linalg.norm(m, axis=1)
    n_o = m / k[:, None]
    n_s = n_o @ R.T
    d_s = 1.0 / k + np.einsum("ni,i->n", n_s, t) if np.ndim(t) == 1 else 1.0 / k + np.einsum("ni,ni->n", n_s, t)
    r, th = d.r1[idx], d.th1[idx]
    u = np.stack([np.sin(th), np.cos(th), np.zeros_like(th)], -1)
    A = r * np.einsum("mi,mi->m", u, n_s)
    Bc = r * n_s[:, 2]
    roots = _trig_roots(A, Bc, d_s)  # (2, n)
    half = d.fov / 2 + d.margin
    closest = np.clip(np.arctan2(Bc, A), -half, half)
    roots = np.where(np.isfinite(roots), np.clip(roots, -half, half), closest[None])
    out = np.empty((idx.size, 2, 2))
    for k_ in range(2):
        P = _arc(d, roots[k_], idx)
        X = (P - t) @ R
        z = np.where(np.abs(X[:, 2]) > 1e-9, X[:, 2], 1e-9)
        out[:, k_] = X[:, :2] / z[:, None]
    return out


def _triangulate_optical(x1, x2, R_o, t_o):
    """Linear two-view triangulation (camera frame of view 1): ``l1 R_o q1 - l2 q2 = -t_o``."""
    q1 = np.concatenate([x1, np.ones((x1.shape[0], 1))], 1)
    q2 = np.concatenate([x2, np.ones((x2.shape[0], 1))], 1)
    a = q1 @ R_o.T
    A = np.stack([a, -q2], -1)  # (N, 3, 2)
    AtA = np.einsum("nij,nik->njk", A, A)
    Atb = np.einsum("nij,i->nj", A, -t_o)
    det = AtA[:, 0, 0] * AtA[:, 1, 1] - AtA[:, 0, 1] ** 2
    ok = det > 1e-12 * np.maximum(AtA[:, 0, 0] * AtA[:, 1, 1], 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        l1 = (AtA[:, 1, 1] * Atb[:, 0] - AtA[:, 0, 1] * Atb[:, 1]) / det
    tn = max(float(np.linalg.norm(t_o)), 1e-9)
    l1 = np.where(ok & np.isfinite(l1) & (l1 > 0), l1, 1.0)
    l1 = np.clip(l1, 1e-3 * tn, 1e4 * tn)
    return q1 * l1[:, None]


def _triangulate_sonar(d: _Data, idx, R_o, t_o):
    """Appendix B's closed forms for sonar matches as candidate camera-frame points ``(n, 5, 3)``."""
    R, t = d.rig.R, d.rig.t
    R_s, t_s = sonar_motion(d.rig, R_o, t_o)
    cf = _closed_forms(d.r1[idx], d.th1[idx], d.r2[idx], d.th2[idx], R_s, t_s)
    cands = np.stack([cf.b3, cf.b5, cf.b7, cf.planes[:, 0], cf.planes[:, 1]], 1)
    # where the azimuth planes coincide (heave): the radical form's two roots
    none = ~np.any(np.all(np.isfinite(cands), 2), 1)
    cands[none, 3:5] = cf.radical[none]
    # where none exists (no parallax at all): the zero-elevation point of the arc
    none = ~np.any(np.all(np.isfinite(cands), 2), 1)
    cands[none, 0] = _arc(d, np.zeros(int(none.sum())), idx[none])
    return (cands - t) @ R


def _problem(d: _Data, labels_o, labels_s, model, R_ref, planes_m, which="inliers"):
    bo, bs, io, is_ = _blocks(d, labels_o, labels_s, model, which)
    k = len(planes_m) if model == "plane" else 0
    prob = B.Problem(d.K, [bo, bs], k, R_ref)
    # a point's own solve stops within 1e-8 of its cost (to second order): the chi-squares
    # only meet thresholds, and the joint solve refines the points anyway
    prob.inner_rtol = 1e-8
    # the outer solve stops when the cost falls by less than 1e-6 of itself: a few 1e-4 of a
    # chi-square of a few hundred, i.e. parameters within a few hundredths of their standard
    # deviation of the minimum (1e-8 spent most evaluations creeping along a flat valley)
    prob.ftol = 1e-6
    return prob, bo, bs, io, is_


def _theta(t_o, planes_m):
    return np.concatenate([np.zeros(3), t_o, np.asarray(planes_m, float).reshape(-1)])


def _chi2_all(d: _Data, model, R_o, t_o, planes_m, points=False):
    """Reduced chi-square of every match under every plane (or the free model): ``(P, N_o), (P, M)``.

    With ``points=True`` also the per-point parameters at those optima, ``((P, N_o, n_p),
    (P, M, n_p))``: the start of a fit at this state (see :func:`_starts`).
    """
    k = len(planes_m) if model == "plane" else 1
    lo = np.zeros(d.n_o, int)
    ls = np.zeros(d.n_s, int)
    prob, bo, bs, _, _ = _problem(d, lo, ls, model, R_o, planes_m, which="all")
    th = _theta(t_o, planes_m if model == "plane" else np.zeros((0, 3)))
    n_p = 2 if model == "plane" else 3
    co = np.full((k, d.n_o), np.inf)
    cs = np.full((k, d.n_s), np.inf)
    po = np.full((k, d.n_o, n_p), np.nan)
    ps = np.full((k, d.n_s, n_p), np.nan)
    for j in range(k):
        for blk, c, p, n in ((bo, co, po, d.n_o), (bs, cs, ps, d.n_s)):
            if n:
                p[j], e, _, _ = prob.solve_points(blk, th, plane=np.full(n, j))
                c2 = np.sum(e * e, axis=1)
                c[j] = np.where(np.isfinite(c2), c2, np.inf)
    return (co, cs, (po, ps)) if points else (co, cs)


def _starts(points, lo, ls):
    """Starts of a fit with labels ``lo, ls``: each inlier's parameters on its plane, from
    :func:`_chi2_all` at the fit's start (one array per non-empty block, as the problem's)."""
    po, ps = points
    io, is_ = np.flatnonzero(lo >= 0), np.flatnonzero(ls >= 0)
    return [x for x in (po[lo[io], io], ps[ls[is_], is_]) if x.shape[0] > 0]


def _relabel(co, cs, thr):
    lo = np.argmin(co, 0)
    lo = np.where(co[lo, np.arange(co.shape[1])] < thr, lo, -1) if co.size else np.zeros(0, int)
    ls = np.argmin(cs, 0)
    ls = np.where(cs[ls, np.arange(cs.shape[1])] < thr, ls, -1) if cs.size else np.zeros(0, int)
    return lo.astype(int), ls.astype(int)


def _ml_loop(d: _Data, model, R_o, t_o, planes_m, lo, ls, thr, max_iterations, info=None, max_nfev=100,
             points=None):
    """Maximum likelihood with relabelling until the labels settle; returns the new state.

    The state is ``(R_o, t_o, planes_m, lo, ls, iterations, cost, problem)``, ``problem``
    being the last fit's (its points at the optimum, for :func:`_finish`), or None; ``lo, ls``
    are always the labels that fit used, also when ``max_iterations`` stops the loop while
    the labels still change.
    ``info`` (a dict), when given, receives ``"chi2"``: the per-match chi-squares
    ``(co, cs)`` of :func:`_chi2_all` at the returned state, when they were computed there,
    and ``"points"``: the per-match parameters there. ``points``: such parameters at the
    given state (the first fit starts from them instead of solving every point afresh).
    """
    planes_m = np.asarray(planes_m, float).reshape(-1, 3)
    it = 0
    res = None
    co = cs = None
    last = None
    fit_lo, fit_ls = lo, ls  # the labels of the last fit (``last``), returned with it
    for it in range(1, max_iterations + 1):
        prob, _, _, _, _ = _problem(d, lo, ls, model, R_o, planes_m)
        starts = None if points is None else _starts(points, lo, ls)
        sol = prob.solve(_theta(t_o, planes_m if model == "plane" else np.zeros((0, 3))), max_nfev=max_nfev,
                         starts=starts)
        R_new, t_new, pm = prob.unpack(sol.x)
        if not (np.all(np.isfinite(R_new)) and np.all(np.isfinite(t_new)) and np.all(np.isfinite(pm))):
            break
        R_o, t_o = R_new, t_new
        last, fit_lo, fit_ls = prob, lo, ls
        if model == "plane":
            planes_m = pm
        res = float(2 * sol.cost)
        co, cs, points = _chi2_all(d, model, R_o, t_o, planes_m, points=True)
        nlo, nls = _relabel(co, cs, thr)
        if (nls >= 0).sum() == 0:
            nls = ls  # never drop the last sonar match: it carries the scale
        if np.sum(nlo >= 0) < (4 if model == "plane" else 5):
            nlo = lo
        changed = int(np.sum(nlo != lo) + np.sum(nls != ls))
        # settled: no label changes, or so few that refitting would not move the estimate
        # (the labels reported are then those of the last fit)
        if changed <= max(0, int(0.005 * (lo.size + ls.size))):
            break
        lo, ls = nlo, nls
        co = cs = None
    # Stopped by max_iterations (or a non-finite step) while the labels were still changing:
    # the state returned is the last fit's, with the labels that fit used (not the newer ones,
    # which no fit has seen): its motion, cost, points and labels belong together.
    if info is not None and co is not None:
        info["chi2"] = (co, cs)
        info["points"] = points
    return R_o, t_o, planes_m, fit_lo, fit_ls, it, res, last


def _points_for(d: _Data, R_o, t_o):
    """Every match triangulated with the motion (free model): optical (camera 1), sonar (sonar 1)."""
    prob, bo, bs, _, _ = _problem(d, np.zeros(d.n_o, int), np.zeros(d.n_s, int), "free", R_o, np.zeros((0, 3)), "all")
    th = _theta(t_o, np.zeros((0, 3)))
    Po = prob.solve_points(bo, th)[0] if d.n_o else np.zeros((0, 3))
    Ps = prob.solve_points(bs, th)[0] if d.n_s else np.zeros((0, 3))
    return Po, d.rig.sonar_from_camera(Ps) if d.n_s else Ps


def _stage(d, name, R_o, t_o, planes_m, lo, ls, it, cost):
    """A :class:`MotionStage` whose triangulated points are computed on first access."""
    planes = tuple(Plane.from_m(m) for m in np.asarray(planes_m).reshape(-1, 3))
    return MotionStage(name, R_o, t_o, planes, lo.copy(), ls.copy(), int(it), float(cost),
                       lambda R, t: _points_for(d, R, t))


def _failed(d_or_rig, message, n_o=0, n_s=0, stages=(), monocular=(), model="homography"):
    rig = d_or_rig.rig if isinstance(d_or_rig, _Data) else d_or_rig
    return MotionResult(False, message, model, np.full((3, 3), np.nan), np.full(3, np.nan), (),
                        np.full(n_o, -1), np.full(n_s, -1), np.full((6, 6), np.nan), tuple(stages), tuple(monocular),
                        np.full(n_s, np.nan), -1, (), float("nan"), 0, rig)


# --------------------------------------------------------------------------- entry point
def estimate(
    rig: Rig,
    pixels_1,
    pixels_2,
    sonar_1,
    sonar_2,
    *,
    sigma_pixel: float,
    sigma_range: float,
    sigma_azimuth: float,
    model: str = "homography",
    planes: int | str = "auto",
    max_iterations: int = 10,
    inlier_probability: float = 0.99,
    ransac_threshold: float | None = None,
    ransac_confidence: float = 0.999,
    ransac_max_iters: int = 2000,
    min_inlier_fraction: float = 0.25,
    seed: int | np.random.Generator | None = 0,
) -> MotionResult:
    """Metric motion of an opti-acoustic rig between two views (thesis ch. 6).

    Parameters
    ----------
    rig : Rig
        The calibrated rig (``R``, ``t``, camera; the sonar spec's elevation aperture, when
        attached, picks among elevation roots).
    pixels_1, pixels_2 : array_like, shape (N, 2)
        Optical matches: pixels ``(u, v)`` of the same points in image 1 and image 2.
    sonar_1, sonar_2 : pair of array_like, shape (M,) each, or array_like (2, M)
        Sonar matches: ``(ranges (m), azimuths (rad))`` of the same points in sonar view 1
        and view 2. They need not be the optical points. An array is read as rows
        ``(ranges, azimuths)``: shape (2, M); an (M, 2) array is refused (pass its transpose),
        and so is a (2, 2) array (pass a tuple). Azimuths beyond +-pi are refused (degrees?).
    sigma_pixel : float
        Pixel noise standard deviation (px).
    sigma_range : float
        Range noise standard deviation (m).
    sigma_azimuth : float
        Azimuth noise standard deviation (rad).
    model : {"homography", "essential"}
        Dominant plane (thesis) or five-point essential matrix (non-planar scenes). On a
        (nearly) planar scene the essential model, whose points are all free, may find two
        different motions (the homography's two interpretations) whose truncated chi-squares
        differ by less than 22.5 (the 99.9 % quantile of chi-square with 6 degrees of freedom):
        the likelihood cannot tell which is true, and the homography model, whose sonar points
        lie on the plane, is run on the same matches and its result returned
        (``result.model == "homography"``, the message says why); when it fails too, the
        result is falsy with ``ambiguous=True`` (both motions are in ``stages``). For planar
        scenes use ``model="homography"``.
    planes : int or "auto"
        Most planes to fit (homography model): 1 fits the dominant plane only; ``"auto"``
        looks for more (up to 4) among the matches left off the dominant plane.
    max_iterations : int
        Relabelling iterations of each maximum likelihood stage.
    inlier_probability : float
        Chi-square quantile that separates inliers from outliers.
    ransac_threshold : float, optional
        OpenCV's threshold (px); default ``3 sigma_pixel``.
    ransac_confidence, ransac_max_iters :
        OpenCV USAC settings: a confidence in (0, 1) and at least 1 iteration.
    min_inlier_fraction : float
        The final model must explain at least this fraction of the optical matches (and 8
        of them), else the result is falsy: random matches can always be fitted by a few.
    seed : int or Generator
        For the plane clustering's random hypotheses.

    Returns
    -------
    MotionResult
        Falsy, with a message, on degenerate data: too few matches, collinear points, a
        plane seen edge-on, no sonar match on the plane, a pure rotation the sonar shows no
        parallax of, an essential model that cannot choose between two motions. A pure
        rotation (or a translation of a few mm, which OpenCV reads as one) is estimated: the
        homography gives the rotation, the sonar matches' own parallax (the rig's lever arm)
        the plane, and the ML the translation.
    """
    d = _data(rig, pixels_1, pixels_2, sonar_1, sonar_2, sigma_pixel, sigma_range, sigma_azimuth)
    if model not in ("homography", "essential"):
        raise ValueError(f"model: expected 'homography' or 'essential', got {model!r}")
    if planes != "auto" and (isinstance(planes, bool) or not isinstance(planes, (int, np.integer)) or planes < 1):
        raise ValueError(f"planes: expected a positive integer or 'auto', got {planes!r}")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer)) or max_iterations < 1:
        raise ValueError(f"max_iterations: expected a positive integer, got {max_iterations!r}")
    if not 0 < inlier_probability < 1:
        raise ValueError(f"inlier_probability: must be in (0, 1), got {inlier_probability!r}")
    if not 0 <= min_inlier_fraction <= 1:
        raise ValueError(f"min_inlier_fraction: must be in [0, 1], got {min_inlier_fraction!r}")
    if not 0 < ransac_confidence < 1:
        raise ValueError(f"ransac_confidence: must be in (0, 1), got {ransac_confidence!r}")
    if (isinstance(ransac_max_iters, bool) or not isinstance(ransac_max_iters, (int, np.integer))
            or ransac_max_iters < 1):
        raise ValueError(f"ransac_max_iters: expected a positive integer, got {ransac_max_iters!r}")
    d.min_inliers = float(min_inlier_fraction)
    thr_px = 3 * d.sp if ransac_threshold is None else as_positive(ransac_threshold, "ransac_threshold")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    n_min = 4 if model == "homography" else 5
    fail = lambda msg, **kw: _failed(d, msg, d.n_o, d.n_s, model=model, **kw)  # noqa: E731
    if d.n_o < n_min:
        return fail(f"too few optical matches: {d.n_o} (the {model} needs at least {n_min})")
    if d.n_s < 1:
        return fail("no sonar match: the scale cannot be recovered")
    if _collinear(d.u1, d.sp) or _collinear(d.u2, d.sp):
        return fail("the optical matches are collinear (or the plane is seen edge-on): no homography")
    if model == "essential":
        return _estimate_essential(d, thr_px, ransac_confidence, ransac_max_iters, inlier_probability, max_iterations)
    return _estimate_homography(d, thr_px, ransac_confidence, ransac_max_iters, inlier_probability, max_iterations,
                                planes, rng)


def _estimate_homography(d, thr_px, conf, iters, p_in, max_it, planes, rng):
    fail = lambda msg, **kw: _failed(d, msg, d.n_o, d.n_s, **kw)  # noqa: E731
    thr1 = float(_chi2.ppf(p_in, 1))
    thr2 = float(_chi2.ppf(p_in, 2))
    # Homographies of the largest planes, one after the other (OpenCV's MAGSAC on what the
    # previous ones left), each decomposed; every visible interpretation is scored by the
    # sonar matches it explains. The sonar thus removes the dual interpretations and also a
    # homography that straddles two planes (which no interpretation makes consistent).
    remaining = np.ones(d.n_o, bool)
    trials = []  # (support, cost, sol, optical inliers, scale candidates, pick)
    first_msg = ""
    all_sols = []
    for h in range(2):
        idx = np.flatnonzero(remaining)
        if idx.size < 8 and h > 0:
            break
        sub = _subset(d, idx)
        H, inl_sub, msg = _homography(sub, thr_px, conf, iters)
        if H is None or inl_sub.sum() < 4 or _collinear(sub.u1[inl_sub], d.sp):
            if h == 0:
                first_msg = msg or (f"the homography has {int(inl_sub.sum())} inliers (needs 4)" if H is not None
                                    else "no homography")
                if H is not None and inl_sub.sum() >= 4:
                    first_msg = "the homography's inliers are collinear (plane seen edge-on)"
            break
        inl = np.zeros(d.n_o, bool)
        inl[idx[inl_sub]] = True
        sols, why = _decompose(d, H, inl)
        if h == 0:
            all_sols = sols
            if not sols:
                first_msg = why
        for sol in sols:
            cands, phi, c = _plane_scale(d, sol)
            pick = _pick_scale(cands, c, lambda dc, sol=sol: _plane_consensus(d, sol, dc), thr1, thr2)
            sup = 0 if pick is None else pick[1]
            trials.append((sup, np.inf if pick is None else pick[3], sol, inl, cands, pick, h))
        remaining &= ~inl
        if h == 0 and trials and max(t[0] for t in trials) >= max(2, int(0.5 * d.n_s)):
            break  # the first plane already explains most sonar matches
    if not trials:
        return fail(first_msg or "no homography explains the optical matches")
    trials.sort(key=lambda t: (-t[0], t[1]))
    trials = [t for t in trials if t[5] is not None] or trials[:1]
    if trials[0][5] is None:
        return fail("no sonar match lies on the dominant plane: the scale cannot be recovered", monocular=all_sols)
    if d.n_s >= 3 and trials[0][0] < 2:
        return fail("no two sonar matches agree on the dominant plane's distance: no sonar match on the plane",
                    monocular=all_sols)
    # The up-to-scale motion of a homography is only as good as the monocular geometry allows
    # (degrees at 1 px over part of a plane), and a few degrees off the sonar agrees with
    # few matches: when other interpretations explain at least 40% as many sonar matches,
    # let the maximum likelihood decide, by the truncated cost of all matches at each
    # one's optimum.
    # Both interpretations of the best-supported homography are screened by their
    # loose-threshold fit (the support alone misleads: the true one may explain fewer sonar
    # matches from its start); the best by that likelihood, and any within a chi-square of
    # 10 of it, get the full fit.
    # Interpretations of another homography (another plane) compete only with enough
    # support, as before.
    cand = [t for t in trials[:4] if t[6] == trials[0][6] or t[0] >= 0.4 * trials[0][0]]
    screens = [None] * len(cand)
    if len(cand) > 1:
        screens = [_start_planar(d, t, thr2, max_it, screen=True) for t in cand]
        best_screen = min(sc["score"] for sc in screens)
        keep = [k for k, sc in enumerate(screens) if sc["score"] <= best_screen + 10.0]
        cand, screens = [cand[k] for k in keep], [screens[k] for k in keep]
    if len(cand) == 1 and screens[0] is None:  # nothing to choose between: one plain fit
        runs = [_start_planar(d, cand[0], thr2, max_it, graduated=False)]
    else:
        runs = [_start_planar(d, t, thr2, max_it, loose=sc) for t, sc in zip(cand, screens)]
    best = min(runs, key=lambda r: r["score"])
    sol, inl, cands, pick = best["trial"][2], best["trial"][3], best["trial"][4], best["trial"][5]
    h_best = best["trial"][6]
    supports = tuple(t[0] for t in trials if t[6] == h_best)
    sols = all_sols if h_best == 0 else [t[2] for t in trials if t[6] == h_best]
    j = pick[0]
    stages = [best["initial"]]
    R_o, t_o, pm, lo, ls, it, cost, prob = best["planar"]
    stages.append(_stage(d, "planar", R_o, t_o, pm, lo, ls, it, cost if cost is not None else np.nan))
    max_planes = 4 if planes == "auto" else int(planes)
    total_it = it
    while pm.shape[0] < max_planes:
        new = _find_plane(d, R_o, t_o, lo, rng, thr2)
        if new is None:
            break
        pm2 = np.concatenate([pm, new[None]])
        co, cs = _chi2_all(d, "plane", R_o, t_o, pm2)
        lo2, ls2 = _relabel(co, cs, thr2)
        if np.sum(lo2 == pm2.shape[0] - 1) < 3:
            break
        R_o, t_o, pm, lo, ls, it, cost, prob = _ml_loop(d, "plane", R_o, t_o, pm2, lo2, ls2, thr2, max_it)
        total_it += it
    if pm.shape[0] > 1:
        stages.append(_stage(d, "clustered", R_o, t_o, pm, lo, ls, total_it, cost if cost is not None else np.nan))
    return _finish(d, "homography", R_o, t_o, pm, lo, ls, stages, sols, cands, j, supports, prob)


_LOOSE = 4.0  # the first relabelling's threshold, in units of the final one
_LOOSE_NFEV = 15  # evaluations per solve of the loose pass


def _start_planar(d: _Data, trial, thr2, max_it, screen=False, loose=None, graduated=True):
    """Initial estimate of one interpretation and its planar maximum likelihood, with a score.

    Graduated threshold: a first maximum likelihood with a loose one, so that matches a
    few-degrees-off start misfits are not locked out, then one with the final threshold.
    ``screen``: stop after the loose fit (its score and state come back, for comparing
    interpretations); ``loose``: such a screened result, to continue from;
    ``graduated=False``: the final threshold from the start.
    """
    _, _, sol, inl, cands, pick, _ = trial
    j, _, son_inl, _ = pick
    d_o = float(cands[j])
    R_o, t_o, m0 = sol.R_o, sol.t_over_d * d_o, sol.normal / d_o
    lo = np.where(inl, 0, -1)
    ls = np.where(son_inl, 0, -1)
    ls[j] = 0
    initial = _stage(d, "initial", R_o, t_o, m0[None], lo, ls, 0, np.nan)
    if not graduated:
        info = {}
        planar = _ml_loop(d, "plane", R_o, t_o, m0[None], lo, ls, thr2, max_it, info)
        co, cs = info["chi2"] if "chi2" in info else _chi2_all(d, "plane", planar[0], planar[1], planar[2])
        score = float(np.minimum(co.min(0), thr2).sum() + np.minimum(cs.min(0), thr2).sum())
        return dict(trial=trial, initial=initial, planar=planar, score=score)
    if loose is None:
        info = {}
        # (a capped number of evaluations: an interpretation that needs more is not the one)
        state = _ml_loop(d, "plane", R_o, t_o, m0[None], lo, ls, _LOOSE * thr2, max_it, info, max_nfev=_LOOSE_NFEV)
        chi = info["chi2"] if "chi2" in info else _chi2_all(d, "plane", state[0], state[1], state[2])
        loose = dict(state=state, chi2=chi, exact="chi2" in info, points=info.get("points"),
                     score=float(np.minimum(chi[0].min(0), thr2).sum() + np.minimum(chi[1].min(0), thr2).sum()))
    if screen:
        return loose
    state = loose["state"]
    R_o, t_o, pm, lo, ls = state[:5]
    same = False
    if loose["exact"]:
        lo2, ls2 = _relabel(*loose["chi2"], thr2)
        same = np.array_equal(lo2, lo) and (np.array_equal(ls2, ls) or (ls2 >= 0).sum() == 0)
    if same:  # the final threshold keeps the loose pass's labels: its fit is the answer
        planar, (co, cs) = state, loose["chi2"]
    else:
        info = {}
        planar = _ml_loop(d, "plane", R_o, t_o, pm, lo, ls, thr2, max_it, info, points=loose.get("points"))
        co, cs = info["chi2"] if "chi2" in info else _chi2_all(d, "plane", planar[0], planar[1], planar[2])
    score = float(np.minimum(co.min(0), thr2).sum() + np.minimum(cs.min(0), thr2).sum())
    return dict(trial=trial, initial=initial, planar=planar, score=score)


def _find_plane(d: _Data, R_o, t_o, lo, rng, thr2):
    """Another plane among the optical outliers (sequential RANSAC scored by Sampson error)."""
    out = np.flatnonzero(lo < 0)
    min_support = max(8, int(0.05 * d.n_o))
    if out.size < min_support:
        return None
    X = _triangulate_optical(d.x1[out], d.x2[out], R_o, t_o)
    fx, fy, cx, cy = d.K
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    Ki = np.linalg.inv(K)

    def score(m):
        Hs = K @ (R_o[None] + t_o[None, :, None] * m[:, None, :]) @ Ki
        e = homography_sampson(Hs, d.u1[out], d.u2[out]) / d.sp**2
        return (e < thr2).sum(1), np.minimum(e, thr2).sum(1)

    cands = []
    m_tri = sequential_ransac_plane(X, score, rng, n_hypotheses=128, min_support=min_support)
    if m_tri is not None:
        cands.append(m_tri)
    # a hypothesis that does not lean on the current motion: OpenCV's homography of the
    # remaining matches, and the plane m that best explains it, lambda H ~ R_o + t_o m^T
    sub = _Data(d.rig, d.K, d.x1[out], d.x2[out], d.u1[out], d.u2[out], d.r1[:0], d.th1[:0], d.r2[:0], d.th2[:0],
                d.sp, d.sr, d.sa, d.fov)
    H, inl, _ = _homography(sub, 3 * d.sp, 0.999, 1000)
    if H is not None and inl.sum() >= min_support and not _collinear(d.u1[out][inl], d.sp):
        He = Ki @ H @ K
        # unknowns (lambda, m): lambda He - t_o m^T = R_o, nine linear equations
        A = np.zeros((9, 4))
        A[:, 0] = He.ravel()
        for i in range(3):
            for j in range(3):
                A[3 * i + j, 1 + j] = -t_o[i]
        sol = np.linalg.lstsq(A, R_o.ravel(), rcond=None)[0]
        m_h = sol[1:]
        if np.all(np.isfinite(m_h)) and np.median(np.c_[d.x1[out][inl], np.ones(inl.sum())] @ m_h) > 0:
            cands.append(m_h)
    if not cands:
        return None
    sup, cost = score(np.array(cands))
    k = int(np.lexsort((cost, -sup))[0])
    return cands[k] if sup[k] >= min_support else None


def _estimate_essential(d, thr_px, conf, iters, p_in, max_it):
    fail = lambda msg, **kw: _failed(d, msg, d.n_o, d.n_s, model="essential", **kw)  # noqa: E731
    R_E, t_E, inl, msg = _essential(d, thr_px, conf, iters)
    if R_E is None:
        return fail(msg)
    thr1 = float(_chi2.ppf(p_in, 1))
    # Starts: the five-point essential matrix, and, where one homography explains (nearly) all its
    # inliers (a planar scene, or a rotation), each of the homography's decompositions too. On a
    # plane the essential matrix is not unique: RANSAC's may be another that fits the optical
    # matches within the noise, and the sonar then agrees with a wrong motion at a local minimum
    # of the likelihood. Each start is scaled by the sonar and refined; the one with the least
    # truncated cost over all matches (every match's chi-square, capped at the inlier threshold)
    # wins.
    starts = [(R_E, t_E)]
    plane = _dominant_plane(d, inl, thr_px, conf, iters)
    if plane is not None:
        for sol in _decompose(d, *plane)[0]:
            nt = float(np.linalg.norm(sol.t_over_d))
            t_dir = sol.t_over_d / nt if nt > 1e-12 else None
            # RANSAC's essential matrix is often one of these: the same start is refined once
            if t_dir is not None and not any(np.abs(R - sol.R_o).max() < 1e-5 and t @ t_dir > 1 - 1e-9
                                             for R, t in starts):
                starts.append((sol.R_o, t_dir))
    runs = []
    first_fail = None
    for R_o, t_dir in starts:
        cands, c = _essential_scale(d, R_o, t_dir)
        pick = _pick_scale(cands, c, lambda sc, R_o=R_o, t_dir=t_dir: _essential_consensus(d, R_o, t_dir, sc),
                           thr1, thr1)
        if pick is None:
            first_fail = first_fail or "no sonar match gives a scale (no parallax in the sonar views)"
            continue
        j, support, son_inl, _ = pick
        if d.n_s >= 3 and support < 2:
            first_fail = first_fail or "no two sonar matches agree on the scale"
            continue
        lo = np.where(inl, 0, -1)
        ls = np.where(son_inl, 0, -1)
        ls[j] = 0
        t_o = float(cands[j]) * t_dir
        initial = _stage(d, "initial", R_o, t_o, np.zeros((0, 3)), lo, ls, 0, np.nan)
        info = {}
        state = _ml_loop(d, "free", R_o, t_o, np.zeros((0, 3)), lo, ls, thr1, max_it, info=info)
        co, cs = info["chi2"] if "chi2" in info else _chi2_all(d, "free", state[0], state[1], np.zeros((0, 3)))
        score = float(np.minimum(co, thr1).sum() + np.minimum(cs, thr1).sum())
        runs.append((score, state, initial, (R_o, t_dir), cands, j, support))
    if not runs:
        return fail(first_fail)
    best = min(runs, key=lambda r: r[0])
    score, state, initial, (R_m, t_m), cands, j, support = best
    R_o, t_o, _, lo, ls, it, cost, prob = state
    stages = [initial, _stage(d, "essential", R_o, t_o, np.zeros((0, 3)), lo, ls, it,
                              cost if cost is not None else np.nan)]
    mono = (MonocularSolution(R_m, t_m, np.full(3, np.nan)),)
    res = _finish(d, "essential", R_o, t_o, np.zeros((0, 3)), lo, ls, stages, mono, cands, j, (support,), prob)
    if plane is None or not res or len(runs) < 2:
        return res
    # A planar scene: with every point free, the likelihood may not tell the true motion from
    # another (the homography's dual), the sonar points settling wherever fits (the dual won
    # by 13.6 in one draw, lost by 7 in others). A rival start's refined motion whose truncated
    # cost is within _AMBIGUOUS_CHI2 of the winner's, and which is a different motion (outside
    # the winner's 99.9 % confidence region), makes the answer a coin toss: the homography
    # model, whose sonar points lie on the plane, decides; if it cannot, the result is falsy
    # (``ambiguous``) and says so.
    try:
        Ci = np.linalg.inv(res.covariance_motion)
    except np.linalg.LinAlgError:
        Ci = None
    rivals = []
    for r in runs:
        if r is best or r[0] > score + _AMBIGUOUS_CHI2:
            continue
        e = np.concatenate([B.log_so3(r[1][0] @ R_o.T), r[1][1] - t_o])
        if Ci is None or not np.all(np.isfinite(e)) or e @ Ci @ e > _chi2.ppf(0.999, 6):
            rivals.append(r)
    if not rivals:
        return res
    r = min(rivals, key=lambda x: x[0])
    dw = float(np.rad2deg(np.linalg.norm(B.log_so3(r[1][0] @ R_o.T))))
    why = (f"the scene is planar and the essential model cannot tell two motions apart (truncated chi-square "
           f"{score:.1f} and {r[0]:.1f}, within {_AMBIGUOUS_CHI2:.1f}; {dw:.2g} deg and "
           f"{np.linalg.norm(r[1][1] - t_o):.2g} m apart)")
    hom = _estimate_homography(d, thr_px, conf, iters, p_in, max_it, 1, np.random.default_rng(0))
    if hom:
        return replace(hom, message=f"{why}: the homography model decided; {hom.message}")
    alt = _stage(d, "essential_rival", r[1][0], r[1][1], np.zeros((0, 3)), r[1][3], r[1][4], r[1][5],
                 r[1][6] if r[1][6] is not None else np.nan)
    out = _failed(d, f"{why}, and the homography model could not decide ({hom.message}): no answer rather than "
                     f"a wrong one; both motions are in .stages ('essential', 'essential_rival')",
                  d.n_o, d.n_s, stages=stages + [alt], monocular=mono, model="essential")
    return replace(out, ambiguous=True)


# Two motions (6 parameters apart) whose truncated costs differ by less than the 99.9 % quantile
# of chi-square with 6 degrees of freedom are not told apart by the likelihood ratio (see estimate)
_AMBIGUOUS_CHI2 = float(_chi2.ppf(0.999, 6))


def _dominant_plane(d: _Data, inl_e, thr_px, conf, iters):
    """``(H, inliers)`` (a mask over all optical matches) when one homography explains at least
    80 % of the essential matrix's inliers ``inl_e``: a planar scene (or a rotation about the
    camera centre), where the essential matrix is not unique; else None.

    The homography's transfer error carries both images' noise in two axes (``sqrt(2) sigma``
    per axis) where the essential matrix's Sampson distance is one axis: its threshold is the
    essential's times 1.43 (3 sigma -> the 99 % radius of that 2-D error, 4.29 sigma). This only
    decides whether the homography's motions are tried as well; the likelihood chooses."""
    idx = np.flatnonzero(inl_e)
    H, inl_h, _ = _homography(_subset(d, idx), 1.43 * thr_px, conf, iters)
    if H is None or int(np.sum(inl_h)) < max(4, 0.8 * idx.size):
        return None
    mask = np.zeros(d.n_o, bool)
    mask[idx[inl_h]] = True
    return H, mask


def _finish(d, model, R_o, t_o, pm, lo, ls, stages, mono, cands, j, supports, prob=None):
    kind = "plane" if model == "homography" else "free"
    th = _theta(t_o, pm if kind == "plane" else np.zeros((0, 3)))
    last = prob
    prob, bo, bs, _, _ = _problem(d, lo, ls, kind, R_o, pm)
    if last is not None:  # the last fit's, at this state: its points are at the optimum
        # (only when its blocks are these, the same matches on the same planes; else every
        # point is solved afresh at this state)
        prob.adopt_points(last)
    e = prob.residuals(th)
    J = prob.jacobian(th)
    cov, full = B.covariance_from_jacobian(J)
    n_p = 2 if kind == "plane" else 3
    dof = int(e.size - J.shape[1] - n_p * (bo.n + bs.n))
    if not full or (ls >= 0).sum() == 0:
        return _failed(d, "the motion is not observable from these matches (rank-deficient Jacobian)", d.n_o, d.n_s,
                       stages=stages, monocular=mono, model=model)
    n_in = int((lo >= 0).sum())
    if n_in < max(8, d.min_inliers * d.n_o):
        return _failed(d, f"only {n_in} of {d.n_o} optical matches fit the {model} model: no consistent motion "
                          f"(min_inlier_fraction={d.min_inliers:g})", d.n_o, d.n_s, stages=stages, monocular=mono,
                       model=model)
    planes = tuple(Plane.from_m(m) for m in pm)
    msg = (f"{model}: {int((lo >= 0).sum())}/{d.n_o} optical and {int((ls >= 0).sum())}/{d.n_s} sonar inliers, "
           f"{len(planes)} plane(s), {stages[-1].iterations} iteration(s)")
    return MotionResult(True, msg, model, R_o, t_o, planes, lo, ls, cov, tuple(stages), tuple(mono),
                        np.asarray(cands, float), int(j), tuple(int(s) for s in supports), float(e @ e), dof, d.rig)
