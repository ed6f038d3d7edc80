"""Amplitude statistics of sonar bottom reverberation (thesis sec. 2.7, Tables 2.1-2.3).

Four models of the amplitude ``x >= 0`` of one resolution cell's echo, parametrised as in
thesis Table 2.1 (derivations, samplers and the EM updates: ``docs/derivations.md (sec. 2.7)``):

===================  ================================================================
``Rayleigh``         ``p(x) = (2x/lam) exp(-x^2/lam)``, ``E[x^2] = lam``
``Weibull``          ``p(x) = alpha beta x^(beta-1) exp(-alpha x^beta)``
``KDistribution``    ``p(x) = 4 / (sqrt(alpha) Gamma(nu)) (x/sqrt(alpha))^nu
                     K_(nu-1)(2x/sqrt(alpha))``, ``E[x^2] = nu alpha``
                     (Table 2.1's K formula is garbled: it does not integrate to 1)
``RayleighMixture``  ``p(x) = sum_i eps_i (2x/lam_i) exp(-x^2/lam_i)``
===================  ================================================================

Amplitudes are dimensionless (linear, not dB). :data:`BOTTOM_TYPES` holds the fitted
parameter sets of Table 2.2 and the goodness-of-fit figures of Table 2.3;
:func:`bottom_model` returns one of them rescaled to unit mean square, which is what a
noise model multiplies a noise-free echo amplitude by.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Sequence

import numpy as np
from scipy import optimize, special, stats

from .._validate import as_array, as_positive

__all__ = [
    "BOTTOM_TYPES",
    "MODELS",
    "BottomType",
    "GofResult",
    "KDistribution",
    "MixtureFit",
    "ModelFit",
    "Rayleigh",
    "RayleighMixture",
    "Table23Row",
    "Weibull",
    "amplitudes_from_image",
    "bottom_model",
    "compare_models",
    "fit_rayleigh_mixture",
    "goodness_of_fit",
    "lookup_bottom",
]

# Search range of the K shape parameter when fitting. nu -> infinity is the Rayleigh limit;
# at nu = 1e4 the K and Rayleigh pdfs differ by ~1e-4, far below any data set's resolution.
_NU_BOUNDS = (1e-2, 1e4)


# --------------------------------------------------------------------------- helpers


def _rng(rng) -> np.random.Generator:
    """A Generator from a seed, a Generator or None."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is not None and (isinstance(rng, bool) or not isinstance(rng, (int, np.integer))):
        raise ValueError(f"rng: expected an int seed, a numpy.random.Generator or None, got {type(rng).__name__}")
    return np.random.default_rng(rng)


def _size(size) -> tuple[int, ...]:
    shape = (size,) if np.ndim(size) == 0 else tuple(size)
    try:
        shape = tuple(int(s) for s in shape)
    except (TypeError, ValueError):
        raise ValueError(f"size: expected a non-negative int or a tuple of them, got {size!r}") from None
    if any(s < 0 for s in shape):
        raise ValueError(f"size: must be >= 0, got {size!r}")
    return shape


def _samples(samples, name: str = "samples") -> np.ndarray:
    """Flatten amplitude samples; they must be finite and > 0 and there must be some."""
    x = as_array(samples, name).ravel()
    if x.size == 0:
        raise ValueError(f"{name}: is empty, need at least one amplitude")
    if np.any(x <= 0):
        raise ValueError(
            f"{name}: amplitudes must be > 0, found {int(np.sum(x <= 0))} of {x.size} <= 0 "
            f"(min {x.min():.3g}); drop zeros first"
        )
    return x


def _log_kv(v, z):
    """``log K_v(z)`` for ``z > 0``, also where ``K_v(z)`` overflows a double.

    ``kve`` is exact where finite. Where it overflows (large order, small argument) the
    uniform (Debye) expansion with three correction terms is used for ``|v| >= 5`` and
    the leading small-argument term ``Gamma(v)/2 (2/z)^v`` below that (overflow there needs
    ``z < 1e-60``, where that term is exact to double precision).
    """
    v = np.abs(np.asarray(v, float))
    z = np.asarray(z, float)
    v, z = np.broadcast_arrays(v, z)
    shape = v.shape
    v, z = v.ravel(), z.ravel()
    with np.errstate(over="ignore", divide="ignore"):
        out = np.log(special.kve(v, z)) - z
    bad = ~np.isfinite(out) & (z > 0) & np.isfinite(z)
    if np.any(bad):
        vb, zb = v[bad], z[bad]
        t = zb / vb
        sq = np.sqrt(1.0 + t * t)
        p = 1.0 / sq
        u1 = (3 * p - 5 * p**3) / 24
        u2 = (81 * p**2 - 462 * p**4 + 385 * p**6) / 1152
        u3 = (30375 * p**3 - 369603 * p**5 + 765765 * p**7 - 425425 * p**9) / 414720
        debye = (
            0.5 * np.log(np.pi / (2 * vb))
            - vb * (sq + np.log(t / (1 + sq)))
            - 0.5 * np.log(sq)
            + np.log1p(-u1 / vb + u2 / vb**2 - u3 / vb**3)
        )
        small = special.gammaln(vb) + (vb - 1) * np.log(2.0) - vb * np.log(zb)
        out[bad] = np.where(vb >= 5, debye, small)
    return out.reshape(shape)


