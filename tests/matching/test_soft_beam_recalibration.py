"""Soft-beam frames: each candidate's probability recalibrated on the realistic model's frames.

The matcher's candidate models were fitted on the thesis model's frames (hard-edged elevation aperture).
On soft-beam frames, with the seabed from the navigation, their probabilities do not say how often the
candidates are right (the crease and face-plane points over-confident, the seabed point under-confident);
``SOFT_BEAM_RECALIBRATION`` maps them. Checked here: the shipped constants are what the fitter gives
from the tree; the matcher applies the map to soft-beam frames only; and on seeded scenes outside the
fit the recalibrated probabilities agree with the depth-map truth where the thesis-frame ones do not.
"""

import numpy as np
import pytest

from optiacoustic.experiments.matching import random_scene, realistic_pair
from optiacoustic.matching import MatchOptions, SeabedPlane, match, truth
from optiacoustic.matching.match import CANDIDATES, SOFT_BEAM_RECALIBRATION, soft_beam_probability


def _pair(sd):
    sonar, optical, rig, pose = realistic_pair(random_scene(sd), sd)
    return sonar, optical, rig, SeabedPlane.from_pose(pose)


def test_shipped_constants_are_what_the_fitter_gives():
    """``calibrate_soft_beam()`` at its defaults (48 realistic scenes, about 20 s) reproduces the shipped map."""
    from optiacoustic.experiments.matching import calibrate_soft_beam

    fitted = calibrate_soft_beam()
    assert set(fitted) == set(CANDIDATES)
    for k, (a, b) in SOFT_BEAM_RECALIBRATION.items():
        assert fitted[k]["a"] == pytest.approx(a, abs=1.5e-3) and fitted[k]["b"] == pytest.approx(b, abs=1.5e-3), k


def test_map_applies_to_soft_beam_frames_only():
    """A soft-beam frame's candidate probabilities are the map of the thesis-frame ones (the option off gives
    those); the choice is the most probable of the mapped ones; a thesis-model frame is untouched."""
    import dataclasses

    sonar, optical, rig, plane = _pair(337)
    on = match(sonar, optical.image, rig, seabed=plane, min_score=0.0)
    off = match(sonar, optical.image, rig, seabed=plane, options=MatchOptions(soft_beam_recalibration=False),
                min_score=0.0)
    assert on and len(on) == len(off)
    j_off = {int(i): j for j, i in enumerate(off.sonar_index)}
    idx = np.array([j_off[int(i)] for i in on.sonar_index])
    probs = []
    for k in CANDIDATES:
        raw, mapped = np.asarray(off.features[f"p_{k}"])[idx], np.asarray(on.features[f"p_{k}"])
        np.testing.assert_allclose(mapped, np.where(raw > 0, soft_beam_probability(raw, k), 0.0), rtol=1e-12)
        probs.append(mapped)
    P = np.column_stack(probs)
    np.testing.assert_array_equal(on.features["face_source"], np.argmax(P, axis=1))
    np.testing.assert_allclose(on.score, P.max(axis=1), rtol=1e-12)
    thesis = dataclasses.replace(sonar, beam_model="thesis")
    a = match(thesis, optical.image, rig, seabed=plane, min_score=0.0)
    b = match(thesis, optical.image, rig, seabed=plane, options=MatchOptions(soft_beam_recalibration=False),
              min_score=0.0)
    np.testing.assert_array_equal(a.score, b.score)
    # the map is monotone: within a kind the order of the candidates is kept
    p = np.linspace(0.01, 0.99, 99)
    for k in CANDIDATES:
        assert np.all(np.diff(soft_beam_probability(p, k)) > 0)


def test_recalibrated_probabilities_agree_with_the_truth_outside_the_fit():
    """Realistic frames of seeded scenes 340-345 (not among the fit's 5000-5023 and 8000-8023), the exact plane:
    per candidate kind, the mean recalibrated probability of the offered candidates is their fraction right
    by the depth map within three binomial standard deviations; the thesis-frame probabilities of the crease
    and face-plane points are not (over-confident, as on the fit's scenes)."""
    acc = {k: {"raw": [], "cal": [], "ok": []} for k in CANDIDATES}
    for sd in range(340, 346):
        sonar, optical, rig, plane = _pair(sd)
        raw = match(sonar, optical.image, rig, seabed=plane, options=MatchOptions(soft_beam_recalibration=False),
                    min_score=0.0)
        cal = match(sonar, optical.image, rig, seabed=plane, min_score=0.0)
        j_raw = {int(i): j for j, i in enumerate(raw.sonar_index)}
        bw, aw = float(np.median(np.diff(sonar.ranges))), float(np.median(np.diff(sonar.azimuths)))
        f = cal.features
        for k in CANDIDATES:
            p = np.asarray(f[f"p_{k}"])
            px = np.column_stack([f[f"{k}_u"], f[f"{k}_v"]])
            c = (p > 0) & np.all(np.isfinite(px), axis=1)
            if not c.any():
                continue
            acc[k]["ok"].append(truth.correct(rig, optical.depth, px[c], cal.ranges[c], cal.azimuths[c], bin_width=bw,
                                              beam_width=aw))
            acc[k]["cal"].append(p[c])
            acc[k]["raw"].append(np.array([raw.features[f"p_{k}"][j_raw[int(i)]] for i in cal.sonar_index[c]]))
    for k in CANDIDATES:
        ok, p_cal, p_raw = (np.concatenate(acc[k][x]) for x in ("ok", "cal", "raw"))
        assert ok.size >= 50, (k, ok.size)
        three_sd = 3.0 * np.sqrt(ok.mean() * (1.0 - ok.mean()) / ok.size)
        assert abs(p_cal.mean() - ok.mean()) < three_sd, (k, p_cal.mean(), ok.mean(), three_sd)
        if k in ("crease", "plane"):
            assert p_raw.mean() - ok.mean() > three_sd, (k, p_raw.mean(), ok.mean(), three_sd)
