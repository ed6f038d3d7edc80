"""Extrinsic calibration of an opti-acoustic rig from views of a planar grid (thesis appendix A).

Each view shows the same grid corners to both sensors: pixels ``(u, v)`` and sonar
``(range, azimuth)``, matched corner by corner. The grid's layout need not be known, only
that its corners are coplanar; each view has its own plane ``m_v . P_o = 1`` (camera frame).
The unknowns are the rig ``P_s = R P_o + t`` and the planes.

:func:`extrinsics` runs

1. a closed-form start. For points on a plane, ``P_o = q / (m . q)`` with ``q = (x, y, 1)``
   the normalised pixel, so the sonar's ``(X_s, Y_s) = (R_1 . P_o + t_x, R_2 . P_o + t_y)``
   is a homography of ``q``: ``G = [R_1 + t_x m; R_2 + t_y m; m]`` (rows). With the
   elevation taken as zero, ``(X_s, Y_s) ~ r (sin(theta), cos(theta))`` are the fan
   coordinates, so ``G_v`` is fitted per view; ``R_1, R_2, t_x, t_y`` are shared by all
   views, which makes ``lambda_v G_v = G`` a homogeneous linear system (two views or more),
   and ``R_3 = R_1 x R_2``. ``t_z`` never enters ``G``: it is the weak direction, found by a
   one-dimensional search on the ranges;
2. maximum likelihood: the reprojection errors of every corner in the image (px) and in the
   sonar (range, azimuth), whitened by their noise, minimised by
   ``scipy.optimize.least_squares`` over ``(R, t, m_1, ..., m_V)`` with each corner's position
   on its plane eliminated (variable projection, :mod:`._bundle`).

Why the reprojection errors rather than the thesis's (A.3): (A.3) compares 3D points built
from one sensor with 3D points built from the other; both are functions of the unknowns
with noise that depends on them (first-order covariances that must be re-derived at every
step), and the sonar's 3D point needs an elevation that (6.16) can only give up to a sign.
The reprojection errors are the measurements themselves: the cost is the exact negative
log-likelihood under Gaussian pixel, range and azimuth noise, the elevation is implicit (the
plane places each corner), and the covariance at the optimum follows from the Jacobian.

The elevation ambiguity of the sonar makes some directions weak (rotation about the sonar's
X axis, "pitch", and ``t_z``): the result reports the standard deviations and the
eigen-structure of the covariance, and which directions are weakly observed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_array, as_positive, as_rng, is_integer
from ..camera import PinholeCamera
from ..frames import R_SONAR_FROM_CAMERA_FORWARD, orthonormalize
from ..rig import Rig
from . import _bundle as B

__all__ = ["CalibrationView", "CalibrationResult", "check_view", "extrinsics", "simulate_views", "load_view", "save_view"]


@dataclass(frozen=True, eq=False)
class CalibrationView:
    """One view of the planar grid, corner by corner.

    Attributes
    ----------
    pixels : ndarray (N, 2)
        Image pixels ``(u, v)`` of the corners.
    ranges : ndarray (N,)
        Sonar ranges (m) of the same corners.
    azimuths : ndarray (N,)
        Sonar azimuths (rad).
    """

    pixels: np.ndarray
    ranges: np.ndarray
    azimuths: np.ndarray

    def __post_init__(self):
        px = as_array(self.pixels, "pixels", (None, 2))
        n = px.shape[0]
        r = as_array(self.ranges, "ranges", (n,))
        a = as_array(self.azimuths, "azimuths", (n,))
        if np.any(r <= 0):
            i = int(np.argmax(r <= 0))
            raise ValueError(f"ranges: must be > 0, got {float(r[i])!r} at corner {i}")
        if np.any(np.abs(a) > np.pi / 2):
            i = int(np.argmax(np.abs(a) > np.pi / 2))
            raise ValueError(f"azimuths: a forward-looking sonar sees |azimuth| <= pi/2 rad, got {float(a[i])!r} at corner {i} "
                             "(degrees given as radians? name the column azimuth_deg)")
        object.__setattr__(self, "pixels", px)
        object.__setattr__(self, "ranges", r)
        object.__setattr__(self, "azimuths", a)

    @property
    def n(self) -> int:
        return self.pixels.shape[0]


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """The calibrated rig.

    ``bool(result)`` is False on degenerate input (``message`` says why; arrays are NaN).

    Attributes
    ----------
    success : bool
    message : str
    R : ndarray (3, 3)
        ``R_sonar_from_camera``.
    t : ndarray (3,)
        Camera centre in the sonar frame (m).
    covariance : ndarray (6, 6)
        Covariance of ``(w, t)``: ``w`` (rad) the rotation error in the sonar frame,
        ``R_true ~ exp(w) R``; ``w_x`` is pitch (about the sonar's X, right), ``w_y`` roll
        (about Y, forward), ``w_z`` yaw (about Z, up); ``t`` in m.
    std : ndarray (6,)
        Standard deviations of ``(pitch, roll, yaw, t_x, t_y, t_z)`` (rad, m).
    eigenvalues : ndarray (6,)
        Eigenvalues of the covariance with rotations expressed as displacements at the mean
        range (m^2), largest (weakest direction) first.
    eigenvectors : ndarray (6, 6)
        Matching unit eigenvectors (columns) over ``(pitch, roll, yaw, t_x, t_y, t_z)``.
    weak : tuple of str
        Degrees of freedom whose standard deviation (rotations as displacements at the mean
        range) exceeds three times the best-determined one.
    planes : ndarray (V, 4)
        Each view's plane: unit normal (camera frame) and distance (m).
    initial_R, initial_t : ndarray
        The closed-form start.
    rms_pixel, rms_range, rms_azimuth : float
        Root mean square residuals (px, m, rad).
    chi2 : float
        Sum of whitened squared residuals.
    dof : int
        Its degrees of freedom.
    """

    success: bool
    message: str
    R: np.ndarray
    t: np.ndarray
    covariance: np.ndarray
    std: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    weak: tuple
    planes: np.ndarray
    initial_R: np.ndarray
    initial_t: np.ndarray
    rms_pixel: float
    rms_range: float
    rms_azimuth: float
    chi2: float
    dof: int

    DOF_NAMES = ("pitch", "roll", "yaw", "t_x", "t_y", "t_z")

    def __bool__(self) -> bool:
        return bool(self.success)

    def rig(self, camera: PinholeCamera, sonar=None) -> Rig:
        """The calibrated :class:`Rig` (a ValueError with the failure's message if the calibration failed)."""
        if not self.success:
            raise ValueError(f"rig: the calibration failed ({self.message}); there is no calibrated rig")
        return Rig(self.R, self.t, camera, sonar)

    def to_dict(self) -> dict:
        """JSON-ready summary (angles in degrees where the key says so)."""
        from ..frames import euler_xyz_from_rotation

        ok = self.success
        return {
            "success": bool(ok),
            "message": self.message,
            "R": self.R.tolist() if ok else None,
            "t": self.t.tolist() if ok else None,
            "rotation_about_sonar_xyz_deg": np.rad2deg(
                euler_xyz_from_rotation(self.R @ R_SONAR_FROM_CAMERA_FORWARD.T)).tolist() if ok else None,
            "std": {n: float(v) for n, v in zip(self.DOF_NAMES, self.std)},
            "std_deg_or_mm": {n: float(v * (180 / np.pi if i < 3 else 1e3))
                              for i, (n, v) in enumerate(zip(self.DOF_NAMES, self.std))},
            "weak": list(self.weak),
            "eigenvalues": self.eigenvalues.tolist(),
            "eigenvectors": self.eigenvectors.tolist(),
            "planes_normal_distance": self.planes.tolist(),
            "initial_R": self.initial_R.tolist(),
            "initial_t": self.initial_t.tolist(),
            "rms_pixel": self.rms_pixel,
            "rms_range": self.rms_range,
            "rms_azimuth_deg": float(np.rad2deg(self.rms_azimuth)),
            "chi2": self.chi2,
            "dof": self.dof,
        }


def load_view(path) -> CalibrationView:
    """Read one view's corners from a CSV or NPZ file.

    CSV: a header row naming the columns ``u``, ``v`` (px), ``range`` (m) and ``azimuth``
    (rad) or ``azimuth_deg`` (deg), in any order, comma-separated; lines starting with ``#``
    are comments; one row per grid corner. NPZ: arrays ``u``, ``v``, ``range`` and
    ``azimuth`` (rad) or ``azimuth_deg``.

    Raises
    ------
    ValueError
        Naming the file and what is missing.
    """
    from pathlib import Path

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: view file not found")
    if path.suffix.lower() == ".npz":
        try:
            with np.load(path) as z:
                cols = {k: np.asarray(z[k], float).ravel() for k in z.files}
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: cannot read NPZ: {exc}") from None
    else:
        try:
            lines = [ln for ln in path.read_text(encoding="utf-8-sig").splitlines()  # a spreadsheet's BOM
                     if ln.strip() and not ln.lstrip().startswith("#")]
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: cannot read CSV: {exc}") from None
        if not lines:
            raise ValueError(f"{path}: empty view file")
        names = [c.strip().lower() for c in lines[0].split(",")]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"{path}: column {dup[0]!r} appears twice in the header")
        rows = []
        for k, ln in enumerate(lines[1:], 2):
            cells = ln.split(",")
            if len(cells) != len(names):
                raise ValueError(f"{path}: data row {k - 1} has {len(cells)} values, the header names {len(names)} "
                                 f"columns ({', '.join(names)})")
            try:
                rows.append([float(x) for x in cells])
            except ValueError as exc:
                raise ValueError(f"{path}: data row {k - 1}: {exc}") from None
        rows = np.array(rows, float).reshape(-1, len(names))
        cols = {k: rows[:, i] for i, k in enumerate(names)}
    need = {"u", "v", "range"}
    if not need <= set(cols) or not ({"azimuth", "azimuth_deg"} & set(cols)):
        raise ValueError(f"{path}: expected columns u, v, range and azimuth (rad) or azimuth_deg; got {sorted(cols)}")
    if "azimuth" in cols and "azimuth_deg" in cols:
        raise ValueError(f"{path}: both azimuth (rad) and azimuth_deg given; keep one")
    az = cols["azimuth"] if "azimuth" in cols else np.deg2rad(cols["azimuth_deg"])
    try:
        return CalibrationView(np.stack([cols["u"], cols["v"]], -1), cols["range"], az)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def save_view(path, view: CalibrationView, *, header: str = "") -> None:
    """Write a view as the CSV :func:`load_view` reads (azimuth in degrees)."""
    from .._atomic import write_text

    rows = np.column_stack([view.pixels, view.ranges, np.rad2deg(view.azimuths)])
    comment = "".join(f"# {line}\n" for line in header.splitlines()) if header else ""
    write_text(path, comment + "u,v,range,azimuth_deg\n"
                          + "".join(f"{u:.6f},{v:.6f},{r:.6f},{a:.6f}\n" for u, v, r, a in rows))


def _failed(message, V=0, R0=None, t0=None):
    nan = float("nan")
    return CalibrationResult(False, message, np.full((3, 3), np.nan), np.full(3, np.nan), np.full((6, 6), np.nan),
                             np.full(6, np.nan), np.full(6, np.nan), np.full((6, 6), np.nan), (),
                             np.full((V, 4), np.nan), np.full((3, 3), np.nan) if R0 is None else R0,
                             np.full(3, np.nan) if t0 is None else t0, nan, nan, nan, nan, 0)


def check_view(view: CalibrationView, camera: PinholeCamera, sonar=None, *, name: str = "view") -> None:
    """Raise a ValueError naming ``name`` if a view's corners lie outside the image or the sonar's fan.

    Corners far outside what the sensors can see mean a mistake in the data (wrong units, wrong
    camera, swapped columns), not noise: the slack (5 % of the image, 1 degree or a quarter beam
    beyond the fan, 5 % of the range span) lets noisy corners at the edges through.
    """
    u, v = view.pixels[:, 0], view.pixels[:, 1]
    mu, mv = 0.05 * camera.width, 0.05 * camera.height
    bad = (u < -0.5 - mu) | (u > camera.width - 0.5 + mu) | (v < -0.5 - mv) | (v > camera.height - 0.5 + mv)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise ValueError(f"{name}: corner {i} at pixel ({u[i]:.6g}, {v[i]:.6g}) lies outside the "
                         f"{camera.width} x {camera.height} image")
    if sonar is not None:
        half = float(sonar.fov_azimuth) / 2 + max(np.deg2rad(1.0), 0.25 * float(getattr(sonar, "beamwidth_azimuth", 0.0)))
        bad = np.abs(view.azimuths) > half
        if np.any(bad):
            i = int(np.argmax(bad))
            raise ValueError(f"{name}: corner {i} has azimuth {np.rad2deg(view.azimuths[i]):.4g} deg, outside the "
                             f"sonar's fan of +-{np.rad2deg(sonar.fov_azimuth) / 2:.4g} deg (degrees given as radians?)")
        slack = 0.05 * (float(sonar.range_max) - float(sonar.range_min))
        bad = (view.ranges < float(sonar.range_min) - slack) | (view.ranges > float(sonar.range_max) + slack)
        if np.any(bad):
            i = int(np.argmax(bad))
            raise ValueError(f"{name}: corner {i} has range {view.ranges[i]:.6g} m, outside the sonar's "
                             f"{sonar.range_min:g}-{sonar.range_max:g} m")


def _views(views):
    out = []
    if isinstance(views, (CalibrationView, dict)) or not hasattr(views, "__len__"):
        raise ValueError("views: expected a sequence of views (CalibrationView or (pixels, ranges, azimuths))")
    for i, v in enumerate(views):
        if isinstance(v, CalibrationView):
            out.append(v)
            continue
        try:
            px, r, a = v
        except (TypeError, ValueError):
            raise ValueError(f"views[{i}]: expected a CalibrationView or (pixels, ranges, azimuths)") from None
        try:
            out.append(CalibrationView(px, r, a))
        except ValueError as exc:
            raise ValueError(f"views[{i}]: {exc}") from None
    return out


# --------------------------------------------------------------------------- closed form
def _fan_homography(q, r, az):
    """Least-squares homography from normalised coordinates to fan coordinates (DLT, normalised)."""
    xs, ys = r * np.sin(az), r * np.cos(az)
    src = q[:, :2]
    dst = np.stack([xs, ys], -1)

    def norm(p):
        c = p.mean(0)
        s = np.sqrt(2) / max(np.sqrt(((p - c) ** 2).sum(1)).mean(), 1e-12)
        return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])

    T1, T2 = norm(src), norm(dst)
    a = np.c_[src, np.ones(len(src))] @ T1.T
    b = np.c_[dst, np.ones(len(dst))] @ T2.T
    z = np.zeros((len(a), 3))
    A = np.concatenate([np.c_[a, z, -b[:, :1] * a], np.c_[z, a, -b[:, 1:2] * a]])
    _, s, Vt = np.linalg.svd(A)
    H = Vt[-1].reshape(3, 3)
    G = np.linalg.inv(T2) @ H @ T1
    return G, s[-2] > 1e-9 * s[0]


