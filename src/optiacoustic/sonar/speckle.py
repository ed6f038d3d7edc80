"""Speckle from scatterer counts: correlated, K-like fields (docs/physics.md, "Speckle from scatterers").

Each image cell ``k`` of the seabed holds ``n_k ~ Poisson(mu_k)`` scatterers, ``mu_k`` the
cell's footprint area times the seabed's scatterer density. Their complex sum is
``w_k = sqrt(n_k) z_k`` with ``z_k ~ CN(0, 1)`` (exact in distribution for scatterers of
Rayleigh amplitude). The sonar sees ``w`` through its point-spread function ``h``
(the pulse in range, the two-way amplitude beam pattern across beams):
``f = h * w``. Given the counts ``f`` is circular Gaussian with power ``T = sum h^2 n``,
so the intensity is a compound (texture x exponential) variable whose moments are exact:

    E[I] = mu S2,   E[I^2] / E[I]^2 = 2 (1 + S4 / (mu S2^2))     (uniform mu)

with ``S2 = sum h^2``, ``S4 = sum h^4``: the speckle contrast of a K distribution of shape
``nu = mu N_eff``, ``N_eff = S2^2 / S4`` the resolution cell's size in grid cells. The
intensity autocorrelation coefficient at lag ``d`` is

    rho(d) = [C(d)^2 + (2 / mu) Q(d)] / [S2^2 + (2 / mu) S4],
    C(d) = sum h_k h_{k+d},  Q(d) = sum h_k^2 h_{k+d}^2.

Two further device and seabed terms (docs/physics.md 4.3, "Clustered scatterers and looks"):

* **clustered scatterers**: the count of a cell is gamma-mixed Poisson (negative
  binomial), ``n ~ Poisson(mu T)``, ``T ~ Gamma(nu_c, 1 / nu_c)`` with ``nu_c = kappa A``
  (``kappa`` independent clusters per m^2, ``A`` the cell's footprint): the seabed's
  reflectivity texture. For ``mu -> inf`` the cell's power is ``T``: K speckle whose
  shape follows the cell size (Jakeman and Pusey's negative-binomial K);
* **looks**: a device that averages ``L`` independent speckle realisations per stored
  sample (incoherent averaging within the sample period) gives, given the texture, a
  Gamma(L) intensity; a non-integer ``L`` is the effective number of looks
  ``(sum w)^2 / sum w^2`` of a weighted average of ``ceil(L)`` looks
  (:func:`look_weights`). Texture times looks is the generalised K law
  (:func:`gk_moments`).
"""

from __future__ import annotations

import numpy as np

#: Cell areas (m^2) at or below this mean *no seabed in the cell*. A cell's seabed area is a
#: difference of cumulative sums, so a cell without seabed holds rounding of about 1e-18 to
#: 1e-16 m^2 of either sign instead of 0; read as a real area, a positive one would draw a count
#: (of 0, at ordinary densities) and zero the cell's whole echo (targets included). No real area
#: comes near it: a resolution cell's is about 1e-3 m^2, and a sliver of seabed under 1e-10 m^2
#: returns nothing measurable. The test is on the area, not on the expected count: a tiny density
#: on a real area is a seabed with (almost) no scatterers, so (almost) every such cell is empty.
AREA_NO_SEABED = 1e-10

#: The compiled kernels' form of the same test: ``density x area <= MU_NO_SEABED`` is no seabed.
#: It agrees with :data:`AREA_NO_SEABED` for every area when ``density = MU_NO_SEABED /
#: AREA_NO_SEABED``; ``ScattererNoise`` takes those kernels only at densities of at least that
#: (10 per m^2), where they can differ only on areas in ``(MU_NO_SEABED / density, AREA_NO_SEABED]``
#: (slivers; above 1e4 per m^2 such areas are cleared first, so that rounding stays no seabed).
MU_NO_SEABED = 1e-9