class _Amplitude:
    """Methods shared by the amplitude distributions (``logpdf``/``cdf`` are per model)."""

    name: ClassVar[str] = ""

    def pdf(self, x):
        """Probability density at amplitudes ``x`` (any shape); 0 for ``x < 0``."""
        with np.errstate(over="ignore"):
            return np.exp(self.logpdf(x))

    def log_likelihood(self, samples) -> float:
        """Sum of ``logpdf`` over ``samples`` (flattened, must be > 0)."""
        return float(np.sum(self.logpdf(_samples(samples))))

    def mean_square(self) -> float:
        """``E[x^2]``, the mean echo intensity."""
        return self.moment(2)

    def normalised(self):
        """The same model rescaled in amplitude so that ``E[x^2] = 1`` exactly."""
        return self.scaled(1.0 / np.sqrt(self.mean_square()))

    def describe(self, digits: int = 4) -> str:
        """The parameters as one short line, e.g. ``alpha=1.009, beta=1.955``."""

        def fmt(v):
            if isinstance(v, tuple):
                return "(" + ", ".join(f"{e:.{digits}g}" for e in v) + ")"
            return f"{v:.{digits}g}"

        return ", ".join(f"{k}={fmt(v)}" for k, v in self.params.items())


def _x(x) -> np.ndarray:
    return np.asarray(x, dtype=float)


def _finish_logpdf(x: np.ndarray, out):
    """NaN amplitudes (masked cells) give NaN; ``x = +inf`` has density 0."""
    return np.where(np.isnan(x), np.nan, np.where(x == np.inf, -np.inf, out))


def _finish_cdf(x: np.ndarray, out):
    """NaN amplitudes give NaN; ``cdf(+inf) = 1``."""
    return np.where(np.isnan(x), np.nan, np.where(x == np.inf, 1.0, out))


# --------------------------------------------------------------------------- models


@dataclass(frozen=True)
class Rayleigh(_Amplitude):
    """Rayleigh amplitude: ``p(x) = (2x/lam) exp(-x^2/lam)`` (Table 2.1).

    The amplitude of a circular complex Gaussian echo (fully developed speckle):
    ``x^2`` is exponential with mean ``lam``.

    Parameters
    ----------
    lam : float
        ``E[x^2]`` (> 0), in squared amplitude units.
    """

    lam: float
    name: ClassVar[str] = "rayleigh"

    def __post_init__(self):
        object.__setattr__(self, "lam", as_positive(self.lam, "lam"))

    n_params: ClassVar[int] = 1

    @property
    def params(self) -> dict:
        return {"lam": self.lam}

    def logpdf(self, x):
        """Log density at amplitudes ``x`` (any shape); ``-inf`` for ``x <= 0``."""
        x = _x(x)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.log(2 * x / self.lam) - x * x / self.lam
        return _finish_logpdf(x, np.where(x > 0, out, -np.inf))

    def cdf(self, x):
        """``P(X <= x)`` at amplitudes ``x`` (any shape)."""
        x = np.maximum(_x(x), 0.0)
        return -np.expm1(-x * x / self.lam)

    def moment(self, p: float) -> float:
        """``E[x^p] = lam^(p/2) Gamma(1 + p/2)`` for ``p > -2``."""
        p = _order(p, -2.0)
        return float(self.lam ** (p / 2) * special.gamma(1 + p / 2))

    def scaled(self, factor: float) -> "Rayleigh":
        """The distribution of ``factor * X``."""
        c = as_positive(factor, "factor")
        return Rayleigh(self.lam * c * c)

    def sample(self, size, rng=None, dtype=np.float64) -> np.ndarray:
        """Draw amplitudes ``sqrt(lam E)``, ``E ~ Exp(1)``.

        Parameters
        ----------
        size : int or tuple of int
            Output shape.
        rng : int, numpy.random.Generator or None
            Seed or generator; the same seed gives the same draws.
        dtype : numpy.float64 or numpy.float32
            Precision of the draws (float32 is about twice as fast).
        """
        e = _rng(rng).standard_exponential(_size(size), dtype=dtype)
        return np.sqrt(dtype(self.lam) * e)

    @classmethod
    def fit(cls, samples) -> "Rayleigh":
        """Maximum likelihood (``scipy.stats.rayleigh.fit`` with ``floc=0``: ``lam = mean(x^2)``)."""
        x = _samples(samples)
        _, scale = stats.rayleigh.fit(x, floc=0)
        return cls(2.0 * scale * scale)


