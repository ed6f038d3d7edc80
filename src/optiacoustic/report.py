"""The demo report: every experiment of the thesis, in chapter order, on one HTML page."""

from __future__ import annotations

import html
import time
from pathlib import Path

from . import experiments
from ._atomic import ensure_dir, write_text

__all__ = ["build_report"]

_CSS = """
body { font-family: -apple-system, Segoe UI, Helvetica, Arial, sans-serif; max-width: 1150px; margin: 2em auto;
       color: #1d2a33; line-height: 1.45; padding: 0 1em; }
h1 { border-bottom: 3px solid #2b6777; padding-bottom: .3em; }
h2 { color: #2b6777; margin-top: 2.2em; border-bottom: 1px solid #c8d8dc; }
figure { margin: 1.2em 0; } figure img { max-width: 100%; border: 1px solid #dde; }
figcaption { font-size: .92em; color: #445; }
table { border-collapse: collapse; margin: 1em 0; font-size: .92em; }
td, th { border: 1px solid #c8d8dc; padding: .3em .6em; text-align: right; }
th { background: #eef4f5; } td:first-child, th:first-child { text-align: left; }
.summary { background: #f3f8f9; border-left: 4px solid #2b6777; padding: .6em 1em; }
.meta { color: #667; font-size: .85em; } pre { background: #f6f6f6; padding: .6em; overflow-x: auto; }
.error { background: #fdecea; border-left: 4px solid #c62828; padding: .6em 1em; }
"""

_CHAPTERS = {
    2: "2D imaging sonar simulator",
    3: "Underwater optical image simulator",
    4: "Epipolar geometry of opti-acoustic stereo imaging",
    5: "3D reconstruction from opti-acoustic stereo imaging",
    6: "3D motion estimation from opti-acoustic stereo imaging",
    7: "Underwater optical image enhancement",
    9: "Appendix A: calibration of the opti-acoustic rig",
}


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return html.escape(str(v))


def _section(name: str, result, out_dir: Path, seconds: float) -> str:
    mod = experiments.get(name)
    ch = getattr(mod, "CHAPTER", "")
    parts = [f'<h2 id="{name}">Chapter {ch} &mdash; {html.escape(getattr(mod, "TITLE", name))}</h2>']
    parts.append(f'<p class="summary">{html.escape(result.summary or getattr(mod, "SUMMARY", ""))}</p>')
    for title, header, rows in result.tables:
        parts.append(f"<table><caption>{html.escape(title)}</caption><tr>"
                     + "".join(f"<th>{html.escape(str(h))}</th>" for h in header) + "</tr>")
        for row in rows:
            parts.append("<tr>" + "".join(f"<td>{_fmt(c)}</td>" for c in row) + "</tr>")
        parts.append("</table>")
    for path, caption in result.figures:
        rel = Path(path).resolve().relative_to(out_dir.resolve())
        parts.append(f'<figure><img src="{rel.as_posix()}" alt="{html.escape(caption)}">'
                     f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    parts.append(f'<p class="meta">oas experiment {name} &middot; {seconds:.1f} s &middot; numbers in '
                 f'<a href="{name}/results.json">{name}/results.json</a></p>')
    return "\n".join(parts)


def build_report(out_dir, *, only=None, quick: bool = False, seed: int = 0, progress=None) -> Path:
    """Run the experiments (all, or ``only``) into ``out_dir/NAME`` and write ``out_dir/index.html``.

    An experiment that fails is reported on the page with its error instead of aborting
    the others; the function raises at the end if any failed, so ``make demo`` fails too.
    """
    out_dir = Path(out_dir)
    known = experiments.names()
    if only is not None:
        unknown = [n for n in only if n not in known]
        if unknown or not only:
            raise ValueError(f"only: unknown experiment(s) {unknown or only}; experiments are {known}")
    ensure_dir(out_dir)
    names = [n for n in known if only is None or n in only]
    sections, failures = [], []
    for name in names:
        if progress:
            progress(name)
        t0 = time.perf_counter()
        try:
            res = experiments.run(name, out_dir / name, quick=quick, seed=seed)
            sections.append(_section(name, res, out_dir, time.perf_counter() - t0))
        except Exception:  # keep the other chapters; report and fail at the end
            import traceback

            failures.append(name)
            sections.append(f'<h2 id="{name}">{html.escape(name)}</h2><div class="error">failed: '
                            f"<pre>{html.escape(traceback.format_exc())}</pre></div>")
    toc = "".join(f'<li><a href="#{n}">Chapter {getattr(experiments.get(n), "CHAPTER", "")}: '
                  f'{html.escape(getattr(experiments.get(n), "TITLE", n))}</a></li>' for n in names)
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>optiacoustic demo report</title>
<style>{_CSS}</style></head><body>
<h1>optiacoustic &mdash; the thesis, reproduced</h1>
<p>Opti-acoustic stereo imaging: a forward-looking imaging sonar and an underwater camera on one rig.
Each section below is one experiment, run by <code>oas experiment NAME</code>; its numbers are in its
<code>results.json</code>. Generated {time.strftime('%Y-%m-%d %H:%M')}{' (quick mode)' if quick else ''}.</p>
<ul>{toc}</ul>
{''.join(sections)}
</body></html>"""
    index = out_dir / "index.html"
    write_text(index, page)
    if failures:
        raise RuntimeError(f"experiments failed: {failures}; see {index}")
    return index
