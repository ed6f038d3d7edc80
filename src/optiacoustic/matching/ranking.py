"""Gradient-boosted trees that choose each match's candidate and score it (issue 15, round i15v).

Each sonar feature has up to five candidate pixels (:mod:`.match`: the arc search's pixel, the points
below the crease, on the face's plane, above the foot, on the seabed), each with its own logistic model.
Those models chose the most probable candidate, and its probability was the match's score, and so the
ranking. Each of them sees a dozen inputs through one linear logit, while the evidence acts jointly (a
plane point is worth more with many inlier creases *and* a short run; a foot agrees with a crease only on
faces that stand on the seabed...). Gradient-boosted decision trees (LightGBM) fitted to all of a match's
evidence at once, with the candidate and its own model's probability, give every offered candidate
P(its pixel is right); the most probable is the match, and that probability its score. On held-out
scenes precision at recall 0.5 rose from 0.887 to 0.904 with trees fitted on 96 flat and 48 relief training
pairs (round i15v), to 0.935 with five times the scenes (round i15w: 480 flat and 192 relief pairs, 400 trees
of 31 leaves), and to 0.948 with trees of 255 leaves (round i15x, 200 trees); the right matches from 1857 to
1980 of 2757 (docs/matching.md, "Gradient-boosted trees choose and score the candidates", "More training
scenes for the trees" and "Larger trees for five times the data").

The trees are fitted by :func:`optiacoustic.experiments.matching.calibrate_rank_model` (thesis water, the
training scenes of the candidate models, and random scenes on seabeds with 0.5-2 cm of relief, the fitted
plane's relief ratio among the inputs) and shipped in LightGBM's own text format, which its loader reads
across versions (:data:`MODEL_FILE`). They are applied where they were fitted: where the face-plane model
is offered (images of contrast ``MatchOptions.face_plane_min_contrast`` and more: clear water), on frames
with the thesis's hard elevation beam, with a seabed plane fitted to the image or given without a declared
error. Elsewhere the candidate models choose and score, as before. lightgbm is imported on first use only.
"""

from __future__ import annotations

import functools
import gzip
from pathlib import Path

import numpy as np

#: The evidence the trees see about a match, in the model's column order: every per-match input of the
#: candidate models (:mod:`.match`'s ``features``) that does not depend on the rig's layout (no pixel
#: coordinates, elevations or ranges), the five candidates' probabilities by their own models,
#: ``candidate_epipolar_chi2``, the maximum-likelihood reconstruction's cost of the candidate models' choice, and
#: ``seabed_relief_ratio``, the fitted seabed plane's residual in flat seabeds' (NaN for a given plane).
MATCH_FEATURES = (
    "arc_face_edge", "arc_foot_edge", "arc_score", "contact_dphi_deg", "contact_found", "crease_dphi_deg",
    "crease_face_edge", "crease_foot_edge", "crease_found", "crease_position", "crowding", "echo_depth_bins",
    "echo_end_bins", "elevation_span", "candidate_epipolar_chi2", "foot_crease_dphi_deg", "foot_dphi_deg",
    "foot_face_edge", "foot_foot_edge", "foot_found", "foot_gradient", "foot_height", "foot_in_run",
    "foot_plane_dphi_deg", "image_contrast", "kind", "p_arc", "p_crease", "p_foot", "p_plane", "p_seabed",
    "plane_crease_dphi_deg", "plane_dphi_deg", "plane_face_edge", "plane_fit_height", "plane_foot_edge",
    "plane_found", "plane_height", "plane_in_face", "plane_n_creases", "plane_n_inliers", "plane_own_residual",
    "plane_position", "plane_spread", "position", "run_px", "seabed_contrast", "seabed_dphi_deg", "seabed_found",
    "seabed_gradient", "seabed_in_run", "shadowed", "snr", "top_edge", "visible_px", "seabed_relief_ratio",
)
#: The candidates, in :data:`.match.CANDIDATES`' order (the ``candidate`` input is the index).
CANDIDATES = ("arc", "crease", "plane", "foot", "seabed")
#: One row per (match, offered candidate): the match's evidence, which candidate, and its own model's probability.
RANK_FEATURES = MATCH_FEATURES + ("candidate", "candidate_probability")

#: LightGBM's training parameters (binary log-loss), one thread and ``deterministic`` so that a refit gives the
#: shipped model. Chosen on the comparison protocol of earlier rounds (fitted without random 5024-5047 and varied
#: 8024-8047, compared on them). Round i15x: with round i15w's five-fold data the trees were too small; on the
#: comparison halves, 31 leaves (400 trees) gave 0.937 at recall 0.5, 63 leaves 0.953-0.954, 127 leaves 0.956-0.965,
#: 255 leaves 0.959-0.971 and 511-1023 leaves 0.967-0.969 (400-600 trees, 20-80 rows a leaf; docs/matching.md).
RANK_PARAMS = dict(objective="binary", learning_rate=0.05, num_leaves=255, min_data_in_leaf=40, lambda_l2=1.0,
                   max_bin=255, deterministic=True, force_col_wise=True, num_threads=1, seed=0, verbose=-1)
#: Boosting rounds (trees). Round i15x: 200 of 255 leaves, the smallest model at the comparison halves' level
#: (0.966 at 200, 300 and 400 trees; 2.5 MB compressed).
RANK_ROUNDS = 200

#: The shipped model: LightGBM's text format, gzip-compressed.
MODEL_FILE = Path(__file__).resolve().parent.parent / "data" / "match_candidate_trees.txt.gz"