@dataclass(frozen=True)
class Weibull(_Amplitude):
    """Weibull amplitude: ``p(x) = alpha beta x^(beta-1) exp(-alpha x^beta)`` (Table 2.1).

    ``beta = 2`` is Rayleigh with ``lam = 1/alpha``; ``beta < 2`` has a heavier tail.
    In scipy's terms this is ``weibull_min(c=beta, scale=alpha^(-1/beta))``.

    Parameters
    ----------
    alpha : float
        Scale parameter (> 0), units of ``amplitude^(-beta)``.
    beta : float
        Shape parameter (> 0).
    """

    alpha: float
    beta: float
    name: ClassVar[str] = "weibull"
    n_params: ClassVar[int] = 2

    def __post_init__(self):
        object.__setattr__(self, "alpha", as_positive(self.alpha, "alpha"))
        object.__setattr__(self, "beta", as_positive(self.beta, "beta"))

    @property
    def params(self) -> dict:
        return {"alpha": self.alpha, "beta": self.beta}

    def logpdf(self, x):
        """Log density at amplitudes ``x`` (any shape); ``-inf`` for ``x < 0``."""
        x = _x(x)
        a, b = self.alpha, self.beta
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.log(a * b) + (b - 1) * np.log(x) - a * x**b
        # x = 0: the limit is 0 (beta > 1), alpha (beta = 1) or +inf (beta < 1).
        at0 = -np.inf if b > 1 else (np.log(a) if b == 1 else np.inf)
        return _finish_logpdf(x, np.where(x > 0, out, np.where(x == 0, at0, -np.inf)))

    def cdf(self, x):
        """``P(X <= x) = 1 - exp(-alpha x^beta)`` at amplitudes ``x`` (any shape)."""
        x = np.maximum(_x(x), 0.0)
        return -np.expm1(-self.alpha * x**self.beta)

    def moment(self, p: float) -> float:
        """``E[x^p] = alpha^(-p/beta) Gamma(1 + p/beta)`` for ``p > -beta``."""
        p = _order(p, -self.beta)
        return float(self.alpha ** (-p / self.beta) * special.gamma(1 + p / self.beta))

    def scaled(self, factor: float) -> "Weibull":
        """The distribution of ``factor * X``: ``alpha -> alpha factor^(-beta)``."""
        c = as_positive(factor, "factor")
        return Weibull(self.alpha * c ** (-self.beta), self.beta)

    def sample(self, size, rng=None, dtype=np.float64) -> np.ndarray:
        """Draw amplitudes by inversion, ``(E/alpha)^(1/beta)``, ``E ~ Exp(1)``.

        Parameters
        ----------
        size : int or tuple of int
            Output shape.
        rng : int, numpy.random.Generator or None
            Seed or generator.
        dtype : numpy.float64 or numpy.float32
            Precision of the draws (float32 is about twice as fast).
        """
        e = _rng(rng).standard_exponential(_size(size), dtype=dtype)
        return (e * dtype(1.0 / self.alpha)) ** dtype(1.0 / self.beta)

    @classmethod
    def fit(cls, samples) -> "Weibull":
        """Maximum likelihood via ``scipy.stats.weibull_min.fit(floc=0)``, converted to (alpha, beta)."""
        x = _samples(samples)
        c, _, scale = stats.weibull_min.fit(x, floc=0)
        return cls(scale ** (-c), c)


