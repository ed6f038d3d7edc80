"""The command line never shows a traceback: bad paths, counts and seeds are one-line errors (exit 2);
its help is honest and fast to load; the package has no import circles."""

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from optiacoustic.cli import app

runner = CliRunner()
SRC = Path(__file__).resolve().parents[1] / "src"
PKG = SRC / "optiacoustic"
SONAR = ["sonar", "flat_seabed", "--preset", "didson-300-hf", "--eye", "0", "-4", "1.5", "--target", "0", "0", "0",
         "--no-noise", "--no-figures"]


def _one_line_error(r, *words):
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output
    for w in words:
        assert w in r.output, (w, r.output)


def test_quiet_sonar_prints_nothing(tmp_path):
    # not even the blank line a non-interactive progress bar leaves on stderr when it stops
    r = runner.invoke(app, ["-q"] + SONAR + ["--out", str(tmp_path / "s")])
    assert r.exit_code == 0 and r.output == "", repr(r.output)
    assert (tmp_path / "s" / "frame.npz").is_file()


def test_bad_thread_count_in_the_environment_is_one_line(tmp_path):
    r = runner.invoke(app, SONAR + ["--out", str(tmp_path / "s")], env={"OAS_THREADS": "two"})
    _one_line_error(r, "OAS_THREADS", "'two'")


def test_output_folder_that_is_a_file(tmp_path):
    f = tmp_path / "taken"
    f.write_text("x")
    _one_line_error(runner.invoke(app, SONAR + ["--out", str(f)]), str(f), "a folder was expected")
    _one_line_error(runner.invoke(app, SONAR + ["--out", str(f / "sub")]), str(f))


def test_output_file_that_is_a_folder_or_a_device(tmp_path):
    (tmp_path / "s.yaml").mkdir()
    _one_line_error(runner.invoke(app, ["scene", "flat_seabed", "--export", str(tmp_path / "s.yaml")]),
                    "s.yaml", "it is a folder")
    _one_line_error(runner.invoke(app, ["scene", "flat_seabed", "--export", os.devnull]), os.devnull)
    _one_line_error(runner.invoke(app, ["noise-fit", "--bottom", "mud", "--n", "300", "--out", str(tmp_path)]),
                    str(tmp_path), "folder")


def test_scene_export_names_a_format_and_outputs_are_checked_before_the_work(tmp_path):
    # a .txt (or a trailing-slash folder name) got YAML under that name
    for name in ("s.txt", "newdir/"):
        _one_line_error(runner.invoke(app, ["scene", "flat_seabed", "--export", str(tmp_path / name)]),
                        ".yaml, .yml or .json")
    assert not (tmp_path / "s.txt").exists() and not (tmp_path / "newdir").exists()
    # calibrate: a --json that cannot be written fails before the solve, so --out is not written either
    cal = PKG / "examples" / "calibration"
    (tmp_path / "j").mkdir()
    views = sorted(str(p) for p in cal.glob("view_*.csv"))
    r = runner.invoke(app, ["calibrate", *views, "--rig", str(cal / "rig.yaml"), "--out", str(tmp_path / "rig.yaml"),
                            "--json", str(tmp_path / "j")])
    _one_line_error(r, str(tmp_path / "j"), "it is a folder")
    assert not (tmp_path / "rig.yaml").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere: no permission error to provoke")
