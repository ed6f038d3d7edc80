"""Sonar features: CFAR detections on the polar image, non-maximum suppression, sub-bin refinement.

Works on any sonar frame through the shared protocol (``.image`` linear intensity
``(n_bins, n_beams)``, ``.ranges``, ``.azimuths``, ``.spec``): simulated or measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from .._validate import as_array, as_positive, is_integer

PEAK, ONSET = 0, 1

__all__ = ["PEAK", "ONSET", "SonarFeatures", "CfarOptions", "detect_sonar_features", "cfar_map"]


@dataclass(frozen=True)
class CfarOptions:
    """Cell-averaging CFAR on the polar image.

    Attributes
    ----------
    guard : (int, int)
        Guard cells (bins, beams) each side of the cell under test.
    train : (int, int)
        Training cells (bins, beams) each side beyond the guard cells.
    factor : float
        Detection threshold: smoothed cell > ``factor`` x mean of the training cells. The
        3 x 3 smoothed speckle of a homogeneous seabed (exponential intensity) passes 6x
        its mean with probability about 1e-4.
    nms : (int, int)
        Non-maximum-suppression window (bins, beams): one feature per window.
    max_features : int
        Keep the strongest ones (at least 1).
    onsets, peaks : bool
        Detect echo onsets, local maxima.
    min_run : int
        An onset starts a detection run of at least this many bins (at least 1).

    Raises
    ------
    ValueError
        Naming the field and its value: pairs that are not two integers (``guard`` >= 0,
        ``train`` and ``nms`` >= 1), a ``factor`` that is not finite and > 0, counts below 1.
    """

    guard: tuple = (3, 3)
    train: tuple = (12, 12)
    factor: float = 6.0
    nms: tuple = (9, 9)
    max_features: int = 400
    onsets: bool = True
    peaks: bool = True
    min_run: int = 3

    def __post_init__(self):
        for name, least in (("guard", 0), ("train", 1), ("nms", 1)):
            check_pair(f"CfarOptions.{name}", getattr(self, name), least)
        as_positive(self.factor, "CfarOptions.factor")
        for name in ("max_features", "min_run"):
            check_count(f"CfarOptions.{name}", getattr(self, name), 1)
        for name in ("onsets", "peaks"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"CfarOptions.{name}: expected True or False, got {getattr(self, name)!r}")


def check_count(name: str, value, least: int) -> int:
    """``value`` as an int when it is an integer >= ``least``; else a ValueError naming ``name``."""
    if not is_integer(value) or value < least:
        raise ValueError(f"{name}: expected an integer >= {least}, got {value!r}")
    return int(value)


def check_pair(name: str, value, least: int) -> tuple:
    """``value`` as a pair ``(bins, beams)`` of integers >= ``least``; else a ValueError naming ``name``."""
    if not (isinstance(value, (tuple, list)) and len(value) == 2
            and all(is_integer(v) and v >= least for v in value)):
        raise ValueError(f"{name}: expected a pair (bins, beams) of integers >= {least}, got {value!r}")
    return tuple(int(v) for v in value)


def check_axes(ranges, azimuths, what: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Bin centres and beam centres: 1-D, finite and strictly increasing (else a ValueError naming them)."""
    r = as_array(ranges, f"{what}ranges", (None,))
    th = as_array(azimuths, f"{what}azimuths", (None,))
    for name, a in ((f"{what}ranges", r), (f"{what}azimuths", th)):
        bad = np.nonzero(np.diff(a) <= 0)[0]
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"{name}: must be strictly increasing (near to far, left to right); "
                             f"got {a[i]:g} then {a[i + 1]:g} at index {i + 1}")
    return r, th


@dataclass(frozen=True, eq=False)
class SonarFeatures:
    """Point features of a sonar image, with their measurement uncertainty.

    Attributes
    ----------
    ranges, azimuths : ndarray, shape (N,)
        Sub-bin refined range (m) and azimuth (rad), sonar frame.
    sigma_range, sigma_azimuth : ndarray, shape (N,)
        1-sigma uncertainty (m, rad).
    bins, beams : ndarray of int, shape (N,)
        Cell of the peak (row, column of the polar image).
    snr : ndarray, shape (N,)
        Peak over local CFAR background (linear).
    kind : ndarray of int, shape (N,)
        ``PEAK`` (0): a local maximum of the echo; ``ONSET`` (1): the leading edge of an
        echo in its beam (the nearest surface point in that beam, where range is stationary
        over the surface, so the camera's view of it is range-sharp).
    """

    ranges: np.ndarray
    azimuths: np.ndarray
    sigma_range: np.ndarray
    sigma_azimuth: np.ndarray
    bins: np.ndarray
    beams: np.ndarray
    snr: np.ndarray
    kind: np.ndarray = None

    def __post_init__(self):
        if self.kind is None:
            object.__setattr__(self, "kind", np.zeros(self.ranges.shape, int))

    def __len__(self) -> int:
        return int(self.ranges.size)

    def subset(self, keep) -> "SonarFeatures":
        return SonarFeatures(*(getattr(self, f)[keep] for f in
                               ("ranges", "azimuths", "sigma_range", "sigma_azimuth", "bins", "beams", "snr", "kind")))


