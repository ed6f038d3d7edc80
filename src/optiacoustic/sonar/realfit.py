"""Amplitude-model fits on real (or simulated) sonar frames, done the way real data need.

:func:`fit_frames` takes frames (``.image`` linear intensity; measured frames also
``.raw`` and ``.encoding``), a polar region (range and azimuth window, or a boolean
``(n_bins, n_beams)`` mask), and:

1. **linearises** from the device encoding: the frames' ``.image`` already is linear
   intensity (the reader decoded ``.raw``); amplitudes are ``sqrt(intensity)``;
2. **dithers** quantised device counts: an integer ``.raw`` value ``v`` stands for
   anything in ``[v - 1/2, v + 1/2)``, so ``v + U(-1/2, 1/2)`` is decoded instead of
   ``v``. Without it the fitted CDF meets a staircase and KS statistics measure the
   quantisation, not the model (and zero counts would be dropped);
3. optionally **detrends** in range: each range bin is divided by the (pooled, smoothed)
   mean intensity of its row, removing TVG and spreading trends that would otherwise
   look like texture;
4. **pools** every selected cell of every frame, normalises to unit mean square, and
   fits Rayleigh, Weibull, Rayleigh mixture and K (:func:`compare_models`);
5. **flags** fits that sit at a parameter bound or collapse (K at its ``nu`` bounds;
   mixture components equal, empty or EM not converged) and data that are
   sub-Rayleigh (Weibull ``beta > 2``), which K and the Rayleigh mixture cannot express
   (their tails are never lighter than Rayleigh's).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import distributions as D

__all__ = ["RegionFit", "fit_frames", "region_amplitudes", "fit_flags"]


@dataclass(frozen=True)
class RegionFit:
    """Result of :func:`fit_frames`.

    Attributes
    ----------
    fits : list of ModelFit
        One per model (:func:`compare_models`).
    n_samples, n_frames : int
    linearisation : str
        How device values became linear intensity (one line per distinct encoding).
    dithered, detrended : bool
    flags : dict of str -> list of str
        Per model: why its fit is doubtful (empty list: nothing to report).
    weibull_beta : float
    sub_rayleigh : bool
        ``weibull_beta > 2``: lighter-tailed than Rayleigh, outside what K and the
        mixture can express.
    notes : list of str
    """

    fits: list
    n_samples: int
    n_frames: int
    linearisation: str
    dithered: bool
    detrended: bool
    flags: dict = field(default_factory=dict)
    weibull_beta: float = float("nan")
    sub_rayleigh: bool = False
    notes: list = field(default_factory=list)

    @property
    def best(self) -> str:
        """Model with the lowest AIC."""
        return min(self.fits, key=lambda f: f.aic).model


def _region_mask(frame, ranges, azimuths, mask):
    shape = np.shape(frame.image)
    m = np.ones(shape, bool)
    if mask is not None:
        mask = np.asarray(mask, bool)
        if mask.shape != shape:
            raise ValueError(f"mask: expected shape (n_bins, n_beams) = {shape}, got {mask.shape}")
        m &= mask
    if ranges is not None:
        lo, hi = ranges
        r = np.asarray(frame.ranges)
        m &= ((r >= lo) & (r <= hi))[:, None]
    if azimuths is not None:
        lo, hi = azimuths
        a = np.asarray(frame.azimuths)
        m &= ((a >= lo) & (a <= hi))[None, :]
    return m


def _dithered_intensity(frame, rng):
    """Intensity of ``raw + U(-1/2, 1/2)`` through the frame's encoding; None when not quantised."""
    from ..io import units

    raw = getattr(frame, "raw", None)
    enc = getattr(frame, "encoding", None)
    if raw is None or enc not in units.ENCODINGS or np.asarray(raw).dtype.kind not in "ui":
        return None
    raw = np.asarray(raw)
    info = np.iinfo(raw.dtype)
    v = raw.astype(np.float64) + rng.uniform(-0.5, 0.5, raw.shape)
    v = np.clip(v, max(info.min, 0) if enc != "linear" else info.min, info.max + 0.5)
    params = dict(getattr(frame, "meta", {}).get("encoding_params", {}) or {})
    return np.asarray(units.decode(v, enc, **params), np.float64)


