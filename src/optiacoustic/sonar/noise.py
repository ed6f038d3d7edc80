"""Noise and reverberation applied to a sonar image (thesis sec. 2.7).

Each cell's echo is the coherent sum of its seabed returns (bottom reverberation, whose
amplitude follows a bottom-type model of Table 2.2), its target returns (fully developed
speckle: circular Gaussian) and ambient/thermal noise (circular Gaussian, amplified with
range by the TVG):

    image = | sqrt(I_bottom) X e^{i psi} + sqrt(I_target) Z_t + sqrt(N(r)) Z_n |^2

with ``E[X^2] = 1``, ``Z ~ CN(0, 1)``, ``psi`` uniform. The circular Gaussian terms merge
into one, and a Rayleigh-mixture amplitude of a given component is one too; a circular
Gaussian's intensity is its power times ``E ~ Exp(1)``. So the thesis's cell costs one
uniform (the mixture component) and one exponential (docs/physics.md, "Noise in one
exponential draw"). ``E[image] = I_bottom + I_target + N``: noise adds power,
reverberation and speckle only redistribute it (docs/physics.md).
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

import numpy as np

from .propagation import MAX_DB, absorption_db_per_m, check_number
from .speckle import AREA_NO_SEABED, MU_NO_SEABED

if TYPE_CHECKING:  # for the field's annotation only
    from .gain import DeviceGain

__all__ = ["NoiseModel", "NoEchoWarning"]


class NoEchoWarning(UserWarning):
    """A frame without any positive echo met a ``NoiseModel`` whose noise floor is relative to the
    frame's echo (no ``reference_level``): the floor has no reference, and the frame gets none.
    Set ``NoiseModel(reference_level=...)`` for an absolute noise floor."""


#: Linear factors of the noise models must stay below this (float32 holds up to 3.4e38; the
#: exponential and speckle variates multiply them by up to a few tens): else the image overflows.
_F32_SAFE = 1e35

_MODELS = ("mixture", "rayleigh", "weibull", "k")


@dataclass(frozen=True)
class NoiseModel:
    """How ``SonarFrame.image`` departs from the noise-free ``intensity``. Every part switchable.

    Attributes
    ----------
    reverberation : {"mixture", "rayleigh", "weibull", "k"} or None
        Amplitude model of seabed returns (thesis: Rayleigh mixture). ``None`` leaves
        seabed returns unfluctuating.
    bottom_type : str, optional
        Bottom type of Table 2.2 for every seabed; default: each seabed body's own
        ``Material.bottom_type``.
    target_speckle : bool
        Fully developed (Rayleigh amplitude) speckle on non-seabed returns.
    noise_floor_db : float or None
        Ambient/thermal noise power, in dB relative to the reference level (the median
        positive noise-free echo of the frame, or ``reference_level``), at the median
        echo range; within +-300 dB (``propagation.MAX_DB``). ``None`` switches the noise
        floor off. A frame with no positive echo and no ``reference_level`` has no
        reference: it gets no noise floor, with a :class:`NoEchoWarning`.
    reference_level : float, optional
        Absolute reference for ``noise_floor_db`` in the image's units, to make the
        noise floor the same across frames (and present in frames without echo); > 0,
        with ``reference_level x 10^(noise_floor_db / 10)`` at most 1e30.
    tvg_noise : bool
        With ideal TVG (the default propagation) the receiver noise is amplified by the
        TVG gain ``r^2 10^(2 alpha r / 10)``, so it rises with range; ``False`` keeps it flat.
    """

    reverberation: Optional[str] = "mixture"
    bottom_type: Optional[str] = None
    target_speckle: bool = True
    noise_floor_db: Optional[float] = -18.0
    reference_level: Optional[float] = None
    tvg_noise: bool = True

    def __post_init__(self):
        if self.reverberation is not None and (not isinstance(self.reverberation, str) or self.reverberation not in _MODELS):
            raise ValueError(f"NoiseModel.reverberation: expected one of {_MODELS} or None, got {self.reverberation!r}")
        for name in ("target_speckle", "tvg_noise"):
            v = getattr(self, name)
            if not isinstance(v, (bool, np.bool_)):  # "no" is truthy: a switch must be a bool
                raise ValueError(f"NoiseModel.{name}: expected True or False, got {v!r} ({type(v).__name__})")
        check_number("NoiseModel.noise_floor_db", self.noise_floor_db, -MAX_DB, MAX_DB, none=True, unit="dB")
        check_number("NoiseModel.reference_level", self.reference_level, 0.0, 1e30, none=True, lo_open=True)
        if self.reference_level is not None and self.noise_floor_db is not None:
            level = float(self.reference_level) * 10.0 ** (float(self.noise_floor_db) / 10.0)
            if level > 1e30:
                raise ValueError(f"NoiseModel.reference_level x 10^(noise_floor_db / 10) = {level:.3g}: a noise floor over "
                                 f"1e30 overflows the image (reference_level={self.reference_level!r}, "
                                 f"noise_floor_db={self.noise_floor_db!r})")
        _check_bottom_type("NoiseModel", self.bottom_type)

    @classmethod
    def off(cls) -> "NoiseModel":
        """A model that changes nothing (``image == intensity``)."""
        return cls(reverberation=None, target_speckle=False, noise_floor_db=None)

    # ------------------------------------------------------------------ pieces
    def noise_power(self, intensity: np.ndarray, ranges: np.ndarray, frequency: float, propagation: str, water) -> np.ndarray:
        """Mean noise power per range bin, ``(n_bins,)``, in the image's units."""
        if self.noise_floor_db is None:
            return np.zeros(len(ranges), np.float32)
        # medians over every 7th cell: a stable reference at a seventh of the cost
        sub = intensity.reshape(-1)[::7]
        rows = _subsample_rows(intensity.shape)
        pos = sub > 0
        any_echo = bool(pos.any())
        if self.reference_level is not None:
            ref = float(self.reference_level)
        elif any_echo:
            ref = float(np.median(sub[pos]))
        else:  # the floor is relative to the frame's echo, and there is none: no reference, no floor
            warnings.warn("NoiseModel: a frame without echo has no noise floor (noise_floor_db is relative to the "
                          "frame's echo); set NoiseModel(reference_level=...) for an absolute noise floor",
                          NoEchoWarning, stacklevel=3)
            return np.zeros(len(ranges), np.float32)
        r_ref = _median_of_rows(ranges, rows[pos]) if any_echo else float(np.median(ranges))
        level = ref * 10.0 ** (self.noise_floor_db / 10.0)
        if propagation == "tvg" and self.tvg_noise:
            alpha = absorption_db_per_m(frequency, water)
            with np.errstate(over="ignore"):
                gain = (ranges / r_ref) ** 2 * 10.0 ** (2.0 * alpha * (ranges - r_ref) / 10.0)
        else:
            gain = np.ones_like(ranges)
        out = level * gain
        top = float(np.max(out, initial=0.0))
        if not top <= _F32_SAFE:  # (n_bins,) values: once per frame
            raise ValueError(f"NoiseModel: the noise floor reaches {top:.3g} at {float(ranges[np.argmax(out)]):.4g} m, "
                             f"beyond what the float32 image holds (noise_floor_db={self.noise_floor_db!r}, "
                             f"reference_level={self.reference_level!r}, tvg_noise={self.tvg_noise!r}, "
                             f"reference {ref:.3g})")
        return out.astype(np.float32)

    def _gaussian_bottom(self) -> bool:
        """True when the bottom amplitude is a Rayleigh mixture (Rayleigh included): given its
        component, ``sqrt(I_b) x e^{i psi}`` is then circular Gaussian of power ``I_b lam_c``."""
        return self.reverberation in ("mixture", "rayleigh")

    def _needs_psi(self) -> bool:
        """Whether a steady part can meet a Gaussian part (then their relative phase is drawn)."""
        if self.reverberation is None:
            return self.target_speckle or self.noise_floor_db is not None
        return not self._gaussian_bottom() or not self.target_speckle

    def _counter(self) -> bool:
        """Whether the variates come from the counter stream (:class:`NoiseKey`): every model but
        Weibull and K, whose amplitudes have no per-cell form here (their ``sample``: gamma
        variates for K) and are drawn from the generator as before (:class:`NoiseDraws`)."""
        return self.reverberation is None or self._gaussian_bottom()

    def draw(self, shape: tuple, bottom_types, rng: np.random.Generator, *,
             _reuse: bool = False, _field: bool = False) -> "NoiseKey | NoiseDraws":
        """The frame's random variates, or the key they are computed from; independent of the echo.

        Rayleigh-family bottoms and no reverberation (the thesis's models): a :class:`NoiseKey`, two
        words drawn from ``rng``; each cell's uniforms, exponential and phase are words of
        Philox4x32-10 of its index under that key (:func:`counter_words`; docs/physics.md, "The
        thesis model's noise from a counter stream"), computed by :meth:`apply` row by row (the
        compiled path inside its kernel, on every thread: no array of draws). Weibull and K
        bottoms: a :class:`NoiseDraws` from ``rng`` in a fixed order (per bottom type its
        amplitude ``x``; then ``E``, then the phases), so a seed gives the same image.
        ``_reuse`` (``simulate_sonar``): those arrays go into buffers of
        ``sonar._kernels.pooled`` (the same numbers: ``out=``), which the caller hands back
        (:func:`release_noise_draws`) once :meth:`apply` has read them. ``_field``
        (``simulate_sonar`` with a second thread: this runs beside the scan) with ``_reuse``: the
        key's echo-free variates are formed now, into pooled buffers (``E``, each bottom type's
        component power, ``cos psi``: ``_numba_kernels.noise_variates``), and :meth:`apply`
        finishes the image from them, the same numbers as without.
        """
        from ._kernels import kernels, pooled, use_numba

        if self._counter():
            key = NoiseKey(rng.integers(0, 2**32, size=2, dtype=np.uint32), tuple(shape))
            off = self.reverberation is None and not self.target_speckle and self.noise_floor_db is None
            if not (_field and _reuse and use_numba()) or off:
                return key
            B, J = key.shape
            types = tuple(dict.fromkeys(bottom_types))
            cumw, lams = self._component_tables(types)
            use_psi = self._needs_psi()
            T = len(types) if self._gaussian_bottom() else 0
            v = (pooled((B, J), np.float32), pooled((T, B, J), np.float32),
                 pooled((B, J) if use_psi else (B, 0), np.float32))
            kernels().noise_variates(np.uint32(key.key[0]), np.uint32(key.key[1]), _STREAM, cumw, lams,
                                     self._gaussian_bottom(), use_psi, 0, B, *v)
            return NoiseKey(key.key, key.shape, types, v)
        shape = tuple(shape)
        buf = (lambda: pooled(shape, np.float32)) if _reuse else (lambda: None)  # noqa: E731
        x = {}
        for b in bottom_types:
            if b not in x:
                x[b] = bottom_model_for(self, b).sample(shape, rng, dtype=np.float32)
        e = rng.standard_exponential(shape, dtype=np.float32, out=buf())
        phase = None
        if not self.target_speckle:
            phase = rng.random(shape, dtype=np.float32, out=buf())
            phase *= np.float32(2 * np.pi)
        psi = None
        if self._needs_psi():
            psi = rng.random(shape, dtype=np.float32, out=buf())
            psi *= np.float32(2 * np.pi)
        return NoiseDraws(e, {}, x, phase, psi)

    def apply(self, intensity: np.ndarray, *, spec, seabed_share: dict, rng: np.random.Generator | None = None,
              options, draws: "NoiseKey | NoiseDraws | None" = None, threads: int = 1) -> np.ndarray:
        """The noisy image ``(n_bins, n_beams)`` float32 from the noise-free ``intensity``.

        ``seabed_share[bottom_type]`` is the share of each cell's echo returned by seabed
        bodies of that bottom type (``SonarFrame.seabed_share``). Pass either ``draws``
        (from :meth:`draw`) or ``rng``. ``threads``: rows are split over this many threads
        (the counter stream makes the image the same for any number).

        Every cell is ``|a + g|^2``: ``a`` its steady (non-Gaussian given the draws) part of
        power ``S``, ``g`` its circular Gaussian part of power ``P``; with ``|g|^2 = P E``
        (``E ~ Exp(1)``) and a uniform relative phase ``psi``,
        ``|a + g|^2 = S + P E + 2 sqrt(S P E) cos(psi)`` (docs/physics.md, "Noise in one
        exponential draw"). Rayleigh-mixture seabed returns, target speckle and noise are
        all Gaussian given the mixture component, so the thesis model costs one uniform and
        one exponential variate per cell.
        """
        from ._kernels import chunked_run, kernels, use_numba

        I = np.asarray(intensity, np.float32)
        shape = I.shape
        if draws is None:
            draws = self.draw(shape, list(seabed_share), rng)
        if self.reverberation is None and not self.target_speckle and self.noise_floor_db is None:
            return I.copy()
        if isinstance(draws, NoiseKey) != self._counter():
            raise ValueError(f"NoiseModel.apply: draws of type {type(draws).__name__} do not belong to "
                             f"reverberation={self.reverberation!r} (draw them with this model's draw)")
        if isinstance(draws, NoiseKey) and draws.shape != shape:
            raise ValueError(f"NoiseModel.apply: draws for shape {draws.shape}, intensity has shape {shape}")
        noise = self.noise_power(I, spec.ranges, spec.frequency, options.propagation, options.water)
        types = list(seabed_share)
        if isinstance(draws, NoiseKey) and use_numba():
            sh = _stack([np.asarray(seabed_share[t], np.float32) for t in types], shape)
            out = np.empty(shape, np.float32)
            kn = kernels()
            gauss, speckle, use_psi = self._gaussian_bottom(), self.target_speckle, self._needs_psi()
            # rows in chunks that the threads take as they finish (a cell's words are its index's: the same numbers)
            if draws.variates is not None and draws.types == tuple(types):  # formed beside the scan
                E, lam, cs = draws.variates
                chunked_run(lambda r0, r1: kn.noise_apply(I, sh, noise, E, lam, cs, gauss, speckle, use_psi, r0, r1,
                                                          out), shape[0], threads)
                return out
            cumw, lams = self._component_tables(types)
            k0, k1 = np.uint32(draws.key[0]), np.uint32(draws.key[1])
            chunked_run(lambda r0, r1: kn.noise_counter(I, sh, noise, cumw, lams, k0, k1, _STREAM, gauss, speckle,
                                                        use_psi, r0, r1, out), shape[0], threads)
            return out
        if isinstance(draws, NoiseKey):
            draws = _counter_draws(draws, types, self._needs_psi())
        return self._apply_numpy(I, noise[:, None], seabed_share, draws)

    def _component_tables(self, types) -> tuple:
        """``(cumw, lams)`` ``(max(T, 1), C)`` float64 of the bottom types ``types``: each mixture's
        cumulative weights (1 beyond its last threshold) and component powers (the last repeated),
        padded to the most components ``C``."""
        tables = [_mixture_table(bottom_model_for(self, t)) for t in types] if self._gaussian_bottom() else []
        C = max([len(w) for w, _ in tables], default=1)
        cumw = np.ones((max(len(types), 1), C))
        lams = np.zeros((max(len(types), 1), C))
        for k, (w, lam) in enumerate(tables):  # pad with zero-weight copies of the last component
            cumw[k, : len(w) - 1] = np.cumsum(w)[:-1]
            lams[k, : len(w)] = lam
            lams[k, len(w):] = lam[-1]
        return cumw, lams

    def _apply_numpy(self, I, noise, seabed_share, draws):
        """The reference implementation of :meth:`apply` (``OAS_KERNELS=numpy``)."""
        shape = I.shape
        bottom = np.zeros(shape, np.float32)
        P = np.broadcast_to(noise, shape).astype(np.float32)
        amp_b = None
        for btype, share in seabed_share.items():
            part = I * share
            bottom += part
            if self._gaussian_bottom():
                w, lam = _mixture_table(bottom_model_for(self, btype))
                lam_c = np.full(shape, lam[-1], np.float32)
                if len(w) > 1:
                    u = draws.u[btype]
                    for c, l in zip(np.cumsum(w)[:-1][::-1], lam[:-1][::-1]):
                        lam_c[u < c] = l
                P += part * lam_c
            elif self.reverberation is not None:
                amp = np.sqrt(part) * draws.x[btype]
                amp_b = amp if amp_b is None else amp_b + amp
        target = np.maximum(I - bottom, 0.0)
        if self.reverberation is None:
            amp_b = np.sqrt(bottom) if self.target_speckle else np.sqrt(I)
            if not self.target_speckle:
                target = np.zeros_like(I)
        if self.target_speckle:
            P += target
            S = None if amp_b is None else amp_b * amp_b
        elif amp_b is None:  # Gaussian seabed: only the magnitude of the steady target matters
            S = target
        elif draws.phase is None:  # no reverberation: the whole echo is the steady amp_b
            S = amp_b * amp_b
        else:  # a steady target adds to the bottom amplitude with an independent random phase
            S = amp_b * amp_b + target + np.float32(2.0) * amp_b * np.sqrt(target) * np.cos(draws.phase)
        pe = P * draws.e
        if S is None:
            return pe
        out = S + pe
        if draws.psi is not None:
            out += np.float32(2.0) * np.sqrt(np.maximum(S, 0.0) * pe) * np.cos(draws.psi)
        return np.maximum(out, 0.0)