#: Upper bounds of the scatterer model's counts (:func:`check_scatterer_parameters`): a density of
#: one scatterer per um^2 (sonar scatterers are far larger); a cell's mean count then stays within
#: what ``numpy.random.Generator.poisson`` takes (about 9e18). Looks: each is a field drawn and
#: filtered per frame; devices average a few to a few tens.
MAX_DENSITY = 1e12
MAX_LOOKS = 1000.0

__all__ = [
    "AREA_NO_SEABED",
    "MU_NO_SEABED",
    "gaussian_pulse_kernel",
    "beam_kernel",
    "speckle_field",
    "analytic_contrast",
    "analytic_autocorrelation",
    "correlation_length",
    "autocorrelation",
    "look_weights",
    "cluster_ratio",
    "gk_moments",
    "speckle_statistics",
    "check_scatterer_parameters",
]


def gaussian_pulse_kernel(resolution_bins: float) -> np.ndarray:
    """Amplitude kernel of a pulse whose *power* has FWHM ``resolution_bins`` (in bins).

    ``|h|^2 = exp(-x^2 / (2 s^2))``, ``s = FWHM / 2.3548``; so ``h = exp(-x^2 / (4 s^2))``.
    A resolution under half a bin gives the one-tap kernel ``[1]``.
    """
    s = float(resolution_bins) / 2.3548
    if s < 0.2:
        return np.ones(1)
    half = int(np.ceil(4.0 * s * np.sqrt(2.0)))
    x = np.arange(-half, half + 1, dtype=float)
    return np.exp(-(x**2) / (4 * s * s))


def beam_kernel(pattern, spacing: float, max_taps: int = 64) -> np.ndarray:
    """Two-way amplitude kernel across beams: ``F^2`` averaged over beam cells of ``spacing`` (rad).

    Reaches to the pattern's second null (or ``max_taps`` beams each side).
    """
    reach = pattern.null_angle(2)
    m = int(min(max_taps, max(1, np.ceil(reach / spacing))))
    centres = np.arange(-m, m + 1) * spacing
    off = ((np.arange(16) + 0.5) / 16 - 0.5) * spacing
    # the two-way amplitude is F_tx F_rx = F^2 >= 0: the one-way power pattern
    k = pattern.one_way(centres[:, None] + off).mean(-1)
    return k / np.max(k)


def filter_complex(field: np.ndarray, h_range, h_beam, out=None) -> np.ndarray:
    """Separable filter of a complex field stored as ``(n_bins, n_beams, 2)`` float32 (real, imag).

    ``cv2.sepFilter2D`` (zero borders) on the two-channel image; ``h_range`` runs along
    rows (axis 0), ``h_beam`` along columns (axis 1). Symmetric kernels, so correlation
    equals convolution. ``out``: a C-contiguous float32 array of ``field``'s shape to write
    into (a reused buffer: fresh large arrays cost page faults every frame).
    """
    import cv2

    kx = np.asarray(h_beam, np.float32).reshape(-1, 1)
    ky = np.asarray(h_range, np.float32).reshape(-1, 1)
    if kx.size == 1 and ky.size == 1:
        return field * np.float32(kx[0, 0] * ky[0, 0])
    src = np.ascontiguousarray(field, np.float32)
    if out is None:
        return cv2.sepFilter2D(src, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_CONSTANT)
    got = cv2.sepFilter2D(src, cv2.CV_32F, kx, ky, dst=out, borderType=cv2.BORDER_CONSTANT)
    return got if got.shape == src.shape else got.reshape(src.shape)


def filter_real(image: np.ndarray, h_range, h_beam, out=None) -> np.ndarray:
    """Separable filter of a real ``(n_bins, n_beams)`` image, float32 out (zero borders).

    ``cv2.sepFilter2D``: the same numbers as :func:`_filter` (``scipy.ndimage.convolve1d``,
    ``mode="constant"``) for the symmetric kernels used here, at a fraction of the cost.
    ``out`` as :func:`filter_complex`.
    """
    return filter_complex(np.asarray(image, np.float32), h_range, h_beam, out=out)


