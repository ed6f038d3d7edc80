"""Sonar-to-optical mapping learned from matched features with Gaussian RBFs (thesis 7.1-7.3).

The input is a sonar fan coordinate ``(x_s, y_s) = r (sin theta, cos theta)`` (m), the output
an optical pixel ``(u, v)``. There is no global closed form (the pixel also depends on the
unknown elevation, docs/derivations.md (ch. 7)), so the mapping is interpolated from
matches with :class:`scipy.interpolate.RBFInterpolator`:

``f(x) = b(x) + sum_i w_i exp(-|x - c_i|^2 / (2 sigma^2))``  (thesis eqs. 7.6-7.7)

with centres ``c_i`` at the training features, width ``sigma`` (m, in the fan plane; scipy's
``epsilon = 1 / (sqrt(2) sigma)``) and a base ``b``:

* ``"none"``: ``b = 0``, the thesis's network (7.6) as written;
* ``"affine"``: a degree-1 polynomial solved with the weights (scipy's ``degree=1``);
* ``"homography"``: the least-squares homography of the matches (``cv2.findHomography``);
  the RBF interpolates what it leaves. A plane seen by a sonar with small elevations
  induces exactly such a homography, so this base is the "dominant plane".

``smoothing = 0`` interpolates (zero training error up to conditioning); ``smoothing > 0``
trades training error for smoothness and tends to the base as it grows: with the homography
base, that is the thesis's "modified mapping" that sends the features to a dominant plane
(sec. 7.3.2). :func:`cross_validate` picks it by leave-one-out error on the matches alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from scipy.interpolate import RBFInterpolator

from .._validate import as_array, as_positive
from ._checks import check_layout, check_matches, query_points

__all__ = ["RBFMapping", "CrossValidation", "IllConditionedWarning", "cross_validate", "epsilon_from_sigma", "BASES",
           "MAX_CONDITION"]

#: Above this condition number of the kernel matrix an exact fit's weights are mostly round-off.
MAX_CONDITION = 1e12


class IllConditionedWarning(RuntimeWarning):
    """An exact RBF fit whose kernel matrix is too ill-conditioned for its weights to mean anything."""

Base = Literal["none", "affine", "homography"]
#: Bases of :class:`RBFMapping` and the fewest features each needs.
BASES = {"none": 3, "affine": 3, "homography": 4}
_DEGREE = {"none": -1, "affine": 1, "homography": -1}


def epsilon_from_sigma(sigma: float) -> float:
    """scipy's Gaussian shape parameter for a width ``sigma``.

    scipy's kernel is ``exp(-(epsilon r)^2)``; the thesis's (7.7) is ``exp(-r^2 / (2 sigma^2))``,
    so ``epsilon = 1 / (sqrt(2) sigma)``, in the inverse units of ``sigma``.
    """
    return 1.0 / (np.sqrt(2.0) * as_positive(sigma, "sigma"))


def _apply_homography(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    w = xy @ H[:2, :2].T + H[:2, 2]
    den = xy @ H[2, :2] + H[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = w / den[:, None]
    return np.where(np.abs(den)[:, None] > 1e-12 * np.abs(H).max(), out, np.nan)


def _fit_homography(xy: np.ndarray, px: np.ndarray) -> np.ndarray:
    import cv2

    H, _ = cv2.findHomography(xy.astype(np.float64), px.astype(np.float64), 0)
    if H is None or not np.all(np.isfinite(H)):
        raise ValueError("sonar_xy: no homography fits these matches (degenerate layout, e.g. three of "
                         "four features collinear); use base='affine'")
    return H


def _base(xy, px, base):
    """The base homography (or None) and what is left for the RBF to interpolate."""
    H = _fit_homography(xy, px) if base == "homography" else None
    target = px - _apply_homography(H, xy) if H is not None else px
    if not np.all(np.isfinite(target)):
        raise ValueError("sonar_xy: the fitted homography sends a feature to infinity; use base='affine'")
    return H, target


def _rbf(xy, target, sigma, smoothing, base) -> RBFInterpolator:
    """scipy's interpolator; LinAlgError when the system is singular."""
    return RBFInterpolator(xy, target, kernel="gaussian", epsilon=epsilon_from_sigma(sigma),
                           degree=_DEGREE[base], smoothing=smoothing)


def _condition(xy, sigma, smoothing) -> float:
    """2-norm condition number of ``K + smoothing I`` (symmetric positive semi-definite: eigenvalues)."""
    from scipy.spatial.distance import cdist

    K = np.exp(-(epsilon_from_sigma(sigma) * cdist(xy, xy)) ** 2) + smoothing * np.eye(len(xy))
    ev = np.abs(np.linalg.eigvalsh(K))
    return float(ev.max() / ev.min()) if ev.min() > 0 else float("inf")