def match_inputs(features: dict) -> np.ndarray:
    """The matches' evidence ``(N, len(MATCH_FEATURES))`` float64 from a match's per-match ``features`` (booleans
    as 0/1; NaN where a candidate does not exist, which the trees route as missing).

    Raises ``KeyError`` naming the first missing feature."""
    cols = []
    for name in MATCH_FEATURES:
        if name not in features:
            raise KeyError(f"match_inputs: the match features lack {name!r} (needed by the candidate trees)")
        cols.append(np.asarray(features[name], float).reshape(-1))
    return np.column_stack(cols)


def available(features: dict) -> np.ndarray:
    """Which candidates the trees score, ``(N, 5)`` bool in :data:`CANDIDATES`' order: those offered (their own
    model's probability ``p_<candidate>`` above 0, a finite pixel ``<candidate>_u``, ``_v``) on matches where the
    face-plane model is offered (``plane_offered``), as in the training (``experiments.matching.rank_training_data``)."""
    offered = np.asarray(features["plane_offered"], bool)[:, None]
    return offered & np.column_stack([(np.asarray(features[f"p_{k}"], float) > 0)
                                      & np.isfinite(np.asarray(features[f"{k}_u"], float))
                                      & np.isfinite(np.asarray(features[f"{k}_v"], float)) for k in CANDIDATES])


def candidate_rows(features: dict, available: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The trees' rows ``X`` ``(M, len(RANK_FEATURES))``, one per available candidate (``available`` bool ``(N, 5)``,
    columns in :data:`CANDIDATES`' order), with each row's match ``(M,)`` and candidate index ``(M,)``."""
    B = match_inputs(features)
    available = np.asarray(available, bool)
    if available.shape != (B.shape[0], len(CANDIDATES)):
        raise ValueError(f"candidate_rows: available must be ({B.shape[0]}, {len(CANDIDATES)}), got {available.shape}")
    row, cand = np.nonzero(available)
    p_own = np.column_stack([np.asarray(features[f"p_{k}"], float) for k in CANDIDATES])
    X = np.column_stack([B[row], cand.astype(float), p_own[row, cand]])
    return X, row, cand


class RankModelError(OSError, RuntimeError):
    """The candidate trees cannot be loaded: their file is unreadable or was fitted on other inputs, or lightgbm
    itself does not load (on Linux it needs the system's libgomp1). An ``OSError`` (the command line reports
    it in one line) and a ``RuntimeError``."""


@functools.lru_cache(maxsize=4)
def _booster(path: str):
    fix = "or match with MatchOptions(rank_model=False) (the candidate models alone)"
    try:
        import lightgbm as lgb
    except (ImportError, OSError) as e:  # e.g. "libgomp.so.1: cannot open shared object file"
        raise RankModelError(0, f"lightgbm, which runs the matcher's candidate trees, does not load ({e}); on "
                                f"Debian and Ubuntu install libgomp1, {fix}", path) from e
    try:
        text = gzip.decompress(Path(path).read_bytes()).decode("ascii")
        booster = lgb.Booster(model_str=text)
    except (OSError, EOFError, UnicodeDecodeError, lgb.basic.LightGBMError) as e:
        raise RankModelError(0, f"cannot read the ranking model: {e}; reinstall optiacoustic, {fix}", path) from e
    names = tuple(booster.feature_name())
    if names != RANK_FEATURES:
        raise RankModelError(0, f"the ranking model was fitted on features {names[:3]}... ({len(names)}), not "
                                f"RANK_FEATURES ({len(RANK_FEATURES)}): refit it "
                                f"(experiments.matching.calibrate_rank_model), {fix}", path)
    return booster


def candidate_probabilities(features: dict, available: np.ndarray, model_file: Path | str | None = None) -> np.ndarray:
    """P(the candidate's pixel is right) by the trees of ``model_file`` (default :data:`MODEL_FILE`, the shipped
    ones), ``(N, 5)`` (:data:`CANDIDATES`' order), NaN where a candidate is not ``available``. Raises
    :class:`RankModelError` when the trees cannot be loaded."""
    X, row, cand = candidate_rows(features, available)
    out = np.full(np.shape(available), np.nan)
    if X.shape[0]:
        booster = _booster(str(MODEL_FILE if model_file is None else model_file))
        out[row, cand] = np.asarray(booster.predict(X, num_threads=1), float)
    return out


def fit_rank_model(X: np.ndarray, y: np.ndarray) -> str:
    """LightGBM's text of trees fitted to rows ``X`` ``(M, len(RANK_FEATURES))`` (:func:`candidate_rows`) and
    labels ``y`` ``(M,)`` (1: that candidate's pixel is right) with :data:`RANK_PARAMS` and :data:`RANK_ROUNDS`."""
    import lightgbm as lgb

    X = np.asarray(X, float)
    y = np.asarray(y, float).reshape(-1)
    if X.ndim != 2 or X.shape[1] != len(RANK_FEATURES) or X.shape[0] != y.size:
        raise ValueError(f"fit_rank_model: X must be (N, {len(RANK_FEATURES)}) and y (N,), got {X.shape} "
                         f"and {y.shape}")
    data = lgb.Dataset(X, y, feature_name=list(RANK_FEATURES), free_raw_data=False)
    return lgb.train(dict(RANK_PARAMS), data, num_boost_round=RANK_ROUNDS).model_to_string()


def write_model(text: str, path: Path | str = MODEL_FILE) -> Path:
    """Write a model's text (:func:`fit_rank_model`) gzip-compressed (``mtime=0``: the same bytes for the
    same model) to ``path``; returns it."""
    path = Path(path)
    path.write_bytes(gzip.compress(text.encode("ascii"), mtime=0))
    _booster.cache_clear()
    return path