@dataclass(frozen=True)
class KDistribution(_Amplitude):
    """K amplitude distribution (the standard one; thesis Table 2.1's formula is garbled).

    Compound model: intensity ``x^2 = G E`` with texture ``G ~ Gamma(shape nu, scale
    alpha)`` and speckle ``E ~ Exp(1)``, so ``x | G`` is Rayleigh with ``lam = G`` and

    ``p(x) = 4 / (sqrt(alpha) Gamma(nu)) (x/sqrt(alpha))^nu K_(nu-1)(2x/sqrt(alpha))``,
    ``E[x^2] = nu alpha``. ``nu -> inf`` at fixed ``nu alpha`` is the Rayleigh limit.

    Parameters
    ----------
    alpha : float
        Texture scale (> 0), squared amplitude units.
    nu : float
        Texture shape (> 0); small is spiky.
    """

    alpha: float
    nu: float
    name: ClassVar[str] = "k"
    n_params: ClassVar[int] = 2

    def __post_init__(self):
        object.__setattr__(self, "alpha", as_positive(self.alpha, "alpha"))
        object.__setattr__(self, "nu", as_positive(self.nu, "nu"))

    @property
    def params(self) -> dict:
        return {"alpha": self.alpha, "nu": self.nu}

    def logpdf(self, x):
        """Log density at amplitudes ``x`` (any shape); ``-inf`` for ``x < 0``."""
        x = _x(x)
        a, nu = self.alpha, self.nu
        const = np.log(4.0) - 0.5 * np.log(a) - special.gammaln(nu)
        pos = (x > 0) & np.isfinite(x)
        u = np.where(pos, x, 1.0) / np.sqrt(a)
        out = const + nu * np.log(u) + _log_kv(nu - 1, 2 * u)
        # x -> 0: p ~ x^(2 nu - 1) for nu < 1 and ~ x (log x) for nu >= 1.
        if nu > 0.5:
            at0 = -np.inf
        elif nu < 0.5:
            at0 = np.inf
        else:  # nu = 1/2: p(0) = 2 / sqrt(alpha)
            at0 = np.log(2.0) - 0.5 * np.log(a)
        return _finish_logpdf(x, np.where(pos, out, np.where(x == 0, at0, -np.inf)))

    def cdf(self, x):
        """``P(X <= x) = 1 - 2/Gamma(nu) (x/sqrt(alpha))^nu K_nu(2x/sqrt(alpha))``."""
        x = _x(x)
        pos = (x > 0) & np.isfinite(x)
        u = np.where(pos, x, 1.0) / np.sqrt(self.alpha)
        log_sf = np.log(2.0) - special.gammaln(self.nu) + self.nu * np.log(u) + _log_kv(self.nu, 2 * u)
        return _finish_cdf(x, np.where(pos, -np.expm1(np.minimum(log_sf, 0.0)), 0.0))

    def moment(self, p: float) -> float:
        """``E[x^p] = alpha^(p/2) Gamma(nu + p/2) Gamma(1 + p/2) / Gamma(nu)``, ``p > max(-2, -2 nu)``."""
        p = _order(p, max(-2.0, -2.0 * self.nu))
        lg = special.gammaln(self.nu + p / 2) + special.gammaln(1 + p / 2) - special.gammaln(self.nu)
        return float(self.alpha ** (p / 2) * np.exp(lg))

    def scaled(self, factor: float) -> "KDistribution":
        """The distribution of ``factor * X``: ``alpha -> alpha factor^2``."""
        c = as_positive(factor, "factor")
        return KDistribution(self.alpha * c * c, self.nu)

    def sample(self, size, rng=None, dtype=np.float64) -> np.ndarray:
        """Draw amplitudes ``sqrt(G E)``, ``G ~ Gamma(nu, alpha)``, ``E ~ Exp(1)``.

        Parameters
        ----------
        size : int or tuple of int
            Output shape.
        rng : int, numpy.random.Generator or None
            Seed or generator.
        dtype : numpy.float64 or numpy.float32
            Precision of the draws (float32 is about twice as fast).
        """
        g = _rng(rng)
        shape = _size(size)
        gam = g.standard_gamma(self.nu, shape, dtype=dtype)
        return np.sqrt(dtype(self.alpha) * gam * g.standard_exponential(shape, dtype=dtype))

    @classmethod
    def fit(cls, samples) -> "KDistribution":
        """Maximum likelihood, from a method-of-moments start.

        The data are first divided by their RMS (K is a scale family in ``alpha``) and
        the negative mean log-likelihood is minimised by L-BFGS-B over ``(log E[x^2],
        log nu)``, which are close to orthogonal. The start is the moment estimate
        ``nu0 = 1 / (E[x^4] / (2 E[x^2]^2) - 1)`` (from ``E[x^4] = 2 nu (nu+1) alpha^2``);
        ``nu`` is searched within ``[1e-2, 1e4]`` (the upper end is the Rayleigh limit).
        """
        x = _samples(samples)
        rms = np.sqrt(np.mean(x * x))
        y = x / rms
        y2 = y * y
        excess = np.mean(y2 * y2) / 2.0 - 1.0
        lo, hi = _NU_BOUNDS
        nu0 = float(np.clip(1.0 / excess, lo, hi)) if excess > 1.0 / hi else hi

        def nll(theta):
            m2, nu = np.exp(theta)
            return -float(np.mean(KDistribution(m2 / nu, nu).logpdf(y)))

        res = optimize.minimize(
            nll,
            x0=[0.0, np.log(nu0)],
            method="L-BFGS-B",
            bounds=[(-3.0, 3.0), (np.log(lo), np.log(hi))],
            options={"ftol": 1e-13, "gtol": 1e-9},
        )
        m2, nu = np.exp(res.x)
        return cls(m2 / nu * rms * rms, nu)