def _filter(field: np.ndarray, h_range: np.ndarray, h_beam: np.ndarray) -> np.ndarray:
    from scipy.ndimage import convolve1d

    out = field
    if h_range.size > 1:
        out = convolve1d(out, h_range.astype(out.dtype), axis=0, mode="constant")
    if h_beam.size > 1:
        out = convolve1d(out, h_beam.astype(out.dtype), axis=1, mode="constant")
    return out


def speckle_field(mean_count, h_range, h_beam, rng, shape=None, complex_field: bool = False) -> np.ndarray:
    """Unit-mean intensity speckle ``|f|^2 / E|f|^2`` from scatterer counts, ``(n_bins, n_beams)`` float32.

    With ``complex_field`` the normalised complex field ``f / sqrt(E|f|^2)`` (complex64).

    Parameters
    ----------
    mean_count : float or array ``(n_bins, n_beams)``
        Expected scatterers per image cell, ``mu``; ``inf`` gives fully developed
        (Rayleigh) speckle, cells with ``mu = 0`` get 0.
    h_range, h_beam : 1-D arrays
        Amplitude kernels along range (rows) and across beams (columns).
    rng : numpy.random.Generator
    shape : tuple, optional
        Needed when ``mean_count`` is a scalar.
    """
    mu = np.asarray(mean_count, float)
    shape = tuple(shape) if shape is not None else mu.shape
    mu = np.broadcast_to(mu, shape)
    z = rng.standard_normal((2,) + shape, dtype=np.float32)
    gauss = ~np.isfinite(mu)
    if np.all(gauss):
        amp = np.ones(shape, np.float32)
        power = np.ones(shape)
    else:
        n = rng.poisson(np.where(gauss, 0.0, mu)).astype(np.float32)
        amp = np.where(gauss, np.float32(1.0), np.sqrt(n)).astype(np.float32)
        power = np.where(gauss, 1.0, mu)
    h_r = np.asarray(h_range, float)
    h_b = np.asarray(h_beam, float)
    re = _filter(amp * z[0], h_r, h_b)
    im = _filter(amp * z[1], h_r, h_b)
    # E|f|^2 = (h^2 * power) * 2 (two real normals of unit variance per cell)
    expected = 2.0 * _filter(power.astype(np.float32), h_r**2, h_b**2)
    with np.errstate(invalid="ignore", divide="ignore"):
        if complex_field:
            norm = np.where(expected > 0, 1.0 / np.sqrt(expected), 0.0).astype(np.float32)
            return ((re * norm) + 1j * (im * norm)).astype(np.complex64)
        out = np.where(expected > 0, (re * re + im * im) / expected, 0.0)
    return out.astype(np.float32)


def _sums(h_range, h_beam):
    h = np.outer(np.asarray(h_range, float), np.asarray(h_beam, float))
    return h, float((h**2).sum()), float((h**4).sum())


def analytic_contrast(mean_count: float, h_range, h_beam) -> float:
    """Exact std/mean of speckle intensity for a uniform ``mean_count`` (``inf``: 1)."""
    _, s2, s4 = _sums(h_range, h_beam)
    extra = 0.0 if not np.isfinite(mean_count) else s4 / (mean_count * s2 * s2)
    return float(np.sqrt(1.0 + 2.0 * extra))


def effective_shape(mean_count: float, h_range, h_beam) -> float:
    """K shape ``nu = mu S2^2 / S4`` of the cell-scale intensity."""
    _, s2, s4 = _sums(h_range, h_beam)
    return float(mean_count * s2 * s2 / s4)


def _lag_sums(h: np.ndarray, lag: int):
    n = h.size
    if lag >= n:
        return 0.0, 0.0
    a, b = h[: n - lag], h[lag:]
    return float((a * b).sum()), float((a * a * b * b).sum())


def analytic_autocorrelation(mean_count: float, h_range, h_beam, lags, axis: int) -> np.ndarray:
    """Exact intensity autocorrelation coefficient at integer ``lags`` along ``axis`` (0 range, 1 beams)."""
    h_r = np.asarray(h_range, float)
    h_b = np.asarray(h_beam, float)
    along, other = (h_r, h_b) if axis == 0 else (h_b, h_r)
    o2, o4 = float((other**2).sum()), float((other**4).sum())
    c0, q0 = _lag_sums(along, 0)
    g = 0.0 if not np.isfinite(mean_count) else 2.0 / mean_count
    den = (c0 * o2) ** 2 + g * q0 * o4
    out = []
    for d in np.atleast_1d(lags):
        c, q = _lag_sums(along, int(abs(d)))
        out.append(((c * o2) ** 2 + g * q * o4) / den)
    return np.asarray(out)