def _closed_form(qs, views, sr, sa, fov):
    """Closed-form ``R, t, planes`` (see the module docstring), or a message."""
    Gs = []
    for q, v in zip(qs, views):
        G, ok = _fan_homography(q, v.ranges, v.azimuths)
        if not ok:
            return None, "a view's corners do not determine a homography (collinear corners?)"
        Gs.append(G / np.linalg.norm(G))
    V = len(Gs)
    M = np.zeros((6 * V, 6 + 3 * V))
    for v, G in enumerate(Gs):
        c = 6 + 3 * v
        M[6 * v:6 * v + 3, 0:3] = np.eye(3)
        M[6 * v:6 * v + 3, c] = -G[0]
        M[6 * v:6 * v + 3, c + 1] = G[2]
        M[6 * v + 3:6 * v + 6, 3:6] = np.eye(3)
        M[6 * v + 3:6 * v + 6, c] = -G[1]
        M[6 * v + 3:6 * v + 6, c + 2] = G[2]
    _, s, Vt = np.linalg.svd(M)
    if s.size >= M.shape[1] and s[-2] < 1e-9 * s[0]:
        return None, "the views do not determine the rotation (planes too alike or too few views)"
    z = Vt[-1]
    R1, R2 = z[0:3], z[3:6]
    k = 2.0 / (np.linalg.norm(R1) + np.linalg.norm(R2))
    z = z * k
    lam = z[6::3]
    m = np.array([lam[v] * Gs[v][2] for v in range(V)])
    # sign: the points are in front of the camera, m . q > 0
    if np.median(np.concatenate([q @ mv for q, mv in zip(qs, m)])) < 0:
        z, m, lam = -z, -m, -lam
    R1, R2 = z[0:3], z[3:6]
    R = orthonormalize(np.stack([R1, R2, np.cross(R1, R2)]))
    return _translation_start(qs, views, R, sr, sa, fov), ""


