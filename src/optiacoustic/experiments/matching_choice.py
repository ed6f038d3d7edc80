"""Choosing among a sonar feature's candidate pixels with a model trained to choose (measured, not kept).

The one-view matcher (:mod:`optiacoustic.matching.match`) offers up to four candidate pixels per
sonar feature (the arc search's run pixel, the point below the crease, the point on the face's
plane, the point above the foot), scores each by its own logistic model and keeps the most probable
one. This module measures the alternative the matching page calls "Choosing among candidates
(round i15g)": a conditional logit (a softmax over the candidates of one feature) fitted to pick
the right candidate, and a logistic recalibration of the chosen pixel's probability. It is an
evaluation tool: the matcher does not use it (on the protocol's comparison scenes it did not beat
the most-probable rule; ``docs/matching.md``). Labels come from the simulators' depth maps, never
from the matcher's own output.

Inputs per candidate (:func:`choice_inputs`, ``variant="full"``): its own calibrated
probability's logit; which candidate it is (three indicators, the arc pixel the reference) and
the logit times each indicator; how many other candidates of the feature lie within 0.5 deg of it
in elevation, log of 1 + its elevation distance to the nearest other one (units of 0.25 deg) and
log of 1 + its pixel distance to the nearest other one (units of 2 px); for each non-arc kind, log
of 1 + the bins to the echo's end and from its start, and its signed elevation offset from the
arc pixel (deg, clipped to +-3). ``variant="plain"`` keeps the first seven (probability, kind,
kind times probability).
"""

from __future__ import annotations

import numpy as np

#: The candidates in ``features["face_source"]`` order (as :data:`optiacoustic.matching.match.CANDIDATES`).
CANDIDATES = ("arc", "crease", "plane", "foot")