def _solve(xy, px, sigma, smoothing, base):
    H, target = _base(xy, px, base)
    return _rbf(xy, target, sigma, smoothing, base), H


def _evaluate(rbf, H, q):
    return rbf(q) + (_apply_homography(H, q) if H is not None else 0.0)


@dataclass(frozen=True, eq=False)
class RBFMapping:
    """A mapping from sonar fan coordinates to optical pixels; build with :meth:`fit`.

    Attributes
    ----------
    sigma : float
        Gaussian width (m, in the fan plane).
    smoothing : float
        scipy's smoothing (dimensionless: added to the kernel matrix's unit diagonal).
    base : {"none", "affine", "homography"}
    sonar_xy : ndarray, shape (N, 2)
        Training features, fan coordinates ``(x_s, y_s)`` (m); the RBF centres.
    pixels : ndarray, shape (N, 2)
        Their optical pixels ``(u, v)``.
    homography : ndarray, shape (3, 3) or None
        The base homography (fan metres -> pixels) when ``base="homography"``.
    training_residuals : ndarray, shape (N, 2)
        ``mapping(sonar_xy) - pixels`` (px). Zero up to the kernel matrix's conditioning
        when ``smoothing = 0``.
    """

    sigma: float
    smoothing: float
    base: str
    sonar_xy: np.ndarray
    pixels: np.ndarray
    homography: np.ndarray | None
    training_residuals: np.ndarray
    _rbf: RBFInterpolator = field(repr=False)

    @classmethod
    def fit(cls, sonar_xy, pixels, *, sigma: float, smoothing: float = 0.0, base: Base = "none") -> "RBFMapping":
        """Learn the mapping from matches.

        Parameters
        ----------
        sonar_xy : array_like, shape (N, 2)
            Sonar fan coordinates ``(x_s, y_s)`` (m) of the matched features.
        pixels : array_like, shape (N, 2)
            Optical pixels ``(u, v)`` of the same features.
        sigma : float
            Gaussian width (m, fan plane), thesis eq. 7.7. A width given in sonar-image
            pixels is ``sigma_px * pixel_size``.
        smoothing : float
            0 for exact interpolation; > 0 for the smoothed ("modified") mapping.
        base : {"none", "affine", "homography"}
            What the RBF adds to (module docstring).

        Returns
        -------
        RBFMapping

        Raises
        ------
        ValueError
            Bad shapes, NaN, fewer than 3 features (4 for the homography base),
            duplicated or collinear features, a negative smoothing, or a kernel system
            that is numerically singular.
        """
        if base not in BASES:
            raise ValueError(f"base: expected one of {list(BASES)}, got {base!r}")
        xy, px = check_matches(sonar_xy, pixels, min_count=BASES[base])
        xy, px = xy.copy(), px.copy()  # frozen below: never freeze the caller's arrays
        sigma = as_positive(sigma, "sigma")
        smoothing = as_positive(smoothing, "smoothing", allow_zero=True)
        try:
            rbf, H = _solve(xy, px, sigma, smoothing, base)
        except np.linalg.LinAlgError as exc:
            raise ValueError(
                f"sonar_xy: the RBF system is singular for sigma={sigma:g} m ({exc}); features too close "
                f"for this width: use a smaller sigma or smoothing > 0"
            ) from None
        fitted = _evaluate(rbf, H, xy)
        cond = _condition(xy, sigma, smoothing)
        if cond > MAX_CONDITION:
            import warnings

            warnings.warn(
                f"RBFMapping.fit: kernel condition number {cond:.1e} at sigma={sigma:g} m, smoothing={smoothing:g} "
                f"(above {MAX_CONDITION:.0e}): the weights are dominated by round-off and the mapping away from the "
                "features is not reproducible; use a smaller sigma or smoothing > 0 (fusion.cross_validate picks one)",
                IllConditionedWarning, stacklevel=2)
        for a in (xy, px, fitted):
            a.setflags(write=False)
        res = fitted - px
        res.setflags(write=False)
        if H is not None:
            H.setflags(write=False)
        return cls(sigma, smoothing, base, xy, px, H, res, rbf)

    @property
    def epsilon(self) -> float:
        """scipy's shape parameter, ``1 / (sqrt(2) sigma)`` (1/m)."""
        return epsilon_from_sigma(self.sigma)

    @property
    def condition_number(self) -> float:
        """2-norm condition number of the Gaussian kernel matrix (plus smoothing) of the centres.

        Above about 1e16 the interpolation weights, and so the mapping away from the
        centres, are dominated by round-off: wide Gaussians (the flat limit) or near-coincident
        features.
        """
        return _condition(self.sonar_xy, self.sigma, self.smoothing)

    @property
    def training_error(self) -> float:
        """RMS distance between mapped and true training pixels (px)."""
        return float(np.sqrt(np.mean(np.sum(self.training_residuals ** 2, axis=-1))))

    def __call__(self, sonar_xy) -> np.ndarray:
        """Optical pixels ``(..., 2)`` of fan coordinates ``(..., 2)`` (m); NaN in, NaN out."""
        flat, ok, shape = query_points(sonar_xy)
        out = np.full(flat.shape, np.nan)
        if ok.any():
            out[ok] = _evaluate(self._rbf, self.homography, flat[ok])
        return out.reshape(shape + (2,))