def _translation_start(qs, views, R, sr, sa, fov):
    """``t`` and the planes given ``R``: ``t_x, t_y`` linear, ``t_z`` by a one-dimensional search."""
    # t_x, t_y: each corner's fan point (X_s, Y_s) lies on the line t + z (R_1 q, R_2 q) (its
    # depth z unknown), so its normal n gives one linear equation n . t = n . (X_s, Y_s)
    Q = np.concatenate(qs)
    r_all = np.concatenate([v.ranges for v in views])
    a_all = np.concatenate([v.azimuths for v in views])
    fan = np.stack([r_all * np.sin(a_all), r_all * np.cos(a_all)], -1)
    d = np.stack([Q @ R[0], Q @ R[1]], -1)
    nrm = np.stack([d[:, 1], -d[:, 0]], -1) / np.linalg.norm(d, axis=1, keepdims=True)
    txy = np.linalg.lstsq(nrm, np.einsum("ni,ni->n", nrm, fan), rcond=None)[0]
    tx, ty = float(txy[0]), float(txy[1])
    # t_z: one-dimensional search on the whitened range and azimuth errors, with each corner
    # placed where its ray meets its range sphere (for the trial t)
    Q = np.concatenate(qs)
    QR = Q @ R.T
    qq = np.einsum("ni,ni->n", Q, Q)
    r = np.concatenate([v.ranges for v in views])
    a = np.concatenate([v.azimuths for v in views])
    span = 0.5 * float(np.median(r))

    def cost(tz):
        T = np.stack([np.full_like(tz, tx), np.full_like(tz, ty), tz], -1)[:, None, :]  # (G, 1, 3)
        b = np.einsum("ni,gni->gn", QR, np.broadcast_to(T, (tz.size,) + QR.shape))
        c = np.sum(T * T, -1) - r**2
        zz = (-b + np.sqrt(np.maximum(b * b - qq * c, 0.0))) / qq
        Y = QR[None] * zz[..., None] + T
        rr = np.linalg.norm(Y, axis=-1)
        aa = np.arctan2(Y[..., 0], Y[..., 1])
        el = np.arctan2(Y[..., 2], np.hypot(Y[..., 0], Y[..., 1]))
        c = (((rr - r) / sr) ** 2 + (B.wrap(aa - a) / sa) ** 2).sum(-1)
        # corners must lie inside the elevation aperture
        return c + 1e6 * np.sum(np.maximum(np.abs(el) - fov / 2, 0.0) ** 2, -1)

    grid = np.linspace(-span, span, 401)
    c = cost(grid)
    i = int(np.argmin(c))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    for _ in range(60):  # golden section
        x1, x2 = hi - 0.618 * (hi - lo), lo + 0.618 * (hi - lo)
        if cost(np.array([x1]))[0] < cost(np.array([x2]))[0]:
            hi = x2
        else:
            lo = x1
    t = np.array([tx, ty, 0.5 * (lo + hi)])
    return R, t, _planes_from_ranges(qs, views, R, t)