@dataclass(frozen=True)
class RayleighMixture(_Amplitude):
    """Mixture of Rayleigh amplitudes: ``p(x) = sum_i eps_i (2x/lam_i) exp(-x^2/lam_i)``.

    Parameters
    ----------
    weights : sequence of float, shape (m,)
        Component probabilities ``eps_i >= 0``, summing to 1 (within 1e-6; they are then
        divided by their sum so the pdf integrates to 1 to rounding).
    lams : sequence of float, shape (m,)
        Component mean squares ``lam_i > 0``.
    """

    weights: tuple[float, ...]
    lams: tuple[float, ...]
    name: ClassVar[str] = "mixture"

    def __post_init__(self):
        w = as_array(self.weights, "weights", (None,))
        lam = as_array(self.lams, "lams", (None,))
        if w.size == 0:
            raise ValueError("weights: need at least one component, got none")
        if lam.size != w.size:
            raise ValueError(f"lams: expected {w.size} values (one per weight), got {lam.size}")
        if np.any(w < 0):
            raise ValueError(f"weights: must be >= 0, got {w.tolist()}")
        if np.any(lam <= 0):
            raise ValueError(f"lams: must be > 0, got {lam.tolist()}")
        if abs(w.sum() - 1.0) > 1e-6:
            raise ValueError(f"weights: must sum to 1, got {w.tolist()} (sum {w.sum():.6g})")
        object.__setattr__(self, "weights", tuple(float(v) for v in w / w.sum()))
        object.__setattr__(self, "lams", tuple(float(v) for v in lam))

    @property
    def n_params(self) -> int:
        """Free parameters: ``m`` scales and ``m - 1`` weights."""
        return 2 * len(self.weights) - 1

    @property
    def params(self) -> dict:
        return {"eps": self.weights, "lam": self.lams}

    def _wl(self):
        return np.asarray(self.weights), np.asarray(self.lams)

    def logpdf(self, x):
        """Log density at amplitudes ``x`` (any shape); ``-inf`` for ``x <= 0``."""
        x = _x(x)
        w, lam = self._wl()
        xs = np.where((x > 0) & np.isfinite(x), x, 1.0)[..., None]
        with np.errstate(divide="ignore"):
            terms = np.log(w) + np.log(2 * xs / lam) - xs * xs / lam
        out = special.logsumexp(terms, axis=-1)
        return _finish_logpdf(x, np.where(x > 0, out, -np.inf))

    def cdf(self, x):
        """``P(X <= x) = sum_i eps_i (1 - exp(-x^2/lam_i))``."""
        x = np.maximum(_x(x), 0.0)[..., None]
        w, lam = self._wl()
        return np.sum(w * -np.expm1(-x * x / lam), axis=-1)

    def moment(self, p: float) -> float:
        """``E[x^p] = Gamma(1 + p/2) sum_i eps_i lam_i^(p/2)`` for ``p > -2``."""
        p = _order(p, -2.0)
        w, lam = self._wl()
        return float(special.gamma(1 + p / 2) * np.sum(w * lam ** (p / 2)))

    def scaled(self, factor: float) -> "RayleighMixture":
        """The distribution of ``factor * X``: ``lam_i -> lam_i factor^2``."""
        c = as_positive(factor, "factor")
        return RayleighMixture(self.weights, tuple(v * c * c for v in self.lams))

    def sample(self, size, rng=None, dtype=np.float64) -> np.ndarray:
        """Draw a component ``i`` with probability ``eps_i``, then ``sqrt(lam_i E)``, ``E ~ Exp(1)``.

        Parameters
        ----------
        size : int or tuple of int
            Output shape.
        rng : int, numpy.random.Generator or None
            Seed or generator.
        dtype : numpy.float64 or numpy.float32
            Precision of the draws (float32 is about twice as fast).
        """
        g = _rng(rng)
        shape = _size(size)
        w, lam = self._wl()
        u = g.random(shape, dtype=dtype)
        e = g.standard_exponential(shape, dtype=dtype)
        # component by comparing u with the cumulative weights (cheaper than searchsorted for few components)
        lam_u = np.full(shape, lam[-1], dtype)
        for c, l in zip(np.cumsum(w)[:-1][::-1], lam[:-1][::-1]):
            lam_u[u < c] = l
        return np.sqrt(lam_u * e)

    @classmethod
    def fit(cls, samples, n_components: int = 3, *, tol: float = 1e-10, max_iter: int = 5000) -> "RayleighMixture":
        """Maximum likelihood by EM; see :func:`fit_rayleigh_mixture` (this returns its ``.dist``)."""
        return fit_rayleigh_mixture(samples, n_components, tol=tol, max_iter=max_iter).dist


def _order(p, lower: float) -> float:
    p = float(p)
    if not np.isfinite(p) or p <= lower:
        raise ValueError(f"p: moment order must be finite and > {lower:g}, got {p!r}")
    return p


MODELS: dict[str, type] = {
    "rayleigh": Rayleigh,
    "weibull": Weibull,
    "k": KDistribution,
    "mixture": RayleighMixture,
}
"""Model name -> distribution class."""


def _model_class(model: str) -> type:
    if model not in MODELS:
        raise ValueError(f"model: unknown model {model!r}, expected one of {sorted(MODELS)}")
    return MODELS[model]


# --------------------------------------------------------------------------- mixture EM


@dataclass(frozen=True)
class MixtureFit:
    """Result of :func:`fit_rayleigh_mixture`.

    Attributes
    ----------
    dist : RayleighMixture
        The fitted mixture, components sorted by increasing ``lam``.
    log_likelihood : float
        Total log-likelihood of the samples under ``dist``.
    n_iter : int
        EM updates made (each accelerated cycle counts three).
    converged : bool
        Whether the mean log-likelihood changed by less than ``tol`` in the last cycle.
    message : str
        Why it stopped.
    """

    dist: RayleighMixture
    log_likelihood: float
    n_iter: int
    converged: bool
    message: str

    def __bool__(self) -> bool:
        return self.converged


def _em_update(intensity, w, lam):
    """One EM update for a mixture of exponentials in ``I = x^2`` (Rayleigh in ``x``).

    Returns the updated ``(w, lam)`` and the mean log-likelihood of ``I`` under the
    *input* parameters (the Jacobian ``2x`` of ``I = x^2`` is added by the caller).
    """
    inv = 1.0 / lam
    shift = inv.min()  # exp(-I (1/lam_j - 1/lam_max)) <= 1 for all j and = 1 for one j: no underflow
    resp = np.empty((w.size, intensity.size))
    for j in range(w.size):  # (m, n) rows keep each exp contiguous: ~10x faster than (n, m)
        np.multiply(intensity, -(inv[j] - shift), out=resp[j])
        np.exp(resp[j], out=resp[j])
        resp[j] *= w[j] * inv[j]
    total = resp.sum(axis=0)
    mean_ll = float(np.mean(np.log(total)) - shift * np.mean(intensity))
    resp /= total
    nk = resp.sum(axis=1)
    safe = nk > 1e-300
    new_lam = np.where(safe, (resp @ intensity) / np.where(safe, nk, 1.0), lam)
    return nk / intensity.size, new_lam, mean_ll


