"""The matching experiment runs (quick mode), writes its figures and reports consistent numbers."""

import json

import numpy as np

from optiacoustic import experiments


def test_matching_experiment(tmp_path):
    res = experiments.run("matching", tmp_path, quick=True)
    data = json.loads((tmp_path / "results.json").read_text())
    assert data["name"] == "matching" and len(res.figures) == 9
    for path, caption in res.figures:
        assert path.is_file() and path.stat().st_size > 10_000 and caption
    n = res.numbers
    prec, rec = np.asarray(n["precision"], float), np.asarray(n["recall"], float)
    assert n["n_visible"] > 0 and prec.size == rec.size == len(n["thresholds"])
    # Recall can only fall as the score threshold rises; everything is a fraction.
    assert np.all(np.diff(rec) <= 1e-12) and np.all((rec >= 0) & (rec <= 1))
    assert 0 < n["precision_all_assigned"] <= 1 and 0 <= n["baseline_precision"] <= 1
    assert n["precision_all_assigned"] > n["baseline_precision"]
    assert n["median_error_true_matches_m"] < n["median_error_auto_m"]
    # The verdict is taken on the exact curve (every distinct score a threshold); the 20-point curve samples
    # it (each of its thresholds cuts the ranking where some distinct score does), so it cannot do better.
    assert n["target_met"] == bool(n["best_precision_at_recall_0_5"] >= 0.95)
    if np.any(rec >= 0.5):
        assert n["best_precision_at_recall_0_5_sampled"] == np.max(prec[rec >= 0.5])
        assert n["best_precision_at_recall_0_5"] >= n["best_precision_at_recall_0_5_sampled"] - 1e-12
    # The face-plane figure's numbers: the chosen pixel is one of the five candidates, so "any of
    # the five" is right at least as often as the choice, which is the headline precision.
    fp = n["face_plane"]
    assert fp["chosen"] == n["precision_all_assigned"]
    assert fp["any"] >= fp["chosen"] and all(0 <= fp[k] <= 1 for k in ("arc", "crease", "plane", "foot", "seabed", "any"))
    assert sum(fp["source_counts"]) == fp["n"][5]
    # One view and two views reported side by side, on plain and textured scenes.
    tv = n["two_view"]
    for kind in ("plain", "textured"):
        d = tv[kind]
        assert d["n_visible"] > 0
        for key in ("single_precision_all", "two_view_precision_all", "single_max_recall", "two_view_max_recall"):
            assert 0 <= d[key] <= 1
    assert {row["scenes"] for row in tv["baseline_sweep"]} == {"plain", "textured"}
    # The sonar beam section: the realistic (soft-beam) frames are declined unless the seabed is given, and
    # with it (navigation) they are matched far better than with the plane fitted to the image.
    sb = {(r["sonar"], r["seabed"]): r for r in n["soft_beam"]}
    assert sb[("realistic", "fitted (declined)")]["declined"] == 2
    assert sb[("realistic", "fitted (declined)")]["n_matches"] == 0
    nav, fit = sb[("realistic", "navigation")], sb[("realistic", "fitted (allow_soft_beam)")]
    assert nav["declined"] == fit["declined"] == 0
    assert nav["precision_all"] > 2 * fit["precision_all"]
    # The navigation plane with a drawn error: the same matches' features whether or not its sigmas are
    # declared; declared, the seabed points' scores fall by the chance the error leaves them right.
    blind = next(r for k, r in sb.items() if k[1].endswith("error, not declared"))
    told = next(r for k, r in sb.items() if k[1].endswith("error, declared"))
    assert told["n_matches"] == blind["n_matches"] > 0 and told["mean_score"] < blind["mean_score"]
    # quick mode has no built-in scenes: the thesis row with the fitted plane is the headline's pairs
    assert sb[("thesis", "fitted")]["precision_all"] == n["precision_all_assigned"]
    # Seabed relief: fractions, and 5 cm of relief costs precision (the matcher's seabed is one plane).
    rl = n["seabed_relief"]
    assert [d["rms_m"] for d in rl] == [0.0, 0.01, 0.05]
    assert all(0 <= d["precision_all"] <= 1 and d["n_visible"] > 0 for d in rl)
    assert rl[2]["precision_all"] < rl[0]["precision_all"]
    for d in rl:  # the same pairs with the relief taken as the plane's error (MatchOptions.relief_as_plane_error)
        for k in ("plane_error_precision_at_recall_0_25", "plane_error_precision_at_recall_0_5"):
            assert np.isnan(d[k]) or 0 <= d[k] <= 1
    assert rl[0]["plane_error_precision_at_recall_0_5"] == rl[0]["precision_at_recall_0_5"]  # flat: none warned


