"""``oas view FILE --out DIR``: polar and fan PNGs of a log's frames and a contact sheet."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import app, out, reports_errors


def parse_frames(text: Optional[str], n: int) -> range:
    """``i:j`` (Python slice, negatives allowed), ``i`` or None (first 12) -> frame indices in ``0..n-1``."""
    if text is None:
        return range(min(n, 12))
    try:
        if ":" in text:
            parts = text.split(":")
            if len(parts) > 3:
                raise ValueError
            s = slice(*[int(p) if p.strip() else None for p in parts])
            r = range(*s.indices(n))
        else:
            i = int(text)
            i = i + n if i < 0 else i
            if not 0 <= i < n:
                raise IndexError
            r = range(i, i + 1)
    except ValueError:
        raise ValueError(f"--frames: expected i:j (or i), got {text!r}") from None
    except IndexError:
        raise ValueError(f"--frames: frame {text} out of range (the log has {n} frames)") from None
    if len(r) == 0:
        raise ValueError(f"--frames {text}: selects no frame of the {n}")
    return r


@app.command("view")
@reports_errors
def view(
    path: Path = typer.Argument(..., help="Sonar log: .aris, Oculus ping stream, bag or .mcap."),
    out_dir: Path = typer.Option(..., "--out", help="Folder for the PNGs."),
    topic: Optional[str] = typer.Option(None, "--topic", help="Bag topic (default: the only sonar topic)."),
    frames: Optional[str] = typer.Option(None, "--frames", help="Frames i:j (Python slice; default the first 12)."),
    width: int = typer.Option(600, "--width", help="Fan image width (px)."),
    dynamic_range_db: float = typer.Option(50.0, "--dynamic-range-db", help="Displayed dynamic range (dB)."),
):
    """Write polar and fan PNGs of a log's frames (dB display, fixed reference) and a contact sheet."""
    from ..io import open_sonar
    from ..sonar.preview import write_previews

    with open_sonar(path, topic=topic) as seq:
        idx = parse_frames(frames, len(seq))
        written = write_previews((seq[i] for i in idx), out_dir, indices=idx, width=width,
                                 dynamic_range_db=dynamic_range_db)
    out.print(f"{len(idx)} frames -> {out_dir} ({len(written)} files, contact_sheet.png)", highlight=False)
