"""Shared pieces of the command line: the app, scene resolution, error reporting."""

from __future__ import annotations

import functools
from pathlib import Path

import typer
from rich.console import Console

app = typer.Typer(
    name="oas",
    help="optiacoustic: simulate and relate forward-looking sonar and underwater camera images.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console(stderr=True)
out = Console()

Vec3 = tuple[float, float, float]


def fail(message: str, code: int = 2):
    console.print(f"[bold red]error:[/] {message}", highlight=False, markup=True)
    raise typer.Exit(code)


def reports_errors(func):
    """Turn caller mistakes (ValueError, KeyError, FileNotFoundError) into a one-line error and exit 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except typer.Exit:
            raise
        except (ValueError, KeyError, FileNotFoundError, TypeError) as exc:
            msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
            fail(str(msg))

    return wrapper


def resolve_scene(name_or_path: str):
    """A built-in scene by name, or a scene file by path."""
    from .. import scenes
    from ..scene import Scene

    p = Path(name_or_path)
    if p.suffix.lower() in (".yaml", ".yml", ".json") or p.exists():
        return Scene.load(p)
    if name_or_path in scenes.names():
        return scenes.get(name_or_path)
    raise ValueError(f"scene {name_or_path!r} is neither a scene file nor a built-in scene {scenes.names()}")


def resolve_view(scene, eye, target):
    """Eye and target from the options, else from the scene's suggested view."""
    import numpy as np

    if eye is None:
        if scene.view is None:
            raise ValueError(f"scene '{scene.name}' has no suggested view: pass --eye X Y Z (and --target X Y Z)")
        eye = scene.view.eye
    if target is None:
        target = scene.view.target if scene.view is not None else (0.0, 0.0, 0.0)
    return np.asarray(eye, float), np.asarray(target, float)

