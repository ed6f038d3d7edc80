"""``oas examples``: list the example files shipped with the package, or copy them into a folder."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import app, examples_dir, out, reports_errors


@app.command("examples")
@reports_errors
def examples_cmd(
    copy_to: Optional[Path] = typer.Option(None, "--copy", metavar="DIR", help="Copy the examples into DIR/examples."),
):
    """List the shipped examples (rig files, a calibration sequence); `examples/...` paths work from any folder."""
    from .._atomic import ensure_dir, write_bytes

    root = examples_dir()
    files = sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    if copy_to is None:
        for p in files:
            out.print(f"examples/{p.relative_to(root).as_posix()}", highlight=False)
        return
    dest = ensure_dir(Path(copy_to) / "examples")
    for p in files:
        write_bytes(dest / p.relative_to(root), p.read_bytes())
    out.print(f"copied {len(files)} files to {dest}")