def _box_sum(a, half):
    size = (2 * half[0] + 1, 2 * half[1] + 1)
    return ndi.uniform_filter(a, size, mode="nearest") * (size[0] * size[1])


def given_maps(maps, shape: tuple, what: str):
    """``maps`` (a caller's ``cfar_map`` of the image, or None) checked against the image's ``shape``."""
    if maps is None:
        return None
    if not (isinstance(maps, tuple) and len(maps) == 2 and all(np.shape(m) == tuple(shape) for m in maps)):
        got = [np.shape(m) for m in maps] if isinstance(maps, tuple) else type(maps).__name__
        raise ValueError(f"{what}: maps must be cfar_map's (smooth, background), each of the image's shape "
                         f"{tuple(shape)}; got {got}")
    return maps


def cfar_map(image, options: CfarOptions = CfarOptions()) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed image and its CFAR background level, both ``(n_bins, n_beams)``.

    The background of each cell is the mean of its training ring (the box of half size
    ``guard + train`` minus the box of half size ``guard``), via two box filters.
    """
    img = np.asarray(image, np.float64)
    g, w = options.guard, options.train
    outer = (g[0] + w[0], g[1] + w[1])
    n_outer = (2 * outer[0] + 1) * (2 * outer[1] + 1)
    n_inner = (2 * g[0] + 1) * (2 * g[1] + 1)
    background = (_box_sum(img, outer) - _box_sum(img, g)) / (n_outer - n_inner)
    smooth = ndi.uniform_filter(img, 3, mode="nearest")
    return smooth, background


def _parabolic(lm, l0, lp):
    """Vertex offset (cells, in [-0.5, 0.5]) of the parabola through three log samples."""
    d = lm - 2 * l0 + lp
    with np.errstate(invalid="ignore", divide="ignore"):
        off = np.where(d < 0, 0.5 * (lm - lp) / d, 0.0)
    return np.clip(np.nan_to_num(off), -0.5, 0.5)


def detect_sonar_features(image, ranges, azimuths, *, range_resolution: float, beamwidth: float,
                          options: CfarOptions = CfarOptions(), maps=None) -> SonarFeatures:
    """CFAR detections, one per NMS window, refined to sub-bin and sub-beam precision.

    Parameters
    ----------
    image : array_like, shape (n_bins, n_beams)
        Linear intensity, row = range bin (near to far), column = beam (left to right).
    ranges : array_like, shape (n_bins,)
        Bin centres (m).
    azimuths : array_like, shape (n_beams,)
        Beam centres (rad), increasing; need not be evenly spaced.
    range_resolution : float
        The sonar's range resolution (m; 0: not known, the bin spacing stands in).
    beamwidth : float
        The sonar's azimuth beamwidth (rad, -3 dB; 0: not known, the beam spacing stands in).
    options : CfarOptions
    maps : tuple of ndarray, optional
        ``cfar_map(image, options)`` when the caller already has it (the same numbers; computed here
        otherwise).

    Raises
    ------
    ValueError
        Naming the argument: an image of the wrong shape or with NaN or infinity, ranges or
        azimuths that are not finite and strictly increasing, a resolution or beamwidth not >= 0.

    Returns
    -------
    SonarFeatures
        Strongest first. Range sigma: the bin or resolution cell over sqrt(12), shrunk by
        the peak's SNR; azimuth sigma: the beamwidth's Gaussian sigma over sqrt(SNR),
        never below a beam spacing over sqrt(12).
    """
    r, th = check_axes(ranges, azimuths)
    img = as_array(image, "image", finite=False, dtype=np.float64)
    if img.ndim != 2 or img.shape != (r.size, th.size):
        raise ValueError(f"sonar image: expected shape (n_bins, n_beams) = ({r.size}, {th.size}), got {img.shape}")
    if not np.all(np.isfinite(img)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(img))[0])
        raise ValueError(f"image: must be finite, found {img[bad]} at (bin, beam) {bad}")
    # 0: not stated (the bin and the beam spacing bound the sigmas anyway)
    range_resolution = as_positive(range_resolution, "range_resolution", allow_zero=True)
    beamwidth = as_positive(beamwidth, "beamwidth", allow_zero=True)
    if not isinstance(options, CfarOptions):
        raise ValueError(f"options: expected a CfarOptions, got {type(options).__name__}")
    empty = SonarFeatures(*([np.zeros(0)] * 4), np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0, int))
    if img.shape[0] < 3 or img.shape[1] < 3 or not np.any(img > 0):
        return empty
    maps = given_maps(maps, img.shape, "detect_sonar_features")
    smooth, background = cfar_map(img, options) if maps is None else maps
    floor = np.percentile(img[img > 0], 1) if np.any(img > 0) else 0.0
    bg = np.maximum(background, max(floor, 1e-30))
    detected = smooth > options.factor * bg
    dr = float(np.median(np.diff(r))) if r.size > 1 else range_resolution
    da = float(np.median(np.diff(th))) if th.size > 1 else beamwidth
    parts = []
    if options.peaks:
        parts.append(_peaks(img, smooth, bg, detected, r, th, dr, da, range_resolution, beamwidth, options))
    if options.onsets:
        parts.append(_onsets(img, bg, detected, r, th, dr, da, range_resolution, options))
    parts = [p for p in parts if len(p)]
    if not parts:
        return empty
    cat = SonarFeatures(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                          ("ranges", "azimuths", "sigma_range", "sigma_azimuth", "bins", "beams", "snr", "kind")))
    order = np.argsort(-cat.snr, kind="stable")[: options.max_features]
    return cat.subset(order)


def _peaks(img, smooth, bg, detected, r, th, dr, da, range_resolution, beamwidth, options) -> SonarFeatures:
    """Local maxima of the CFAR-detected echo, sub-cell by parabolic fits of the log intensity."""
    peak = detected & (smooth == ndi.maximum_filter(smooth, options.nms, mode="nearest"))
    b, k = np.nonzero(peak)
    snr = smooth[b, k] / bg[b, k]
    L = np.log(np.maximum(smooth, 1e-30))
    bc, kc = np.clip(b, 1, img.shape[0] - 2), np.clip(k, 1, img.shape[1] - 2)
    off_r = _parabolic(L[bc - 1, kc], L[bc, kc], L[bc + 1, kc])
    off_a = _parabolic(L[bc, kc - 1], L[bc, kc], L[bc, kc + 1])
    rr = np.interp(b + off_r, np.arange(r.size), r)
    aa = np.interp(k + off_a, np.arange(th.size), th)
    s_r = np.maximum(max(dr, range_resolution) / np.sqrt(12) / np.sqrt(snr / options.factor), dr / np.sqrt(12))
    s_a = np.maximum(beamwidth / 2.355 / np.sqrt(snr), da / np.sqrt(12))
    return SonarFeatures(rr, aa, s_r, s_a, b, k, snr, np.full(b.shape, PEAK))


def _onsets(img, bg, detected, r, th, dr, da, range_resolution, options) -> SonarFeatures:
    """Leading edges of detected echoes along each beam, sub-bin at the half-peak crossing."""
    n_bins = img.shape[0]
    run = options.min_run
    # A detection run of at least min_run bins starting at b (not detected at b - 1).
    prev = np.vstack([np.zeros((1, img.shape[1]), bool), detected[:-1]])
    start = detected & ~prev
    sustained = ndi.minimum_filter1d(detected.astype(np.uint8), run, axis=0, origin=-(run // 2), mode="constant") > 0
    start &= sustained
    # Strength: the echo just after the edge, over the background; one onset per NMS window.
    beam_smooth = ndi.uniform_filter1d(np.asarray(img, np.float64), 3, axis=1, mode="nearest")
    ahead = ndi.maximum_filter1d(beam_smooth, 2 * run + 1, axis=0, origin=-run, mode="nearest")
    S = np.where(start, ahead / bg, 0.0)
    keep = (S > 0) & (S == ndi.maximum_filter(S, options.nms, mode="constant"))
    b, k = np.nonzero(keep)
    if b.size == 0:
        return SonarFeatures(*([np.zeros(0)] * 4), np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros(0, int))
    snr = S[b, k]
    # Sub-bin: where the beam's profile first reaches half the peak just ahead, by linear interpolation.
    idx = np.clip(b[:, None] + np.arange(-2, 2 * run + 1)[None, :], 0, n_bins - 1)
    prof = beam_smooth[idx, k[:, None]]
    half = 0.5 * ahead[b, k]
    above = prof >= half[:, None]
    j = np.argmax(above, axis=1)
    j = np.clip(j, 1, prof.shape[1] - 1)
    lo, hi = prof[np.arange(b.size), j - 1], prof[np.arange(b.size), j]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.clip(np.where(hi > lo, (half - lo) / (hi - lo), 1.0), 0.0, 1.0)
    # The crossing sits half a bin before the centre of the first bin the surface fills.
    pos = idx[np.arange(b.size), j - 1] + frac + 0.5
    rr = np.interp(pos, np.arange(r.size), r)
    s_r = np.full(b.shape, max(dr, range_resolution) / np.sqrt(12))
    s_a = np.full(b.shape, da / np.sqrt(12))
    return SonarFeatures(rr, th[k], s_r, s_a, b, k, snr, np.full(b.shape, ONSET))
