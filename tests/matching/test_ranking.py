"""The candidate trees (round i15v, :mod:`optiacoustic.matching.ranking`): what they read, what they change, and
what they are worth on scenes never used to fit them.

Truths: the depth maps of seeded scenes outside the training seeds (the trees were fitted on random 5000-5047,
varied 8000-8047 and random 5000-5015 on seabeds with relief), the matcher with the trees off, and the calibration
function that made the shipped model.
"""

import os
import warnings

import numpy as np
import pytest

from optiacoustic.experiments.matching import random_scene, simulate_pair
from optiacoustic.matching import MatchOptions, match, truth
from optiacoustic.matching import ranking
from optiacoustic.matching.match import CANDIDATES


def _verdicts(m, s, o, rig):
    bw, aw = float(np.median(np.diff(s.ranges))), float(np.median(np.diff(s.azimuths)))
    return truth.correct(rig, o.depth, m.pixels, m.ranges, m.azimuths, bin_width=bw, beam_width=aw)


@pytest.fixture(scope="module")
def unseen():
    """Seeded random scenes 211-216 (thesis water), matched with the trees on and off, with the depth maps'
    verdicts on the chosen pixels."""
    out = []
    for sd in range(211, 217):
        s, o, rig = simulate_pair(random_scene(sd), "thesis", "default", sd)
        on = match(s, o.image, rig, min_score=0.0)
        off = match(s, o.image, rig, min_score=0.0, options=MatchOptions(rank_model=False))
        out.append((on, off, _verdicts(on, s, o, rig), _verdicts(off, s, o, rig)))
    return out


def test_inputs_are_the_named_evidence_in_order(unseen):
    on = unseen[0][0]
    assert ranking.CANDIDATES == CANDIDATES
    B = ranking.match_inputs(on.features)
    assert B.shape == (len(on), len(ranking.MATCH_FEATURES))
    for k, name in enumerate(ranking.MATCH_FEATURES):
        np.testing.assert_array_equal(B[:, k], np.asarray(on.features[name], float))
    # Nothing that depends on where the rig puts things: no pixel coordinates, elevations or ranges.
    assert not [n for n in ranking.RANK_FEATURES if n.endswith(("_u", "_v", "elevation")) or n == "range_m"]
    # One row per available candidate: the match's evidence, the candidate's index and its own probability.
    avail = np.zeros((len(on), 5), bool)
    avail[0, [0, 2]] = True
    avail[1, 4] = True
    X, row, cand = ranking.candidate_rows(on.features, avail)
    assert X.shape == (3, len(ranking.RANK_FEATURES))
    np.testing.assert_array_equal(row, [0, 0, 1])
    np.testing.assert_array_equal(cand, [0, 2, 4])
    np.testing.assert_array_equal(X[:, :-2], B[row])
    np.testing.assert_array_equal(X[:, -2], cand)
    np.testing.assert_array_equal(X[:, -1], [on.features["p_arc"][0], on.features["p_plane"][0],
                                             on.features["p_seabed"][1]])
    f = dict(on.features)
    del f["plane_n_inliers"]
    with pytest.raises(KeyError, match="plane_n_inliers"):
        ranking.match_inputs(f)
    with pytest.raises(ValueError, match="available must be"):
        ranking.candidate_rows(on.features, avail[:, :3])


def test_the_trees_choose_among_the_offered_candidates(unseen):
    """Every match's pixel is one of its offered candidates: the one the trees give the highest probability,
    which is its score. The candidate models' choice and probability are kept and equal the matcher's with the
    trees off, sonar feature for sonar feature."""
    changed = n = 0
    for on, off, _, _ in unseen:
        assert len(on) == len(off) > 0
        f = on.features
        q = np.column_stack([f[f"tree_p_{k}"] for k in CANDIDATES])
        offered = np.isfinite(q)
        assert np.all(offered.any(axis=1))
        assert np.all(offered <= (np.column_stack([f[f"p_{k}"] for k in CANDIDATES]) > 0))
        src = np.asarray(f["face_source"])
        np.testing.assert_array_equal(src, np.argmax(np.nan_to_num(q, nan=-1.0), axis=1))
        np.testing.assert_allclose(on.score, q[np.arange(len(on)), src])
        assert np.all((on.score > 0) & (on.score < 1)) and np.all(np.diff(on.score) <= 0)
        for k, name in enumerate(CANDIDATES):
            s = src == k
            np.testing.assert_allclose(on.pixels[s], np.column_stack([f[f"{name}_u"], f[f"{name}_v"]])[s])
        a, b = np.argsort(on.sonar_index), np.argsort(off.sonar_index)
        np.testing.assert_array_equal(on.sonar_index[a], off.sonar_index[b])
        np.testing.assert_array_equal(f["candidate_score"][a], off.score[b])
        np.testing.assert_array_equal(f["candidate_source"][a], off.features["face_source"][b])
        changed += int(np.sum(src[a] != f["candidate_source"][a]))
        n += len(on)
    assert 0 < changed < 0.5 * n  # they overrule the candidate models on some matches, not most