def _planes_from_ranges(qs, views, R, t):
    """Each view's plane through its corners placed where their pixel rays meet their range spheres.

    Along the ray ``P_o = z q`` the sonar range is ``|z R q + t| = r``:
    ``|q|^2 z^2 + 2 (t . R q) z + |t|^2 - r^2 = 0``, positive root; the plane ``m`` is then
    the least-squares solution of ``P_o m = 1``.
    """
    ms = []
    for q, v in zip(qs, views):
        a = np.einsum("ni,ni->n", q, q)
        b = (q @ R.T) @ t
        c = t @ t - v.ranges**2
        z = (-b + np.sqrt(np.maximum(b * b - a * c, 0.0))) / a
        P = q * z[:, None]
        ms.append(np.linalg.lstsq(P, np.ones(v.n), rcond=None)[0])
    return np.array(ms)


# --------------------------------------------------------------------------- maximum likelihood
def _problem(K, qs, views, sp, sr, sa, R_ref):
    meas = []
    plane = []
    q0 = []
    for v, (q, view) in enumerate(zip(qs, views)):
        u = np.stack([K[0] * q[:, 0] + K[2], K[1] * q[:, 1] + K[3]], -1)
        meas.append(np.stack([u, np.stack([view.ranges, view.azimuths], -1)], 1))
        plane.append(np.full(view.n, v))
        q0.append(q[:, :2])
    meas = np.concatenate(meas)
    plane = np.concatenate(plane)
    q0 = np.concatenate(q0)
    chans = (B.Channel("camera", False, np.eye(3), np.zeros(3)), B.Channel("sonar", True, np.eye(3), np.zeros(3)))
    sig = np.array([[sp, sp], [sr, sa]])
    block = B.Block(chans, meas, sig, "plane", lambda Rv, cv, planes, pl: q0, plane)
    return B.Problem(K, [block], len(views), R_ref), block