def autocorrelation(image: np.ndarray, max_lag: int, axis: int, mask=None) -> np.ndarray:
    """Sample autocorrelation coefficient of ``image`` at lags ``0..max_lag`` along ``axis``.

    Means and variances are taken over the pairs used at each lag; ``mask`` (bool,
    image's shape) keeps only pairs of cells both inside it.
    """
    x = np.asarray(image, float)
    if axis == 1:
        x = x.T
        mask = None if mask is None else np.asarray(mask).T
    m = np.ones(x.shape, bool) if mask is None else np.asarray(mask, bool)
    out = np.empty(max_lag + 1)
    for d in range(max_lag + 1):  # a loop over lags, each vectorised over the image
        a, b = x[: x.shape[0] - d], x[d:]
        ok = m[: x.shape[0] - d] & m[d:]
        if ok.sum() < 10:
            out[d] = np.nan
            continue
        av, bv = a[ok], b[ok]
        av = av - av.mean()
        bv = bv - bv.mean()
        out[d] = float((av * bv).mean() / np.sqrt((av * av).mean() * (bv * bv).mean()))
    return out


def correlation_length(rho: np.ndarray, level: float = 0.5) -> float:
    """First lag (interpolated, in samples) where the autocorrelation ``rho`` falls to ``level``."""
    rho = np.asarray(rho, float)
    below = np.flatnonzero(rho < level)
    if below.size == 0:
        return float(len(rho))
    i = int(below[0])
    if i == 0:
        return 0.0
    r0, r1 = rho[i - 1], rho[i]
    return float(i - 1 + (r0 - level) / (r0 - r1))


# --------------------------------------------------------------------------- clustering and looks
def check_scatterer_parameters(owner: str, density, clusters_per_m2, looks) -> None:
    """Refuse scatterer-model parameters outside their domain, naming ``owner.field`` and the value.

    ``density`` (scatterers/m^2) and ``clusters_per_m2`` must be numbers (not bools or strings) in
    ``(0, MAX_DENSITY]`` or inf (no clustering / Rayleigh limit); ``looks`` a finite number in
    ``[1, MAX_LOOKS]``.
    """
    from .propagation import check_number

    check_number(f"{owner}.density", density, 0.0, MAX_DENSITY, lo_open=True, inf=True, unit="scatterers/m^2 (or inf)")
    check_number(f"{owner}.clusters_per_m2", clusters_per_m2, 0.0, MAX_DENSITY, lo_open=True, inf=True,
                 unit="per m^2 (or inf)")
    check_number(f"{owner}.looks", looks, 1.0, MAX_LOOKS)


def look_weights(looks: float) -> np.ndarray:
    """Weights (summing to 1) of ``ceil(looks)`` independent looks whose weighted average has
    ``looks`` effective looks, ``(sum w)^2 / sum w^2 = looks``: ``ceil(looks) - 1`` equal
    weights and a last one ``w`` solving ``(m + w)^2 / (m + w^2) = looks`` (``m = ceil - 1``)."""
    L = float(looks)
    if not (np.isfinite(L) and L >= 1.0):
        raise ValueError(f"looks: must be a finite number >= 1, got {looks!r}")
    K = int(np.ceil(L - 1e-9))
    if K <= 1:
        return np.ones(1)
    m = K - 1
    # (m + w)^2 = L (m + w^2)  ->  (1 - L) w^2 + 2 m w + m^2 - L m = 0, root in (0, 1]
    a, b, c = 1.0 - L, 2.0 * m, m * m - L * m
    w = 1.0 if abs(a) < 1e-12 else (-b + np.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a)  # the root in (0, 1]
    w = float(np.clip(w, 0.0, 1.0))
    out = np.ones(K)
    out[-1] = w
    return out / out.sum()