def test_trees_score_is_calibrated_and_ranks_on_unseen_scenes(unseen):
    """The trees' score is a probability: its mean matches the fraction the depth maps call right, within three
    sampling sds of that fraction plus 0.08 (the candidate models' test, tests/matching/test_face_models.py), and
    the right matches score higher than the wrong ones. And they choose no worse than the candidate models on
    these scenes: at least as many right matches, less 3 (the difference's sampling spread here)."""
    p = np.concatenate([on.score for on, _, _, _ in unseen])
    ok = np.concatenate([ok for _, _, ok, _ in unseen])
    ok_off = np.concatenate([ok for _, _, _, ok in unseen])
    assert p.size >= 100
    sd_rate = np.sqrt(np.sum(p * (1 - p))) / p.size
    print(f"mean score {p.mean():.3f}, fraction right {ok.mean():.3f} ({p.size} matches); right with the trees "
          f"{ok.sum()}, without {ok_off.sum()}")
    assert abs(p.mean() - ok.mean()) <= 3 * sd_rate + 0.08
    assert p[ok].mean() > p[~ok].mean() + 0.1
    assert ok.sum() >= ok_off.sum() - 3


def test_turbid_water_keeps_the_candidate_models():
    """Where the face-plane model is not offered (image contrast under 0.65: Jerlov 1C) the trees, fitted in clear
    water, are not applied: the candidate models choose and score."""
    s, o, rig = simulate_pair(random_scene(212), "jerlov-1C", "default", 212)
    m = match(s, o.image, rig, min_score=0.0)
    assert m and not np.any(m.features["plane_offered"])
    np.testing.assert_array_equal(m.score, m.features["candidate_score"])
    np.testing.assert_array_equal(m.features["face_source"], m.features["candidate_source"])


def test_relief_is_an_input_and_declared_plane_errors_keep_the_candidate_models(tmp_path):
    """The trees were fitted on flat seabeds and on seabeds with 0.5-2 cm of relief, with the fitted plane's relief
    ratio among their inputs: where the fit warns of relief they still choose and score, and see that ratio (NaN for
    a plane given from outside). Where the plane comes with a declared error the candidate models choose and score;
    with the exact plane from the pose the trees apply."""
    from optiacoustic.experiments.matching import _rig_for, relief_scene
    from optiacoustic.matching import SeabedPlane, SeabedReliefWarning
    from optiacoustic.matching.match import RELIEF_RATIO_WARN

    sc = relief_scene(6001, 0.02, tmp_path)
    s, o, rig = simulate_pair(sc, "thesis", "default", 6001)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = match(s, o.image, rig, min_score=0.0)
    assert any(issubclass(w.category, SeabedReliefWarning) for w in caught)
    assert m and np.any(m.features["plane_offered"])
    ratio = m.features["seabed_relief_ratio"]
    assert np.all(ratio == ratio[0]) and ratio[0] > RELIEF_RATIO_WARN and ratio[0] == m.seabed.relief_ratio
    assert np.any(np.abs(m.score - m.features["candidate_score"]) > 1e-6)

    flat = random_scene(213)
    s, o, rig = simulate_pair(flat, "thesis", "default", 213)
    _, pose = _rig_for(flat.view.eye, flat.view.target)
    declared = match(s, o.image, rig, min_score=0.0, seabed=SeabedPlane.from_pose(pose, sigma_height=0.01))
    np.testing.assert_array_equal(declared.score, declared.features["candidate_score"])
    exact = match(s, o.image, rig, min_score=0.0, seabed=SeabedPlane.from_pose(pose))
    assert np.all(np.isnan(exact.features["seabed_relief_ratio"]))
    assert np.any(np.abs(exact.score - exact.features["candidate_score"]) > 1e-6)


