"""``oas match PAIR --out DIR`` on a folder written by ``oas render``."""

import json
from pathlib import Path

from typer.testing import CliRunner

from optiacoustic.cli import app

runner = CliRunner()
RIG = Path(__file__).resolve().parents[2] / "examples" / "rig_thesis.yaml"


def test_match_command_on_a_rendered_pair(tmp_path):
    pair = tmp_path / "pair"
    r = runner.invoke(app, ["render", "thesis_scene1", "--rig", str(RIG), "--out", str(pair)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "m"
    r = runner.invoke(app, ["match", str(pair), "--out", str(out)])
    assert r.exit_code == 0, r.output
    data = json.loads((out / "matches.json").read_text())
    assert (out / "matches.png").stat().st_size > 10_000
    assert data["n_matches"] == len(data["matches"]) > 0
    assert len(data["matches"][0]) == len(data["columns"]) == 8
    assert len(data["correct_by_depth_map"]) == data["n_matches"]


def test_match_command_reports_bad_input(tmp_path):
    r = runner.invoke(app, ["match", str(tmp_path / "missing")])
    assert r.exit_code == 2 and "not a folder" in r.output
    (tmp_path / "p").mkdir()
    r = runner.invoke(app, ["match", str(tmp_path / "p")])
    assert r.exit_code == 2 and "pair.json" in r.output
    r = runner.invoke(app, ["match", str(tmp_path / "p"), "--min-score", "2"])
    assert r.exit_code == 2 and "--min-score" in r.output
    (tmp_path / "afile").write_text("x")  # was: 'afile: File exists', after the matching
    r = runner.invoke(app, ["match", str(tmp_path / "p"), "--out", str(tmp_path / "afile")])
    assert r.exit_code == 2 and "it is a file, a folder was expected" in r.output


def test_match_command_with_a_second_pair(tmp_path):
    """Two rendered pairs of one scene from two sonar positions: two-view matching from the CLI."""
    pairs = []
    for name, eye in (("a", ["0", "-6", "2"]), ("b", ["0.4", "-5.7", "2.05"])):
        p = tmp_path / name
        r = runner.invoke(app, ["render", "cuboids", "--rig", str(RIG), "--eye", *eye, "--target", "0", "0", "0",
                                "--out", str(p)])
        assert r.exit_code == 0, r.output
        pairs.append(p)
    out = tmp_path / "m"
    r = runner.invoke(app, ["match", str(pairs[0]), "--second", str(pairs[1]), "--out", str(out)])
    assert r.exit_code == 0, r.output
    data = json.loads((out / "matches.json").read_text())
    assert data["second_pair"] == str(pairs[1]) and "second view" in data["message"]
    assert data["n_matches"] == len(data["matches"]) > 0
    (pairs[1] / "pair.json").write_text("{}")
    r = runner.invoke(app, ["match", str(pairs[0]), "--second", str(pairs[1]), "--out", str(out)])
    assert r.exit_code == 2 and "pair.json" in r.output


def test_match_command_with_the_seabed_from_the_pair_pose(tmp_path):
    """A pair marked as a soft-beam sonar's is declined with a message; --seabed-z takes the seabed from pair.json's
    sonar pose and matches it; without a sonar pose, --seabed-z names the missing field."""
    pair = tmp_path / "pair"
    r = runner.invoke(app, ["render", "cuboids", "--rig", str(RIG), "--out", str(pair)])
    assert r.exit_code == 0, r.output
    out = tmp_path / "m"
    r = runner.invoke(app, ["match", str(pair), "--out", str(out)])
    fitted = json.loads((out / "matches.json").read_text())
    r = runner.invoke(app, ["match", str(pair), "--out", str(out), "--seabed-z", "0"])
    assert r.exit_code == 0, r.output
    nav_thesis = json.loads((out / "matches.json").read_text())
    # (the images are the thesis model's: the true seabed does as well as the plane fitted to its hard edges)
    n_fit, n_nav = sum(fitted["correct_by_depth_map"]), sum(nav_thesis["correct_by_depth_map"])
    assert nav_thesis["n_matches"] > 0 and n_nav >= n_fit - max(2, 0.1 * fitted["n_matches"]), (n_nav, n_fit)
    meta = json.loads((pair / "pair.json").read_text())
    assert meta["sonar"]["beam_model"] == "thesis"
    meta["sonar"]["beam_model"] = "aperture"
    (pair / "pair.json").write_text(json.dumps(meta))
    r = runner.invoke(app, ["match", str(pair), "--out", str(out)])
    assert r.exit_code == 0, r.output
    data = json.loads((out / "matches.json").read_text())
    assert data["n_matches"] == 0 and "soft elevation beam" in data["message"] and "--seabed-z" not in r.output
    r = runner.invoke(app, ["match", str(pair), "--out", str(out), "--seabed-z", "0"])
    assert r.exit_code == 0, r.output
    data = json.loads((out / "matches.json").read_text())
    # marked soft-beam, the same features are matched (their candidates scored by the soft-beam recalibration)
    assert data["n_matches"] == nav_thesis["n_matches"] > 0
    # the navigation's declared errors: the same matches, scores no higher; refused without --seabed-z or below 0
    r = runner.invoke(app, ["match", str(pair), "--out", str(out), "--seabed-z", "0", "--seabed-sigma-z", "0.02",
                            "--seabed-sigma-tilt", "0.1"])
    assert r.exit_code == 0, r.output
    told = json.loads((out / "matches.json").read_text())
    assert told["n_matches"] == data["n_matches"]
    # matches.json records the plane used, where it came from and its declared errors, and each match's candidate
    assert told["seabed"]["source"].startswith("navigation") and told["seabed"]["sigma_offset_m"] == 0.02
    assert abs(told["seabed"]["sigma_tilt_deg"] - 0.1) < 1e-12 and abs(told["seabed"]["offset_m"] - data["seabed"]["offset_m"]) < 1e-12
    assert fitted["seabed"]["source"].startswith("fitted") and fitted["seabed"]["sigma_offset_m"] == 0.0
    assert len(told["candidate"]) == told["n_matches"]
    assert set(told["candidate"]) <= {"arc", "crease", "plane", "foot", "seabed"}
    assert sum(m[-1] for m in told["matches"]) <= sum(m[-1] for m in data["matches"]) + 1e-9
    r = runner.invoke(app, ["match", str(pair), "--out", str(out), "--seabed-sigma-z", "0.02"])
    assert r.exit_code == 2 and "--seabed-z" in r.output
    r = runner.invoke(app, ["match", str(pair), "--out", str(out), "--seabed-z", "0", "--seabed-sigma-tilt", "-1"])
    assert r.exit_code == 2 and "--seabed-sigma-tilt" in r.output
    del meta["sonar_pose"]
    (pair / "pair.json").write_text(json.dumps(meta))
    r = runner.invoke(app, ["match", str(pair), "--out", str(out), "--seabed-z", "0"])
    assert r.exit_code == 2 and "sonar_pose" in r.output