@dataclass(frozen=True)
class CrossValidation:
    """Leave-one-out errors of :class:`RBFMapping` over widths and smoothings.

    Attributes
    ----------
    sigmas : ndarray, shape (J,)
        Candidate widths (m).
    smoothings : ndarray, shape (K,)
        Candidate smoothings.
    errors : ndarray, shape (J, K)
        RMS leave-one-out pixel error (px) of each pair.
    best_sigma, best_smoothing : float
        The pair with the smallest error (the first in ``sigmas`` then ``smoothings`` on ties).
    """

    sigmas: np.ndarray
    smoothings: np.ndarray
    errors: np.ndarray
    best_sigma: float
    best_smoothing: float


def _candidates(values, name: str, positive: bool) -> np.ndarray:
    v = np.atleast_1d(as_array(values, name))
    if v.ndim != 1 or v.size == 0 or np.any(v <= 0 if positive else v < 0):
        rel = "> 0" if positive else ">= 0"
        raise ValueError(f"{name}: expected a 1D list of values {rel}, got {np.asarray(values).tolist()}")
    return v


def cross_validate(sonar_xy, pixels, *, sigmas, smoothings=(0.0,), base: Base = "none") -> CrossValidation:
    """Leave-one-out error of the mapping for each width and smoothing (training matches only).

    Each feature in turn is left out, the mapping is fitted to the others and its pixel
    error at the left-out feature is recorded; the RMS over the features is the score.

    Parameters
    ----------
    sonar_xy, pixels : array_like, shape (N, 2)
        Matches, as in :meth:`RBFMapping.fit`; one more than the base needs.
    sigmas : array_like, shape (J,)
        Candidate Gaussian widths (m), > 0.
    smoothings : array_like, shape (K,)
        Candidate smoothing values, >= 0.
    base : {"none", "affine", "homography"}

    Returns
    -------
    CrossValidation

    Raises
    ------
    ValueError
        As :meth:`RBFMapping.fit`, also when leaving a feature out leaves a degenerate layout.
    """
    if base not in BASES:
        raise ValueError(f"base: expected one of {list(BASES)}, got {base!r}")
    xy, px = check_matches(sonar_xy, pixels, min_count=BASES[base] + 1)
    sig = _candidates(sigmas, "sigmas", True)
    sm = _candidates(smoothings, "smoothings", False)
    n = len(xy)
    folds = []  # (kept indices, base homography, RBF target) of each fold, computed once
    for i in range(n):
        keep = np.arange(n) != i
        try:
            check_layout(xy[keep], min_count=BASES[base])
            folds.append((keep, *_base(xy[keep], px[keep], base)))
        except ValueError as exc:
            raise ValueError(f"cross_validate: leaving feature {i} out: {exc}") from None
    errors = np.empty((len(sig), len(sm)))
    for j, s in enumerate(sig):
        for k, lam in enumerate(sm):
            sq = 0.0
            for i, (keep, H, target) in enumerate(folds):
                try:
                    rbf = _rbf(xy[keep], target, float(s), float(lam), base)
                except np.linalg.LinAlgError:  # numerically singular at this width: no score
                    sq = np.inf
                    break
                sq += float(np.sum((_evaluate(rbf, H, xy[i:i + 1])[0] - px[i]) ** 2))
            errors[j, k] = np.sqrt(sq / n)
    if not np.any(np.isfinite(errors)):
        raise ValueError("cross_validate: no candidate gives a finite leave-one-out error")
    j, k = np.unravel_index(int(np.argmin(np.where(np.isfinite(errors), errors, np.inf))), errors.shape)
    return CrossValidation(sig, sm, errors, float(sig[j]), float(sm[k]))