def test_varied_scene_is_seeded_and_stands_on_the_seabed():
    """The wider training generator: the same seed gives the same scene; every body rests on the seabed.

    Independent truth: each body's lowest point, from its shape's tessellation placed by its pose
    (not from the generator's own arithmetic), lies on the seabed plane z = 0 within 1 mm.
    """
    from optiacoustic.experiments.matching import varied_scene

    a, b, c = varied_scene(8123), varied_scene(8123), varied_scene(8124)
    assert [x.name for x in a.bodies] == [x.name for x in b.bodies]
    assert a.view.eye == b.view.eye and a.view.eye != c.view.eye
    kinds = set()
    for seed in range(8100, 8130):
        sc = varied_scene(seed)
        eye = np.asarray(sc.view.eye)
        assert 3.5 <= -eye[1] <= 6.5 and 1.2 <= eye[2] <= 2.5
        for body in sc.bodies[1:]:
            kinds.add(body.name.split("_")[0])
            mesh = body.shape.tessellate()
            V = np.asarray(mesh.vertices) @ body.pose.R.T + body.pose.t
            assert abs(V[:, 2].min()) < 1e-3, (seed, body.name, V[:, 2].min())
    assert kinds == {"box", "cylinder", "sphere", "bar", "wall", "lying"}


def test_relief_scene_has_the_asked_relief(tmp_path):
    """The heightfield's RMS height is the one asked for, its mean is the flat seabed's, and the bodies are
    random_scene's; a negative or NaN relief is refused."""
    import pytest
    import trimesh

    from optiacoustic.experiments.matching import random_scene, relief_scene

    sc = relief_scene(6001, 0.02, tmp_path)
    bed = trimesh.load(sc.bodies[0].shape.path, process=False)
    z = np.asarray(bed.vertices)[:, 2]
    assert abs(z.std() - 0.02) < 1e-9 and abs(z.mean()) < 0.005
    plain = random_scene(6001)
    assert [b.name for b in sc.bodies] == [b.name for b in plain.bodies]
    assert all(a.pose == b.pose for a, b in zip(sc.bodies[1:], plain.bodies[1:]))
    for bad in (-0.01, float("nan")):
        with pytest.raises(ValueError, match="rms_m"):
            relief_scene(6001, bad, tmp_path)


def test_exact_curve_cuts_only_between_distinct_scores():
    """The exact precision-recall curve has one point per distinct score (a threshold cannot split a tie), and
    matches a brute-force ``score >= t`` over every distinct score; the operating point obeys the same rule."""
    from optiacoustic.experiments.matching import _best_at, _fine_curve, _operating_point

    rng = np.random.default_rng(7)
    evals = [dict(score=rng.choice([0.2, 0.5, 0.5, 0.8, 0.9, 0.9, 0.9, 0.97], 40), ok=rng.random(40) < 0.7,
                  n_visible=50) for _ in range(3)]
    score = np.concatenate([e["score"] for e in evals])
    ok = np.concatenate([e["ok"] for e in evals])
    rec, prec = _fine_curve(evals)
    ts = np.unique(score)[::-1]
    assert rec.size == ts.size
    np.testing.assert_allclose(prec, [ok[score >= t].mean() for t in ts])
    np.testing.assert_allclose(rec, [ok[score >= t].sum() / 150 for t in ts])
    assert _best_at(rec, prec, 0.3) == max(ok[score >= t].mean() for t in ts if ok[score >= t].sum() / 150 >= 0.3)
    op = _operating_point(evals, target=0.6)
    good = [t for t in ts if ok[score >= t].mean() >= 0.6]
    assert op["threshold"] == min(good) and op["n"] == int((score >= min(good)).sum())