def fit_rayleigh_mixture(
    samples, n_components: int = 3, *, tol: float = 1e-10, max_iter: int = 5000
) -> MixtureFit:
    """Fit a Rayleigh mixture by expectation-maximisation (SQUAREM-accelerated).

    EM updates (docs/derivations.md (sec. 2.7)): with responsibilities
    ``r_ij = eps_j p_j(x_i) / sum_k eps_k p_k(x_i)``,
    ``eps_j <- mean_i r_ij`` and ``lam_j <- sum_i r_ij x_i^2 / sum_i r_ij``.
    Plain EM crawls when components overlap (thousands of updates), so cycles of two
    updates are extrapolated (SQUAREM, Varadhan & Roland 2008, on ``(log eps, log lam)``)
    and the extrapolation is kept only if it does not lower the likelihood, so the
    likelihood still never decreases.

    Parameters
    ----------
    samples : array_like
        Amplitudes (any shape, flattened), finite and > 0, at least ``n_components``.
    n_components : int
        Number of components ``m`` (fixed).
    tol : float
        Stop when a cycle changes the mean log-likelihood per sample by less than this.
    max_iter : int
        Maximum number of EM updates (checked after each accelerated cycle, which makes
        three or more).

    Returns
    -------
    MixtureFit
        Falsy (``converged = False``) if ``max_iter`` was reached; ``.dist`` is then the
        last iterate.

    Notes
    -----
    Initialisation is deterministic: the sorted intensities are split into ``m``
    equal-count groups (quantile bins), ``lam_j`` is each group's mean, ``eps_j = 1/m``.
    """
    x = _samples(samples)
    if isinstance(n_components, bool) or not isinstance(n_components, (int, np.integer)) or n_components < 1:
        raise ValueError(f"n_components: must be a positive integer, got {n_components!r}")
    if x.size < n_components:
        raise ValueError(f"samples: need at least n_components={n_components} amplitudes, got {x.size}")
    tol = as_positive(tol, "tol")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter: must be a positive integer, got {max_iter!r}")

    intensity = np.sort(x * x)
    m = int(n_components)
    lam = np.array([g.mean() for g in np.array_split(intensity, m)])
    w = np.full(m, 1.0 / m)
    jacobian = float(np.mean(np.log(2 * x)))

    def pack(w_, l_):
        with np.errstate(divide="ignore"):
            return np.concatenate([np.log(w_), np.log(l_)])

    def unpack(t):
        lw = t[:m] - t[:m].max()
        ww = np.exp(lw)
        return ww / ww.sum(), np.exp(t[m:])

    n_iter, prev, converged = 0, -np.inf, False
    while n_iter < max_iter:
        w1, l1, _ = _em_update(intensity, w, lam)
        w2, l2, ll1 = _em_update(intensity, w1, l1)
        n_iter += 2
        t0, t1, t2 = pack(w, lam), pack(w1, l1), pack(w2, l2)
        finite = np.isfinite(t0) & np.isfinite(t1) & np.isfinite(t2)  # a weight that hit 0 stays 0
        r = np.where(finite, t1 - t0, 0.0)
        v = np.where(finite, t2 - t1, 0.0) - r
        nv = np.linalg.norm(v)
        step = min(-np.linalg.norm(r) / nv, -1.0) if nv > 0 else -1.0
        while True:
            if step == -1.0:
                wp, lp = w2, l2
            else:
                wp, lp = unpack(np.where(finite, t0 - 2 * step * r + step * step * v, t2))
            wn, ln, ll_p = _em_update(intensity, wp, lp)
            n_iter += 1
            if step == -1.0 or ll_p >= ll1:
                break
            step = (step - 1.0) / 2.0  # halve the extrapolation towards plain EM
            if step > -1.01:
                step = -1.0
        w, lam = wn, ln
        if abs(ll_p - prev) < tol:
            converged = True
            break
        prev = ll_p
    _, _, ll = _em_update(intensity, w, lam)
    order = np.argsort(lam)
    dist = RayleighMixture(tuple(w[order] / w.sum()), tuple(lam[order]))
    msg = "converged" if converged else f"stopped after max_iter={max_iter} EM updates"
    return MixtureFit(dist, float((ll + jacobian) * x.size), n_iter, converged, msg)


# --------------------------------------------------------------------------- Table 2.2 / 2.3


@dataclass(frozen=True)
class Table23Row:
    """One row of thesis Table 2.3: goodness-of-fit figures reported by its source [6].

    The thesis does not name the statistic; the values lie in [0, 1] and the Rayleigh
    column goes to 1e-7 where the data are visibly non-Rayleigh, so they read as test
    p-values (higher = better fit). Reference data only, for display beside our own.
    """

    rayleigh: float
    weibull: float
    mixture: float
    k: float

    def get(self, model: str) -> float:
        """The figure for ``model`` in ``{"rayleigh", "weibull", "mixture", "k"}``."""
        _model_class(model)
        return getattr(self, model)


