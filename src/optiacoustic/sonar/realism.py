"""Statistics that say whether a sonar frame looks like a real one (docs/physics.md, "Fitting a sensor profile").

One procedure, applied the same way to measured and simulated frames:

* **range profiles** per group of beams (mean linear intensity), smoothed over a few
  resolution cells;
* **seabed onset**: from the background before the seabed to the plateau (the profile's
  peak), the ranges where the profile crosses 10 % and 90 % of the rise; its width
  ``r90 - r10`` (median over beam groups);
* **plateau end**: beyond the peak, the range where the profile last falls through 50 % of
  the rise (the far edge of the seabed's echo; median over beam groups);
* **background flatness**: the smoothed background profile (ranges before the onset) in
  dB, its largest deviation from its median;
* **speckle**: intensity normalised by its local mean (a box of ``smooth_bins`` x
  ``smooth_beams``) in the seabed region (local mean 10 dB over the background): its
  contrast (std / mean), the K shape ``nu = 2 / (C^2 - 1)`` it implies, its
  autocorrelation along range and across beams and their half-level lengths.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .speckle import autocorrelation, correlation_length

__all__ = ["FrameStatistics", "frame_statistics", "ks_distance", "beam_groups"]


@dataclass(frozen=True, eq=False)
class FrameStatistics:
    """Statistics of one frame (or several frames pooled). Ranges in m, lengths in samples."""

    ranges: np.ndarray
    group_azimuths: np.ndarray
    group_profiles: np.ndarray  # (n_bins, n_groups) mean linear intensity
    profile: np.ndarray  # (n_bins,) mean over groups
    onset_r10: float
    onset_r90: float
    onset_width: float
    plateau_end: float
    background_level: float
    background_flatness_db: float
    background_profile_db: np.ndarray
    background_ranges: np.ndarray
    contrast: float
    k_shape: float
    corr_range: np.ndarray
    corr_beam: np.ndarray
    corr_length_range: float
    corr_length_beam: float
    normalised: np.ndarray = field(repr=False)  # normalised intensities of the speckle region
    region: np.ndarray = field(repr=False)  # bool (n_bins, n_beams)
    # (n_bins, n_groups) mean squared linear intensity over each group's beams and the frames
    group_sq_profiles: np.ndarray | None = field(default=None, repr=False)
    group_beams: np.ndarray | None = field(default=None, repr=False)
    n_images: int = 1

    def summary(self) -> dict:
        return {
            "onset_width_m": _f(self.onset_width),
            "onset_r10_m": _f(self.onset_r10),
            "onset_r90_m": _f(self.onset_r90),
            "plateau_end_m": _f(self.plateau_end),
            "background_flatness_db": _f(self.background_flatness_db),
            "speckle_contrast": _f(self.contrast),
            "k_shape": _f(self.k_shape),
            "corr_length_range_samples": _f(self.corr_length_range),
            "corr_length_beam_samples": _f(self.corr_length_beam),
            "speckle_cells": int(self.region.sum()),
        }


def _f(x) -> float | None:
    return None if x is None or not np.isfinite(x) else float(x)


def beam_groups(n_beams: int, size: int | None = None) -> list[np.ndarray]:
    """Indices of contiguous beam groups (about ``n_beams / 16`` beams each, at least 2)."""
    size = size or max(2, n_beams // 16)
    return [np.arange(i, min(i + size, n_beams)) for i in range(0, n_beams - size + 1, size)]


def _smooth1(x: np.ndarray, w: int, axis: int = 0) -> np.ndarray:
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(x, max(1, int(w)), axis=axis, mode="nearest")


def _onset(profile: np.ndarray, ranges: np.ndarray):
    """``(r10, r90, background, plateau_end)`` of one smoothed profile; NaNs without a rise
    from a background (``plateau_end`` NaN when the profile does not fall back through 50 %
    of the rise before the window's end)."""
    i_peak = int(np.argmax(profile))
    if i_peak < 5:
        return np.nan, np.nan, np.nan, np.nan
    before = profile[:i_peak]
    bg = float(np.percentile(before, 10))
    peak = float(profile[i_peak])
    if peak < 4 * bg:  # less than 6 dB of rise: no onset
        return np.nan, np.nan, bg, np.nan
    half = bg + 0.5 * (peak - bg)
    above = np.flatnonzero(profile[i_peak:] >= half)  # the last one: dips inside the plateau do not end it
    j = i_peak + int(above[-1]) + 1
    if j < profile.size:
        p0, p1 = profile[j - 1], profile[j]
        t = (p0 - half) / (p0 - p1) if p0 != p1 else 0.0
        end = float(ranges[j - 1] + t * (ranges[j] - ranges[j - 1]))
    else:
        end = np.nan
    out = []
    for frac in (0.1, 0.9):
        level = bg + frac * (peak - bg)
        below = np.flatnonzero(before < level)
        if below.size == 0:
            return np.nan, np.nan, bg, np.nan
        i = int(below[-1])
        p0, p1 = profile[i], profile[i + 1]
        t = (level - p0) / (p1 - p0) if p1 != p0 else 0.0
        out.append(ranges[i] + t * (ranges[i + 1] - ranges[i]))
    return out[0], out[1], bg, end


def frame_statistics(images, ranges, azimuths, *, region=None, smooth_bins: int | None = None,
                     smooth_beams: int | None = None, max_lag: int = 12) -> FrameStatistics:
    """Statistics of linear-intensity images ``(n_bins, n_beams)`` (one, or a list pooled).

    ``region`` (bool ``(n_bins, n_beams)``) restricts the speckle statistics to a region.
    """
    from scipy.ndimage import uniform_filter

    imgs = [np.asarray(im, float) for im in (images if isinstance(images, (list, tuple)) else [images])]
    r = np.asarray(ranges, float)
    az = np.asarray(azimuths, float)
    n_bins, n_beams = imgs[0].shape
    groups = beam_groups(n_beams)
    w_r = smooth_bins or max(5, n_bins // 100)
    prof = np.mean([np.stack([im[:, g].mean(1) for g in groups], 1) for im in imgs], axis=0)
    prof_sq = np.mean([np.stack([np.square(im[:, g]).mean(1) for g in groups], 1) for im in imgs], axis=0)
    sm = _smooth1(prof, w_r, 0)
    ons = np.array([_onset(sm[:, k], r) for k in range(len(groups))])
    if np.isfinite(ons[:, 0]).sum() < max(1, len(groups) // 2):  # no seabed onset in most groups
        ons[:] = np.nan
    else:
        ons[~np.isfinite(ons[:, 0])] = np.nan
    r10 = float(np.nanmedian(ons[:, 0])) if np.isfinite(ons[:, 0]).any() else np.nan
    r90 = float(np.nanmedian(ons[:, 1])) if np.isfinite(ons[:, 1]).any() else np.nan
    width = float(np.nanmedian(ons[:, 1] - ons[:, 0])) if np.isfinite(ons[:, 0]).any() else np.nan
    bg = float(np.nanmedian(ons[:, 2])) if np.isfinite(ons[:, 2]).any() else np.nan
    p_end = float(np.nanmedian(ons[:, 3])) if np.isfinite(ons[:, 3]).any() else np.nan
    # background: ranges before the earliest onset of any group, minus a margin
    first = np.nanmin(ons[:, 0]) if np.isfinite(ons[:, 0]).any() else np.nan
    if np.isfinite(first):
        sel = (r < first - 0.05 * (first - r[0])) & (r > r[0] + 0.05 * (first - r[0]))
    else:
        sel = np.zeros(n_bins, bool)
    if sel.sum() >= 10:
        bprof = 10 * np.log10(np.maximum(_smooth1(prof.mean(1), max(3, sel.sum() // 10))[sel], 1e-30))
        flat = float(np.max(np.abs(bprof - np.median(bprof))))
    else:
        bprof, flat = np.zeros(0), np.nan
    # speckle: normalise by the local mean
    w_b = smooth_beams or max(3, n_beams // 24)
    zs, masks, ar, ab = [], [], [], []
    for im in imgs:
        mean = uniform_filter(im, (w_r * 3, w_b), mode="nearest")
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(mean > 0, im / mean, np.nan)
        m = np.isfinite(z)
        if np.isfinite(bg) and bg > 0:
            m &= mean > 10 * bg
        if region is not None:
            m &= np.asarray(region, bool)
        # keep away from the smoothing box's borders
        m[: w_r * 2] = False
        m[-w_r * 2:] = False
        m[:, : w_b // 2 + 1] = False
        m[:, -(w_b // 2 + 1):] = False
        zs.append(z[m])
        masks.append(m)
        ar.append(autocorrelation(np.where(m, z, 0.0), max_lag, 0, mask=m))
        ab.append(autocorrelation(np.where(m, z, 0.0), min(max_lag, n_beams // 4), 1, mask=m))
    zall = np.concatenate(zs) if zs else np.zeros(0)
    if zall.size > 100:
        contrast = float(np.std(zall) / np.mean(zall))
    else:
        contrast = np.nan
    nu = 2.0 / (contrast**2 - 1.0) if np.isfinite(contrast) and contrast > 1 else np.inf
    with np.errstate(invalid="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # no speckle cells: NaN autocorrelations
            cr = np.nanmean(ar, axis=0)
            cb = np.nanmean(ab, axis=0)
    return FrameStatistics(
        ranges=r, group_azimuths=np.array([az[g].mean() for g in groups]), group_profiles=prof,
        profile=prof.mean(1), onset_r10=r10, onset_r90=r90, onset_width=width, plateau_end=p_end, background_level=bg,
        background_flatness_db=flat, background_profile_db=bprof, background_ranges=r[sel],
        contrast=contrast, k_shape=float(nu), corr_range=cr, corr_beam=cb,
        corr_length_range=correlation_length(cr), corr_length_beam=correlation_length(cb),
        normalised=zall, region=np.logical_or.reduce(masks), group_sq_profiles=prof_sq,
        group_beams=np.array([len(g) for g in groups]), n_images=len(imgs),
    )


def ks_distance(a, b, max_samples: int = 200_000, seed: int = 0) -> float:
    """Two-sample Kolmogorov-Smirnov distance between two samples (subsampled when huge)."""
    from scipy.stats import ks_2samp

    rng = np.random.default_rng(seed)
    a = np.asarray(a, float).ravel()
    b = np.asarray(b, float).ravel()
    if a.size > max_samples:
        a = rng.choice(a, max_samples, replace=False)
    if b.size > max_samples:
        b = rng.choice(b, max_samples, replace=False)
    return float(ks_2samp(a, b).statistic)
