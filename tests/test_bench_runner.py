"""benchmarks/run_all.py: re-measuring one module keeps every other table and the notes.

The runner is driven end to end on a throw-away folder of two tiny bench modules (no
simulator is run), so what is checked is the file it writes, not timing.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run_all():
    spec = importlib.util.spec_from_file_location("run_all_under_test", ROOT / "benchmarks" / "run_all.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


BENCH = '''
TITLE = "Module {name}"
DESCRIPTION = "What module {name} measures."
def run():
    return [dict(name="{name} thing", value={value}, unit="ms", reference="{name} ref", ratio={ratio}, note="n")]
'''

NOTES = "## Hand-written notes\n\nA table row quoted in prose:\n\n(`benchmarks/bench_alpha.py`, 3 s)\n\nand more prose.\n"


def _bench_dir(tmp_path: Path, values: dict[str, float]) -> Path:
    d = tmp_path / "benchmarks"
    d.mkdir(exist_ok=True)
    for name, value in values.items():
        (d / f"bench_{name}.py").write_text(BENCH.format(name=name, value=value, ratio=value / 2))
    (d / "notes.md").write_text(NOTES)
    return d


def _section(text: str, title: str) -> str:
    m = re.search(rf"(?ms)^## {re.escape(title)}\n.*?(?=^## |\Z)", text)
    assert m, f"no section {title!r} in\n{text}"
    return m.group(0)


def test_full_run_writes_every_table_then_the_notes(run_all, tmp_path):
    d = _bench_dir(tmp_path, {"alpha": 1.5, "beta": 7.0})
    out = tmp_path / "benchmarks.md"
    assert run_all.main(["--out", str(out)], bench_dir=d) == 0
    text = out.read_text()
    assert text.startswith("# Benchmarks\n")
    assert text.index("## Module alpha") < text.index("## Module beta") < text.index("## Hand-written notes")
    assert text.endswith(NOTES)
    assert "| alpha thing | 1.5 | ms | alpha ref | 0.75 | n |" in _section(text, "Module alpha")
    trailer = _section(text, "Module beta").rstrip().rsplit("\n", 1)[-1]
    assert re.fullmatch(r"\(`benchmarks/bench_beta\.py`, \d+ s, \d{4}-\d\d-\d\d, .+, \d+ cores, Python [\d.]+\)",
                        trailer), trailer


def test_only_replaces_its_table_and_keeps_the_others_byte_for_byte(run_all, tmp_path):
    d = _bench_dir(tmp_path, {"alpha": 1.5, "beta": 7.0, "gamma": 2.0})
    out = tmp_path / "benchmarks.md"
    assert run_all.main(["--out", str(out)], bench_dir=d) == 0
    before = out.read_text()
    # a table in the older trailer format (no date, no machine) is still recognised and kept
    before = before.replace(_section(before, "Module gamma"), "## Module gamma\n\nold gamma\n\n(`benchmarks/bench_gamma.py`, 4 s)\n\n")
    out.write_text(before)
    _bench_dir(tmp_path, {"beta": 9.0})  # module beta now measures something else
    assert run_all.main(["--out", str(out), "--only", "beta"], bench_dir=d) == 0
    after = out.read_text()
    assert _section(after, "Module alpha") == _section(before, "Module alpha")
    assert _section(after, "Module gamma") == _section(before, "Module gamma")
    assert "| beta thing | 9 | ms | beta ref | 4.5 | n |" in _section(after, "Module beta")
    assert "| beta thing | 7 |" not in after
    assert after.endswith(NOTES) and after.count("## Hand-written notes") == 1
    assert after.index("## Module alpha") < after.index("## Module beta") < after.index("## Module gamma")


def test_only_without_an_existing_file_writes_what_it_ran(run_all, tmp_path):
    d = _bench_dir(tmp_path, {"alpha": 1.5, "beta": 7.0})
    out = tmp_path / "new" / "benchmarks.md"
    assert run_all.main(["--out", str(out), "--only", "alpha"], bench_dir=d) == 0
    text = out.read_text()
    assert "## Module alpha" in text and "## Module beta" not in text and text.endswith(NOTES)


def test_a_removed_module_loses_its_table(run_all, tmp_path):
    d = _bench_dir(tmp_path, {"alpha": 1.5, "beta": 7.0})
    out = tmp_path / "benchmarks.md"
    assert run_all.main(["--out", str(out)], bench_dir=d) == 0
    (d / "bench_beta.py").unlink()
    assert run_all.main(["--out", str(out), "--only", "alpha"], bench_dir=d) == 0
    assert "## Module beta" not in out.read_text()


def test_only_matching_nothing_is_an_error_and_leaves_the_file(run_all, tmp_path, capsys):
    d = _bench_dir(tmp_path, {"alpha": 1.5})
    out = tmp_path / "benchmarks.md"
    out.write_text("precious\n")
    assert run_all.main(["--out", str(out), "--only", "sonarr"], bench_dir=d) == 2
    assert out.read_text() == "precious\n"
    err = capsys.readouterr().err
    assert "'sonarr'" in err and "bench_alpha" in err


def test_an_unreadable_existing_file_is_an_error_before_any_module_runs(run_all, tmp_path, capsys):
    d = _bench_dir(tmp_path, {"alpha": 1.5})
    (d / "bench_alpha.py").write_text("raise RuntimeError('a module must not run')\n")
    out = tmp_path / "benchmarks.md"
    out.write_bytes(b"# Benchmarks\n\xff\xfe not utf-8\n")
    assert run_all.main(["--out", str(out), "--only", "alpha"], bench_dir=d) == 2
    assert out.read_bytes() == b"# Benchmarks\n\xff\xfe not utf-8\n"
    assert str(out) in capsys.readouterr().err


def test_the_committed_file_is_what_the_runner_would_compose(run_all):
    """docs/benchmarks.md = header + a table per bench module + benchmarks/notes.md, nothing lost."""
    doc = (ROOT / "docs" / "benchmarks.md").read_text(encoding="utf-8")
    stems = [p.stem for p in sorted((ROOT / "benchmarks").glob("bench_*.py"))]
    notes = (ROOT / "benchmarks" / "notes.md").read_text(encoding="utf-8")
    assert sorted(run_all.generated_tables(doc)) == stems
    assert run_all.compose(stems, {}, run_all.generated_tables(doc), notes) == doc


def test_an_out_that_is_a_folder_is_an_error_before_any_module_runs(run_all, tmp_path, capsys):
    d = _bench_dir(tmp_path, {"alpha": 1.5})
    (d / "bench_alpha.py").write_text("raise RuntimeError('a module must not run')\n")
    out = tmp_path / "benchmarks.md"
    out.mkdir()
    assert run_all.main(["--out", str(out)], bench_dir=d) == 2
    assert out.is_dir() and not any(out.iterdir())
    err = capsys.readouterr().err
    assert str(out) in err and "folder" in err