@dataclass(frozen=True)
class BottomType:
    """A seabed type of thesis Table 2.2 (40-60 deg grazing angle), as printed.

    Attributes
    ----------
    name : str
    weibull : Weibull
    mixture : RayleighMixture
        Table 2.2's three components; weights divided by their sum (printed to three
        decimals, posidonia's sum to 1.001).
    k : KDistribution
    table_2_3 : Table23Row
        The goodness-of-fit figures of Table 2.3 for this seabed.
    """

    name: str
    weibull: Weibull
    mixture: RayleighMixture
    k: KDistribution
    table_2_3: Table23Row

    def model(self, model: str):
        """Table 2.2's distribution for ``model`` (``"rayleigh"`` is ``Rayleigh(1)``), not rescaled."""
        _model_class(model)
        return Rayleigh(1.0) if model == "rayleigh" else getattr(self, model)


def _row(name, weibull, eps, lams, k, t23) -> BottomType:
    eps = np.asarray(eps, float)
    return BottomType(
        name, Weibull(*weibull), RayleighMixture(tuple(eps / eps.sum()), tuple(lams)), KDistribution(*k), Table23Row(*t23)
    )


# Table 2.3's "1.28310x10^-7" and "4.25310x10^-4" are read as 1.283e-7 and 4.253e-4
# (the "10" of "x 10^" duplicated by the text extraction).
BOTTOM_TYPES: dict[str, BottomType] = {
    b.name: b
    for b in (
        _row("sand/shell", (1.009, 1.955), (0.369, 0.262, 0.369), (1.101, 0.717, 1.101), (0.033, 30.20), (0.652, 0.929, 0.961, 0.962)),
        _row("coarse sand", (1.031, 1.862), (0.353, 0.375, 0.272), (1.172, 1.172, 0.542), (0.108, 9.224), (0.864, 0.905, 0.864, 0.797)),
        _row("posidonia", (1.092, 1.656), (0.228, 0.588, 0.185), (2.049, 0.823, 0.269), (0.377, 2.654), (1.283e-7, 0.367, 0.989, 0.996)),
        _row("mud", (1.018, 1.918), (0.316, 0.338, 0.346), (0.754, 1.112, 1.115), (0.042, 24.03), (0.487, 0.691, 0.784, 0.874)),
        _row("medium sand", (1.087, 1.658), (0.546, 0.399, 0.055), (0.652, 1.606, 0.040), (0.337, 2.970), (4.253e-4, 0.716, 0.881, 0.615)),
        _row("shells", (1.060, 1.754), (0.286, 0.372, 0.342), (0.348, 1.300, 1.218), (0.242, 4.128), (0.002, 0.508, 0.963, 0.866)),
    )
}
"""Thesis Table 2.2 (fitted parameters) and Table 2.3 (fit quality), by seabed name."""


def lookup_bottom(bottom_type) -> BottomType:
    """The :class:`BottomType` named ``bottom_type`` (case-insensitive; ``_``/``-`` for spaces).

    Raises
    ------
    ValueError
        For an unknown name, listing the valid ones.
    """
    if isinstance(bottom_type, BottomType):
        return bottom_type
    key = str(bottom_type).strip().lower().replace("_", " ").replace("-", " ")
    if key not in BOTTOM_TYPES:
        raise ValueError(f"bottom_type: unknown seabed {bottom_type!r}, expected one of {list(BOTTOM_TYPES)}")
    return BOTTOM_TYPES[key]


def bottom_model(bottom_type, model: str = "mixture"):
    """Reverberation amplitude distribution of a Table 2.2 seabed, with ``E[x^2] = 1``.

    Table 2.2's parameter sets have mean squares within 0.6% of 1 (rounding in the
    table); they are rescaled in amplitude so that ``E[x^2] = 1`` exactly, which keeps a
    multiplicative reverberation factor from biasing the mean echo intensity.

    Parameters
    ----------
    bottom_type : str or BottomType
        A key of :data:`BOTTOM_TYPES` (case-insensitive; ``_`` or ``-`` may stand for a
        space, e.g. ``"coarse_sand"``).
    model : {"rayleigh", "weibull", "k", "mixture"}
        ``"rayleigh"`` is ``Rayleigh(1)`` for every seabed.

    Returns
    -------
    Rayleigh, Weibull, KDistribution or RayleighMixture
    """
    return lookup_bottom(bottom_type).model(model).normalised()


# --------------------------------------------------------------------------- goodness of fit


@dataclass(frozen=True)
class GofResult:
    """One-sample Kolmogorov-Smirnov test of samples against a distribution.

    Attributes
    ----------
    ks_statistic : float
        ``sup |F_n(x) - F(x)|``.
    p_value : float
        KS p-value. Exact only if ``F`` was fixed before seeing the data: with parameters
        fitted to the same samples it is optimistic (too large; Lilliefors 1967).
    n : int
        Number of samples.
    """

    ks_statistic: float
    p_value: float
    n: int