def test_output_without_permission(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        _one_line_error(runner.invoke(app, ["scene", "flat_seabed", "--export", str(ro / "s.yaml")]), str(ro))
    finally:
        ro.chmod(0o700)


@pytest.mark.parametrize("args, words", [
    (["--frames", "0"], "--frames"),
    (["--frames", "-3"], "--frames"),
    (["--seed", "1.5"], "--seed"),
    (["--seed", "-1"], "--seed"),
    (["--elevation-samples", "0"], "--elevation-samples"),
    (["--eye", "0", "1"], "--eye"),
])
def test_bad_counts_and_seeds(tmp_path, args, words):
    r = runner.invoke(app, SONAR + ["--out", str(tmp_path)] + args)
    assert r.exit_code == 2 and words in r.output and "Traceback" not in r.output
    assert not list(tmp_path.iterdir())  # refused before anything was written


def test_demo_only_unknown_experiment(tmp_path):
    _one_line_error(runner.invoke(app, ["demo", "--only", "nosuch", "--out", str(tmp_path / "d")]), "nosuch",
                    "calibration")
    assert not (tmp_path / "d").exists()
    _one_line_error(runner.invoke(app, ["experiment", "nosuch", "--out", str(tmp_path / "e")]), "nosuch")
    assert not (tmp_path / "e").exists()


def test_noise_fit_on_complex_data(tmp_path):
    import numpy as np

    f = tmp_path / "iq.npy"
    np.save(f, np.full((16, 16), 1 + 2j))
    _one_line_error(runner.invoke(app, ["noise-fit", "--input", str(f)]), "iq.npy", "complex")


def test_help_version_quiet_and_metavars():
    r = runner.invoke(app, ["-h"])
    assert r.exit_code == 0 and "sonar" in r.output and "--version" in r.output and "--quiet" in r.output
    from optiacoustic import __version__

    r = runner.invoke(app, ["--version"])
    assert r.exit_code == 0 and __version__ in r.output
    r = runner.invoke(app, ["sonar", "-h"], env={"COLUMNS": "200"})
    assert r.exit_code == 0
    assert "<bool>" not in r.output and "X Y Z" in r.output and "float,float" not in r.output
    r = runner.invoke(app, ["experiment", "--help"], env={"COLUMNS": "200"})
    for name in ("sonar", "optical", "epipolar", "reconstruction", "motion", "enhancement", "calibration"):
        assert name in r.output
    r = runner.invoke(app, ["--quiet", "scene", "flat_seabed"])
    assert r.exit_code == 0 and r.output.strip() == ""


def test_help_imports_no_heavy_library():
    code = ("import sys, contextlib, io\nfrom optiacoustic.cli import app\n"
            "with contextlib.suppress(SystemExit), contextlib.redirect_stdout(io.StringIO()):\n    app(['--help'])\n"
            "print(sorted(m for m in ('scipy', 'matplotlib', 'cv2', 'embreex', 'trimesh') if m in sys.modules))")
    env = dict(os.environ, PYTHONPATH=str(SRC))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def _module_imports():
    graph = {}
    for path in PKG.rglob("*.py"):
        rel = path.relative_to(SRC).with_suffix("")
        parts = list(rel.parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts = parts[:-1]
        name = ".".join(parts)
        package = name if is_pkg else name.rsplit(".", 1)[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
                deps.add(mod)
                deps.update(f"{mod}.{a.name}" for a in node.names)
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("optiacoustic"):
                deps.add(node.module)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name.startswith("optiacoustic"))
        graph[name] = deps
    return {k: {d for d in v if d in graph and d != k} for k, v in graph.items()}


@pytest.mark.parametrize("a, b", [("optiacoustic.scene.io", "optiacoustic.scene.model"),
                                  ("optiacoustic.sonar.display", "optiacoustic.sonar.frame")])
def test_the_two_old_import_circles_are_gone(a, b):
    g = _module_imports()
    assert not (b in g[a] and a in g[b]), f"{a} and {b} import each other"


def test_no_module_pair_imports_each_other():
    """Two modules of one package importing each other (even lazily) is a circle; packages' __init__ excepted."""
    g = _module_imports()
    pairs = sorted({tuple(sorted((a, b))) for a, ds in g.items() for b in ds if a in g.get(b, ())
                    and not (PKG.parent / (a.replace(".", "/") + "/__init__.py")).exists()
                    and not (PKG.parent / (b.replace(".", "/") + "/__init__.py")).exists()})
    assert not pairs, pairs


def test_packaged_examples_work_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = runner.invoke(app, ["calibrate", "examples/calibration/view_*.csv", "--rig", "examples/calibration/rig.yaml",
                            "--sigma-pixel", "0.5", "--sigma-range", "0.005", "--sigma-azimuth-deg", "0.1",
                            "--json", "cal.json"])
    assert r.exit_code == 0, r.output
    import json

    d = json.loads((tmp_path / "cal.json").read_text())
    # the sequence was made with the camera at (-0.25, 0.02, 0.05) m: x and y are well observed
    assert abs(d["t"][0] + 0.25) < 0.02 and abs(d["t"][1] - 0.02) < 0.02
    r = runner.invoke(app, ["examples"])
    assert r.exit_code == 0 and "examples/rig_thesis.yaml" in r.output


def test_sonar_frames_of_neighbouring_seeds_do_not_repeat_and_match_a_dataset_s(tmp_path):
    # was seed + k: frame 1 of --seed 5 was frame 0 of --seed 6
    import numpy as np

    from optiacoustic import Pose, SonarSpec, scenes, simulate_sonar
    from optiacoustic.simulation.sequence import frame_seed

    base = ["sonar", "flat_seabed", "--preset", "didson-300-hf", "--eye", "0", "-4", "1.5", "--target", "0", "0", "0",
            "--no-figures"]
    for s in (5, 6):
        assert runner.invoke(app, base + ["--seed", str(s), "--frames", "2", "--out", str(tmp_path / str(s))]).exit_code == 0
    a = np.load(tmp_path / "5" / "frame_0001.npz")["image"]
    b = np.load(tmp_path / "6" / "frame_0000.npz")["image"]
    assert not np.array_equal(a, b)
    ref = simulate_sonar(scenes.get("flat_seabed"), SonarSpec.preset("didson-300-hf"), Pose.look_at((0, -4, 1.5), (0, 0, 0)),
                         seed=frame_seed(5, "sonar", 1))
    assert np.array_equal(a, ref.image)