def region_amplitudes(frames, *, ranges=None, azimuths=None, mask=None, detrend: bool = False,
                      detrend_window: int = 15, dither: bool = True, seed=0):
    """Pooled, unit-RMS amplitudes of a polar region of several frames (see the module docstring).

    Parameters
    ----------
    frames : sequence of sonar frames (same ``(n_bins, n_beams)`` shape)
    ranges : (float, float), optional
        Range window (m).
    azimuths : (float, float), optional
        Azimuth window (rad, positive to starboard).
    mask : array_like of bool ``(n_bins, n_beams)``, optional
    detrend : bool
        Divide each range bin by its mean intensity (pooled over frames and selected
        beams, smoothed over ``detrend_window`` bins).
    dither : bool
        Dither quantised device counts before linearising.
    seed : int or Generator

    Returns
    -------
    amplitudes : ndarray (N,)
    info : dict
        ``n_frames``, ``linearisation``, ``dithered``, ``detrended``.
    """
    from scipy.ndimage import uniform_filter1d

    from ..io import units

    rng = np.random.default_rng(seed)
    frames = list(frames)
    if not frames:
        raise ValueError("frames: need at least one frame")
    shape = np.shape(frames[0].image)
    stacks, masks, encs, dithered = [], [], set(), False
    for k, f in enumerate(frames):
        if np.shape(f.image) != shape:
            raise ValueError(f"frames: frame {k} is {np.shape(f.image)}, frame 0 is {shape}; pool frames of one shape")
        inten = _dithered_intensity(f, rng) if dither else None
        dithered |= inten is not None
        inten = np.asarray(f.image, np.float64) if inten is None else inten
        stacks.append(inten)
        masks.append(_region_mask(f, ranges, azimuths, mask))
        enc = getattr(f, "encoding", "linear (simulated)")
        params = dict(getattr(f, "meta", {}).get("encoding_params", {}) or {}) if hasattr(f, "meta") else {}
        encs.add(units.describe(enc, **params) if enc in units.ENCODINGS else enc)
    I = np.stack(stacks)
    M = np.stack(masks)
    if not M.any():
        raise ValueError("the region selects no cell (check the range/azimuth window against the frames')")
    if detrend:
        with np.errstate(invalid="ignore"):
            row_mean = np.where(M, I, 0.0).sum(axis=(0, 2)) / M.sum(axis=(0, 2))
        have = np.isfinite(row_mean) & (row_mean > 0)
        smooth = row_mean.copy()
        if have.any():
            idx = np.flatnonzero(have)
            smooth[idx] = uniform_filter1d(row_mean[idx], max(1, int(detrend_window)), mode="nearest")
        I = I / np.where(have, smooth, np.nan)[None, :, None]
    vals = I[M]
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if vals.size < 10:
        raise ValueError(f"the region holds {vals.size} positive cells; need at least 10 to fit")
    amp = np.sqrt(vals)
    return amp / np.sqrt(np.mean(vals)), dict(n_frames=len(frames), linearisation="; ".join(sorted(encs)),
                                              dithered=dithered, detrended=bool(detrend))


def fit_flags(fit, samples=None) -> list[str]:
    """Why one :class:`ModelFit` is doubtful: parameters at a bound, collapsed components."""
    out = []
    d = fit.dist
    if fit.model == "k":
        lo, hi = D._NU_BOUNDS
        if d.nu >= hi * 0.99:
            out.append(f"nu at its upper bound {hi:g}: the fit collapsed to the Rayleigh limit")
        elif d.nu <= lo * 1.01:
            out.append(f"nu at its lower bound {lo:g}")
    elif fit.model == "mixture":
        w, lam = np.asarray(d.weights, float), np.asarray(d.lams, float)
        if np.any(w < 1e-3):
            out.append(f"{int(np.sum(w < 1e-3))} empty component(s) (weight < 1e-3)")
        rel = np.diff(np.sort(lam)) / np.sort(lam)[1:]
        if np.any(rel < 0.02):
            out.append("components collapsed (two lam within 2%): fewer distinct components than fitted")
        if samples is not None:
            mf = D.fit_rayleigh_mixture(samples, len(w))
            if not mf.converged:
                out.append(f"EM not converged ({mf.message})")
    elif fit.model == "weibull" and d.beta > 2:
        out.append(f"beta = {d.beta:.3g} > 2: sub-Rayleigh data")
    return out


def fit_frames(frames, *, ranges=None, azimuths=None, mask=None, detrend: bool = False, detrend_window: int = 15,
               dither: bool = True, seed=0, models=("rayleigh", "weibull", "mixture", "k")) -> RegionFit:
    """Fit the amplitude models to a polar region of frames; see the module docstring."""
    amp, info = region_amplitudes(frames, ranges=ranges, azimuths=azimuths, mask=mask, detrend=detrend,
                                  detrend_window=detrend_window, dither=dither, seed=seed)
    fits = D.compare_models(amp, models=models)
    flags = {f.model: fit_flags(f) for f in fits}
    beta = next((f.dist.beta for f in fits if f.model == "weibull"), float("nan"))
    sub = bool(beta > 2)
    notes = []
    if sub:
        notes.append(f"sub-Rayleigh data (Weibull beta = {beta:.3g} > 2): lighter-tailed than Rayleigh, outside "
                     "what K and the Rayleigh mixture can express (both are at least as heavy-tailed as Rayleigh); "
                     "their fits sit at the Rayleigh limit")
    if not info["dithered"]:
        notes.append("no quantised device counts were dithered (float data, or dithering off)")
    return RegionFit(fits, int(amp.size), info["n_frames"], info["linearisation"], info["dithered"],
                     info["detrended"], flags, float(beta), sub, notes)