def extrinsics(
    camera: PinholeCamera,
    views,
    *,
    sigma_pixel: float = 1.0,
    sigma_range: float = 0.01,
    sigma_azimuth: float = float(np.deg2rad(0.2)),
    sonar=None,
    initial=None,
) -> CalibrationResult:
    """The rig's ``R`` and ``t`` from views of a planar grid seen by both sensors (appendix A).

    Parameters
    ----------
    camera : PinholeCamera
        The camera's intrinsics.
    views : sequence of CalibrationView or (pixels (N, 2), ranges (N,), azimuths (N,))
        Each view's grid corners: pixels (px) and sonar range (m) and azimuth (rad), in the
        same order. Two views or more (planes of different orientation) for the closed-form
        start; one view is enough when ``initial`` is given.
    sigma_pixel : float
        Pixel noise (px).
    sigma_range : float
        Range noise (m).
    sigma_azimuth : float
        Azimuth noise (rad).
    sonar : SonarSpec, optional
        Its elevation aperture keeps the corners inside the fan in the closed form.
    initial : (R (3, 3), t (3,)), optional
        A start instead of the closed form (e.g. the mounting drawing). ``R`` must be a
        rotation to within 0.01 (``max |R^T R - I|``, ``det > 0``); it is then orthonormalised.

    Returns
    -------
    CalibrationResult
        Falsy, with a message, on degenerate input (too few views or corners, collinear
        corners, views that do not determine the rotation).
    """
    if not isinstance(camera, PinholeCamera):
        raise ValueError(f"camera: expected a PinholeCamera, got {type(camera).__name__}")
    vs = _views(views)
    for i, v in enumerate(vs):
        check_view(v, camera, sonar, name=f"views[{i}]")
    sp = as_positive(sigma_pixel, "sigma_pixel")
    sr = as_positive(sigma_range, "sigma_range")
    sa = as_positive(sigma_azimuth, "sigma_azimuth")
    fov = float(sonar.fov_elevation) if sonar is not None else np.pi
    V = len(vs)
    if V == 0:
        return _failed("no views")
    if any(v.n < 4 for v in vs):
        return _failed(f"every view needs at least 4 corners; got {[v.n for v in vs]}", V)
    qs = []
    for v in vs:
        xn = camera.normalized(v.pixels)
        q = np.c_[xn, np.ones(v.n)]
        c = xn - xn.mean(0)
        if np.linalg.svd(c, compute_uv=False)[1] * camera.fx / np.sqrt(v.n) < 2 * sp:
            return _failed("a view's corners are collinear in the image (grid seen edge-on)", V)
        qs.append(q)
    K = (camera.fx, camera.fy, camera.cx, camera.cy)
    rbar = float(np.mean(np.concatenate([v.ranges for v in vs])))
    if initial is None:
        if V < 2:
            return _failed("the closed-form start needs two views or more (or pass initial=(R, t))", V)
        cf, msg = _closed_form(qs, vs, sr, sa, fov)
        if cf is None:
            return _failed(msg, V)
        # the closed form's rotation can be poor where the planes are nearly fronto-parallel
        # (R_2 and m then nearly parallel): also start from a camera looking where the sonar
        # looks, the usual mounting, and keep the better fit
        starts = [cf, _translation_start(qs, vs, R_SONAR_FROM_CAMERA_FORWARD, sr, sa, fov)]
    else:
        try:
            R0, t0 = initial
        except (TypeError, ValueError):
            raise ValueError("initial: expected a pair (R (3, 3), t (3,))") from None
        R0 = as_array(R0, "initial R", (3, 3))
        t0 = as_array(t0, "initial t", (3,))
        # a start may be rounded (a mounting drawing), not arbitrary: orthonormalising would turn
        # a zero matrix into the identity and a reflection into some rotation without a word
        dev = float(np.max(np.abs(R0.T @ R0 - np.eye(3))))
        det = float(np.linalg.det(R0))
        if not (dev <= 0.01 and det > 0):
            raise ValueError(f"initial R: not close to a rotation (max |R^T R - I| = {dev:.3g}, det = {det:.3g}; "
                             f"expected R_sonar_from_camera, orthonormal with det +1): {np.round(R0, 4).tolist()}")
        R0 = orthonormalize(R0)
        starts = [(R0, t0, _planes_from_ranges(qs, vs, R0, t0))]

    def fit(R0, t0, m0):
        if not (np.all(np.isfinite(m0)) and np.all(np.isfinite(t0))):
            return None
        prob, _ = _problem(K, qs, vs, sp, sr, sa, R0)
        sol = prob.solve(np.concatenate([np.zeros(3), t0, m0.ravel()]), max_nfev=200)
        if not np.all(np.isfinite(sol.x)):
            return None
        return (sol.cost,) + prob.unpack(sol.x)

    fits = [f for f in (fit(*st) for st in starts) if f is not None]
    if not fits:
        return _failed("the least squares diverged", V, starts[0][0], starts[0][1])
    best = min(fits, key=lambda f: f[0])
    # t_z (and with it pitch) is weakly observed: restart along t_z too
    for dz in (-0.15, 0.15):
        t1 = best[2] + np.array([0.0, 0.0, dz * rbar])
        f = fit(best[1], t1, _planes_from_ranges(qs, vs, best[1], t1))
        if f is not None and f[0] < best[0]:
            best = f
    R0, t0 = starts[0][0], starts[0][1]
    _, R, t, planes = best
    prob2, block2 = _problem(K, qs, vs, sp, sr, sa, R)
    th = np.concatenate([np.zeros(3), t, planes.ravel()])
    e = prob2.residuals(th)
    J = prob2.jacobian(th)
    cov_all, full = B.covariance_from_jacobian(J)
    if not full:
        return _failed("the views do not determine the rig (rank-deficient Jacobian)", V, R0, t0)
    cov = cov_all[:6, :6]
    std = np.sqrt(np.abs(np.diag(cov)))
    S = np.diag([rbar] * 3 + [1.0] * 3)
    lam, vec = np.linalg.eigh(S @ cov @ S)
    order = np.argsort(lam)[::-1]
    lam, vec = lam[order], vec[:, order]
    disp = std * np.diag(S)
    weak = tuple(n for n, s_ in zip(CalibrationResult.DOF_NAMES, disp) if s_ > 3 * disp.min())
    E = e.reshape(-1, 4)
    res_px = np.sqrt(np.mean((E[:, :2] * sp) ** 2))
    res_r = float(np.sqrt(np.mean((E[:, 2] * sr) ** 2)))
    res_a = float(np.sqrt(np.mean((E[:, 3] * sa) ** 2)))
    dof = int(e.size - J.shape[1] - 2 * block2.n)
    pl = np.array([np.r_[m / np.linalg.norm(m), 1 / np.linalg.norm(m)] for m in planes])
    msg = (f"{V} views, {block2.n} corners: rms {res_px:.3g} px, {res_r * 1e3:.3g} mm, "
           f"{np.rad2deg(res_a):.3g} deg; weak: {', '.join(weak) or 'none'}")
    return CalibrationResult(True, msg, R, t, cov, std, lam, vec, weak, pl, R0, t0, float(res_px), res_r, res_a,
                             float(e @ e), dof)


