"""The candidate-choice study (experiments.matching_choice): the conditional logit and its inputs.

Truths: a conditional logit recovers the weights that generated seeded choices (Monte Carlo, with
bounds from the sample size); the agreement inputs against hand-computed distances; on a
simulated scene, identities between the rules (the oracle is an upper bound; a choice model that
only sees each candidate's own probability is the most-probable rule).
"""

import numpy as np
import pytest

from optiacoustic.experiments.matching_choice import (CANDIDATES, candidate_records, choice_inputs,
                                                      choice_probabilities, compare_choice, fit_conditional_logit)


def test_conditional_logit_recovers_the_generating_weights():
    rng = np.random.default_rng(15)
    n, k, w_true = 4000, 4, np.array([1.5, -1.0, 0.5])
    X = rng.normal(size=(n, k, 3)) * np.array([1.0, 2.0, 0.5]) + np.array([0.3, -1.0, 2.0])
    A = rng.random((n, k)) < 0.7
    A[:, 0] = True
    u = np.where(A, X @ w_true, -np.inf)
    q = np.exp(u - u.max(1, keepdims=True))
    q /= q.sum(1, keepdims=True)
    pick = (q.cumsum(1) > rng.random((n, 1))).argmax(1)
    Y = np.zeros((n, k), bool)
    Y[np.arange(n), pick] = True
    m = fit_conditional_logit(X, A, Y, ridge=0.01)
    w = np.asarray(m["weights"]) / np.asarray(m["std"])  # back to the inputs' own units
    # About 3000 informative choices: over 20 seeds the estimates scatter by 0.03-0.06 (sd) around
    # the true weights (largest error 0.12); 0.25 is four or more of those and far below the weights.
    assert np.all(np.abs(w - w_true) < 0.25), w
    assert m["n"] == int(np.sum(A.sum(1) >= 2))
    # The fitted softmax puts the most mass on the candidate with the highest true utility more
    # often than chance (1 in 2-4) would.
    Q = choice_probabilities(m, X, A)
    assert np.all(Q[~A] == 0) and np.allclose(Q.sum(1), 1)
    assert np.mean(Q.argmax(1) == np.argmax(u, 1)) > 0.9


def test_conditional_logit_needs_a_contested_feature():
    X = np.zeros((3, 4, 2))
    A = np.zeros((3, 4), bool)
    A[:, 0] = True
    with pytest.raises(ValueError, match="two candidates"):
        fit_conditional_logit(X, A, A)


def _feats(elev_deg, pixels, probs):
    f = dict(echo_end_bins=np.array([4.0, 0.0]), echo_depth_bins=np.array([2.0, 9.0]))
    for j, nm in enumerate(CANDIDATES):
        f[f"{nm}_elevation"] = np.deg2rad(elev_deg[:, j])
        f[f"{nm}_u"], f[f"{nm}_v"] = pixels[:, j, 0], pixels[:, j, 1]
        f[f"p_{nm}"] = probs[:, j]
    return f


def test_choice_inputs_agreement_by_hand():
    nan = np.nan
    elev = np.array([[1.0, 1.3, nan, 3.0], [2.0, nan, nan, nan]])
    px = np.array([[[100, 200], [100, 196], [nan, nan], [100, 170]], [[50, 50], [nan, nan], [nan, nan], [nan, nan]]])
    probs = np.array([[0.6, 0.5, 0.0, 0.3], [0.4, 0.0, 0.0, 0.0]])
    X, A = choice_inputs(_feats(elev, px, probs))
    assert A.tolist() == [[True, True, False, True], [True, False, False, False]]
    assert X.shape == (2, 4, 19) and np.all(X[~A] == 0)
    np.testing.assert_allclose(X[0, [0, 1, 3], 0], np.log(probs[0, [0, 1, 3]] / (1 - probs[0, [0, 1, 3]])))
    # Agreement within 0.5 deg: the arc and crease points agree (0.3 deg), the foot point agrees with none.
    np.testing.assert_allclose(X[0, [0, 1, 3], 7], [1, 1, 0])
    np.testing.assert_allclose(X[0, [0, 1, 3], 8], np.log1p(np.array([0.3, 0.3, 1.7]) / 0.25))
    np.testing.assert_allclose(X[0, [0, 1, 3], 9], np.log1p(np.array([4.0, 4.0, 26.0]) / 2.0))
    # The echo's extent only on the non-arc candidates of its own kind; the foot's offset from the arc.
    np.testing.assert_allclose(X[0, 3, 10:13], [0, 0, np.log1p(4.0)])
    np.testing.assert_allclose(X[0, 3, 16:19], [0, 0, 2.0])
    # A match with the arc pixel alone has nothing to agree with.
    np.testing.assert_allclose(X[1, 0], [np.log(0.4 / 0.6)] + [0] * 18)
    with pytest.raises(ValueError, match="variant"):
        choice_inputs(_feats(elev, px, probs), variant="nope")


def test_choice_rules_on_a_simulated_scene():
    from optiacoustic.experiments.matching import random_scene, simulate_pair

    recs = candidate_records([simulate_pair(random_scene(201), "thesis", "default", 201)])
    r = recs[0]
    assert r["features"] and r["right"].shape == (len(r["ok"]), 4) and r["n_visible"] > 0
    # A choice that sees only each candidate's own probability (weight 1 on its logit) is the
    # most-probable rule: it switches nothing and gets the same matches right.
    own = dict(variant="plain", choice=dict(weights=(1.0,) + (0.0,) * 6, mean=(0.0,) * 7, std=(1.0,) * 7),
               score=dict(weights=(0.0, 1.0) + (0.0,) * 6, mean=(0.0,) * 7, std=(1.0,) * 7))
    c = compare_choice(own, recs)
    assert c["switched"] == 0
    assert c["choice"]["correct"] == c["max_probability"]["correct"] == int(r["ok"].sum())
    # Choosing a right candidate wherever there is one is an upper bound of every rule.
    assert c["oracle"]["correct"] == int(r["right"].any(1).sum()) >= c["max_probability"]["correct"]
    assert c["contested_right_max_probability"] <= c["contested"]
    for rule in ("max_probability", "choice", "oracle"):
        assert 0 <= c[rule]["precision_all"] <= 1 and 0 <= c[rule]["recall_all"] <= 1