def _logit(p):
    p = np.clip(np.asarray(p, float), 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


def candidate_table(feats: dict):
    """The candidates of each match: probabilities, elevations (deg), pixels and availability.

    Returns ``P`` ``(N, 4)``, ``E`` ``(N, 4)``, ``U`` ``(N, 4, 2)`` (camera pixels u, v) and ``A``
    ``(N, 4)`` (bool), in :data:`CANDIDATES` order.

    ``feats`` is a one-view :attr:`optiacoustic.matching.Matches.features` mapping. The arc
    search's pixel is always available; the others where their search found one (finite pixel and
    elevation, probability > 0).
    """
    P = np.column_stack([feats[f"p_{n}"] for n in CANDIDATES]).astype(float)
    E = np.rad2deg(np.column_stack([feats[f"{n}_elevation"] for n in CANDIDATES]).astype(float))
    U = np.stack([np.column_stack([feats[f"{n}_u"], feats[f"{n}_v"]]) for n in CANDIDATES], 1).astype(float)
    A = np.isfinite(E) & np.all(np.isfinite(U), -1) & (P > 0)
    A[:, 0] = True
    return P, E, U, A


def choice_inputs(feats: dict, *, variant: str = "full"):
    """Per-candidate inputs of the choice model: ``X`` ``(N, 4, d)`` (zero where unavailable) and available ``(N, 4)``.

    ``variant``: ``"full"`` (d = 19) or ``"plain"`` (d = 7); see the module's docstring.
    """
    if variant not in ("full", "plain"):
        raise ValueError(f"choice_inputs: variant {variant!r}: expected 'full' or 'plain'")
    P, E, U, A = candidate_table(feats)
    n = len(P)
    T = np.zeros((n, 4, 3))
    T[:, 1, 0] = T[:, 2, 1] = T[:, 3, 2] = 1.0
    lp = _logit(P)
    cols = [lp[..., None], T, T * lp[..., None]]
    if variant == "full":
        Ez = np.where(A, E, np.nan)
        dE = np.abs(Ez[:, :, None] - Ez[:, None, :])
        dU = np.linalg.norm(U[:, :, None, :] - U[:, None, :, :], axis=-1)
        both = A[:, :, None] & A[:, None, :]
        eye = np.eye(4, dtype=bool)[None]
        dE = np.where(both & ~eye, dE, np.inf)
        dU = np.where(both & ~eye, dU, np.inf)
        n_agree = np.sum(dE < 0.5, axis=2).astype(float)
        min_e, min_u = dE.min(axis=2), dU.min(axis=2)
        has = np.isfinite(min_e)
        min_e, min_u = np.where(has, min_e, 0.0), np.where(has, min_u, 0.0)
        end = np.log1p(np.asarray(feats["echo_end_bins"], float))[:, None, None]
        dep = np.log1p(np.asarray(feats["echo_depth_bins"], float))[:, None, None]
        offset = np.clip(np.nan_to_num(E - E[:, :1]), -3.0, 3.0)
        cols += [n_agree[..., None], np.log1p(min_e / 0.25)[..., None], np.log1p(min_u / 2.0)[..., None],
                 T * end, T * dep, T * offset[..., None]]
    X = np.concatenate(cols, axis=-1)
    return np.where(A[..., None], X, 0.0), A


def fit_conditional_logit(X, available, right, *, ridge: float = 1.0) -> dict:
    """Conditional logit (softmax over a feature's candidates) fitted to choose a right one.

    Maximises ``sum_i log sum_{k right} softmax_k(w . z_ik)`` over the features with at least two
    available candidates and at least one right one, ``z`` the inputs standardised over the
    available candidates, minus ``ridge * |w|^2`` (``scipy.optimize.minimize``, BFGS, analytic
    gradient). There is no intercept: a softmax is blind to anything common to all candidates.

    Parameters
    ----------
    X : (N, K, d) array
    available, right : (N, K) bool arrays
        Which candidates exist; which are right (depth-map truth).

    Returns
    -------
    dict
        ``weights`` (d,), ``mean``, ``std`` (d,), ``n`` (features used).
    """
    from scipy.optimize import minimize

    X = np.asarray(X, float)
    A = np.asarray(available, bool)
    Y = np.asarray(right, bool) & A
    use = Y.any(1) & (A.sum(1) >= 2)
    if not use.any():
        raise ValueError("fit_conditional_logit: no feature has two candidates and a right one")
    X, A, Y = X[use], A[use], Y[use]
    flat = X[A]
    mu, sd = flat.mean(0), flat.std(0)
    sd = np.where(sd > 0, sd, 1.0)
    Z = np.where(A[..., None], (X - mu) / sd, 0.0)

    def nll(w):
        z = Z @ w
        za, zy = np.where(A, z, -np.inf), np.where(Y, z, -np.inf)
        la, ly = np.logaddexp.reduce(za, axis=1), np.logaddexp.reduce(zy, axis=1)
        qa, qy = np.exp(za - la[:, None]), np.exp(zy - ly[:, None])
        return -(ly - la).sum() + ridge * (w @ w), -np.einsum("nk,nkd->d", qy - qa, Z) + 2 * ridge * w

    w = minimize(nll, np.zeros(Z.shape[-1]), jac=True, method="BFGS").x
    return dict(weights=tuple(np.round(w, 3)), mean=tuple(np.round(mu, 4)), std=tuple(np.round(sd, 4)),
                n=int(use.sum()))


def choice_probabilities(model: dict, X, available) -> np.ndarray:
    """The softmax over each feature's available candidates ``(N, K)`` (0 where unavailable)."""
    A = np.asarray(available, bool)
    z = ((np.asarray(X, float) - np.asarray(model["mean"])) / np.asarray(model["std"])) @ np.asarray(model["weights"])
    z = np.where(A, z, -np.inf)
    e = np.exp(z - z.max(axis=1, keepdims=True))
    return e / e.sum(axis=1, keepdims=True)


def chosen_score_inputs(P, A, Q, source) -> np.ndarray:
    """Inputs of the chosen pixel's recalibration ``(N, 7)``: its own probability's logit, its softmax share's
    logit, its kind (three indicators), the number of candidates, the logit of the best candidate's probability."""
    i = np.arange(len(source))
    T = np.zeros((len(source), 3))
    T[source > 0, source[source > 0] - 1] = 1.0
    return np.column_stack([_logit(P[i, source]), _logit(Q[i, source]), T, A.sum(1), _logit(P.max(1))])


def _logistic(model, X):
    w = np.asarray(model["weights"], float)
    return 1.0 / (1.0 + np.exp(-(w[0] + ((X - np.asarray(model["mean"])) / np.asarray(model["std"])) @ w[1:])))


def candidate_records(scenes):
    """Run the one-view matcher on ``scenes`` and label every candidate by the depth map (evaluation only).

    ``scenes``: iterable of ``(sonar, optical, rig)``; the matcher's candidate trees off (``MatchOptions(
    rank_model=False)``): the candidate models choose. Returns one dict per scene: ``features``
    (the matches' feature mapping, ``{}`` when none), ``right`` ``(N, 4)`` (each candidate right),
    ``ok`` and ``score`` (the matcher's chosen pixel), ``n_visible`` (the recall's denominator,
    :func:`optiacoustic.matching.truth.visible`).
    """
    from ..matching import MatchOptions, match, truth

    recs = []
    # the candidate models' own choice: the rules compared here are rules over their probabilities (the trees
    # of matching.ranking, round i15v, choose otherwise and are off)
    opts = MatchOptions(rank_model=False)
    for sonar, optical, rig in scenes:
        m = match(sonar, optical.image, rig, min_score=0.0, options=opts)
        bw, aw = float(np.median(np.diff(sonar.ranges))), float(np.median(np.diff(sonar.azimuths)))
        sf = m.sonar_features
        nv = int(truth.visible(rig, optical.depth, sf.ranges, sf.azimuths, bin_width=bw, beam_width=aw).sum()) \
            if sf is not None and len(sf) else 0
        rec = dict(n_visible=nv, features={}, right=np.zeros((0, 4), bool), ok=np.zeros(0, bool), score=np.zeros(0))
        if m:
            f = {k: np.asarray(v) for k, v in m.features.items()}
            right = np.zeros((len(m), 4), bool)
            for k, nm in enumerate(CANDIDATES):
                px = np.column_stack([f[f"{nm}_u"], f[f"{nm}_v"]])
                fin = np.all(np.isfinite(px), 1)
                if fin.any():
                    right[fin, k] = truth.correct(rig, optical.depth, px[fin], m.ranges[fin], m.azimuths[fin],
                                                  bin_width=bw, beam_width=aw)
            rec.update(features=f, right=right, score=np.asarray(m.score, float),
                       ok=truth.correct(rig, optical.depth, m.pixels, m.ranges, m.azimuths, bin_width=bw,
                                        beam_width=aw))
        recs.append(rec)
    return recs


def _stack(recs, variant):
    Xs, As, Ps, Ys, ok, sc = [], [], [], [], [], []
    for r in recs:
        if not r["features"]:
            continue
        X, A = choice_inputs(r["features"], variant=variant)
        Xs.append(X)
        As.append(A)
        Ps.append(candidate_table(r["features"])[0])
        Ys.append(np.asarray(r["right"], bool) & A)
        ok.append(np.asarray(r["ok"], bool))
        sc.append(np.asarray(r["score"], float))
    d = X.shape[-1] if Xs else (19 if variant == "full" else 7)
    cat = (lambda a, shape: np.concatenate(a) if a else np.zeros(shape))
    return dict(X=cat(Xs, (0, 4, d)), A=cat(As, (0, 4)).astype(bool), P=cat(Ps, (0, 4)), Y=cat(Ys, (0, 4)).astype(bool),
                ok=cat(ok, (0,)).astype(bool), score=cat(sc, (0,)), n_visible=sum(r["n_visible"] for r in recs))


def calibrate_choice(records, *, variant: str = "full", ridge: float = 1.0) -> dict:
    """Fit the choice (:func:`fit_conditional_logit`) and the chosen pixel's recalibration on training ``records``.

    ``records`` from :func:`candidate_records` on training scenes only. The recalibration is a
    ridge logistic regression (``experiments.matching._fit_logistic``) of whether the chosen
    candidate is right on :func:`chosen_score_inputs`.

    Returns
    -------
    dict
        ``choice`` (:func:`fit_conditional_logit`'s model), ``score`` (logistic model), ``variant``.
    """
    from .matching import _fit_logistic

    D = _stack(records, variant)
    choice = fit_conditional_logit(D["X"], D["A"], D["Y"], ridge=ridge)
    Q = choice_probabilities(choice, D["X"], D["A"])
    src = Q.argmax(1)
    ok = D["Y"][np.arange(len(src)), src]
    score = _fit_logistic(chosen_score_inputs(D["P"], D["A"], Q, src), ok.astype(float), ridge)
    return dict(choice=choice, score=score, variant=variant)


def _pr_figures(score, ok, n_visible) -> dict:
    from .matching import score_auc

    out = dict(p_at_recall_0_25=float("nan"), p_at_recall_0_5=float("nan"), precision_all=float("nan"),
               recall_all=float("nan"), auc=float("nan"), correct=int(np.sum(ok)), n=int(len(ok)))
    if len(ok) == 0 or n_visible == 0:
        return out
    order = np.argsort(-score, kind="stable")
    tp = np.cumsum(ok[order])
    prec, rec = tp / np.arange(1, len(ok) + 1), tp / n_visible
    for key, t in (("p_at_recall_0_25", 0.25), ("p_at_recall_0_5", 0.5)):
        if np.any(rec >= t):
            out[key] = float(np.max(prec[rec >= t]))
    out["precision_all"], out["recall_all"] = float(ok.mean()), float(ok.sum() / n_visible)
    out["auc"] = score_auc(score, ok)
    return out


def compare_choice(models: dict, records) -> dict:
    """The most-probable rule against the fitted choice on ``records`` (depth-map labels).

    Returns
    -------
    dict
        ``max_probability`` and ``choice``: precision at recall 0.25 and 0.5 (the best over score
        thresholds), all matches' precision and recall, AUC, correct, n; ``oracle``: the same with
        a right candidate chosen wherever one exists (scored by the best candidate's probability);
        ``contested`` (features with a right and a wrong candidate) and how many of them each rule
        gets right (``contested_right_max_probability``, ``contested_right_choice``), ``switched`` (features where
        the two rules differ) with ``switched_right_before`` / ``_after``; and ``pair_auc_own`` /
        ``pair_auc_choice``: over a contested feature's (right, wrong) candidate pairs, how often
        the right one ranks higher by its own probability / by the choice's softmax.
    """
    D = _stack(records, models["variant"])
    i = np.arange(len(D["P"]))
    Q = choice_probabilities(models["choice"], D["X"], D["A"])
    src = Q.argmax(1)
    src0 = D["P"].argmax(1)
    ok1 = D["Y"][i, src]
    s1 = _logistic(models["score"], chosen_score_inputs(D["P"], D["A"], Q, src))
    A, Y = D["A"], D["Y"]
    contested = Y.any(1) & (~Y & A).any(1)

    def pair_auc(S):
        d = S[:, :, None] - S[:, None, :]  # (right k) - (wrong l)
        pair = (Y & A)[:, :, None] & (~Y & A)[:, None, :] & contested[:, None, None]
        return float(((d > 0) + 0.5 * (d == 0))[pair].mean()) if pair.any() else float("nan")

    sw = src != src0
    return dict(contested_right_max_probability=int(Y[i, src0][contested].sum()),
                contested_right_choice=int(ok1[contested].sum()),
                max_probability=_pr_figures(D["score"], D["ok"], D["n_visible"]),
                choice=_pr_figures(s1, ok1, D["n_visible"]),
                oracle=_pr_figures(D["P"].max(1), Y.any(1), D["n_visible"]),
                contested=int(contested.sum()), switched=int(sw.sum()),
                switched_right_before=int(Y[i, src0][sw].sum()), switched_right_after=int(ok1[sw].sum()),
                pair_auc_own=pair_auc(D["P"]), pair_auc_choice=pair_auc(Q))
