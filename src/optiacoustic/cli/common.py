"""Shared pieces of the command line: the app, scene resolution, error reporting."""

from __future__ import annotations

import contextlib
import functools
import os
from pathlib import Path

import typer
from rich.console import Console
from typer.core import TyperCommand, TyperGroup

_CONTEXT = {"help_option_names": ["-h", "--help"]}


def _polish(params):
    """Metavars that say what is typed: ``--eye X Y Z``, flags with none, ``NAME`` for arguments."""
    for p in params:
        # typer's parameters are not click's classes: test what they are, not their type
        if getattr(p, "is_flag", False) or getattr(p, "count", False):
            p.metavar = ""
        elif p.metavar is None and p.nargs > 1:
            p.metavar = " ".join("XYZW"[: p.nargs]) if p.nargs <= 4 else f"V1 ... V{p.nargs}"
        elif p.param_type_name == "argument" and p.metavar is None:
            p.metavar = p.name.upper()
    return params


class _Command(TyperCommand):
    def get_params(self, ctx):
        return _polish(super().get_params(ctx))


class _Group(TyperGroup):
    def get_params(self, ctx):
        return _polish(super().get_params(ctx))


class _App(typer.Typer):
    """A Typer whose commands show honest metavars and accept ``-h``."""

    def command(self, *args, cls=None, context_settings=None, **kwargs):
        return super().command(*args, cls=cls or _Command, context_settings={**_CONTEXT, **(context_settings or {})},
                               **kwargs)


app = _App(
    name="oas",
    help="optiacoustic: simulate and relate forward-looking sonar and underwater camera images.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    cls=_Group,
    context_settings=_CONTEXT,
)
console = Console(stderr=True)
# no markup: what commands print holds user paths and values, where '[red]' or '[/x]' is text
# (with markup a '[/x]' in a path raised rich.errors.MarkupError after the work was done)
out = Console(markup=False)

Vec3 = tuple[float, float, float]


def quiet() -> bool:
    """Whether ``--quiet`` was given (no progress, no listing of written files)."""
    return out.quiet


def _version(value: bool):
    if value:
        from .. import __version__

        out.print(f"oas (optiacoustic) {__version__}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(
    version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Show the version and exit."),
    quiet_: bool = typer.Option(False, "--quiet", "-q", help="Print only errors (no progress, no file lists)."),
):
    """optiacoustic: simulate and relate forward-looking sonar and underwater camera images."""
    out.quiet = quiet_


@contextlib.contextmanager
def progress(label: str | None = None):
    """Show the library's long loops (``optiacoustic._progress.track``) as bars on stderr; ``--quiet`` hides them.

    Yields a function ``step(text)`` that shows which step runs now (a spinner with elapsed time),
    so a step without a loop of its own still shows that it is alive.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from .._progress import listening

    columns = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn())
    with Progress(*columns, console=console, transient=True, disable=quiet()) as bar:
        tasks: dict = {}
        current = bar.add_task(label or "working", total=None, visible=label is not None)

        def listener(text, done, total):
            if text not in tasks:
                tasks[text] = bar.add_task(text, total=total)
            bar.update(tasks[text], completed=done, total=total)
            if total is not None and done >= total:
                bar.remove_task(tasks.pop(text))

        def step(text):
            bar.update(current, description=text, visible=True)

        with listening(listener):
            yield step


def fail(message: str, code: int = 2):
    from rich.markup import escape

    console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, markup=True, soft_wrap=True)
    raise typer.Exit(code)


def _os_message(exc: OSError) -> str:
    names = " -> ".join(str(f) for f in (exc.filename, exc.filename2) if f is not None)
    reason = exc.strerror or exc.__class__.__name__
    return f"{names}: {reason}" if names else f"{reason}: {exc}"


def reports_errors(func):
    """Turn caller mistakes into a one-line error and exit 2; Ctrl-C into a one-line message and exit 130.

    Caller mistakes are ``ValueError`` (incl. the library's validation errors and
    :class:`~optiacoustic._atomic.OutputError`), ``KeyError``, ``TypeError``, ``OSError`` (a path
    that is missing, a folder, not writable, ...) and ``MemoryError`` (a request too big).
    """

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except typer.Exit:
            raise
        except KeyboardInterrupt:
            from ._interrupt import delivered

            delivered()
            console.print("interrupted: files already written are complete; partial ones were removed",
                          highlight=False)
            raise typer.Exit(130) from None
        except OSError as exc:
            fail(_os_message(exc))
        except MemoryError as exc:
            fail(f"not enough memory: {exc}" if str(exc) else "not enough memory for this request")
        except (ValueError, KeyError, TypeError) as exc:
            msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else str(exc)
            fail(str(msg))

    return wrapper


def examples_dir() -> Path:
    """The example files shipped inside the package (``examples/`` of the source tree)."""
    return Path(__file__).resolve().parents[1] / "examples"


def resolve_input(path) -> Path:
    """An input file by path; ``examples/...`` that is not in the current folder is the packaged example.

    So ``oas render ... --rig examples/rig_thesis.yaml`` works from any folder after ``pip install``.
    """
    p = Path(path)
    if p.exists():
        return p
    parts = p.parts
    if parts and parts[0] == "examples":
        packaged = examples_dir().joinpath(*parts[1:])
        if packaged.exists():
            return packaged
    return p


def check_output(path, option: str, *inputs) -> None:
    """Before the work: refuse an output file that is one of the inputs (it would be overwritten)
    or that cannot be written (a folder, a parent that is a file)."""
    if path is None:
        return
    from .._atomic import check_destination

    p = Path(path)
    for inp in inputs:
        if inp is None:
            continue
        q = Path(inp)
        same = p.resolve() == q.resolve()
        if not same and p.exists() and q.exists():
            try:
                same = os.path.samefile(p, q)
            except OSError:
                same = False
        if same:
            raise ValueError(f"{option} {p}: is the input {q}; refusing to overwrite it (name another file)")
    check_destination(p)


def resolve_inputs(paths) -> list[Path]:
    """:func:`resolve_input` for each path; an unexpanded glob (``examples/calibration/view_*.csv``) is expanded."""
    out = []
    for path in paths:
        p = Path(path)
        if not p.exists() and any(c in str(p) for c in "*?["):
            base = examples_dir().joinpath(*p.parts[1:-1]) if p.parts[:1] == ("examples",) else p.parent
            hits = sorted(base.glob(p.name))
            if not hits:
                raise ValueError(f"{path}: no file matches")
            out.extend(hits)
        else:
            out.append(resolve_input(p))
    return out


def resolve_scene(name_or_path: str):
    """A built-in scene by name, or a scene file by path."""
    from .. import scenes
    from ..scene import Scene

    p = resolve_input(name_or_path)
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

