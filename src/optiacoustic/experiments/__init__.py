"""Experiments of the thesis, one module each, run by ``oas experiment NAME --out DIR``.

An experiment module defines ``NAME`` (command name), ``TITLE``, ``CHAPTER`` (thesis
chapter number, orders the report), ``SUMMARY`` (one sentence: what it shows) and
``run(out_dir, *, quick=False, seed=0) -> ExperimentResult``. It writes its PNG figures
and ``results.json`` into ``out_dir``. Modules are discovered automatically.
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass, field
from pathlib import Path

from .._atomic import ensure_dir, write_json
from .._atomic import jsonable as _jsonable

__all__ = ["ExperimentResult", "names", "get", "run", "write_results"]


@dataclass
class ExperimentResult:
    """What an experiment produced.

    Attributes
    ----------
    name : str
    figures : list of (Path, caption)
        PNG files written, each with a one-line caption.
    numbers : dict
        JSON-serialisable results (also written to ``results.json``).
    summary : str
        One sentence of what the experiment shows, with its key figure of merit.
    tables : list of (title, header, rows)
        Tables for the report (rows of strings or numbers).
    """

    name: str
    figures: list = field(default_factory=list)
    numbers: dict = field(default_factory=dict)
    summary: str = ""
    tables: list = field(default_factory=list)


def write_results(result: ExperimentResult, out_dir) -> Path:
    """Write ``results.json`` (numbers, summary, figure list, tables) into ``out_dir``."""
    out_dir = Path(out_dir)
    ensure_dir(out_dir)
    data = {
        "name": result.name,
        "summary": result.summary,
        "numbers": result.numbers,
        "figures": [{"file": Path(f).name, "caption": c} for f, c in result.figures],
        "tables": [{"title": t, "header": h, "rows": r} for t, h, r in result.tables],
    }
    path = out_dir / "results.json"
    return write_json(path, _jsonable(data))


def _modules() -> dict:
    mods = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods[mod.NAME] = mod
    return dict(sorted(mods.items(), key=lambda kv: (getattr(kv[1], "CHAPTER", 99), kv[0])))


def names() -> list[str]:
    """Experiment names, in thesis chapter order."""
    return list(_modules())


def get(name: str):
    """The experiment module ``name``."""
    mods = _modules()
    if name not in mods:
        raise KeyError(f"unknown experiment {name!r}; experiments are {list(mods)}")
    return mods[name]


def run(name: str, out_dir, *, quick: bool = False, seed: int = 0) -> ExperimentResult:
    """Run experiment ``name`` into ``out_dir`` and write its ``results.json``."""
    out_dir = Path(out_dir)
    ensure_dir(out_dir)
    result = get(name).run(out_dir, quick=quick, seed=seed)
    write_results(result, out_dir)
    return result