def _check_bottom_type(owner: str, bottom_type) -> None:
    """``bottom_type``: None or the name of a Table 2.2 bottom type (a string: a list is a mistake)."""
    if bottom_type is None:
        return
    from .distributions import BOTTOM_TYPES

    if not isinstance(bottom_type, str) or bottom_type not in BOTTOM_TYPES:
        raise ValueError(f"{owner}.bottom_type: unknown {bottom_type!r}; expected one of {sorted(BOTTOM_TYPES)} or None")


@functools.lru_cache(maxsize=8)
def _subsample_rows(shape: tuple) -> np.ndarray:
    """Row of every 7th cell of an image of ``shape`` (read-only, cached)."""
    rows = np.arange(0, shape[0] * shape[1], 7) // shape[1]
    rows.setflags(write=False)
    return rows


def _median_of_rows(ranges: np.ndarray, rows: np.ndarray) -> float:
    """``np.median(ranges[rows])`` for ascending ``ranges`` and sorted ``rows``, by counting."""
    n = rows.size
    lo, hi = rows[(n - 1) // 2], rows[n // 2]  # rows are sorted: the middle elements' rows
    return float(np.mean([ranges[lo], ranges[hi]]))


def _look_weights(looks: float) -> np.ndarray:
    from .speckle import look_weights

    return look_weights(looks)


def _stack(arrays: list, shape: tuple) -> np.ndarray:
    """``np.stack`` without the copy for one array (the usual single bottom type)."""
    if not arrays:
        return np.zeros((0,) + tuple(shape), np.float32)
    if len(arrays) == 1:
        return np.ascontiguousarray(arrays[0])[None]
    return np.stack(arrays)


def bottom_model_for(model: NoiseModel, bottom_type: str):
    """The amplitude model a :class:`NoiseModel` applies to seabeds of ``bottom_type`` (cached: the
    models are immutable and building one costs a fraction of a millisecond per frame)."""
    return _bottom_model_cached(model.bottom_type or bottom_type, model.reverberation)


@functools.lru_cache(maxsize=64)
def _bottom_model_cached(bottom_type, reverberation):
    from .distributions import bottom_model

    return bottom_model(bottom_type, reverberation)


def _mixture_table(model):
    """``(weights, lams)`` of a Rayleigh mixture or a Rayleigh (one component), float64 arrays."""
    if hasattr(model, "weights"):
        return np.asarray(model.weights, float), np.asarray(model.lams, float)
    return np.ones(1), np.array([float(model.lam)])


def release_noise_draws(draws: "NoiseKey | NoiseDraws") -> None:
    """Hand the buffers of ``NoiseModel.draw(..., _reuse=True)`` back to the pool; the caller must
    not read ``draws`` afterwards (the amplitudes ``x`` are fresh arrays and are left alone; a
    :class:`NoiseKey` holds none)."""
    from ._kernels import give_back

    if isinstance(draws, NoiseDraws):
        give_back(draws.e, *draws.u.values(), draws.phase, draws.psi)
    elif draws.variates is not None:
        give_back(*draws.variates)


#: Counter word 2 of the thesis model's Philox blocks (the scatterer noise's words have 0 there): the
#: two models' streams stay apart under one key.
_STREAM = 1


@dataclass(frozen=True, eq=False)
class NoiseKey:
    """The thesis model's draws of one frame (``NoiseModel.draw``): the key ``(2,)`` uint32 of its
    counter stream, for an image of ``shape`` ``(n_bins, n_beams)``. The variates of cell
    ``(i, j)`` are functions of ``(key, i n_beams + j)`` alone (:func:`counter_words`). With a second
    thread ``simulate_sonar`` has them formed beside the scan: ``variates`` (pooled buffers, for the
    bottom types ``types`` in that order; handed back by :func:`release_noise_draws`)."""

    key: np.ndarray
    shape: tuple
    types: tuple = ()
    variates: Optional[tuple] = None  # (E, lam, cos psi) formed beside the scan (``draw(_field=True)``)


def _n_blocks(n_types: int) -> int:
    """Philox blocks (of 4 words) per cell: ``E``, ``psi`` and one uniform per bottom type."""
    return (2 + n_types + 3) // 4


def counter_words(draws: NoiseKey, n_types: int) -> np.ndarray:
    """The thesis model's random words ``(4 n_blocks, n_bins, n_beams)`` uint32 of a frame (numpy
    reference of ``_numba_kernels.noise_counter``'s): row ``4 b + k`` is word ``k`` of
    Philox4x32-10 of the counters ``(cell, b, 1, 0)`` under ``draws.key``, ``cell = i n_beams + j``
    the flat index. Word 0: ``E``, word 1: ``psi``, word ``2 + t``: the component's uniform of
    bottom type ``t`` (``n_types`` of them)."""
    B, J = draws.shape
    cells = np.arange(B * J)
    words = [w for b in range(_n_blocks(n_types)) for w in _philox_numpy(cells, draws.key, b, _STREAM)]
    return np.stack(words).reshape(-1, B, J)


def _counter_draws(draws: NoiseKey, types: list, psi: bool) -> "NoiseDraws":
    """The variates of :class:`NoiseDraws` from the counter words (the numpy reference path):
    ``E = -ln x``, ``x = (w0 + 1/2) 2^-32``; ``psi = 2 pi w1 2^-32`` (float64); the component
    uniforms ``(w + 1/2) 2^-32`` (float64) of each bottom type, in the order of ``types``."""
    words = counter_words(draws, len(types))
    e = (-np.log(_uniforms(words[0]))).astype(np.float32)
    u = {t: _uniforms(words[2 + k]) for k, t in enumerate(types)}
    phase = (2.0 * np.pi * 2.0**-32) * words[1].astype(np.float64) if psi else None
    return NoiseDraws(e, u, {}, None, phase)


@dataclass(frozen=True, eq=False)
class NoiseDraws:
    """Random variates of one frame, each ``(n_bins, n_beams)``: ``e ~ Exp(1)`` (float32, the power
    of the Gaussian part), per bottom type the mixture component's uniform ``u[bottom_type]``
    (Rayleigh-family models, float64, from the counter words: :func:`_counter_draws`) or the
    amplitude ``x[bottom_type]`` with ``E[x^2] = 1`` (Weibull, K, float32 from the generator), the
    phase of steady target echoes (only when ``target_speckle`` is off and the seabed is not
    Gaussian) and the relative phase ``psi`` of steady and Gaussian parts (``None`` when no
    cell has both). ``NoiseModel.draw`` returns one for Weibull and K bottoms; the other
    models' numpy path makes one from their :class:`NoiseKey`."""

    e: np.ndarray
    u: dict
    x: dict
    phase: Optional[np.ndarray]
    psi: Optional[np.ndarray]


@dataclass(frozen=True)
class ScattererNoise:
    """A device-like image: speckle from scatterer counts, background and gain before the device TVG.

    ``image = TVG(r) | sqrt(g I) f_s + sqrt(B(r)) f_n |^2`` with ``I`` the raw echo
    (simulate with ``SonarOptions(propagation="spreading")`` so that it carries the
    water's losses), ``g`` the source level and receiver gain, ``B`` the receiver noise
    and volume reverberation before the TVG (:class:`~optiacoustic.sonar.gain.DeviceGain`),
    ``f_s`` the unit-power speckle field of the seabed's scatterer counts
    (``sonar.speckle``: Poisson counts of mean ``density x cell area``, filtered by the
    pulse and the two-way azimuth amplitude pattern) and ``f_n`` the background's
    Gaussian field filtered the same way (docs/physics.md, "Speckle from scatterers").

    Attributes
    ----------
    density : float
        Seabed scatterers per square metre, in ``(0, 1e12]`` (``speckle.MAX_DENSITY``); ``inf``: fully
        developed (Rayleigh) speckle. A cell holds seabed when its area exceeds
        ``speckle.AREA_NO_SEABED``; its count is Poisson of mean ``density x area``, so a tiny
        density leaves (almost) every seabed cell empty (probability ``exp(-density x area)``).
    gain : DeviceGain
        Source level, receiver noise, volume reverberation and the device's TVG.
    bottom_type : str, optional
        A Table 2.2 bottom type instead of scatterer counts: its reverberation amplitude
        (thesis, i.i.d. per cell) takes the place of ``f_s``.
    clusters_per_m2 : float
        Independent scatterer clusters per m^2: a cell's count is gamma-mixed Poisson of
        shape ``clusters_per_m2 x cell area`` (``sonar.speckle.cluster_ratio``); ``inf``: none.
    looks : float
        Effective number of independent looks the device averages per stored sample, in
        ``[1, 1000]`` (``speckle.MAX_LOOKS``).
    """

    density: float = float("inf")
    gain: "DeviceGain" = None  # type: ignore[assignment]
    bottom_type: Optional[str] = None
    clusters_per_m2: float = float("inf")  # issue 10: gamma clustering of the counts (inf: none)
    looks: float = 1.0  # issue 10: independent looks the device averages per sample
    needs_cell_area = True

    def __post_init__(self):
        from .gain import DeviceGain

        if self.gain is None:
            object.__setattr__(self, "gain", DeviceGain())
        if not isinstance(self.gain, DeviceGain):
            raise ValueError(f"ScattererNoise.gain: expected a DeviceGain, got {type(self.gain).__name__}")
        from .speckle import check_scatterer_parameters

        check_scatterer_parameters("ScattererNoise", self.density, self.clusters_per_m2, self.looks)
        _check_bottom_type("ScattererNoise", self.bottom_type)

    def draw(self, shape: tuple, bottom_types, rng: np.random.Generator, *, _reuse: bool = False,
             _field: bool = False):
        """The key of the frame's noise words, and the generator for counts of large mean.

        Returns ``(key, rng)``: ``key`` (2,) uint32, one draw of ``rng``. Each cell's three
        random words (its count's uniform, its Box-Muller radius and phase) are Philox4x32-10
        of the cell's index under this key (:func:`cell_words`; docs/physics.md, "Random words
        of the scatterer noise"): the compiled path draws them row by row inside its kernel, so
        no array of draws is made. ``_reuse`` is accepted for ``simulate_sonar`` and changes
        nothing by itself. ``_field`` (``simulate_sonar``, with a second thread: this runs beside
        the scan) also draws the part of the field that does not depend on the echo, when
        :meth:`apply` takes its one-pass path: ``(key, rng, (words, r2, unit))``
        (``_numba_kernels.field_words``, buffers from the pool: :func:`release_draws` hands
        them back), which :meth:`apply` finishes with the same numbers as without."""
        key = rng.integers(0, 2**32, size=2, dtype=np.uint32)
        if not (_field and _reuse and self._one_pass()):
            return key, rng
        from ._kernels import kernels, pooled

        B, J = shape
        field = (pooled((B, J), np.uint32), pooled((B, J), np.float32), pooled((B, J, 2), np.float32))
        kernels().field_words(np.uint32(key[0]), np.uint32(key[1]), 0, B, *field)
        return key, rng, field

    def _one_pass(self) -> bool:
        """Whether :meth:`apply` forms the field in one compiled pass (given the cells' areas)."""
        from ._kernels import use_numba

        # the kernels test ``density x area > MU_NO_SEABED`` for seabed: the area test (AREA_NO_SEABED)
        # only from this density up (below it a real area of a tiny density would read as no seabed)
        return (use_numba() and self.bottom_type is None and np.isfinite(self.density)
                and self.density >= _KERNEL_DENSITY_MIN
                and not np.isfinite(self.clusters_per_m2) and len(_look_weights(self.looks)) == 1)

    def kernels(self, spec):
        """Amplitude kernels along range (the pulse) and across beams (two-way ``F^2``)."""
        return _kernels(spec)

    def apply(self, intensity: np.ndarray, *, spec, seabed_share: dict, options, draws=None, rng=None,
              cell_area=None, threads: int = 1) -> np.ndarray:
        """The image ``(n_bins, n_beams)`` float32, linear intensity after the device's TVG.

        One complex white field carries both parts, ``w = sqrt(g I n / mu + B) z`` (``n``
        the Poisson counts of mean ``mu``, ``z ~ CN(0, 1)``): given the counts the two
        are independent circular Gaussians, so their sum is one with the summed power.
        It is filtered by the pulse and beam kernels and normalised by ``S2 = sum h^2``,
        so a uniform region has mean ``g I + B`` and the moments of :mod:`.speckle`.
        """
        from ._kernels import chunked_run, kernels, use_numba
        from .speckle import filter_complex

        I = np.asarray(intensity, np.float32)
        key, rng, *field = draws if draws is not None else self.draw(I.shape, (), np.random.default_rng(rng))
        h_r, h_b = self.kernels(spec)
        g = self.gain
        back = _background_column(g, spec, options.water if options.propagation == "spreading" else None)
        from ._kernels import workspace as _workspace

        # the compiled path reuses per-thread scratch for the echo and the mean (fresh pages fault on
        # every frame): neither outlives this call
        fast = use_numba()
        gain = np.float32(10.0 ** (g.gain_db / 10.0))  # gain_db within +-300 dB: finite
        mean = None
        if fast and cell_area is not None and self._one_pass():
            cell_area = _kernel_area(cell_area, self.density)
        if fast and cell_area is not None and self._one_pass() and _FUSED:
            # issue 14 (i14q): the field and the speckle image in one pass over row blocks (no field or mean
            # image stored); the rare frame with cells of large mean takes the two passes below instead
            area = np.ascontiguousarray(cell_area, np.float32)
            out = np.empty(I.shape, np.float32)
            have = bool(field)
            words, r2, unit = field[0] if have else (_NO_WORDS, _NO_R2, _NO_UNIT)
            tvg = np.ascontiguousarray(_tvg_column(g, spec)[:, 0])
            hr32 = np.ascontiguousarray(h_r, np.float32)
            hb32 = np.ascontiguousarray(h_b, np.float32)
            kn = kernels()
            k0, k1 = np.uint32(key[0]), np.uint32(key[1])
            n_big = []  # per chunk (list.append is atomic under the GIL)

            def part(r0, r1):
                n_big.append(kn.scatterer_speckle(I, gain, back[:, 0], area, float(self.density), _POISSON_INVERSION_MAX,
                                                 k0, k1, have, words, r2, unit, hr32, hb32, tvg, r0, r1, out))

            chunked_run(part, I.shape[0], threads)
            if not any(n_big):
                return out
        if fast and cell_area is not None and self._one_pass():
            # counts, power, complex normals and the mean image in one pass
            z = _workspace("scatterer_z", I.shape + (2,), np.float32)  # reused: no page faults per frame
            big = _workspace("scatterer_big", I.shape, np.bool_)
            mean = _workspace("scatterer_mean", I.shape, np.float32)
            area = np.ascontiguousarray(cell_area, np.float32)
            kn = kernels()
            k0, k1 = np.uint32(key[0]), np.uint32(key[1])
            if field:  # the echo's part only: the words were drawn beside the scan
                words, r2, unit = field[0]
                chunked_run(lambda r0, r1: kn.scatterer_field_words(I, gain, back[:, 0], area, float(self.density),
                                                                  _POISSON_INVERSION_MAX, r0, r1, words, r2, unit,
                                                                  z, big, mean), I.shape[0], threads)
            else:
                chunked_run(lambda r0, r1: kn.scatterer_field(I, gain, back[:, 0], area, float(self.density), k0, k1,
                                                            _POISSON_INVERSION_MAX, r0, r1, z, big, mean),
                          I.shape[0], threads)
            if big.any():  # the rare cells of large mean: counts from the generator, as the numpy path
                mu = self.density * area[big].astype(np.float64)
                ratio = (rng.poisson(mu) / mu).astype(np.float32)
                z[big] = _complex_normals(cell_words(key, np.flatnonzero(big))[:, None],
                                          np.sqrt((I[big] * gain * ratio + back[:, 0][np.nonzero(big)[0]])
                                                  * np.float32(0.5))[None])[0]
            power = None
        else:
            echo = np.multiply(I, gain, out=_workspace("scatterer_echo", I.shape, np.float32) if fast else None)
            bits = cell_words(key, np.arange(I.size)).reshape((3,) + I.shape)
        if mean is not None:  # done above
            pass
        elif self.bottom_type is not None:
            from .distributions import bottom_model

            x = bottom_model(self.bottom_type, "mixture").sample(I.shape, rng, dtype=np.float32)
            power = echo * x * x + back  # Table 2.2 reverberation: i.i.d. amplitudes, as the thesis
            h_r, h_b = np.ones(1), np.ones(1)
        elif cell_area is None or not (np.isfinite(self.density) or np.isfinite(self.clusters_per_m2)):
            power = echo + back
        else:
            area = np.asarray(cell_area, np.float32).astype(np.float64)
            seabed = area > AREA_NO_SEABED  # at or below: the area's rounding, no seabed (a tiny density: empty cells)
            if np.isfinite(self.clusters_per_m2):
                from .speckle import cluster_ratio

                with np.errstate(invalid="ignore"):  # inf x 0 outside the seabed: no texture there
                    ratio = cluster_ratio(self.density * area, self.clusters_per_m2 * area, rng, seabed=seabed)
            else:  # plain Poisson counts, by inversion of the uniforms drawn during the scan
                mu = np.where(seabed, self.density * area, 0.0)
                n = _poisson_counts(mu, _uniforms(bits[0]), rng).astype(np.float32)
                ratio = np.zeros(area.shape, np.float32)
                np.divide(n, mu, out=ratio, where=mu > 0, casting="unsafe")  # mu = 0 on a seabed: underflow, empty
                ratio[~seabed] = 1.0
            power = echo * np.where(seabed, ratio, np.float32(1.0)) + back
        # issue 10: the mean image ``echo + back`` is already blurred by the pulse and the beam
        # pattern (formation); filtering the field blurs its power a second time, so the
        # speckle is normalised by that filtered mean and multiplied by the image's own mean
        # (all float32; the filters are separable, cv2.sepFilter2D with zero borders)
        from .speckle import filter_real, look_weights

        if mean is None:
            mean = np.add(echo, back, out=_workspace("scatterer_mean", I.shape, np.float32) if fast else None)
        weights = look_weights(self.looks)
        if use_numba() and len(weights) == 1:  # one look: the filters and |f|^2 x mean / expected x TVG in one pass
            zk = z if power is None else _complex_normals(bits, np.sqrt(power * np.float32(0.5)))
            out = np.empty(I.shape, np.float32)
            tvg = np.ascontiguousarray(_tvg_column(g, spec)[:, 0])
            hr32 = np.ascontiguousarray(h_r, np.float32)
            hb32 = np.ascontiguousarray(h_b, np.float32)
            kn = kernels()
            chunked_run(lambda r0, r1: kn.speckle_image(zk, mean, hr32, hb32, tvg, r0, r1, out), I.shape[0], threads)
            return out
        expected = filter_real(mean, np.asarray(h_r, np.float32) ** 2, np.asarray(h_b, np.float32) ** 2)
        # per-cell factor: the image's own mean over the twice-blurred mean, times the device's TVG
        scale = np.zeros(I.shape, np.float32)
        np.divide(mean, expected, out=scale, where=expected > 0)
        scale *= _tvg_column(g, spec)
        out = None
        for k, w in enumerate(weights):
            if k == 0:  # the first look from the uniforms drawn during the scan (or the kernel's field)
                zk = z if power is None else _complex_normals(bits, np.sqrt(power * np.float32(0.5)))
            else:
                zk = rng.standard_normal(I.shape + (2,), dtype=np.float32) * np.sqrt(power * np.float32(0.5))[..., None]
            f = filter_complex(zk, h_r, h_b)
            fk = np.square(f[..., 0])
            fk += np.square(f[..., 1])
            if w != 1.0:
                fk *= np.float32(w)
            out = fk if out is None else np.add(out, fk, out=out)
        out *= scale
        return out


#: Whether :meth:`ScattererNoise.apply` takes the one-pass ``scatterer_speckle`` (issue 14, i14q).
_FUSED = True
#: The least density the compiled field kernels take: there ``density x AREA_NO_SEABED`` reaches their
#: ``MU_NO_SEABED``, so no real area (over ``AREA_NO_SEABED``) reads as no seabed (speckle.MU_NO_SEABED).
_KERNEL_DENSITY_MIN = MU_NO_SEABED / AREA_NO_SEABED
#: Rounding of a cell's area stays under this (m^2; about 1e-16 seen): up to ``MU_NO_SEABED`` over it,
#: the kernels read it as no seabed as they are; above, areas up to ``AREA_NO_SEABED`` are cleared first.
_AREA_ROUNDING = 1e-13


def _kernel_area(cell_area, density: float):
    """``cell_area`` for the compiled field kernels at ``density``: as it is, or (densities over
    ``MU_NO_SEABED / _AREA_ROUNDING``, where the areas' rounding could pass for seabed there) a copy
    with areas of at most ``AREA_NO_SEABED`` set to 0 (one pass, at such densities only)."""
    if density <= MU_NO_SEABED / _AREA_ROUNDING:
        return cell_area
    area = np.array(cell_area, np.float32)
    area[area <= np.float32(AREA_NO_SEABED)] = 0.0
    return area
# stand-ins for the words when the kernel draws its own (one thread: nothing was drawn beside the scan)
_NO_WORDS = np.zeros((1, 1), np.uint32)
_NO_R2 = np.zeros((1, 1), np.float32)
_NO_UNIT = np.zeros((1, 1, 2), np.float32)


def release_draws(draws) -> None:
    """Hand back the buffers of ``ScattererNoise.draw(..., _reuse=True, _field=True)`` to the pool (a
    draw without them holds none); the caller must not read ``draws`` afterwards."""
    if len(draws) > 2:
        from ._kernels import give_back

        give_back(*draws[2])


@functools.lru_cache(maxsize=32)
def _background_column(gain, spec, water) -> np.ndarray:
    """``gain.background_raw`` at the spec's bin centres, ``(n_bins, 1)`` float32, with the absorption of
    ``water`` (``None``: none, as without spreading); cached per gain, spec and water (issue 14, i14q:
    ~0.1 ms a frame). Shared: callers only read it (left writable so that the kernels taking it keep
    their one compiled signature)."""
    from .propagation import absorption_db_per_m

    alpha = absorption_db_per_m(spec.frequency, water) if water is not None else 0.0
    with np.errstate(over="ignore"):
        b = gain.background_raw(spec.ranges, alpha)
    with np.errstate(over="ignore", invalid="ignore"):
        after = b * gain.tvg(spec.ranges)
    _check_factor(after, spec, "the background after the TVG (DeviceGain.noise_db, volume_db, spreading_db, "
                  "absorption_db_per_m)", gain)
    return b.astype(np.float32)[:, None]


def _tvg_column(gain, spec) -> np.ndarray:
    """The device's TVG at the spec's bin centres, ``(n_bins, 1)`` float32 (cached per gain and spec)."""
    return _tvg_cached(gain, spec)


def _check_factor(values: np.ndarray, spec, what: str, gain, scale: float = 1.0) -> None:
    """Refuse a linear factor (``values x scale``) over the ranges of ``spec`` that the float32 image
    cannot hold, naming ``what`` (the fields that set it); once per gain and spec (cached callers)."""
    with np.errstate(over="ignore", invalid="ignore"):
        top = float(np.max(np.abs(values) * scale, initial=0.0))
    if not top <= _F32_SAFE:
        raise ValueError(f"{what} reaches {top:.3g} over {spec.range_min:g}-{spec.range_max:g} m, beyond what the "
                         f"float32 image holds ({gain!r})")


@functools.lru_cache(maxsize=32)
def _tvg_cached(gain, spec):
    with np.errstate(over="ignore"):
        tv = gain.tvg(spec.ranges)
    _check_factor(tv, spec, "the TVG x gain (DeviceGain.gain_db, spreading_db, absorption_db_per_m)", gain,
                  10.0 ** (gain.gain_db / 10.0))
    t = np.ascontiguousarray(tv, np.float32)[:, None]
    t.setflags(write=False)
    return t


#: Counts of mean at least this are drawn by ``Generator.poisson`` after the scan (inversion
#: would take about ``mu`` steps); below it, by inversion of the uniforms drawn beforehand.
_POISSON_INVERSION_MAX = 30.0


def _poisson_counts(mu: np.ndarray, u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Poisson counts of mean ``mu`` (float64, any shape): by inversion of the uniforms ``u`` where
    ``mu < 30`` (exact: the least ``n`` with ``P(N <= n) >= u``), by ``rng.poisson`` elsewhere."""
    from ._kernels import kernels, use_numba

    if use_numba():
        n = np.empty(mu.shape, np.int64)
        kernels().poisson_inverse(mu, u, _POISSON_INVERSION_MAX, n)
    else:
        from scipy.stats import poisson

        small = (mu > 0) & (mu < _POISSON_INVERSION_MAX)
        n = np.where(mu >= _POISSON_INVERSION_MAX, -1, 0).astype(np.int64)
        n[small] = poisson.ppf(u[small], mu[small]).astype(np.int64)
    big = n < 0
    if big.any():
        n[big] = rng.poisson(mu[big])
    return n


_PHILOX_M = (0xD2511F53, 0xCD9E8D57)
_PHILOX_W = (0x9E3779B9, 0xBB67AE85)


def _philox_numpy(cells: np.ndarray, key, c1: int = 0, c2: int = 0) -> tuple:
    """Philox4x32-10 of counters ``(cells, c1, c2, 0)`` under ``key``: four uint32 arrays of the shape
    of ``cells`` (numpy reference of the kernels' generator). In chunks of 32 768 counters whose
    uint64 scratch stays in cache, every operation in place (issue 14: 5x faster than whole-array
    temporaries, the same words)."""
    cells = np.asarray(cells)
    flat = cells.reshape(-1)
    n = flat.size
    out = np.empty((4, n), np.uint32)
    m0, m1 = np.uint64(_PHILOX_M[0]), np.uint64(_PHILOX_M[1])
    mask, s32 = np.uint64(0xFFFFFFFF), np.uint64(32)
    keys, k0, k1 = [], int(key[0]), int(key[1])
    for _ in range(10):
        keys.append((np.uint64(k0), np.uint64(k1)))
        k0, k1 = (k0 + _PHILOX_W[0]) & 0xFFFFFFFF, (k1 + _PHILOX_W[1]) & 0xFFFFFFFF
    chunk = 1 << 15
    scratch = np.empty((6, min(chunk, n)), np.uint64)
    for s in range(0, n, chunk):
        e = min(s + chunk, n)
        w0, w1, w2, w3, p0, p1 = scratch[:, : e - s]
        np.bitwise_and(flat[s:e].astype(np.uint64), mask, out=w0)
        w1.fill(c1)
        w2.fill(c2)
        w3.fill(0)
        for r0, r1 in keys:  # (w0, w1, w2, w3) <- (hi(p1) ^ w1 ^ k0, lo(p1), hi(p0) ^ w3 ^ k1, lo(p0))
            np.multiply(w0, m0, out=p0)
            np.multiply(w2, m1, out=p1)
            np.right_shift(p1, s32, out=w0)
            w0 ^= w1
            w0 ^= r0
            np.bitwise_and(p1, mask, out=w1)
            np.right_shift(p0, s32, out=w2)
            w2 ^= w3
            w2 ^= r1
            np.bitwise_and(p0, mask, out=w3)
        out[:, s:e] = scratch[:4, : e - s]
    return tuple(w.reshape(cells.shape) for w in out)


def cell_words(key, cells: np.ndarray) -> np.ndarray:
    """The three noise words ``(3, n)`` uint32 of the flat cell indices ``cells``: words 0..2 of
    Philox4x32-10 of the counter ``(cell, 0, 0, 0)`` under ``key`` (2,) uint32 (word 0: the
    count's uniform, 1: the Box-Muller radius, 2: the phase)."""
    from ._kernels import kernels, use_numba

    cells = np.ascontiguousarray(cells, np.int64).reshape(-1)
    if use_numba():
        out = np.empty((3, cells.size), np.uint32)
        kernels().cell_words(np.uint32(key[0]), np.uint32(key[1]), cells, out)
        return out
    return np.stack(_philox_numpy(cells, key)[:3])


def _uniforms(words: np.ndarray) -> np.ndarray:
    """``(b + 1/2) 2^-32`` (float64): the uniform in ``(0, 1)`` of uint32 random words."""
    return (words.astype(np.float64) + 0.5) * 2.0**-32


def _complex_normals(bits: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """``(n_bins, n_beams, 2)`` float32 pairs of independent normals times ``scale`` (Box-Muller from
    the random words ``bits[1]`` (radius, ``x = (b1 + 1/2) 2^-32``) and ``bits[2]`` (phase,
    ``u = b2 2^-32``) of ``bits`` ``(3, n_bins, n_beams)`` uint32):
    ``scale sqrt(-2 ln x) (cos, sin)(2 pi u)``."""
    from ._kernels import kernels, use_numba

    scale = np.ascontiguousarray(scale, np.float32)
    if use_numba():
        out = np.empty(scale.shape + (2,), np.float32)
        kernels().box_muller(np.ascontiguousarray(bits), scale, out)
        return out
    r = np.sqrt(-2.0 * np.log(_uniforms(bits[1])))
    ang = (2.0 * np.pi * 2.0**-32) * bits[2].astype(np.float64)
    s = scale * r
    return np.stack([np.cos(ang) * s, np.sin(ang) * s], -1).astype(np.float32)


@functools.lru_cache(maxsize=32)
def _kernels(spec):
    from .speckle import beam_kernel, gaussian_pulse_kernel

    h_r = gaussian_pulse_kernel(spec.pulse_width / spec.bin_width)
    h_b = beam_kernel(spec.azimuth_pattern(), spec.beam_spacing)
    h_r.setflags(write=False)
    h_b.setflags(write=False)
    return h_r, h_b