def test_model_file_and_fit_inputs_are_checked(tmp_path):
    with pytest.raises(ValueError, match=rf"X must be \(N, {len(ranking.RANK_FEATURES)}\)"):
        ranking.fit_rank_model(np.zeros((5, 3)), np.zeros(5))
    bad = tmp_path / "bad.txt.gz"
    bad.write_bytes(b"not gzip")
    feats = {n: np.zeros(2) for n in ranking.MATCH_FEATURES}
    feats.update({f"p_{k}": np.full(2, 0.5) for k in CANDIDATES})
    with pytest.raises(RuntimeError, match="cannot read the ranking model"):
        ranking.candidate_probabilities(feats, np.ones((2, 5), bool), bad)
    # nothing available: NaN everywhere, and the model is not read
    assert np.all(np.isnan(ranking.candidate_probabilities(feats, np.zeros((2, 5), bool), bad)))


@pytest.mark.skipif(os.environ.get("OAS_CALIBRATION_TESTS") != "1",
                    reason="refits the trees on the 672 training pairs (about 6 min); set OAS_CALIBRATION_TESTS=1")
def test_shipped_model_comes_from_calibrate_rank_model(tmp_path):
    """A refit (:func:`calibrate_rank_model`, deterministic LightGBM on one thread) predicts what the shipped
    model predicts, on its own training rows."""
    from optiacoustic.experiments.matching import rank_training_data
    from optiacoustic.matching.ranking import fit_rank_model, write_model

    X, y, _ = rank_training_data()
    path = write_model(fit_rank_model(X, y), tmp_path / "refit.txt.gz")
    refit = ranking._booster(str(path)).predict(X, num_threads=1)
    shipped = ranking._booster(str(ranking.MODEL_FILE)).predict(X, num_threads=1)
    np.testing.assert_allclose(refit, shipped, atol=1e-9)


def test_unloadable_trees_are_a_clear_error_in_the_library_and_the_cli(tmp_path, monkeypatch):
    """A broken model file, or a lightgbm that does not load (no libgomp1), is a ``RankModelError`` (an
    ``OSError``) that names the file and the way out, and ``oas match`` says so in one line (exit 2), no
    traceback."""
    import sys

    from typer.testing import CliRunner

    from optiacoustic.cli import app

    s, o, rig = simulate_pair(random_scene(211), "thesis", "default", 211)
    bad = tmp_path / "trees.txt.gz"
    bad.write_bytes(b"\x1f\x8b truncated")
    monkeypatch.setattr(ranking, "MODEL_FILE", bad)
    ranking._booster.cache_clear()
    with pytest.raises(ranking.RankModelError, match="cannot read the ranking model.*rank_model=False") as err:
        match(s, o.image, rig, min_score=0.0)
    assert isinstance(err.value, OSError) and err.value.filename == str(bad)
    # the candidate models alone still match
    assert match(s, o.image, rig, min_score=0.0, options=MatchOptions(rank_model=False))

    rig_yaml = ranking.Path(__file__).resolve().parents[2] / "examples" / "rig_thesis.yaml"
    pair = tmp_path / "pair"
    runner = CliRunner()
    assert runner.invoke(app, ["render", "thesis_scene1", "--rig", str(rig_yaml), "--out", str(pair)]).exit_code == 0
    r = runner.invoke(app, ["match", str(pair), "--out", str(tmp_path / "m")])
    assert r.exit_code == 2 and "cannot read the ranking model" in r.output and "Traceback" not in r.output
    assert str(bad) in r.output.replace("\n", "")

    monkeypatch.setattr(ranking, "MODEL_FILE", ranking.Path(ranking.__file__).resolve().parent.parent / "data"
                        / "match_candidate_trees.txt.gz")
    ranking._booster.cache_clear()
    monkeypatch.setitem(sys.modules, "lightgbm", None)  # import lightgbm raises ImportError
    with pytest.raises(ranking.RankModelError, match="libgomp1"):
        match(s, o.image, rig, min_score=0.0)
    monkeypatch.undo()
    ranking._booster.cache_clear()
    assert match(s, o.image, rig, min_score=0.0)
