"""Automatic opti-acoustic correspondence: sonar features, their arcs in the image, evidence, score.

The default method (``MatchOptions(method="arc")``, :func:`_match_arcs`) chooses the camera
pixel for each sonar feature: its epipolar arc, narrowed to the elevation interval the seabed
and the shadows allow (:mod:`.acoustic`), is searched for the longest edge-free run of pixels
(:mod:`.arc_search`), the surface the echo comes from as the camera sees it. The first design
(``method="corners"``) is kept for comparison; its pipeline (docs/matching.md):

1. features in each image (:mod:`.sonar_features`, :mod:`.camera_features`), each with its
   measurement uncertainty;
2. candidates: camera features within a chi-square gate of a sonar feature's epipolar conic
   (:mod:`.gating`; the distance is symmetric, so it is also the test on the pixel's curve
   in the sonar image), reconstructed by maximum likelihood
   (:func:`optiacoustic.geometry.reconstruct.refine`) and kept only in front of the camera,
   on the sonar's half-plane and inside its elevation aperture;
3. evidence that survives the change of modality (:mod:`.acoustic`): the point must not be
   under the seabed the sonar sees (the seabed would hide it from the camera: no closer
   occluder), and its elevation must agree with what the sonar's seabed and acoustic shadows
   allow (an echo with no shadow behind it is on the seabed; one with a shadow lies below
   the ray grazing the shadow's end); neighbouring matches must agree on a locally smooth
   surface;
4. one global assignment (``scipy.optimize.linear_sum_assignment``) with a "no match" option
   for every sonar feature; each match's score is a calibrated probability of being right
   given its evidence (epipolar chi-square, how many candidates competed, corner strength:
   strong corners sit on silhouettes where depth jumps, elevation interval width, SNR).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field

import numpy as np

from .._validate import as_positive, is_number
from ..frames import sonar_from_spherical, spherical_from_sonar
from ..geometry import epipolar as ep
from ..geometry import reconstruct as rc
from ..rig import Rig
from .acoustic import (SEABED_LIT, SEABED_SHADOWED, SeabedPlane, check_fov_elevation, elevation_maps, fit_seabed,
                       moved_plane, occluded, seabed_elevation, seabed_view)
from .camera_features import CameraFeatures, KeypointOptions, detect_camera_features
from .gating import mahalanobis_sq
from .sonar_features import CfarOptions, SonarFeatures, cfar_map, detect_sonar_features

__all__ = ["MatchNoise", "MatchOptions", "Matches", "match"]


@dataclass(frozen=True)
class MatchNoise:
    """Measurement noise of the features (1 sigma). ``None``: the detectors' own estimates.

    Attributes
    ----------
    sigma_pixel : float, optional
        Camera feature localisation (px).
    sigma_range : float, optional
        Sonar feature range (m).
    sigma_azimuth : float, optional
        Sonar feature azimuth (rad).
    """

    sigma_pixel: float | None = None
    sigma_range: float | None = None
    sigma_azimuth: float | None = None

    def __post_init__(self):
        for name in ("sigma_pixel", "sigma_range", "sigma_azimuth"):
            v = getattr(self, name)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"MatchNoise.{name}: must be a finite number > 0, got {v!r}")


@dataclass(frozen=True)
class MatchOptions:
    """Tuning of :func:`match` (defaults are the ones the ``matching`` experiment reports).

    Attributes
    ----------
    gate : float
        Chi-square (1 dof) gate on the epipolar distance; 9 keeps 99.7% of true pairs.
    null_cost : float
        Cost of leaving a sonar feature unmatched (same units as the chi-square).
    elevation_sigma : float
        Softness (rad) of the elevation interval from the seabed and shadows.
    seabed_clearance : float
        A point more than this (m) under the fitted seabed is rejected.
    occluder_margin : float
        Echoes on the pixel's ray nearer than the point by more than this (m) occlude it.
    occupancy_factor : float
        An echo this many times its CFAR background counts as a possible occluder (lower
        than the detection factor: a weak echo still hides what is behind it).
    corner_weight : float
        Cost per unit of log corner strength (relative to the image's median); the ratio of
        the score model's weights of log corner strength and epipolar chi-square, so the
        assignment weighs them as the calibration found them to predict correctness.
    smoothness : bool
        Second assignment pass with the neighbours' depth agreement in the cost.
    use_acoustic : bool
        Use the seabed and shadow evidence (off: epipolar distance and uniqueness only).
    method : {"arc", "corners"}
        ``"arc"`` (default): each sonar feature searches its own epipolar arc, inside the
        elevation interval of the seabed and shadow evidence, for the middle of the longest
        edge-free run of pixels (:mod:`.arc_search`), or takes the point below that face's
        crease (:mod:`.contact`) or on the face's fitted plane (:mod:`.face_plane`) where that is
        the more probable; ``"corners"``: OpenCV corners gated by
        the epipolar distance and assigned globally (the first design, kept for comparison).
    arc_threshold : float
        Gradient (gray levels per px) below which an arc pixel is edge-free.
    seabed_contrast : float
        Arc pixels whose colour (image stretched to [0, 1]) is within this RGB distance of the
        seabed's just in front of the echo are not taken. Off by default: at 0.03 it raised
        precision on the random training scenes (0.48 to 0.55 at the same recall) but on the
        experiment's scenes it removed most matches of the built-in scenes whose objects share
        the seabed's colour and, in Jerlov 1C-3C water, where all colours converge to the
        water's, recall fell from 0.72 to 0.38.
    face_plane : bool
        Offer each feature the point where its arc meets its face's fitted plane
        (:mod:`.face_plane`) as a third candidate (off: the arc search's pixel or the point below
        the crease only, the previous round's matcher).
    face_plane_beams : bool
        Fit each face's plane to the creases of every beam its features span (:func:`.face_plane.beam_creases`:
        the echo start of each beam, with the top edge where that beam's arc leaves the face's image region),
        not only to the features' own creases.
    seabed_point : bool
        Offer each feature with no acoustic shadow behind its echo the point where its arc meets the
        sonar's own seabed plane (:func:`.acoustic.seabed_points`) as a fifth candidate (round i15k;
        off: the four candidates of round i15j).
    face_plane_min_contrast : float
        The plane is fitted only in images whose contrast (0.5-99.5 percentile range of the mean
        channel over their sum) is at least this: in turbid water the crease between a box's front
        and top faces washes out and the plane follows the top face's far edge. The training
        scenes' images have 0.79-0.86 in thesis water and 0.53 in Jerlov 1C, where the plane cost
        correct matches (302 -> 298 on scenes 5000-5023); 0.65 lies between.
    relief_as_plane_error : bool
        Where the fitted seabed plane's residual says the seabed is not flat (``SeabedReliefWarning``), treat
        the plane as uncertain by the relief the residual implies (``SeabedPlane.relief_sigma``): the seabed
        points are then scored by the chance that relief leaves them right. Off by default: on held-out
        relief scenes it raised precision at recall 0.25 from 0.84 to 0.91 (1 cm RMS) and 0.73 to 0.86
        (2 cm), but the experiment's one scene without a seabed (two walls) warns too, and its right
        "seabed points" on a plane fitted through the walls' onsets fell from 0.99 to 0.27-0.48, taking the
        experiment's precision at recall 0.5 from 0.917 to 0.904 (docs/matching.md, round i15t).
    rank_model : bool
        Let the gradient-boosted trees of :mod:`.ranking` (all the match's evidence at once) choose among the
        offered candidates and score the choice, where the face-plane model is offered on a thesis-beam frame
        whose seabed plane is fitted or given without a declared error (round i15v: held-out precision at
        recall 0.5 0.887 -> 0.904, and on seabeds with 1-2 cm of relief 0.82 -> 0.87 and 0.51 -> 0.63).
        ``features["candidate_source"]`` and ``["candidate_score"]`` keep the candidate models' choice and
        its probability, ``["tree_p_<candidate>"]`` the trees' probabilities.
        Off: the candidate models choose and score, as before.
    soft_beam_recalibration : bool
        On soft-beam frames, map each candidate's probability through :data:`SOFT_BEAM_RECALIBRATION`
        (fitted on the realistic model's frames, where the models fitted on the thesis model's are
        miscalibrated). Off: the thesis-frame probabilities (``calibrate_soft_beam`` fits on those).
    allow_soft_beam : bool
        Match frames whose elevation beam is soft (``sonar.beam_model == "aperture"``: every measured
        frame, and simulated frames of ``SonarOptions(beam_model="aperture")``) although the seabed
        plane is fitted where the seabed crosses a hard-edged aperture. Off (the default), such a
        frame gives a falsy result that says so: on held-out scenes its plane was degrees off and
        5-19% of its matches were right, median scores 0.43-0.94 (docs/matching.md, "Soft elevation
        beams").
    cfar, keypoints : detector options.

    Raises
    ------
    ValueError
        Naming the field and its value: ``gate``, ``null_cost``, ``elevation_sigma``,
        ``occupancy_factor`` and ``arc_threshold`` must be finite and > 0; ``seabed_clearance``,
        ``occluder_margin``, ``corner_weight``, ``seabed_contrast`` and ``face_plane_min_contrast``
        finite and >= 0; the switches True or False.
    """

    gate: float = 9.0
    null_cost: float = 9.0
    elevation_sigma: float = float(np.deg2rad(1.5))
    seabed_clearance: float = 0.10
    occluder_margin: float = 0.5
    occupancy_factor: float = 3.0
    corner_weight: float = 0.46
    smoothness: bool = False
    use_acoustic: bool = True
    method: str = "arc"
    arc_threshold: float = 3.0
    seabed_contrast: float = 0.0
    face_plane: bool = True
    face_plane_min_contrast: float = 0.65
    face_plane_beams: bool = True
    seabed_point: bool = True
    allow_soft_beam: bool = False
    soft_beam_recalibration: bool = True
    rank_model: bool = True
    relief_as_plane_error: bool = False
    cfar: CfarOptions = field(default_factory=CfarOptions)
    keypoints: KeypointOptions = field(default_factory=KeypointOptions)

    def __post_init__(self):
        if self.method not in ("arc", "corners"):
            raise ValueError(f"MatchOptions.method: expected 'arc' or 'corners', got {self.method!r}")
        for name in ("gate", "null_cost", "elevation_sigma", "occupancy_factor", "arc_threshold"):
            as_positive(getattr(self, name), f"MatchOptions.{name}")
        for name in ("seabed_clearance", "occluder_margin", "corner_weight", "seabed_contrast",
                     "face_plane_min_contrast"):
            as_positive(getattr(self, name), f"MatchOptions.{name}", allow_zero=True)
        for name in ("smoothness", "use_acoustic", "face_plane", "face_plane_beams", "seabed_point", "allow_soft_beam",
                     "soft_beam_recalibration", "rank_model", "relief_as_plane_error"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"MatchOptions.{name}: expected True or False, got {getattr(self, name)!r}")
        if not isinstance(self.cfar, CfarOptions):
            raise ValueError(f"MatchOptions.cfar: expected a CfarOptions, got {type(self.cfar).__name__}")
        if not isinstance(self.keypoints, KeypointOptions):
            raise ValueError(f"MatchOptions.keypoints: expected a KeypointOptions, got {type(self.keypoints).__name__}")


@dataclass(frozen=True, eq=False)
class Matches:
    """Opti-acoustic matches, best first. Falsy (with ``message``) when there are none.

    Attributes
    ----------
    pixels : ndarray, shape (N, 2)
        Camera feature pixels ``(u, v)``.
    ranges, azimuths : ndarray, shape (N,)
        Sonar feature range (m) and azimuth (rad).
    points : ndarray, shape (N, 3)
        Maximum-likelihood reconstruction, camera frame (m); where it failed, the point at the match's
        elevation, and NaN where the match has none (a corner of a two-view result).
    score : ndarray, shape (N,)
        In (0, 1): the probability that the match is correct given its evidence, calibrated on
        simulated scenes: the chosen candidate's logistic model (:data:`SCORE_MODEL` for the corners),
        or, in clear water on thesis-beam frames, the gradient-boosted trees of :mod:`.ranking`, which
        also choose the candidate (``MatchOptions.rank_model``).
    cost : ndarray, shape (N,)
        Total cost (epipolar chi-square + evidence terms).
    sonar_index, camera_index : ndarray of int, shape (N,)
        Rows of ``sonar_features`` and ``camera_features``.
    sonar_features : SonarFeatures
    camera_features : CameraFeatures
    seabed : SeabedPlane or None
    message : str
    features : dict of str -> ndarray (N,)
        Per-match evidence behind the score (candidates of the sonar feature, elevation
        interval width, ...), for diagnostics.
    """

    pixels: np.ndarray
    ranges: np.ndarray
    azimuths: np.ndarray
    points: np.ndarray
    score: np.ndarray
    cost: np.ndarray
    sonar_index: np.ndarray
    camera_index: np.ndarray
    sonar_features: SonarFeatures | None = None
    camera_features: CameraFeatures | None = None
    seabed: SeabedPlane | None = None
    message: str = ""
    features: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.score.size)

    def __bool__(self) -> bool:
        return self.score.size > 0

    def select(self, keep) -> "Matches":
        """The matches where ``keep`` (bool mask or indices) holds."""
        k = np.asarray(keep)
        arrays = [getattr(self, f)[k] for f in ("pixels", "ranges", "azimuths", "points", "score", "cost",
                                                "sonar_index", "camera_index")]
        n = int(arrays[-1].size)
        msg = self.message if n else "no match above the score threshold"
        feats = {key: np.asarray(v)[k] for key, v in self.features.items()}
        return Matches(*arrays, self.sonar_features, self.camera_features, self.seabed, msg, feats)

    def above(self, min_score: float) -> "Matches":
        """The matches with ``score >= min_score``."""
        return self.select(self.score >= min_score)


def _empty(message, sf=None, cf=None, seabed=None) -> Matches:
    z = np.zeros(0)
    zi = np.zeros(0, int)
    return Matches(np.zeros((0, 2)), z, z, np.zeros((0, 3)), z, z, zi, zi, sf, cf, seabed, message)


class SeabedReliefWarning(UserWarning):
    """The sonar's seabed onsets depart from one plane by more than a flat seabed's: relief, objects at the
    near edge, or no seabed. The matcher's seabed is one plane and its scores were calibrated on flat
    seabeds: on seabeds with relief its precision falls and its scores run high (docs/matching.md,
    "Seabed relief")."""


#: The fitted seabed plane's residual, as a multiple of a flat seabed's (``SeabedPlane.relief_ratio``), above
#: which :func:`match` warns (:class:`SeabedReliefWarning`): 52 seeded flat scenes gave 0.9-1.2; 1 cm RMS of
#: relief 1.6-3.7, where precision at recall 0.5 fell from 0.93 to 0.82 (2 cm: 1.9-6.8 and 0.51).
RELIEF_RATIO_WARN = 1.5


#: Soft-beam frames: echoes with no shadow behind them where the seabed lies more than this (rad) below
#: the aperture's lower edge are the sidelobes' seabed returns, left out (0.5 and 2 deg gave the same
#: matches on held-out scenes 6000-6011 and 9000-9005).
SIDELOBE_MARGIN = float(np.deg2rad(0.5))


def _check_sonar(sonar):
    for attr in ("image", "ranges", "azimuths", "spec"):
        if not hasattr(sonar, attr):
            raise ValueError(f"sonar: expected a sonar frame with .image, .ranges, .azimuths and .spec; "
                             f"{type(sonar).__name__} has no .{attr}")
    img = np.asarray(sonar.image, float)
    r, th = np.asarray(sonar.ranges, float), np.asarray(sonar.azimuths, float)
    if img.shape != (r.size, th.size):
        raise ValueError(f"sonar.image: expected shape (n_bins, n_beams) = ({r.size}, {th.size}), got {img.shape}")
    if not np.all(np.isfinite(img)):
        raise ValueError("sonar.image: contains NaN or infinite values")
    if r.size < 3 or th.size < 3:
        raise ValueError(f"sonar.image: expected at least 3 bins and 3 beams, got {img.shape}")
    if np.any(np.diff(r) <= 0) or np.any(np.diff(th) <= 0):
        raise ValueError("sonar.ranges and sonar.azimuths: must be strictly increasing")
    return img, r, th


def _azimuth_span(th) -> float:
    """The fan's width (rad) its beam centres imply: their span plus one beam spacing."""
    return float(th[-1] - th[0] + np.median(np.diff(th)))


def _angle(spec, name: str, limit: float, what: str):
    """``spec.<name>`` as a finite angle (rad) in (0, limit] (``fov_elevation``: in (0, pi)), None when the spec does not state it; a ValueError
    naming ``what.<name>`` otherwise (with a hint when it looks like degrees)."""
    v = getattr(spec, name, None)
    if v is None:
        return None
    if name == "fov_elevation":
        return check_fov_elevation(v, f"{what}.fov_elevation")
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"{what}.{name}: expected an angle in radians, got {v!r}") from None
    if not (np.isfinite(x) and 0 < x <= limit):
        hint = f" (degrees? np.deg2rad({x:g}) = {np.deg2rad(x):.4g} rad)" if np.isfinite(x) and x > limit else ""
        raise ValueError(f"{what}.{name}: expected an angle in radians, finite and in (0, {limit:.4g}], "
                         f"got {x!r}{hint}")
    return x


class _FrameSpec:
    """A frame's spec that states no ``fov_azimuth``, with the one its beams imply (everything else delegated)."""

    def __init__(self, spec, fov_azimuth: float):
        self._spec, self.fov_azimuth = spec, fov_azimuth

    def __getattr__(self, name):
        return getattr(self._spec, name)


def _frame_spec(spec, th):
    """The frame's spec to attach to a rig that carries no sonar: its ``fov_elevation`` in (0, pi) and its
    ``fov_azimuth`` (the beams' span when it states none) checked, naming the field."""
    if getattr(spec, "fov_elevation", None) is None:
        raise ValueError("sonar.spec: has no fov_elevation and the rig carries no sonar; "
                         "attach one with rig.with_sonar(spec)")
    _angle(spec, "fov_elevation", np.pi, "sonar.spec")
    fov_az = _angle(spec, "fov_azimuth", 2 * np.pi, "sonar.spec")
    if fov_az is None:
        return _FrameSpec(spec, _azimuth_span(th))
    return spec


def _unverified(spec, name: str) -> bool:
    return any(str(u).split(" ")[0] == name for u in (getattr(spec, "unverified", None) or ()))


def _check_rig_sonar(rig_sonar, spec, r, th):
    """The rig's sonar (which the geometry uses) against the frame: their elevation apertures must agree where
    both state it (not when the frame's spec marks it ``unverified``: real logs do not record it), and the frame's
    beams must lie inside the rig's fan. A ValueError naming ``rig.sonar`` and ``sonar.spec`` and both values
    otherwise. The range window and a wider azimuth fan may differ (a log recorded at a shorter range than the
    rig's preset, a dual-frequency head): the frame's own ranges and azimuths are the measurements."""
    el = _angle(rig_sonar, "fov_elevation", np.pi, "rig.sonar")
    az = _angle(rig_sonar, "fov_azimuth", 2 * np.pi, "rig.sonar")
    fix = ("; the rig's sonar is the one used: attach the frame's (rig.with_sonar(sonar.spec)) if it is right, "
           "or correct the frame's spec")
    theirs = getattr(spec, "fov_elevation", None) if spec is not None else None
    if el is not None and theirs is not None and not _unverified(spec, "fov_elevation"):
        theirs = _angle(spec, "fov_elevation", np.pi, "sonar.spec")
        if abs(theirs - el) > 1e-3 * max(abs(el), 1e-9):
            raise ValueError(f"rig.sonar.fov_elevation = {el:.6g} rad ({np.rad2deg(el):.4g} deg) and "
                             f"sonar.spec.fov_elevation = {theirs:.6g} rad ({np.rad2deg(theirs):.4g} deg) disagree{fix}")
    if az is not None:
        beyond = np.abs(th) > az / 2 + np.median(np.diff(th))
        if np.any(beyond):
            a = float(th[beyond][0])
            raise ValueError(f"sonar.azimuths: beam {a:.4g} rad ({np.rad2deg(a):.4g} deg) lies outside "
                             f"rig.sonar.fov_azimuth = {az:.4g} rad ({np.rad2deg(az):.4g} deg){fix}")


def _camera_sees_fan(rig: Rig, r, th) -> bool:
    """Whether any part of the fan (a coarse grid of arcs) projects into the image."""
    rr = np.linspace(r.min(), r.max(), 7)
    tt = np.linspace(th.min(), th.max(), 9)
    R, T = np.meshgrid(rr, tt, indexing="ij")
    curves = ep.sonar_to_optical_curves(rig, R.ravel(), T.ravel(), n_samples=25)
    return any(len(c) for c in curves)


#: Logistic model of P(match correct | evidence): intercept and weights of the standardised
#: features (epipolar chi-square, log candidates of the sonar feature, log corner strength
#: relative to the image's median, elevation interval width in degrees, onset or peak, log
#: SNR). Fitted by ``experiments.matching.calibrate_score`` on random scenes seeded
#: 5000-5023 (thesis water, default sonar noise), disjoint from every scene the experiment
#: and the tests evaluate on.
SCORE_MODEL = dict(
    weights=(-1.143, -0.876, -0.279, -0.439, 0.217, -0.137, 0.046),
    mean=(0.3097, 2.6044, 0.3779, 5.9196, 0.4632, 2.8958),
    std=(0.9129, 0.9114, 0.9869, 3.0306, 0.4986, 0.6208),
)


def score_features(feats: dict) -> np.ndarray:
    """The score model's inputs ``(N, 6)`` from a :attr:`Matches.features` mapping."""
    return np.column_stack([feats["epipolar_chi2"], np.log(np.maximum(feats["n_candidates"], 1)),
                            np.log(np.maximum(feats["corner_relative"], 1e-6)), np.rad2deg(feats["elevation_span"]),
                            feats["kind"], np.log(np.maximum(feats["snr"], 1e-6))])


def calibrated_score(feats: dict, model: dict = SCORE_MODEL) -> np.ndarray:
    """P(correct) of each match from its evidence (logistic model), shape (N,)."""
    X = score_features(feats)
    w = np.asarray(model["weights"], float)
    z = w[0] + ((X - np.asarray(model["mean"])) / np.asarray(model["std"])) @ w[1:]
    return 1.0 / (1.0 + np.exp(-z))


def _posterior(cost, rows, cols, shape, null_cost):
    """Each pair's share of ``exp(-cost/2)`` among its row's and its column's candidates (and "none")."""
    w = np.exp(-0.5 * (cost - null_cost))  # relative to the null option, which weighs 1
    row_sum = np.bincount(rows, w, minlength=shape[0]) + 1.0
    col_sum = np.bincount(cols, w, minlength=shape[1]) + 1.0
    return np.minimum(w / row_sum[rows], w / col_sum[cols])


def _assign(cost, rows, cols, n_rows, null_cost):
    """Global assignment with a "no match" column per row; returns the chosen pair indices."""
    from scipy.optimize import linear_sum_assignment

    ucols, cinv = np.unique(cols, return_inverse=True)
    big = 1e6
    M = np.full((n_rows, ucols.size + n_rows), big)
    M[rows, cinv] = cost
    M[np.arange(n_rows), ucols.size + np.arange(n_rows)] = null_cost
    ri, ci = linear_sum_assignment(M)
    real = ci < ucols.size
    ri, ci = ri[real], ci[real]
    # Map back to pair indices.
    key = {(int(a), int(b)): k for k, (a, b) in enumerate(zip(rows, cinv))}
    chosen = np.array([key[(int(a), int(b))] for a, b in zip(ri, ci) if (int(a), int(b)) in key], int)
    return chosen[M[ri, ci][: chosen.size] < big] if chosen.size else chosen


#: Logistic model of P(correct) of a match given two views with known motion: intercept and
#: weights of the standardised :func:`two_view_score_features` (logit of the one-view score, log
#: of 1 + the optical flow's epipolar residual in px, log of 1 + that residual in metres of depth,
#: log of the motion's sensitivity in px per metre of depth, no residual available, consistent
#: with the second pair's own matches). Fitted by
#: ``experiments.matching.calibrate_two_view_score()`` on random scenes seeded 5000-5023, plain
#: and textured, each with the random vehicle motion of its seed
#: (``experiments.matching.vehicle_motion``), disjoint from the evaluation's scenes (1029 arc
#: matches, 67% correct), refitted in round i15v on the one-view scores of the candidate trees (:mod:`.ranking`):
#: with the older constants two views fell below one view (0.911 against 0.950 at recall 0.5 on the
#: experiment's scenes), refitted they are level (0.947; held-out random 6000-6023 0.924 against 0.926;
#: docs/matching.md, round i15v). Refitted again in round i15w on the trees fitted on five times the scenes
#: (held-out random 6000-6023: two views 0.963 against one view's 0.970; textured 6000-6015 0.755 against
#: 0.663). Refitted in round i15x on the trees of 255 leaves (held-out random 6000-6023: two views 0.957 against
#: one view's 0.969). Not applied to the seabed point (it keeps its one-view score).
TWO_VIEW_SCORE_MODEL = dict(
    weights=(1.476, 2.589, -0.29, 0.049, 0.305, 0.033, 0.098, -0.074, 0.571, -0.763),
    mean=(0.8909, 1.0933, 0.5103, 1.4777, 0.0622, 0.5714, 1.7343, 0.7813, 1.7008),
    std=(2.4702, 1.043, 0.6921, 0.9532, 0.2415, 0.4949, 1.2573, 1.5081, 2.39),
)


def two_view_score_features(feats: dict) -> np.ndarray:
    """The two-view score model's inputs ``(N, 6)`` from a :attr:`Matches.features` mapping."""
    p = np.clip(feats["single_view_score"], 1e-6, 1 - 1e-6)
    a = np.asarray(feats["flow_residual_px"], float)
    sens = np.asarray(feats["flow_px_per_m"], float)
    missing = ~np.isfinite(a) | ~np.isfinite(sens) | (np.nan_to_num(sens) <= 0)
    a_px = np.where(missing, 0.0, np.abs(np.nan_to_num(a)))
    a_m = np.where(missing, 0.0, a_px / np.where(missing, 1.0, sens))
    log_sens = np.where(missing, 0.0, np.log(np.where(missing, 1.0, sens)))
    cols = [np.log(p / (1 - p)), np.log1p(a_px), np.log1p(a_m), log_sens, missing.astype(float),
            np.asarray(feats["two_view"], float)]
    # The flow is only as good as the texture it follows: on a uniform face its residual is noise.
    tex = np.log(np.maximum(np.nan_to_num(np.asarray(feats["arc_texture"], float)), 0.25))
    cols += [tex, np.log1p(a_m) * tex, np.log1p(a_px) * tex]
    return np.column_stack(cols)


#: Logistic model of P(correct) of the sweep's choice (:func:`.optical_two_view.sweep_arcs`):
#: intercept and weights of the standardised :func:`sweep_score_features` (log of 1 + the
#: forward-backward flow error, log of the number of crossings, log of 1 + the residual's slope,
#: log sensitivity, log of 1 + the distance to the arc search's pixel and no arc pixel, log SNR,
#: onset or peak). Fitted by ``experiments.matching.calibrate_two_view_score()`` (see
#: :data:`TWO_VIEW_SCORE_MODEL`; 599 sweep choices, 54% correct).
SWEEP_SCORE_MODEL = dict(
    weights=(0.17, -0.697, 0.332, -0.088, 0.573, -0.65, -0.658, -0.004, -0.021),
    mean=(0.502, 0.9535, 1.06, 1.5982, 3.0216, 0.0117, 2.8814, 0.4474),
    std=(0.6587, 0.7588, 0.649, 0.8405, 1.0402, 0.1075, 0.5976, 0.4972),
)


def sweep_score_features(feats: dict) -> np.ndarray:
    """The sweep score model's inputs ``(N, 8)`` from the sweep candidates' evidence."""
    dist = np.asarray(feats["distance_to_arc_px"], float)
    no_arc = ~np.isfinite(dist)
    return np.column_stack([np.log1p(np.minimum(feats["fb_error"], 100.0)), np.log(np.maximum(feats["n_crossings"], 1)),
                            np.log1p(feats["slope"]), np.log(np.maximum(feats["px_per_m"], 1e-3)),
                            np.log1p(np.where(no_arc, 0.0, dist)), no_arc.astype(float),
                            np.log(np.maximum(feats["snr"], 1e-6)), np.asarray(feats["kind"], float)])


#: Logistic model of P(correct) of the photo-consistency sweep's choice
#: (:func:`.optical_two_view.correlate_arcs`): intercept and weights of the standardised
#: :func:`correlation_score_features` (peak correlation, its margin over the best correlation
#: 0.5 deg away, log patch texture, log sensitivity, log of 1 + the distance to the arc search's
#: pixel and no arc pixel, log SNR, onset or peak). Fitted by
#: ``experiments.matching.calibrate_two_view_score()`` (see :data:`TWO_VIEW_SCORE_MODEL`; 1020
#: correlation peaks, 27% correct).
CORRELATION_SCORE_MODEL = dict(
    weights=(-1.365, 0.297, -0.974, 0.274, 0.135, -0.911, -0.931, 0.035, 0.073),
    mean=(0.9128, 0.345, 2.6858, 1.5053, 2.7598, 0.0657, 2.8567, 0.4784),
    std=(0.2013, 0.6665, 0.8448, 0.9116, 1.3085, 0.2477, 0.6175, 0.4995),
)


def correlation_score_features(feats: dict) -> np.ndarray:
    """The correlation score model's inputs ``(N, 8)`` from the correlation candidates' evidence."""
    dist = np.asarray(feats["distance_to_arc_px"], float)
    no_arc = ~np.isfinite(dist)
    return np.column_stack([feats["ncc"], feats["margin"], np.log(np.maximum(feats["texture"], 1e-3)),
                            np.log(np.maximum(feats["px_per_m"], 1e-3)), np.log1p(np.where(no_arc, 0.0, dist)),
                            no_arc.astype(float), np.log(np.maximum(feats["snr"], 1e-6)),
                            np.asarray(feats["kind"], float)])


def two_view_candidates(out: Matches, sf, intervals, image_1, second, motion, rig, noise,
                        opt, *, seabed: SeabedPlane | None = None) -> tuple[dict, dict, dict]:
    """Both kinds of two-view candidates with their evidence (for :func:`_two_view` and the calibration).

    Returns
    -------
    arc : dict
        View 1's arc-search matches (``out``) with ``flow_residual_px``, ``flow_px_per_m``,
        ``two_view`` (consistent with the second pair's matches), ``single_view_score``.
    sweep : dict
        For every sonar feature of view 1: ``pixels`` ``(N, 2)``, ``elevations``, ``found`` and
        the :class:`.optical_two_view.ArcSweep` evidence, plus ``distance_to_arc_px``, ``snr``,
        ``kind``.
    correlation : dict
        The same for :func:`.optical_two_view.correlate_arcs` (``ncc``, ``margin``, ``texture``,
        ``px_per_m``).

    ``seabed``: view 1's seabed plane when the caller gave it (not fitted); the second pair is then
    matched with it moved by ``motion`` (:func:`.acoustic.moved_plane`).
    """
    from .optical_two_view import (correlate_arcs, epipolar_residuals, flow_field, forward_backward_error,
                                   photo_consistency, sweep_arcs)
    from .two_view import consistent, motion_arrays

    if motion is None:
        raise ValueError("motion: required with 'second' (P_camera2 = R_o P_camera1 + t_o)")
    motion_arrays(motion)  # validates
    if not (isinstance(second, (tuple, list)) and len(second) == 2):
        raise ValueError("second: expected (sonar, camera_image) of the second view")
    image_2 = np.asarray(second[1])
    if image_2.shape != np.asarray(image_1).shape:
        raise ValueError(f"second camera_image: expected shape {np.asarray(image_1).shape} like the first, "
                         f"got {image_2.shape}")
    seabed_2 = None if seabed is None else moved_plane(rig, seabed, *motion_arrays(motion))
    try:
        m2 = match(second[0], image_2, rig, noise=noise, options=opt, min_score=0.0, seabed=seabed_2)
    except ValueError as exc:
        raise ValueError(f"second view (second[0], the second pair's sonar frame): {exc}") from None
    n = len(out)
    flow = flow_field(image_1, image_2)
    back = flow_field(image_2, image_1) if flow is not None else None
    arc = dict(out.features) if n else {}
    arc.update(two_view=consistent(out.points, m2.points, motion) if (n and m2) else np.zeros(n, bool),
               single_view_score=out.score, n_second=len(m2))
    if flow is None:
        arc["flow_residual_px"] = arc["flow_px_per_m"] = np.full(n, np.nan)
        nan = np.full(len(sf), np.nan)
        sweep = dict(pixels=np.full((len(sf), 2), np.nan), elevations=nan, found=np.zeros(len(sf), bool),
                     n_crossings=nan, fb_error=nan, slope=nan, px_per_m=nan)
    else:
        arc["flow_residual_px"], arc["flow_px_per_m"] = epipolar_residuals(rig.camera, out.pixels, out.points, flow,
                                                                           motion)
        lo, hi = intervals[0], intervals[1]
        sw = sweep_arcs(rig, sf.ranges, sf.azimuths, lo, hi, flow, forward_backward_error(flow, back), motion)
        sweep = {k: getattr(sw, k) for k in ("pixels", "elevations", "found", "n_crossings", "fb_error", "slope",
                                             "px_per_m")}
    # Image 1's texture at the arc pixel (gray sigma of its 9 x 9 patch): what the flow there can follow.
    arc["arc_texture"] = photo_consistency(image_1, image_2, out.pixels, out.pixels)[1] if n else np.zeros(0)
    lo, hi = intervals[0], intervals[1]
    co = correlate_arcs(rig, sf.ranges, sf.azimuths, lo, hi, image_1, image_2, motion)
    corr = {k: getattr(co, k) for k in ("pixels", "elevations", "found", "ncc", "margin", "texture", "px_per_m")}
    for cand in (sweep, corr):
        dist = np.full(len(sf), np.nan)
        if n:
            dist[out.sonar_index] = np.linalg.norm(cand["pixels"][out.sonar_index] - out.pixels, axis=-1)
        cand.update(distance_to_arc_px=dist, snr=sf.snr, kind=sf.kind)
    return arc, sweep, corr


def _two_view(out: Matches, sf, intervals, image_1, second, motion, rig, noise, opt, seabed=None) -> Matches:
    """Matches from two views of the moved rig (known motion, thesis ch. 6).

    Every sonar feature has up to two candidate pixels: the arc search's (one view), re-scored
    with the second view (:data:`TWO_VIEW_SCORE_MODEL`: does its pixel move in the second
    image as the motion moves its point, is its point also reconstructed by the second pair),
    and the sweep's (:func:`.optical_two_view.sweep_arcs`: the pixel of its arc that moves as
    the motion says, scored by :data:`SWEEP_SCORE_MODEL`). The more probable one is kept.
    """
    arc, sweep, corr = two_view_candidates(out, sf, intervals, image_1, second, motion, rig, noise, opt, seabed=seabed)
    N = len(sf)
    p_arc = np.full(N, -1.0)
    if len(out):
        p_arc[out.sonar_index] = _logistic(two_view_score_features(arc), TWO_VIEW_SCORE_MODEL)
        # The seabed point (face_source 4) keeps its one-view score: it is placed by the sonar's own
        # seabed plane, not by the camera's edge-free run, and TWO_VIEW_SCORE_MODEL was fitted before it
        # existed (it pulled calibrated seabed points from 0.7-0.8 to 0.45; docs/matching.md, round i15m).
        seabed_pt = np.asarray(arc.get("face_source", np.full(len(out), -1))) == CANDIDATES.index("seabed")
        p_arc[out.sonar_index[seabed_pt]] = out.score[seabed_pt]
    p_cand = []
    for cand, featurise, model in ((sweep, sweep_score_features, SWEEP_SCORE_MODEL),
                                   (corr, correlation_score_features, CORRELATION_SCORE_MODEL)):
        found = np.asarray(cand["found"], bool)
        p = np.full(N, -1.0)
        if found.any():
            p[found] = _logistic(featurise({k: np.asarray(v)[found] for k, v in cand.items() if k != "pixels"}),
                                 model)
        p_cand.append(p)
    # The correlation's pixel stands in for the sweep's where it is the more probable of the two.
    use_corr = p_cand[1] > p_cand[0]
    sweep = {k: (np.where(use_corr[:, None] if np.ndim(v) == 2 else use_corr, corr[k], v)
                 if k in ("pixels", "elevations", "px_per_m", "distance_to_arc_px") else v) for k, v in sweep.items()}
    p_sweep = np.maximum(p_cand[0], p_cand[1])
    use_sweep = p_sweep > p_arc
    rows = np.nonzero(np.maximum(p_arc, p_sweep) >= 0)[0]
    if rows.size == 0:
        return _empty("no match in either view: no arc search choice and no arc pixel whose flow agrees with the "
                      "motion", sf, out.camera_features, out.seabed)
    arc_pos = np.full(N, -1)
    arc_pos[out.sonar_index] = np.arange(len(out))
    px = np.where(use_sweep[rows, None], sweep["pixels"][rows],
                  out.pixels[np.maximum(arc_pos[rows], 0)] if len(out) else np.nan)
    s_px = noise.sigma_pixel or 0.5
    s_r = noise.sigma_range or float(np.median(sf.sigma_range[rows]))
    s_a = noise.sigma_azimuth or float(np.median(sf.sigma_azimuth[rows]))
    ref = rc.refine(rig, px, sf.ranges[rows], sf.azimuths[rows], sigma_pixel=float(s_px), sigma_range=float(s_r),
                    sigma_azimuth=float(s_a), max_iter=10)
    from ..geometry.projection import camera_from_sonar

    phi_arc = np.asarray(out.features.get("elevation", np.full(len(out), np.nan)), float)
    phi = np.where(use_sweep[rows], sweep["elevations"][rows], phi_arc[np.maximum(arc_pos[rows], 0)] if len(out)
                   else np.nan)
    # where the reconstruction failed, the point at the candidate's elevation; NaN where it has none
    P = np.where(ref.valid[:, None], ref.points, np.nan)
    at = ~ref.valid & np.isfinite(phi)
    if at.any():
        P[at] = camera_from_sonar(rig, sf.ranges[rows][at], sf.azimuths[rows][at], phi[at])
    score = np.maximum(p_arc, p_sweep)[rows]
    k_arc = np.maximum(arc_pos[rows], 0)

    def from_arc(key):
        v = np.asarray(arc[key], float) if len(out) else np.zeros(0)
        return np.where(arc_pos[rows] >= 0, v[k_arc] if v.size else np.nan, np.nan)

    feats = dict(source=np.where(use_sweep[rows], np.where(use_corr[rows], 2, 1), 0),
                 single_view_score=from_arc("single_view_score"),
                 arc_two_view_score=np.where(p_arc[rows] >= 0, p_arc[rows], np.nan),
                 sweep_score=np.where(p_cand[0][rows] >= 0, p_cand[0][rows], np.nan),
                 correlation_score=np.where(p_cand[1][rows] >= 0, p_cand[1][rows], np.nan),
                 correlation_ncc=np.asarray(corr["ncc"], float)[rows],
                 flow_residual_px=from_arc("flow_residual_px"), flow_px_per_m=from_arc("flow_px_per_m"),
                 two_view=from_arc("two_view"), elevation=phi,
                 **{f"sweep_{k}": np.asarray(sweep[k], float)[rows] for k in ("n_crossings", "fb_error", "slope",
                                                                               "px_per_m", "distance_to_arc_px")})
    order = np.argsort(-score, kind="stable")
    cam_idx = np.where(use_sweep[rows], -1, arc_pos[rows])
    n_sw = int(np.sum(use_sweep[rows] & ~use_corr[rows]))
    n_co = int(np.sum(use_sweep[rows] & use_corr[rows]))
    msg = (f"{rows.size} matches from two views (second view, known motion): {rows.size - n_sw - n_co} arc-search "
           f"choices re-scored, {n_sw} arc pixels whose optical flow agrees with the motion, {n_co} whose patch "
           f"matches its moved point's; {arc.get('n_second', 0)} matches in the second pair")
    feats = {k: np.asarray(v)[order] for k, v in feats.items()}
    return Matches(px[order], sf.ranges[rows[order]], sf.azimuths[rows[order]], P[order], score[order],
                   -np.log(np.maximum(score[order], 1e-12)), rows[order], cam_idx[order], sf, out.camera_features,
                   out.seabed, msg, feats)


def match(sonar, camera_image, rig: Rig, *, noise: MatchNoise | None = None, options: MatchOptions | None = None,
          min_score: float = 0.25, second=None, motion=None, seabed: SeabedPlane | None = None) -> Matches:
    """Match sonar features to camera pixels of one synchronised pair.

    Parameters
    ----------
    sonar : sonar frame
        Simulated or measured: only ``.image`` (linear ``(n_bins, n_beams)``), ``.ranges``,
        ``.azimuths`` and ``.spec`` (``fov_elevation``, ``range_resolution``,
        ``beamwidth_azimuth``) are used.
    camera_image : array_like, shape (H, W, 3)
        The camera image (linear radiance or 8-bit), of ``rig.camera``'s size.
    rig : Rig
        The calibrated rig; when it carries no sonar, ``sonar.spec`` is attached.
    noise : MatchNoise, optional
        Feature noise; default the detectors' estimates.
    options : MatchOptions, optional
    min_score : float
        Only matches with at least this score are returned (0 returns the whole assignment,
        for precision-recall curves). The score is a calibrated probability of being
        correct (:data:`SCORE_MODEL`).
    second : (sonar, camera_image), optional
        A second pair of the same rig after it moved by ``motion``. View 1's matches are
        re-scored (:data:`TWO_VIEW_SCORE_MODEL`) with two pieces of evidence: where each
        match's pixel went in the second camera image (dense optical flow) against where the
        motion takes its 3D point (``features["flow_residual_px"]``, along the epipolar
        direction, and ``features["flow_px_per_m"]``, px per metre of depth), and whether the
        point is also reconstructed by the second pair's own matches
        (:func:`.two_view.consistent`, ``features["two_view"]``). The one-view score is kept in
        ``features["single_view_score"]``; ``min_score`` applies to the two-view score.
    motion : MotionResult, Pose or (R_o, t_o), optional
        ``P_camera2 = R_o P_camera1 + t_o``; required with ``second``.
    seabed : SeabedPlane, optional
        The seabed in the sonar frame from outside the sonar image: the vehicle's navigation
        (altitude and attitude, :meth:`.SeabedPlane.from_pose`). Used instead of the plane fitted
        to the image, and then frames with a soft elevation beam are matched too (the fit is what
        needs hard edges). With ``second`` it is moved by ``motion`` for the second pair. The
        matcher needs it to millimetres and about 0.02 deg: 1 cm of height error halves its
        precision (docs/matching.md, "Soft elevation beams"). Its normal points up, to the sonar's
        side (``offset < 0``); a plane with the sonar under it is refused.

    Returns
    -------
    Matches
        Best first; falsy with a ``message`` when nothing reliable was found (no features,
        a camera that sees nothing of the fan, no candidate passing the gates).

    Raises
    ------
    ValueError
        Naming the argument or field and its value: a sonar frame, camera image, rig, ``options``,
        ``noise`` or ``seabed`` of the wrong kind or shape; ``min_score`` outside [0, 1]; ``motion``
        without ``second``; a ``sonar.beam_model`` other than ``"thesis"`` or ``"aperture"``; a
        ``sonar.spec`` (used when the rig carries no sonar) whose ``fov_elevation`` is not in (0, pi)
        rad or ``fov_azimuth`` not in (0, 2 pi] (without one, the beams' span is used); a
        ``rig.sonar`` that disagrees with ``sonar.spec`` on ``fov_elevation``, ``fov_azimuth``,
        ``range_min`` or ``range_max`` (fields the spec marks ``unverified`` are not compared), or
        whose fan does not hold the frame's beams. Errors of the second pair's inputs say so.
    """
    if not isinstance(rig, Rig):
        raise ValueError(f"rig: expected an optiacoustic.Rig, got {type(rig).__name__}")
    opt = MatchOptions() if options is None else options
    if not isinstance(opt, MatchOptions):
        raise ValueError(f"options: expected a MatchOptions (or None), got {type(options).__name__}")
    noise = MatchNoise() if noise is None else noise
    if not isinstance(noise, MatchNoise):
        raise ValueError(f"noise: expected a MatchNoise, got {type(noise).__name__}")
    if not is_number(min_score) or not 0.0 <= float(min_score) <= 1.0:
        raise ValueError(f"min_score: expected a number in [0, 1] (a probability), got {min_score!r}")
    if motion is not None and second is None:
        raise ValueError("motion: given without 'second' (the second pair it moves view 1 to); pass "
                         "second=(sonar, camera_image) too, or leave motion out")
    img_s, r_bins, th_beams = _check_sonar(sonar)
    beam_model = getattr(sonar, "beam_model", "thesis")
    if beam_model not in ("thesis", "aperture"):
        raise ValueError(f"sonar.beam_model: expected 'thesis' or 'aperture', got {beam_model!r}")
    spec = sonar.spec
    if rig.sonar is None:
        rig = rig.with_sonar(_frame_spec(spec, th_beams))
    else:
        _check_rig_sonar(rig.sonar, spec, r_bins, th_beams)
    # Measured frames may not state these: fall back to one bin and one beam spacing.
    range_res = getattr(spec, "range_resolution", None)
    range_res = float(np.median(np.diff(r_bins))) if range_res is None or range_res == 0 else \
        as_positive(range_res, "sonar.spec.range_resolution")
    beamwidth = getattr(spec, "beamwidth_azimuth", None)
    beamwidth = float(np.median(np.diff(th_beams))) if beamwidth is None or beamwidth == 0 else \
        as_positive(beamwidth, "sonar.spec.beamwidth_azimuth")
    cam_img = np.asarray(camera_image)
    cam = rig.camera
    if cam_img.ndim != 3 or cam_img.shape[:2] != (cam.height, cam.width):
        raise ValueError(f"camera_image: expected shape ({cam.height}, {cam.width}, 3) for the rig's camera, "
                         f"got {cam_img.shape}")
    if not _camera_sees_fan(rig, r_bins, th_beams):
        return _empty("the camera sees nothing of the sonar's fan: no epipolar curve enters the image")
    if seabed is not None and not (isinstance(seabed, SeabedPlane) and seabed
                                   and abs(float(np.linalg.norm(seabed.normal)) - 1.0) < 1e-6
                                   and np.isfinite(seabed.offset)):
        raise ValueError(f"seabed: expected a SeabedPlane with a unit normal and a finite offset, got {seabed!r}")
    if seabed is not None and not seabed.offset < 0:
        raise ValueError(f"seabed: the sonar must be above the seabed plane (SeabedPlane.offset < 0: the sonar's height "
                         f"is -offset), got offset = {seabed.offset:g} m with normal {np.round(seabed.normal, 4).tolist()}; "
                         f"a normal pointing down? the same plane pointing up is (-normal, -offset)")
    if beam_model != "thesis" and opt.use_acoustic and not opt.allow_soft_beam and seabed is None:
        return _empty(f"soft elevation beam (sonar.beam_model={beam_model!r}): the seabed plane that bounds each "
                      f"echo's elevation is fitted where the seabed crosses a hard-edged aperture, and under a soft "
                      f"beam it is degrees off (5-19% of matches right on held-out scenes, median scores 0.43-0.94; "
                      f"docs/matching.md, 'Soft elevation beams'); give the plane from the vehicle's navigation "
                      f"(match(..., seabed=SeabedPlane.from_pose(...))), or MatchOptions(allow_soft_beam=True) to "
                      f"match with the fitted plane anyway")

    # the CFAR maps of the detector's options, computed once here for every stage that reads them
    maps = cfar_map(np.asarray(img_s, np.float64), opt.cfar)
    sf = detect_sonar_features(img_s, r_bins, th_beams, range_resolution=range_res, beamwidth=beamwidth,
                               options=opt.cfar, maps=maps)
    if len(sf) == 0:
        return _empty("no sonar features: CFAR found no echo standing out of its background")
    if opt.method == "arc":
        intervals = _elevation_intervals(sf, img_s, r_bins, th_beams, rig, opt, seabed)
        plane = intervals[3]
        if seabed is None and plane and plane.relief_ratio > RELIEF_RATIO_WARN:
            relief_note = (f"the seabed's echo onsets depart from one plane by {plane.rms * 1000:.1f} mm, "
                           f"{plane.relief_ratio:.1f} times a flat seabed's (relief, objects at the near edge, or no "
                           f"seabed): the matcher's seabed is one plane, and on seabeds with relief its precision "
                           f"falls and its scores, calibrated on flat seabeds, run high")
            if opt.relief_as_plane_error:
                # The plane is then uncertain by the relief the residual implies: the seabed points placed on
                # it are scored by the chance that relief leaves them right, as under a navigation plane's
                # declared error (round i15t; docs/matching.md, "Seabed relief as the plane's error")
                plane = dataclasses.replace(plane, sigma_offset=plane.relief_sigma)
                intervals = intervals[:3] + (plane,)
                relief_note += (f"; its seabed points are scored by the chance that {plane.sigma_offset * 1000:.0f} mm "
                                f"of relief leaves them right")
            else:
                relief_note += "; MatchOptions(relief_as_plane_error=True) scores its seabed points by that relief"
            relief_note += " (docs/matching.md, 'Seabed relief')"
            warnings.warn(SeabedReliefWarning(relief_note), stacklevel=2)
        else:
            relief_note = ""
        if opt.use_acoustic and not plane:
            # Without the seabed every echo's elevation spans the whole aperture and the arc search's
            # choice is a guess: 1.5% of matches right on held-out scenes 6000-6011 and 9000-9005,
            # below the nearest-conic baseline (docs/matching.md, "Soft elevation beams").
            return _empty(f"no seabed plane, which the arc search needs to bound each echo's elevation: "
                          f"{plane.message}", sf)
        if beam_model != "thesis" and opt.use_acoustic:
            # A soft beam's sidelobes return the seabed from below the aperture, before the main lobe
            # reaches it: echoes with no shadow behind them at ranges where the seabed lies more than
            # SIDELOBE_MARGIN below the aperture's lower edge. Their point is off the arc the matcher
            # searches (the aperture), so no pixel of it is right: they are left out (on held-out soft-beam
            # scenes 431 of 1356 matches, none right; docs/matching.md, "Soft elevation beams").
            lo, hi, shadowed, plane = intervals
            below = ~shadowed & (seabed_elevation(plane, sf.ranges, sf.azimuths)
                                 < -rig.fov_elevation / 2 - SIDELOBE_MARGIN)
            if below.all():
                return _empty(f"no sonar features inside the elevation aperture: all {len(sf)} are seabed echoes "
                              f"of the soft beam's sidelobes, below it", sf, None, plane)
            if below.any():
                sf = sf.subset(~below)
                intervals = (lo[~below], hi[~below], shadowed[~below], plane)
        # the echo's start and end and the faces' beam creases read the default options' maps
        echo_maps = maps if opt.cfar == CfarOptions() else cfar_map(np.asarray(img_s, np.float64))
        # The candidate trees were fitted with the fitted plane (its relief ratio an input) or an exact one: not
        # under a plane with a declared error, whose seabed points are scored by that error (round i15v)
        # (and not without a seabed: with MatchOptions(use_acoustic=False) there is none)
        known = intervals[3] is not None and bool(intervals[3])
        out = _match_arcs(sf, cam_img, rig, noise, opt, intervals, sonar=(img_s, r_bins, th_beams, echo_maps),
                          soft_beam=beam_model != "thesis", rank=known and not intervals[3].uncertain)
        if relief_note and out:
            out = dataclasses.replace(out, message=f"{out.message}; {relief_note}")
        return _finish(out, cam_img, second, motion, rig, noise, opt, min_score, sf=sf, intervals=intervals,
                       seabed=seabed)
    cf = detect_camera_features(cam_img, opt.keypoints)
    if len(cf) == 0:
        return _empty("no camera features: the image has no corners (blank or too turbid)", sf)
    s_px = np.full(len(cf), noise.sigma_pixel) if noise.sigma_pixel else cf.sigma_pixel
    s_r = np.full(len(sf), noise.sigma_range) if noise.sigma_range else sf.sigma_range
    s_a = np.full(len(sf), noise.sigma_azimuth) if noise.sigma_azimuth else sf.sigma_azimuth

    d2 = mahalanobis_sq(rig, cf.pixels, s_px, sf.ranges, sf.azimuths, s_r, s_a)
    rows, cols = np.nonzero(d2 < opt.gate)
    if rows.size == 0:
        return _empty(f"no candidates: none of {len(cf)} camera features lies within the epipolar gate of "
                      f"any of {len(sf)} sonar features", sf, cf)
    ref = rc.refine(rig, cf.pixels[cols], sf.ranges[rows], sf.azimuths[rows], sigma_pixel=float(np.median(s_px)),
                    sigma_range=float(np.median(s_r)), sigma_azimuth=float(np.median(s_a)), max_iter=10)
    P = ref.points
    P_s = rig.sonar_from_camera(np.where(np.isfinite(P), P, 0.0))
    _, _, phi = spherical_from_sonar(P_s)
    half = rig.fov_elevation / 2
    ok = ref.valid & (np.abs(phi) <= half + 2 * opt.elevation_sigma)
    cost = np.where(ok, ref.cost, np.inf)

    given, seabed = seabed, None
    if opt.use_acoustic:
        seabed = given if given is not None else fit_seabed(img_s, r_bins, th_beams, rig.fov_elevation)
        if seabed:
            smooth, background = maps
            detected = smooth > opt.occupancy_factor * background
            cells = detected.copy()
            cells[sf.bins, sf.beams] = True
            low_map, high_map, shadow_map = elevation_maps(img_s, r_bins, th_beams, seabed, rig.fov_elevation,
                                                           cells=cells)
            lo, hi = low_map[sf.bins, sf.beams][rows], high_map[sf.bins, sf.beams][rows]
            shadowed = shadow_map[sf.bins, sf.beams]
            e = np.maximum(0.0, np.maximum(lo - phi, phi - hi)) / opt.elevation_sigma
            cost = cost + e ** 2
            height = seabed.height(P_s)
            cost = np.where(height < -opt.seabed_clearance, np.inf, cost)
            # The camera sees the seabed at this pixel: the point must be on the seabed. The
            # seabed there is in an acoustic shadow: the pixel shows an occluder, so the point
            # cannot be a seabed echo (a feature with no shadow behind it).
            state, _ = seabed_view(rig, seabed, cf.pixels, img_s, r_bins, th_beams)
            st = state[cols]
            on_bed = np.abs(height) <= opt.seabed_clearance
            cost = np.where((st == SEABED_LIT) & ~on_bed, np.inf, cost)
            cost = np.where((st == SEABED_SHADOWED) & ~shadowed[rows], np.inf, cost)
            # No closer occluder: no echo the sonar sees lies on the pixel's ray well before the point.
            alive = np.nonzero(np.isfinite(cost) & (cost < opt.null_cost))[0]
            occ = occluded(rig, cf.pixels[cols[alive]], P[alive, 2], detected, low_map, high_map, r_bins, th_beams,
                           margin=opt.occluder_margin)
            cost[alive[occ]] = np.inf

    if opt.corner_weight:
        # Strong corners sit on silhouettes, where the depth jumps and a pixel's neighbour
        # sees another surface: prefer the weaker, interior corners among competitors.
        rel = cf.response / max(float(np.median(cf.response)), 1e-12)
        cost = cost + opt.corner_weight * np.log(np.maximum(rel[cols], 1e-3))
    keep = np.isfinite(cost) & (cost < opt.null_cost)
    if not keep.any():
        return _empty(f"no candidates: the {rows.size} epipolar candidates all fail the reconstruction, "
                      f"elevation or seabed tests", sf, cf, seabed)
    rows, cols, cost, P = rows[keep], cols[keep], cost[keep], P[keep]
    epi = ref.cost[keep]

    chosen = _assign(cost, rows, cols, len(sf), opt.null_cost)
    if opt.smoothness and chosen.size >= 3:
        # Second pass: every candidate pays its disagreement with the first pass's matches
        # around it (its own first-pass match excluded by construction of the median).
        pix_c = cf.pixels[cols[chosen]]
        z_c = P[chosen, 2]
        from scipy.spatial import cKDTree

        tree = cKDTree(pix_c)
        d, idx = tree.query(cf.pixels[cols], k=min(7, chosen.size), distance_upper_bound=60.0)
        idx = np.atleast_2d(idx)
        valid_nb = idx < chosen.size
        # Leave out the candidate's own first-pass match.
        self_hit = valid_nb & (chosen[np.minimum(idx, chosen.size - 1)] == np.arange(rows.size)[:, None])
        use = valid_nb & ~self_hit
        nbz = np.where(use, z_c[np.minimum(idx, chosen.size - 1)], np.nan)
        enough = use.sum(1) >= 2
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(np.where(enough[:, None], nbz, np.nan), axis=1)
        e = np.where(enough, (P[:, 2] - med) / (0.05 * P[:, 2]), 0.0)
        cost = cost + np.minimum(np.nan_to_num(e) ** 2, 25.0) * 0.25
        chosen = _assign(cost, rows, cols, len(sf), opt.null_cost)
    if chosen.size == 0:
        return _empty("no match: leaving every sonar feature unmatched costs less than any assignment", sf, cf, seabed)
    n_cand_row = np.bincount(rows, minlength=len(sf))
    n_cand_col = np.bincount(cols, minlength=len(cf))
    span = (hi - lo)[keep] if (opt.use_acoustic and seabed) else np.full(rows.size, rig.fov_elevation)
    med_resp = max(float(np.median(cf.response)), 1e-12)
    feats = dict(n_candidates=n_cand_row[rows[chosen]], n_candidates_camera=n_cand_col[cols[chosen]],
                 elevation_span=span[chosen], snr=sf.snr[rows[chosen]], kind=sf.kind[rows[chosen]],
                 corner_response=cf.response[cols[chosen]], corner_relative=cf.response[cols[chosen]] / med_resp,
                 epipolar_chi2=epi[chosen], elevation=phi[keep][chosen],
                 share=_posterior(cost, rows, cols, (len(sf), len(cf)), opt.null_cost)[chosen])
    score = calibrated_score(feats)
    order = np.argsort(-score, kind="stable")
    ch = chosen[order]
    feats = {k: np.asarray(v)[order] for k, v in feats.items()}
    out = Matches(cf.pixels[cols[ch]], sf.ranges[rows[ch]], sf.azimuths[rows[ch]], P[ch], score[order], cost[ch],
                  rows[ch], cols[ch], sf, cf, seabed,
                  f"{ch.size} matches of {len(sf)} sonar and {len(cf)} camera features", feats)
    return _finish(out, cam_img, second, motion, rig, noise, opt, min_score, sf=sf, seabed=given)


def _finish(out, cam_img, second, motion, rig, noise, opt, min_score, *, sf=None, intervals=None,
            seabed=None) -> Matches:
    """Two-view check (when asked for) and the score threshold."""
    if second is not None and sf is not None and len(sf) and np.ptp(np.asarray(cam_img, float)) > 0:
        if intervals is None:
            half = rig.fov_elevation / 2
            intervals = (np.full(len(sf), -half), np.full(len(sf), half), np.zeros(len(sf), bool), out.seabed)
        out = _two_view(out, sf, intervals, cam_img, second, motion, rig, noise, opt, seabed)
    if not out:
        return out
    n = len(out)
    res = out.above(min_score)
    if not res:
        return _empty(f"nothing reliable: {n} tentative matches, none with score >= {min_score}",
                      out.sonar_features, out.camera_features, out.seabed)
    return res


#: Logistic model of P(correct) for the arc search's matches: intercept and weights of the
#: standardised :func:`arc_score_features` (log SNR, elevation interval width in degrees and
#: its squared distance from 4.5 deg, visible arc length in px, log edge-free run length in
#: px and its squared distance from log 55 px, position of the choice in the interval, shadow
#: behind the echo, onset or peak, log of 1 + the other matches within 6 px; and, where no
#: shadow lies behind the echo, so that the feature is placed at the seabed's elevation, log of 1 +
#: the bins from its echo's start and to its end: a feature deep inside a long unshadowed echo is an
#: object whose shadow was missed, not the seabed, a low bar or a wall). Labels: the arc search's
#: own pixel. Fitted by ``experiments.matching.calibrate_score()`` on random scenes seeded
#: 5000-5023 and the wider :func:`experiments.matching.varied_scene` seeded 8000-8023 (its
#: defaults; 1241 matches, 51% right; refitted from the current tree in round i15p, and the six
#: one-view models below refitted on top of it), disjoint from every scene the experiment and the
#: tests evaluate on. ``tests/matching/test_face_models.py`` checks that the fitter reproduces it.
ARC_SCORE_MODEL = dict(
    weights=(-0.004, 0.344, 0.21, -0.078, -0.285, -0.14, -0.381, 0.796, -0.289, -0.41, -0.241, -0.196, -0.247),
    mean=(2.7924, 5.1826, 15.3267, 83.7906, 3.3429, 2.1523, 0.5454, 0.8026, 0.4682, 0.2233, 0.2471, 0.3784),
    std=(0.6098, 3.855, 20.6796, 57.041, 1.3117, 3.7878, 0.2015, 0.3981, 0.499, 0.4054, 0.6357, 0.9105),
)


def arc_score_features(feats: dict) -> np.ndarray:
    """The arc score model's inputs ``(N, 12)`` from a :attr:`Matches.features` mapping."""
    span = np.rad2deg(feats["elevation_span"])
    run = np.log(np.maximum(feats["run_px"], 1e-3))
    flat = 1.0 - np.asarray(feats["shadowed"], float)  # no shadow behind the echo: the seabed's elevation
    return np.column_stack([np.log(np.maximum(feats["snr"], 1e-6)), span, (span - 4.5) ** 2,
                            feats["visible_px"], run, (run - 4.0) ** 2, np.clip(feats["position"], -0.5, 1.5),
                            feats["shadowed"].astype(float), feats["kind"], np.log1p(feats["crowding"]),
                            flat * np.log1p(feats["echo_depth_bins"]), flat * np.log1p(feats["echo_end_bins"])])


#: Second-stage logistic model of P(correct) of the arc search's pixel: intercept and weights of
#: the standardised :func:`face_score_features` (logit of :data:`ARC_SCORE_MODEL`'s score; for the
#: seabed-contact search of :mod:`.contact` and for the point below the crease: whether it found
#: one, log of 1 + its elevation's distance from the arc search's in units of 0.25 deg, and whether
#: they agree within 0.5 deg; and (round i15j) :func:`_foot_edges` of the arc search's pixel: its
#: point's foot on an image edge and the way down to it edge-free, :func:`.contact.foot_edges`).
#: Fitted by ``experiments.matching.calibrate_face_score()`` on random
#: scenes seeded 5000-5047 in thesis water and 5000-5023 in Jerlov 1C water
#: and :func:`experiments.matching.varied_scene` seeded 8000-8047 in thesis water
#: (``experiments.matching.FACE_TRAINING``; 3112 matches, 51% correct; sonar noise of the per-cell
#: counter stream, issue 14; refitted in round i15n and on the refitted arc model in i15p, the seabed plane fitted to both aperture edges).
FACE_SCORE_MODEL = dict(
    weights=(0.039, 0.743, 0.893, -0.875, 0.213, 0.232, -0.155, 0.09, -0.216, 0.081),
    mean=(0.0001, 0.2915, 0.4501, 0.0842, 0.6963, 0.8981, 0.2799, 1.6371, 1.1643),
    std=(1.0481, 0.4544, 0.8101, 0.2777, 0.4598, 0.8158, 0.4489, 1.1638, 0.9283),
)

#: :data:`FACE_SCORE_MODEL` where the face-plane candidate is offered (``MatchOptions.face_plane``
#: and an image contrast of at least ``face_plane_min_contrast``): intercept and weights of the
#: standardised :func:`face_plane_score_features` (those of :func:`face_score_features`, then for
#: the point on the face's plane: found, log of 1 + its elevation distance from the arc search's in
#: units of 0.25 deg, agreement within 0.5 deg; and (round i15h) whether the feature's echo fits on
#: its face, :func:`_face_fit`: a wrong surface when not). Fitted by
#: ``experiments.matching.calibrate_face_score()`` on the matches of those scenes where the plane is
#: offered (thesis water; 2564 matches, 50% correct; refitted in round i15n and i15p), with the planes fitted to every beam's crease
#: (``MatchOptions.face_plane_beams``).
FACE_PLANE_SCORE_MODEL = dict(
    weights=(0.014, 0.644, 0.778, -0.766, 0.249, -0.148, 0.108, 0.14, -0.161, 0.137, 0.569, -0.666, -0.123, 0.074, -0.076, 0.31),
    mean=(-0.0019, 0.3537, 0.5463, 0.1022, 0.6775, 0.8258, 0.298, 1.8599, 1.2908, 0.6771, 0.946, 0.2426, 0.9676, 0.4287, 0.6626),
    std=(1.0526, 0.4781, 0.8625, 0.3029, 0.4674, 0.7813, 0.4574, 1.1655, 0.9745, 0.4676, 0.8789, 0.4286, 0.177, 0.7975, 0.4728),
)

#: Logistic model of P(correct) of the point below the crease (:func:`.contact.crease_points`):
#: intercept and weights of the standardised :func:`crease_score_features` (logit of the arc
#: search's own score, log of 1 + the crease point's elevation distance from the arc search's in
#: units of 0.25 deg, onset or peak, the foot search found a face, where the point sits in the
#: run (0 its low end, 1 its top), log of 1 + how many bins the feature lies behind its echo's
#: start (deeper: more likely another object's onset), log run length in px, log of 1 + the
#: gradient just above the run (the crease's edge), log of the image's contrast (turbid water
#: washes out the crease between a box's front and top faces, and the run then ends at the top
#: face's far edge); and (round i15h) the plane point found and log of 1 + its elevation distance
#: from the crease point, and whether the feature's echo fits on its face, :func:`_face_fit`; and
#: (round i15j) the crease point's :func:`_foot_edges`). Fitted by
#: ``experiments.matching.calibrate_face_score()`` on the same scenes (2167 crease points, 62%
#: correct; refitted in round i15n and i15p).
CREASE_SCORE_MODEL = dict(
    weights=(0.536, 0.6, -0.32, -0.196, 0.058, -0.433, -0.405, 0.839, 0.266, -0.495, 0.745, -0.279, 0.24, 0.155, -0.288, 0.306, 0.139),
    mean=(0.2954, 1.2897, 0.4822, 0.3909, 0.5861, 0.965, 4.2161, 1.5257, -0.2678, 0.6982, 0.6518, 0.7817, 0.554, 0.6894, 1.6644, 1.1846),
    std=(0.7454, 0.6713, 0.4997, 0.4879, 0.2212, 0.3288, 0.5854, 1.3969, 0.19, 0.459, 0.7165, 0.4131, 0.4386, 0.4627, 1.2048, 0.8991),
)


def _agreement(found, dphi_deg):
    f = np.asarray(found, bool)
    dp = np.where(f, np.nan_to_num(np.asarray(dphi_deg, float)), 0.0)
    return [f.astype(float), np.where(f, np.log1p(dp / 0.25), 0.0), (f & (dp < 0.5)).astype(float)]


def _logit(p):
    p = np.clip(np.asarray(p, float), 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


def _foot_edges(feats, name):
    """The candidate's foot evidence (:func:`.contact.foot_edges`, round i15j): log of 1 + the gradient at its
    foot's pixel and log of 1 + the largest gradient on the way down to it (0 where there is no candidate)."""
    return [np.log1p(np.nan_to_num(np.asarray(feats[f"{name}_foot_edge"], float))),
            np.log1p(np.nan_to_num(np.asarray(feats[f"{name}_face_edge"], float)))]


def face_score_features(feats: dict) -> np.ndarray:
    """The face score model's inputs ``(N, 9)`` from a :attr:`Matches.features` mapping."""
    return np.column_stack([_logit(feats["arc_score"]), *_agreement(feats["contact_found"], feats["contact_dphi_deg"]),
                            *_agreement(feats["crease_found"], feats["crease_dphi_deg"]), *_foot_edges(feats, "arc")])


def _face_fit(feats):
    """Whether the feature's echo fits on its face (a wrong surface when not): the arc meets the face's plane,
    where (its height as a fraction of the face's top edge, clipped to [-1, 2]), and within [-0.05, 1.05]."""
    h = np.asarray(feats["plane_fit_height"], float)
    fin = np.isfinite(h)
    hh = np.nan_to_num(h, nan=0.5)
    return [fin.astype(float), np.clip(hh, -1.0, 2.0), (fin & (hh >= -0.05) & (hh <= 1.05)).astype(float)]


def face_plane_score_features(feats: dict) -> np.ndarray:
    """:data:`FACE_PLANE_SCORE_MODEL`'s inputs ``(N, 15)``: :func:`face_score_features`, the plane point's
    agreement and whether the feature's echo fits on its face (:func:`_face_fit`)."""
    return np.column_stack([face_score_features(feats), *_agreement(feats["plane_found"], feats["plane_dphi_deg"]),
                            *_face_fit(feats)])


def crease_score_features(feats: dict) -> np.ndarray:
    """The crease score model's inputs ``(N, 16)`` (NaN-free; meaningful where ``crease_found``)."""
    d = np.nan_to_num(np.asarray(feats["crease_dphi_deg"], float))
    dp = np.asarray(feats["plane_crease_dphi_deg"], float)
    fp = np.isfinite(dp)
    return np.column_stack([_logit(feats["arc_score"]), np.log1p(d / 0.25), feats["kind"],
                            np.asarray(feats["contact_found"], float), np.nan_to_num(feats["crease_position"]),
                            np.log1p(feats["echo_depth_bins"]), np.log(np.maximum(feats["run_px"], 1.0)),
                            np.log1p(np.nan_to_num(feats["top_edge"])),
                            np.log(np.maximum(feats["image_contrast"], 1e-6)),
                            fp.astype(float), np.where(fp, np.log1p(np.nan_to_num(dp) / 0.25), 0.0), *_face_fit(feats),
                            *_foot_edges(feats, "crease")])


#: Logistic model of P(correct) of the point on the face's fitted plane (:mod:`.face_plane`):
#: intercept and weights of the standardised :func:`plane_score_features` (logit of the arc
#: search's own score; log of 1 + the point's elevation distance from the arc search's, in units of
#: 0.25 deg; the crease point found, and log of 1 + the plane point's distance from it; onset or
#: peak; the point's pixel in the feature's face; log of 1 + the plane's inlier creases and their
#: fraction; log of 1 + the feature's own crease's distance from the plane in cm; log of 1 + the
#: inliers' extent along the edge in units of 5 cm; where the point sits in the
#: run; its height as a fraction of the face's; log of 1 + how many bins the feature lies behind its
#: echo's start; log of 1 + the gradient just above the run; log of the image's contrast; and
#: (round i15j) the plane point's :func:`_foot_edges`). Fitted by
#: ``experiments.matching.calibrate_face_score()`` on the same scenes as the crease model (1736
#: plane points, all in thesis water where the plane is offered, 68% correct, refitted in round i15n and i15p; the planes fitted to
#: every beam's crease, ``MatchOptions.face_plane_beams``).
PLANE_SCORE_MODEL = dict(
    weights=(0.941, 0.662, -0.185, 0.262, 0.072, -0.159, 0.349, 0.469, 0.357, 0.081, -0.036, -0.053, 0.186, 0.102, 0.045, -0.168, 0.609, -0.106),
    mean=(0.2763, 1.3972, 0.8715, 0.8136, 0.4643, 0.9124, 2.5914, 0.8095, 0.5447, 2.0025, 0.536, 0.5861, 0.9874, 1.8946, -0.177, 1.9669, 1.411),
    std=(0.8281, 0.7144, 0.3346, 0.7136, 0.4987, 0.2827, 0.732, 0.1815, 0.5235, 0.6393, 0.4477, 0.2751, 0.3476, 1.3217, 0.0553, 1.2072, 0.9673),
)


def plane_score_features(feats: dict) -> np.ndarray:
    """The plane score model's inputs ``(N, 17)`` (NaN-free; meaningful where ``plane_found``)."""
    d = np.nan_to_num(np.asarray(feats["plane_dphi_deg"], float))
    cf = np.asarray(feats["crease_found"], bool)
    dc = np.where(cf, np.nan_to_num(np.asarray(feats["plane_crease_dphi_deg"], float)), 0.0)
    n_c = np.maximum(np.asarray(feats["plane_n_creases"], float), 1.0)
    n_i = np.asarray(feats["plane_n_inliers"], float)
    own = np.asarray(feats["plane_own_residual"], float)
    pos = np.clip(np.nan_to_num(np.asarray(feats["plane_position"], float), nan=0.5), -1.0, 2.0)
    hgt = np.clip(np.nan_to_num(np.asarray(feats["plane_height"], float), nan=0.5), -1.0, 2.0)
    return np.column_stack([_logit(feats["arc_score"]), np.log1p(d / 0.25), cf.astype(float), np.log1p(dc / 0.25),
                            feats["kind"], np.asarray(feats["plane_in_face"], float), np.log1p(n_i), n_i / n_c,
                            np.where(np.isfinite(own), np.log1p(np.nan_to_num(own) / 0.01), 0.0),
                            np.log1p(np.nan_to_num(np.asarray(feats["plane_spread"], float)) / 0.05), pos, hgt,
                            np.log1p(feats["echo_depth_bins"]), np.log1p(np.nan_to_num(feats["top_edge"])),
                            np.log(np.maximum(feats["image_contrast"], 1e-6)), *_foot_edges(feats, "plane")])


#: Logistic model of P(correct) of the point above the face's foot (:func:`.contact.foot_points`):
#: intercept and weights of the standardised :func:`foot_score_features`. Fitted by
#: ``experiments.matching.calibrate_face_score()`` on the same scenes as the crease model (2298
#: foot points, 52% correct; refitted in round i15n and i15p).
FOOT_SCORE_MODEL = dict(
    weights=(0.09, -0.006, -0.111, 0.28, -0.709, 1.498, -0.771, 0.222, 0.021, 0.092, -0.071, -0.045, -0.05, -0.13, 0.136, -0.25, 0.174, -0.168, -0.023, -0.788, 0.292, -0.001),
    mean=(0.2729, 1.7835, 0.8847, 1.6311, 0.6954, 1.2283, 0.6823, 0.4604, 1.5482, 1.0006, 0.3709, 0.7218, 2.8494, -0.2597, 0.8216, 0.3764, 0.7981, 0.5043, 0.6841, 1.7442, 1.4018),
    std=(0.8822, 0.7897, 0.3194, 0.9827, 0.4602, 1.0706, 0.4656, 0.4984, 0.3323, 0.34, 0.187, 0.6914, 0.6369, 0.1828, 0.3829, 0.4845, 0.4014, 0.4862, 0.4649, 1.21, 1.0184),
)


def foot_score_features(feats: dict) -> np.ndarray:
    """The foot score model's inputs ``(N, 21)`` (NaN-free; meaningful where ``foot_found``).

    Logit of the arc search's own score; log of 1 + the foot point's elevation distance (units of
    0.25 deg) from the arc search's pixel, and, with whether each exists, from the crease point and
    from the plane point; the point inside the arc search's run; onset or peak; log of 1 + the
    bins between the feature and its echo's end, and between its echo's start and the feature;
    the point's height above the seabed (m); log of 1 + the image gradient at its pixel; log SNR;
    log of the image's contrast; the plane offered; the foot search found a face; and whether the
    feature's echo fits on its face's plane (:func:`_face_fit`); and (round i15j) the point's foot on
    an image edge and the way down to it edge-free (:func:`_foot_edges`).
    """
    def dist(key):
        d = np.asarray(feats[key], float)
        f = np.isfinite(d)
        return [f.astype(float), np.where(f, np.log1p(np.nan_to_num(d) / 0.25), 0.0)]

    d0 = np.nan_to_num(np.asarray(feats["foot_dphi_deg"], float))
    return np.column_stack([_logit(feats["arc_score"]), np.log1p(d0 / 0.25), *dist("foot_crease_dphi_deg"),
                            *dist("foot_plane_dphi_deg"), np.asarray(feats["foot_in_run"], float), feats["kind"],
                            np.log1p(feats["echo_end_bins"]), np.log1p(feats["echo_depth_bins"]),
                            np.clip(np.nan_to_num(feats["foot_height"]), 0.0, 2.0),
                            np.log1p(np.asarray(feats["foot_gradient"], float)),
                            np.log(np.maximum(feats["snr"], 1e-6)),
                            np.log(np.maximum(feats["image_contrast"], 1e-6)),
                            np.asarray(feats["plane_offered"], float), np.asarray(feats["contact_found"], float),
                            *_face_fit(feats), *_foot_edges(feats, "foot")])


#: intercept and weights of the standardised :func:`seabed_score_features`. Fitted by
#: ``experiments.matching.calibrate_face_score()`` on ``FACE_TRAINING`` (round i15k; refitted in rounds i15n and i15p
#: with the seabed plane fitted to both aperture edges: 602 seabed points, 68% correct, 39% before).
SEABED_SCORE_MODEL = dict(
    weights=(1.396, 0.955, 0.561, 0.483, 0.046, 0.105, 0.031, 0.185, -0.536, -0.077, -1.597, 0.14),
    mean=(-1.0037, 0.2923, 0.4701, 0.6196, 1.3773, 2.2499, 1.1913, 2.6662, -0.2598, 3.2512, 1.9956),
    std=(0.823, 0.2138, 0.4991, 0.4855, 0.9534, 1.2499, 1.0632, 0.5671, 0.1847, 4.2097, 0.3032),
)


def seabed_score_features(feats: dict) -> np.ndarray:
    """The seabed point's score model's inputs ``(N, 11)`` (NaN-free; meaningful where ``seabed_found``).

    Logit of the arc search's own score; log of 1 + the seabed point's elevation distance from the
    arc search's pixel (units of 0.25 deg); onset or peak; the point inside the arc search's run;
    log of 1 + the bins from the echo's start to the feature and from the feature to its end; log of
    1 + the image gradient at its pixel; log SNR; log of the image's contrast; the seabed's
    elevation there (deg: how steeply the arc crosses the seabed, i.e. how narrow the right sliver
    is) and log of the feature's range (m).
    """
    d = np.nan_to_num(np.asarray(feats["seabed_dphi_deg"], float))
    return np.column_stack([_logit(feats["arc_score"]), np.log1p(d / 0.25), feats["kind"],
                            np.asarray(feats["seabed_in_run"], float), np.log1p(feats["echo_depth_bins"]),
                            np.log1p(feats["echo_end_bins"]), np.log1p(np.asarray(feats["seabed_gradient"], float)),
                            np.log(np.maximum(feats["snr"], 1e-6)),
                            np.log(np.maximum(feats["image_contrast"], 1e-6)),
                            np.rad2deg(np.nan_to_num(np.asarray(feats["seabed_elevation"], float))),
                            np.log(np.maximum(np.asarray(feats["range_m"], float), 1e-3))])


#: The five candidate pixels of a one-view match, in ``features["face_source"]`` order.
CANDIDATES = ("arc", "crease", "plane", "foot", "seabed")

#: Soft-beam frames (round i15s): ``p' = sigmoid(a + b logit p)`` per candidate, ``(a, b)``, fitted by
#: ``experiments.matching.calibrate_soft_beam()`` (logistic regression of each offered candidate's
#: correctness on the logit of its thesis-frame probability, the slope shrunk towards 1 with weight 1) on
#: the realistic model's frames of random scenes 5000-5023 and varied scenes 8000-8023 with the seabed
#: from the navigation (exact): arc pixel 2326 offered, 52% right (mean probability 0.43); crease 815, 37%
#: (0.55); plane 902, 37% (0.51); foot 850, 39% (0.42); seabed point 1157, 94% (0.85).
SOFT_BEAM_RECALIBRATION = {
    "arc": (0.198, 0.421),
    "crease": (-0.614, 0.355),
    "plane": (-0.673, 0.500),
    "foot": (-0.251, 0.659),
    "seabed": (1.408, 0.902),
}


def logit(p) -> np.ndarray:
    """``log(p / (1 - p))`` of probabilities, clipped to ``[1e-12, 1 - 1e-12]`` first."""
    q = np.clip(np.asarray(p, float), 1e-12, 1.0 - 1e-12)
    return np.log(q / (1.0 - q))


def soft_beam_probability(p, kind: str) -> np.ndarray:
    """A candidate's thesis-frame probability ``p`` mapped through :data:`SOFT_BEAM_RECALIBRATION` ``[kind]``."""
    a, b = SOFT_BEAM_RECALIBRATION[kind]
    return 1.0 / (1.0 + np.exp(-(a + b * logit(p))))


def _logistic(X, model):
    w = np.asarray(model["weights"], float)
    z = w[0] + ((X - np.asarray(model["mean"])) / np.asarray(model["std"])) @ w[1:]
    return 1.0 / (1.0 + np.exp(-z))


def _elevation_intervals(sf, img_s, r_bins, th_beams, rig, opt, given=None):
    """Each sonar feature's elevation interval from the seabed and shadows: (low, high, shadowed, seabed).

    ``given``: the caller's seabed plane (navigation), used instead of fitting one to the image.
    """
    half = rig.fov_elevation / 2
    lo = np.full(len(sf), -half)
    hi = np.full(len(sf), half)
    shadowed = np.zeros(len(sf), bool)
    seabed = None
    if opt.use_acoustic:
        seabed = given if given is not None else fit_seabed(img_s, r_bins, th_beams, rig.fov_elevation)
        if seabed:
            cells = np.zeros(img_s.shape, bool)
            cells[sf.bins, sf.beams] = True
            low_map, high_map, shadow_map = elevation_maps(img_s, r_bins, th_beams, seabed, rig.fov_elevation,
                                                           cells=cells)
            lo, hi = low_map[sf.bins, sf.beams], high_map[sf.bins, sf.beams]
            shadowed = shadow_map[sf.bins, sf.beams]
    return lo, hi, shadowed, seabed


def _beam_creases(rig, sonar, face, c_ok, ranges, azimuths, r_on, labels):
    """:func:`.face_plane.beam_creases` for every face that holds a feature's crease (azimuths within the
    plane fit's window of its features, ranges from 0.5 m before their echoes' starts to their ranges)."""
    from .contact import ECHO_START_FACTOR
    from .face_plane import FACE_WINDOW, beam_creases, echo_run_starts

    _, r_bins, th_beams, (smooth, background) = sonar
    starts = echo_run_starts(smooth > ECHO_START_FACTOR * background)
    use = c_ok & (face > 0)
    labs = np.unique(face[use])
    lo, hi, r0, r1 = (np.empty(labs.size) for _ in range(4))
    for k, lab in enumerate(labs):
        m = use & (face == lab)
        lo[k], hi[k] = azimuths[m].min() - FACE_WINDOW, azimuths[m].max() + FACE_WINDOW
        r0[k], r1[k] = np.minimum(r_on, ranges)[m].min() - 0.5, ranges[m].max() + 0.05
    return beam_creases(rig, starts, r_bins, th_beams, labels, labs, lo, hi, r0, r1)


def _match_arcs(sf, cam_img, rig, noise, opt, intervals, *, sonar=None, soft_beam: bool = False,
                rank: bool = True) -> Matches:
    """Every sonar feature takes a pixel of the longest edge-free run of its arc (:mod:`.arc_search`).

    The run's middle (or 70% up for onsets), the point below the face's crease
    (:func:`.contact.crease_points`), the point where the arc meets the plane fitted to all the
    face's creases (:func:`.face_plane.face_planes`), the point above the face's foot
    (:func:`.contact.foot_points`) or, for an echo with no shadow behind it, the point where the arc
    meets the seabed (:func:`.acoustic.seabed_points`), whichever has the highest calibrated probability.
    """
    from ..geometry.projection import camera_from_sonar
    from .arc_search import gradient_image, pixel_values, search_arcs, stretched
    from .camera_features import to_gray8
    from .contact import (crease_points, crease_positions, echo_end_ranges, echo_start_ranges, foot_edges,
                          foot_points, search_contacts)
    from .face_plane import face_labels, face_planes

    if np.ptp(to_gray8(cam_img)) == 0:
        return _empty("no camera features: the image is blank (or too turbid to show anything)", sf)
    lo, hi, shadowed, seabed = intervals
    grad = gradient_image(cam_img)
    colours = stretched(cam_img) if opt.seabed_contrast > 0 else None
    from .sonar_features import ONSET

    frac = np.where(sf.kind == ONSET, 0.7, 0.5)
    ch = search_arcs(rig, sf.ranges, sf.azimuths, lo, hi, grad, fraction=frac, threshold=opt.arc_threshold,
                     colours=colours, min_contrast=opt.seabed_contrast)
    if not ch.found.any():
        return _empty(f"no candidates: no sonar feature's arc (of {len(sf)}) crosses an edge-free stretch of the "
                      f"image inside its elevation interval", sf, None, seabed)
    rows = np.nonzero(ch.found)[0]
    px_arc = ch.pixels[rows]
    # Several sonar features choosing (nearly) the same pixel cannot all be right: on the
    # training scenes a match with two or more such neighbours is right 1 time in 20.
    from scipy.spatial import cKDTree

    crowding = np.array([len(n) - 1 for n in cKDTree(px_arc).query_ball_point(px_arc, r=6.0)], float)
    feats = dict(snr=sf.snr[rows], kind=sf.kind[rows], elevation_span=(hi - lo)[rows], shadowed=shadowed[rows],
                 visible_px=ch.visible_px[rows], run_px=ch.run_px[rows], position=ch.position[rows],
                 elevation=ch.elevations[rows], crowding=crowding,
                 seabed_contrast=np.nan_to_num(ch.contrast[rows], nan=1.0))
    # The feature's echo in its own beam (:mod:`.contact`): where it starts (the crease of a face seen
    # from above) and where it ends (the foot of a face, where its shadow starts).
    if sonar is not None:  # (polar image, bin ranges, beam azimuths, its default-options cfar_map)
        r_on = echo_start_ranges(sonar[0], sonar[1], sf.bins[rows], sf.beams[rows], maps=sonar[3])
        r_end = echo_end_ranges(sonar[0], sonar[1], sf.bins[rows], sf.beams[rows], maps=sonar[3])
    else:
        r_on = r_end = sf.ranges[rows]
    bin_m = float(np.median(np.diff(sonar[1]))) if sonar is not None else 1.0
    feats["echo_depth_bins"] = (sf.ranges[rows] - np.minimum(r_on, sf.ranges[rows])) / bin_m
    feats["echo_end_bins"] = (np.maximum(r_end, sf.ranges[rows]) - sf.ranges[rows]) / bin_m
    feats["arc_score"] = _logistic(arc_score_features(feats), ARC_SCORE_MODEL)
    # Vertical faces standing on the seabed (a prior, :mod:`.contact`): the foot search's
    # agreement with the arc search, and the point below the face's crease.
    c = search_contacts(rig, seabed, sf.ranges[rows], sf.azimuths[rows], lo[rows], hi[rows], grad)
    feats["contact_found"] = c.found
    feats["contact_dphi_deg"] = np.where(c.found, np.rad2deg(np.abs(np.nan_to_num(c.elevations)
                                                                    - ch.elevations[rows])), np.nan)
    cr = crease_points(rig, seabed, sf.ranges[rows], sf.azimuths[rows], r_on, ch.top_pixels[rows],
                       ch.run_low[rows], ch.run_high[rows])
    feats["crease_found"] = cr.found
    feats["crease_dphi_deg"] = np.where(cr.found, np.rad2deg(np.abs(np.nan_to_num(cr.elevations)
                                                                    - ch.elevations[rows])), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        feats["crease_position"] = np.where(cr.found, (cr.elevations - ch.run_low[rows])
                                            / np.maximum(ch.run_high[rows] - ch.run_low[rows], 1e-9), np.nan)
    feats["top_edge"] = ch.top_edge[rows]
    lo_i, hi_i = np.percentile(np.asarray(cam_img, float)[..., :3].mean(axis=-1), [0.5, 99.5])
    feats["image_contrast"] = np.full(rows.size, (hi_i - lo_i) / max(hi_i + lo_i, 1e-12))
    feats["arc_u"], feats["arc_v"] = px_arc[:, 0], px_arc[:, 1]
    feats["crease_u"], feats["crease_v"] = cr.pixels[:, 0], cr.pixels[:, 1]
    # The face-plane model (:mod:`.face_plane`): the vertical plane through all creases of the face.
    labels = face_labels(grad, opt.arc_threshold)
    H, W = labels.shape
    face = labels[np.clip(np.rint(px_arc[:, 1]).astype(int), 0, H - 1),
                  np.clip(np.rint(px_arc[:, 0]).astype(int), 0, W - 1)]  # the face the arc search chose
    C, c_ok = crease_positions(rig, ch.top_pixels[rows], np.minimum(r_on, sf.ranges[rows]))
    offered = opt.face_plane & (feats["image_contrast"] >= opt.face_plane_min_contrast)
    feats["plane_offered"] = offered
    c_ok &= offered
    extra = None
    if opt.face_plane_beams and sonar is not None and seabed and (c_ok & (face > 0)).any():
        extra = _beam_creases(rig, sonar, face, c_ok, sf.ranges[rows], sf.azimuths[rows], r_on, labels)
    fp = face_planes(rig, seabed, sf.ranges[rows], sf.azimuths[rows], face, C, c_ok, ch.elevations[rows], labels,
                     extra=extra)
    feats["plane_u"], feats["plane_v"] = fp.pixels[:, 0], fp.pixels[:, 1]
    feats["plane_found"] = fp.found
    feats["plane_dphi_deg"] = np.where(fp.found, np.rad2deg(np.abs(np.nan_to_num(fp.elevations)
                                                                  - ch.elevations[rows])), np.nan)
    feats["plane_crease_dphi_deg"] = np.where(fp.found & cr.found, np.rad2deg(np.abs(
        np.nan_to_num(fp.elevations) - np.nan_to_num(cr.elevations))), np.nan)
    feats["plane_n_creases"], feats["plane_n_inliers"] = fp.n_creases, fp.n_inliers
    feats["plane_spread"], feats["plane_own_residual"] = fp.spread, fp.own_residual
    feats["plane_height"], feats["plane_in_face"] = fp.height, fp.in_face
    feats["plane_fit_height"] = fp.fit_height
    with np.errstate(invalid="ignore", divide="ignore"):
        feats["plane_position"] = np.where(fp.found, (fp.elevations - ch.run_low[rows])
                                           / np.maximum(ch.run_high[rows] - ch.run_low[rows], 1e-9), np.nan)
    # The point above the face's foot, where the feature's echo ends (acoustic only, :func:`.contact.foot_points`).
    ft = foot_points(rig, seabed, sf.ranges[rows], sf.azimuths[rows], r_end)
    # A face standing on the seabed casts a shadow behind its foot: with none behind the echo
    # (a low bar, the seabed itself) the echo's end is not a foot.
    ft = dataclasses.replace(ft, found=ft.found & shadowed[rows])
    ft = dataclasses.replace(ft, pixels=np.where(ft.found[:, None], ft.pixels, np.nan),
                             elevations=np.where(ft.found, ft.elevations, np.nan),
                             height=np.where(ft.found, ft.height, np.nan))
    feats["foot_found"] = ft.found
    feats["foot_u"], feats["foot_v"] = ft.pixels[:, 0], ft.pixels[:, 1]
    feats["foot_height"] = ft.height
    feats["foot_in_run"] = ft.found & (np.nan_to_num(ft.elevations) >= ch.run_low[rows] - 1e-9) & \
        (np.nan_to_num(ft.elevations) <= ch.run_high[rows] + 1e-9)
    for name, el in (("foot_dphi_deg", ch.elevations[rows]), ("foot_crease_dphi_deg", cr.elevations),
                     ("foot_plane_dphi_deg", fp.elevations)):
        feats[name] = np.rad2deg(np.abs(ft.elevations - el))
    feats["foot_gradient"] = np.where(ft.found, pixel_values(grad, ft.pixels), 0.0)
    # Every candidate's point dropped onto the seabed: its foot on an image edge and the way down to
    # it edge-free say it stands on a vertical face (:func:`.contact.foot_edges`; round i15j). The four
    # candidates' points in one call (one dilation of the gradient image).
    names = ("arc", "crease", "plane", "foot")
    els = np.concatenate([ch.elevations[rows], np.where(cr.found, cr.elevations, np.nan),
                          np.where(fp.found, fp.elevations, np.nan), ft.elevations])
    n_f = rows.size
    f_edge, c_edge = foot_edges(rig, seabed, np.tile(sf.ranges[rows], 4), np.tile(sf.azimuths[rows], 4), els, grad)
    for k, name in enumerate(names):
        feats[f"{name}_foot_edge"], feats[f"{name}_face_edge"] = f_edge[k * n_f:(k + 1) * n_f], c_edge[k * n_f:(k + 1) * n_f]
    # The seabed point (round i15k): an echo with no shadow behind it is on the seabed, so its point is
    # where its arc meets the sonar's own seabed plane (:func:`.acoustic.seabed_points`).
    from .acoustic import seabed_points

    sb_el, sb_px, sb_found = seabed_points(rig, seabed, sf.ranges[rows], sf.azimuths[rows], rig.fov_elevation)
    sb_found &= ~np.asarray(shadowed[rows], bool) & bool(opt.seabed_point)
    sb_el = np.where(sb_found, sb_el, np.nan)
    sb_px = np.where(sb_found[:, None], sb_px, np.nan)
    feats["seabed_found"] = sb_found
    feats["seabed_u"], feats["seabed_v"] = sb_px[:, 0], sb_px[:, 1]
    feats["seabed_elevation"] = sb_el
    feats["seabed_dphi_deg"] = np.rad2deg(np.abs(sb_el - ch.elevations[rows]))
    feats["seabed_in_run"] = sb_found & (np.nan_to_num(sb_el) >= ch.run_low[rows] - 1e-9) & \
        (np.nan_to_num(sb_el) <= ch.run_high[rows] + 1e-9)
    feats["seabed_gradient"] = np.where(sb_found, pixel_values(grad, sb_px), 0.0)
    feats["range_m"] = sf.ranges[rows]
    # how far the sonar's seabed onsets depart from one plane, in flat seabeds' residuals (NaN for a given plane)
    feats["seabed_relief_ratio"] = np.full(rows.size, float(seabed.relief_ratio) if seabed else np.nan)
    # Where the plane is offered, the arc search's pixel is scored knowing whether the plane
    # point agrees with it; elsewhere exactly as before the face-plane model.
    p_arc = np.where(offered, _logistic(face_plane_score_features(feats), FACE_PLANE_SCORE_MODEL),
                     _logistic(face_score_features(feats), FACE_SCORE_MODEL))
    p_crease = np.where(cr.found, _logistic(crease_score_features(feats), CREASE_SCORE_MODEL), 0.0)
    p_plane = np.where(fp.found, _logistic(plane_score_features(feats), PLANE_SCORE_MODEL), 0.0)
    p_foot = np.where(ft.found, _logistic(foot_score_features(feats), FOOT_SCORE_MODEL), 0.0)
    p_seabed = np.where(sb_found, _logistic(seabed_score_features(feats), SEABED_SCORE_MODEL), 0.0)
    if soft_beam and opt.soft_beam_recalibration:
        # Soft-beam frames: each candidate's probability mapped through its recalibration, fitted on the
        # realistic model's frames (round i15s; docs/matching.md, "Soft-beam frames recalibrated")
        p_arc, p_crease, p_plane, p_foot, p_seabed = (
            np.where(p > 0, soft_beam_probability(p, kind), 0.0)
            for p, kind in zip((p_arc, p_crease, p_plane, p_foot, p_seabed), CANDIDATES))
    feats["seabed_plane_probability"] = np.where(sb_found, 1.0, np.nan)
    if seabed and seabed.uncertain and sonar is not None and sb_found.any():
        # A plane given with a declared error (navigation): the seabed point is placed on it, so it is
        # right only while that error keeps it within a bin and a beam (:func:`.acoustic.plane_error_probability`)
        from .acoustic import plane_error_probability

        beam_rad = float(np.median(np.abs(np.diff(sonar[2])))) if len(sonar[2]) > 1 else float("inf")
        p_nav = plane_error_probability(rig, seabed, sonar_from_spherical(
            sf.ranges[rows], sf.azimuths[rows], np.nan_to_num(sb_el)), bin_m, beam_rad)
        feats["seabed_plane_probability"] = np.where(sb_found, p_nav, np.nan)
        p_seabed = p_seabed * np.where(sb_found, p_nav, 1.0)
    # 0: the arc search's pixel, 1: the point below the crease, 2: the point on the face's plane,
    # 3: the point above the face's foot, 4: the seabed point.
    probs = np.column_stack([p_arc, p_crease, p_plane, p_foot, p_seabed])
    elevs = np.column_stack([ch.elevations[rows], cr.elevations, fp.elevations, ft.elevations, sb_el])
    for k, name in enumerate(CANDIDATES):
        feats[f"p_{name}"], feats[f"{name}_elevation"] = probs[:, k], elevs[:, k]
    source = np.argmax(probs, axis=1)
    cand_el = [ch.elevations[rows], np.nan_to_num(cr.elevations), np.nan_to_num(fp.elevations),
               np.nan_to_num(ft.elevations), np.nan_to_num(sb_el)]
    cand_px = [px_arc, cr.pixels, fp.pixels, ft.pixels, sb_px]
    s_px = noise.sigma_pixel or 0.5
    s_r = np.full(rows.size, noise.sigma_range) if noise.sigma_range else sf.sigma_range[rows]
    s_a = np.full(rows.size, noise.sigma_azimuth) if noise.sigma_azimuth else sf.sigma_azimuth[rows]

    def place(src, at=slice(None)):
        """The chosen candidates' elevations, pixels, ML reconstruction (its cost) and points, rows ``at``."""
        r_, th_ = sf.ranges[rows][at], sf.azimuths[rows][at]
        el = np.choose(src, [c[at] for c in cand_el])
        p = np.choose(src[:, None], [np.nan_to_num(c[at]) for c in cand_px])
        ref = rc.refine(rig, p, r_, th_, sigma_pixel=float(s_px), sigma_range=float(np.median(s_r)),
                        sigma_azimuth=float(np.median(s_a)), max_iter=10)
        pts = np.where(ref.valid[:, None], ref.points, camera_from_sonar(rig, r_, th_, el))
        return el, p, np.nan_to_num(ref.cost, nan=0.0), pts

    el, px, chi2, P = place(source)
    score = probs[np.arange(rows.size), source]
    # the candidate models' choice, its probability and its reconstruction's cost (the trees' inputs)
    feats["candidate_source"], feats["candidate_score"] = source, score
    feats["candidate_epipolar_chi2"] = chi2.copy()  # (chi2 is updated in place below where the trees move a match)
    p_tree = np.full(probs.shape, np.nan)
    if opt.rank_model and rank and not soft_beam and np.any(offered):
        # Gradient-boosted trees on all the match's evidence give each offered candidate P(right); the most
        # probable is the match, that probability its score (round i15v, :mod:`.ranking`), where they were
        # fitted: clear water (the plane offered), the thesis's beam, a fitted or exact seabed plane
        from .ranking import available, candidate_probabilities

        avail = available(feats)
        p_tree = candidate_probabilities(feats, avail)
        use = avail.any(axis=1)
        tree_src = np.argmax(np.nan_to_num(p_tree, nan=-1.0), axis=1)
        score = np.where(use, p_tree[np.arange(rows.size), tree_src], score)
        moved = np.nonzero(use & (tree_src != source))[0]
        if moved.size:  # only the matches whose candidate changed are placed again (the ML refine is per point)
            source = np.where(use, tree_src, source)
            el[moved], px[moved], chi2[moved], P[moved] = place(source[moved], moved)
    for k, name in enumerate(CANDIDATES):
        feats[f"tree_p_{name}"] = p_tree[:, k]
    feats["face_source"] = source
    feats["elevation"] = el
    feats["epipolar_chi2"] = chi2
    cf = CameraFeatures(px, np.full(rows.size, float(s_px)), ch.run_px[rows])
    order = np.argsort(-score, kind="stable")
    feats = {k: np.asarray(v)[order] for k, v in feats.items()}
    cam_idx = np.arange(rows.size)[order]
    return Matches(px[order], sf.ranges[rows[order]], sf.azimuths[rows[order]], P[order], score[order],
                   -np.log(np.maximum(score[order], 1e-12)), rows[order], cam_idx, sf, cf, seabed,
                   f"{rows.size} matches of {len(sf)} sonar features (arc search)", feats)