# --------------------------------------------------------------------------- simulation
def simulate_views(
    rig: Rig,
    n_views: int = 6,
    *,
    grid_shape=(7, 5),
    spacing: float = 0.1,
    distance=(1.5, 3.0),
    tilt_deg: float = 35.0,
    sigma_pixel: float = 0.0,
    sigma_range: float = 0.0,
    sigma_azimuth: float = 0.0,
    seed=0,
) -> tuple[list[CalibrationView], list]:
    """Views of a planar grid placed at random in front of a rig (for tests, examples, experiments).

    The grid (``grid_shape`` corners, ``spacing`` m apart) is centred at a random distance
    in ``distance`` (m) along the sonar's boresight, near the camera's axis, tilted by up to
    ``tilt_deg`` about random axes; only grids whose corners all lie in the image and in
    the sonar's fan (elevation aperture from ``rig.sonar``, else 20 deg) are kept.

    Raises
    ------
    ValueError
        Naming the argument: ``n_views`` not a positive integer, ``grid_shape`` not two positive
        integers, ``spacing`` not > 0, ``distance`` not ``0 < near <= far``, ``tilt_deg`` not in
        [0, 90], a negative noise level.

    Returns
    -------
    views : list of CalibrationView
        Noisy measurements (Gaussian, the given standard deviations).
    corners_camera : list of ndarray (N, 3)
        The corners in the camera frame (m), the ground truth.
    """
    if not isinstance(rig, Rig):
        raise ValueError(f"rig: expected an optiacoustic.Rig, got {type(rig).__name__}")
    if not is_integer(n_views) or n_views < 1:
        raise ValueError(f"n_views: expected a positive integer, got {n_views!r}")
    try:
        nx, ny = grid_shape
    except (TypeError, ValueError):
        raise ValueError(f"grid_shape: expected a pair of positive integers (nx, ny), got {grid_shape!r}") from None
    if any(not is_integer(k) or k < 1 for k in (nx, ny)):
        raise ValueError(f"grid_shape: expected a pair of positive integers (nx, ny), got {grid_shape!r}")
    spacing = as_positive(spacing, "spacing")
    d = as_array(distance, "distance", (2,))
    if not (0 < d[0] <= d[1]):
        raise ValueError(f"distance: expected (near, far) in m with 0 < near <= far, got {d.tolist()}")
    tilt_deg = as_positive(tilt_deg, "tilt_deg", allow_zero=True)
    if tilt_deg > 90:
        raise ValueError(f"tilt_deg: expected a tilt in degrees within [0, 90], got {tilt_deg!r}")
    sigma_pixel = as_positive(sigma_pixel, "sigma_pixel", allow_zero=True)
    sigma_range = as_positive(sigma_range, "sigma_range", allow_zero=True)
    sigma_azimuth = as_positive(sigma_azimuth, "sigma_azimuth", allow_zero=True)
    rng = as_rng(seed)
    fov = rig.fov_elevation if rig.sonar is not None else np.deg2rad(20.0)
    fov_az = float(rig.sonar.fov_azimuth) if rig.sonar is not None else np.deg2rad(90.0)
    nx, ny = int(nx), int(ny)
    gx, gy = np.meshgrid((np.arange(nx) - (nx - 1) / 2) * spacing, (np.arange(ny) - (ny - 1) / 2) * spacing)
    local = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], -1)
    views, truth = [], []
    tries = 0
    while len(views) < n_views:
        tries += 1
        if tries > 5000 * n_views:
            raise ValueError("simulate_views: no grid placement fits both fields of view; relax the settings")
        dist = rng.uniform(d[0], d[1])
        # centre on the sonar's boresight plane, within the elevation aperture
        el = rng.uniform(-0.5, 0.5) * fov / 2
        az = rng.uniform(-0.3, 0.3) * min(fov_az / 2, rig.camera.fov[0] / 2)
        c_s = dist * np.array([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)])
        # grid faces the sonar, tilted about a random axis
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        Rt = B.exp_so3(axis * np.deg2rad(rng.uniform(0, tilt_deg)))
        face = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # grid x -> sonar X, grid y -> -Z, normal -> -Y
        P_s = (local @ face.T) @ Rt.T + c_s
        P_o = rig.camera_from_sonar(P_s)
        if np.any(P_o[:, 2] <= 0.1):
            continue
        uv = rig.camera.project(P_o)
        if not np.all(rig.camera.in_image(uv)):
            continue
        r = np.linalg.norm(P_s, axis=1)
        th = np.arctan2(P_s[:, 0], P_s[:, 1])
        ph = np.arctan2(P_s[:, 2], np.hypot(P_s[:, 0], P_s[:, 1]))
        if np.any(np.abs(ph) > fov / 2) or np.any(np.abs(th) > fov_az / 2):
            continue
        n = len(r)
        views.append(CalibrationView(uv + rng.normal(0, 1, (n, 2)) * sigma_pixel,
                                     r + rng.normal(0, 1, n) * sigma_range,
                                     th + rng.normal(0, 1, n) * sigma_azimuth))
        truth.append(P_o)
    return views, truth
