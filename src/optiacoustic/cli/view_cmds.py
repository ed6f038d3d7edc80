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


def check_view_options(width: int, dynamic_range_db: float) -> None:
    """Refuse bad ``oas view`` numbers before the log is opened (and long before a file is written)."""
    import math

    from ..sonar.display import MAX_FAN_SIDE

    if isinstance(width, bool) or not isinstance(width, int) or not 16 <= width <= MAX_FAN_SIDE:
        raise ValueError(f"--width: expected a whole number of pixels from 16 to {MAX_FAN_SIDE}, got {width!r}")
    if not (math.isfinite(dynamic_range_db) and dynamic_range_db > 0):
        raise ValueError(f"--dynamic-range-db: expected a finite number of dB > 0, got {dynamic_range_db!r}")


def check_fan_sizes(frames, indices, width: int, source="") -> None:
    """Each distinct sonar geometry of the selected frames makes a fan image that fits OpenCV and memory."""
    from ..sonar.display import fan_shape

    seen = set()
    for k, f in zip(indices, frames):
        if f.spec in seen:
            continue
        seen.add(f.spec)
        try:
            fan_shape(f.spec, width, name="--width")
        except ValueError as exc:
            raise ValueError(f"{source + ', ' if source else ''}frame {k}: {exc}") from None


@app.command("view")
@reports_errors
def view(
    path: Path = typer.Argument(..., help="Sonar log: .aris, Oculus ping stream, bag or .mcap."),
    out_dir: Path = typer.Option(..., "--out", help="Folder for the PNGs."),
    topic: Optional[str] = typer.Option(None, "--topic", help="Bag topic (default: the only sonar topic)."),
    frames: Optional[str] = typer.Option(None, "--frames", help="Frames i:j (Python slice; default the first 12)."),
    width: int = typer.Option(600, "--width", help="Fan image width (px), 16 to 32767."),
    dynamic_range_db: float = typer.Option(50.0, "--dynamic-range-db", help="Displayed dynamic range (dB), > 0."),
):
    """Write polar and fan PNGs of a log's frames (dB display, fixed reference) and a contact sheet."""
    from ..io import open_sonar
    from ..sonar.preview import write_previews

    check_view_options(width, dynamic_range_db)
    with open_sonar(path, topic=topic) as seq:
        idx = parse_frames(frames, len(seq))
        selected = [seq[i] for i in idx]  # write_previews holds them all anyway (one reference level for the set)
    # every frame's fan size is checked before the first PNG is written, so a refusal leaves no file behind
    check_fan_sizes(selected, idx, width, str(path))
    written = write_previews(selected, out_dir, indices=idx, width=width, dynamic_range_db=dynamic_range_db)
    out.print(f"{len(idx)} frames -> {out_dir} ({len(written)} files, contact_sheet.png)", highlight=False)