def goodness_of_fit(samples, dist) -> GofResult:
    """Kolmogorov-Smirnov test (``scipy.stats.kstest``) of ``samples`` against ``dist.cdf``.

    Parameters
    ----------
    samples : array_like
        Amplitudes (flattened), finite and > 0.
    dist : Rayleigh, Weibull, KDistribution or RayleighMixture

    Returns
    -------
    GofResult
        See its caveat on p-values with fitted parameters.
    """
    x = _samples(samples)
    if not isinstance(dist, _Amplitude):
        raise ValueError(f"dist: expected a distribution of this module, got {type(dist).__name__}")
    res = stats.kstest(x, dist.cdf)
    return GofResult(float(res.statistic), float(res.pvalue), int(x.size))


@dataclass(frozen=True)
class ModelFit:
    """One row of a Table 2.3-style comparison (:func:`compare_models`).

    Attributes
    ----------
    model : str
        ``"rayleigh"``, ``"weibull"``, ``"mixture"`` or ``"k"``.
    dist : distribution
        The maximum-likelihood fit.
    log_likelihood : float
        Total log-likelihood of the samples.
    aic : float
        ``2 n_params - 2 log_likelihood`` (lower is better).
    ks_statistic, p_value : float
        KS test of the samples against ``dist`` (p-value optimistic: fitted parameters).
    """

    model: str
    dist: object
    log_likelihood: float
    aic: float
    ks_statistic: float
    p_value: float


def compare_models(samples, *, models: Sequence[str] = ("rayleigh", "weibull", "mixture", "k")) -> list[ModelFit]:
    """Fit each model by maximum likelihood and score it (thesis Table 2.3 style).

    Parameters
    ----------
    samples : array_like
        Amplitudes (flattened), finite and > 0.
    models : sequence of str
        Names from :data:`MODELS`, in the order wanted.

    Returns
    -------
    list of ModelFit
        One per model, in the order of ``models``.
    """
    x = _samples(samples)
    classes = [_model_class(m) for m in models]
    if not classes:
        raise ValueError("models: need at least one model name")
    fits = []
    for name, cls in zip(models, classes):
        dist = cls.fit(x)
        ll = dist.log_likelihood(x)
        gof = goodness_of_fit(x, dist)
        fits.append(ModelFit(name, dist, ll, 2.0 * dist.n_params - 2.0 * ll, gof.ks_statistic, gof.p_value))
    return fits


# --------------------------------------------------------------------------- real images


def amplitudes_from_image(path, roi: Sequence[int] | None = None) -> np.ndarray:
    """Amplitudes of a region of a real sonar image, normalised to unit mean square.

    Parameters
    ----------
    path : str or Path
        A ``.npy`` array ``(H, W)`` of linear amplitudes, or an image file OpenCV reads
        (PNG, TIFF, ...) loaded as grayscale at its own bit depth (8 or 16 bit). Pixel
        values are taken as linear amplitudes; a log-compressed (dB) display image must
        be linearised first.
    roi : (x0, y0, x1, y1), optional
        Pixel box, columns ``x0:x1`` and rows ``y0:y1`` (half-open, inside the image).

    Returns
    -------
    numpy.ndarray, shape (N,)
        The ROI's non-zero finite amplitudes divided by their RMS (``mean(x^2) = 1``).
        Zeros (no echo, outside the fan) and NaN (masked cells) are dropped.

    Raises
    ------
    FileNotFoundError
        If ``path`` does not exist.
    ValueError
        Unreadable file, not 2-D, negative values, bad or empty ROI, no non-zero amplitude.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    if path.suffix.lower() == ".npy":
        try:
            img = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise ValueError(f"{path}: cannot read as a .npy array ({exc})") from None
    else:
        import cv2

        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
        if img is None:
            raise ValueError(f"{path}: OpenCV cannot read it as an image")
    img = np.asarray(img)
    if img.dtype.kind not in "fiub":
        what = "complex (I/Q?) values: save the amplitude np.abs(x)" if img.dtype.kind == "c" else f"dtype {img.dtype}"
        raise ValueError(f"{path}: holds {what}; expected real linear amplitudes")
    img = img.astype(float)
    if img.ndim != 2:
        raise ValueError(f"{path}: expected a 2-D amplitude image (H, W), got shape {img.shape}")
    if roi is not None:
        box = as_array(roi, "roi", (4,))
        if np.any(box != np.round(box)):
            raise ValueError(f"roi: expected integer pixel indices (x0, y0, x1, y1), got {box.tolist()}")
        x0, y0, x1, y1 = (int(v) for v in box)
        h, w = img.shape
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            raise ValueError(
                f"roi: (x0, y0, x1, y1) = {(x0, y0, x1, y1)} is empty or outside the image "
                f"(need 0 <= x0 < x1 <= {w}, 0 <= y0 < y1 <= {h})"
            )
        img = img[y0:y1, x0:x1]
    if np.any(np.isinf(img)):
        raise ValueError(f"{path}: the image holds infinite values")
    vals = img[np.isfinite(img)]
    if np.any(vals < 0):
        raise ValueError(f"{path}: amplitudes must be >= 0, found min {vals.min():.3g}")
    vals = vals[vals > 0]
    if vals.size == 0:
        where = f"in roi {tuple(int(v) for v in box)} of" if roi is not None else "in"
        raise ValueError(f"{path}: no finite non-zero amplitude {where} the image")
    return vals / np.sqrt(np.mean(vals * vals))