def cluster_ratio(mean_count, cluster_shape, rng, dtype=np.float32, seabed=None) -> np.ndarray:
    """Per-cell power ratio ``n / mu`` of clustered scatterers (negative-binomial counts).

    ``T ~ Gamma(nu_c, 1 / nu_c)`` (``cluster_shape`` ``nu_c``, ``inf``: ``T = 1``), then
    ``n ~ Poisson(mu T)`` (``mean_count`` ``mu``, ``inf``: ``n / mu = T``). ``seabed`` (bool, the
    cells' shape): the cells that hold seabed (``cell area > AREA_NO_SEABED``); the others get 1
    (the ratio multiplies nothing there). Without it, cells with ``mu > 0`` and ``nu_c > 0``. A
    tiny ``mu`` or ``nu_c`` on a seabed cell is a (nearly) empty cell: ``n = 0``, ratio 0.
    """
    mu = np.asarray(mean_count, np.float64)
    nu = np.broadcast_to(np.asarray(cluster_shape, np.float64), mu.shape)
    if seabed is None:
        with np.errstate(invalid="ignore"):
            seabed = (mu > 0) & (nu > 0)
    seabed = np.broadcast_to(np.asarray(seabed, bool), mu.shape)
    T = np.ones(mu.shape)
    tex = np.isfinite(nu) & seabed
    if tex.any():
        n_t = nu[tex]
        t = np.zeros(n_t.shape)
        ok = n_t > 1e-300  # Gamma(nu, 1/nu) of a smaller shape is 0 in float64 (its scale would overflow)
        t[ok] = rng.gamma(n_t[ok], 1.0 / n_t[ok])
        T[tex] = t
    fin = np.isfinite(mu) & seabed
    if fin.any():
        m = mu[fin]
        lam = m * T[fin]
        n = rng.poisson(np.where(lam > 0, lam, 0.0))
        r = np.zeros(m.shape)
        np.divide(n, m, out=r, where=m > 0)  # mu = 0 (a density that underflows on the area): empty
        T[fin] = r
    return T.astype(dtype)


def gk_moments(shape: float, looks: float = 1.0) -> tuple[float, float]:
    """``(contrast, log_ratio)`` of the unit-mean generalised K intensity ``T G``,
    ``T ~ Gamma(shape)``, ``G ~ Gamma(looks)`` (each of unit mean).

    ``contrast^2 = (1 + 1/shape)(1 + 1/looks) - 1``; ``log_ratio = log E[I] - E[log I]
    = (log shape - psi(shape)) + (log looks - psi(looks))``: the statistic whose value
    fixes the maximum-likelihood gamma shape (``scipy.stats.gamma.fit`` with ``floc=0``).
    """
    from scipy.special import digamma

    def part(k):
        return 0.0 if not np.isfinite(k) else float(np.log(k) - digamma(k))

    inv = lambda k: 0.0 if not np.isfinite(k) else 1.0 / k  # noqa: E731
    return float(np.sqrt((1 + inv(shape)) * (1 + inv(looks)) - 1)), part(shape) + part(looks)


def speckle_statistics(z) -> dict:
    """Statistics of normalised speckle intensities ``z`` (> 0): contrast and the
    maximum-likelihood gamma law (``scipy.stats.gamma.fit``, ``floc=0``): its shape, and
    ``log_ratio = log mean(z) - mean(log z)``, the statistic that shape is a function of."""
    from scipy import stats

    z = np.asarray(z, float)
    z = z[np.isfinite(z) & (z > 0)]
    if z.size < 100:
        return {"contrast": float("nan"), "gamma_shape": float("nan"), "log_ratio": float("nan"), "n": int(z.size)}
    k, _, _ = stats.gamma.fit(z, floc=0.0)
    return {"contrast": float(z.std() / z.mean()), "gamma_shape": float(k),
            "log_ratio": float(np.log(z.mean()) - np.mean(np.log(z))), "n": int(z.size)}
