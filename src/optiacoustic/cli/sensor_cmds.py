"""``oas sensor-fit``: fit a sensor profile to a real log and compare simulated frames with it."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import app, check_output, out, reports_errors


def _parse_frames(text: Optional[str], n: int) -> list[int]:
    """``"0"``, ``"0,2,5"`` or ``"1:4"`` (Python slice) -> frame indices within ``n``."""
    if text is None:
        return [0]
    try:
        if ":" in text:
            a, b = (int(x) if x else None for x in text.split(":", 1))
            idx = list(range(n))[slice(a, b)]
        else:
            idx = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"--frames: expected N, N,M,... or A:B, got {text!r}") from None
    bad = [i for i in idx if not -n <= i < n]
    if bad or not idx:
        raise ValueError(f"--frames: {text!r} selects no frame or frames out of range (the log has {n})")
    return [i % n for i in idx]


@app.command("sensor-fit")
@reports_errors
def sensor_fit_cmd(
    log: Path = typer.Argument(..., help="A real sonar log (ARIS, Oculus, ROS bag, MCAP)."),
    topic: Optional[str] = typer.Option(None, "--topic", help="Sonar topic of a bag."),
    frames: Optional[str] = typer.Option(None, "--frames", help="Frames to fit on: N, N,M,... or A:B (default 0)."),
    region: Optional[tuple[float, float]] = typer.Option(None, "--region", help="Range window R_MIN R_MAX (m) for the speckle statistics."),
    encoding: Optional[str] = typer.Option(None, "--encoding", help="Force the stored values' reading (linear, amplitude, root-amplitude, db)."),
    out_path: Path = typer.Option(Path("profile.yaml"), "--out", help="Profile YAML to write."),
    report: Optional[Path] = typer.Option(None, "--report", help="Folder for real-vs-simulated figures and numbers (every frame of the log, up to --max-report)."),
    max_report: int = typer.Option(6, "--max-report", help="Compare at most this many frames in the report."),
    use_profile: Optional[str] = typer.Option(None, "--profile", help="Skip the fit: compare the log with this profile (YAML or a shipped profile's name)."),
):
    """Fit a sensor profile (beam patterns, gain, TVG, noise, speckle, encoding, seabed pose) to a real log."""
    from ..io import open_sonar
    from ..sonar.profile import fit_profile

    if use_profile is None:  # before the fit (a minute or more), not after it
        check_output(out_path, "--out", log)
    seq = open_sonar(log, topic=topic)
    n = len(seq)
    if n == 0:
        raise ValueError(f"{log}: no sonar frames")
    idx = _parse_frames(frames, n)
    chosen = [seq[i] for i in idx]
    if use_profile is not None:
        from ..sonar.profile import SensorProfile

        p = Path(use_profile)
        profile = SensorProfile.load(p) if p.suffix.lower() in (".yaml", ".yml") or p.exists() else SensorProfile.preset(use_profile)
        idx = []
    else:
        profile = fit_profile(chosen, region=region, encoding=encoding, device=chosen[0].spec.name)
        profile.save(out_path)
    pose = profile.seabed_pose
    where = "no seabed pose" if pose is None else (
        f"seabed pose: height {profile.height:.3g} m, pitch {float(__import__('numpy').rad2deg(profile.pitch)):.3g} deg, "
        f"roll {float(__import__('numpy').rad2deg(profile.roll)):.3g} deg")
    if use_profile is None:
        out.print(f"{log}: profile fitted on frame(s) {idx} ({profile.encoding}); {where} -> {out_path}")
    else:
        out.print(f"{log}: profile {use_profile} ({profile.encoding}); {where}")
    if report is not None:
        from ..sonar.comparison import compare, write_report

        all_frames = [seq[i] for i in range(min(n, max(1, max_report)))]
        comps = compare(all_frames, profile)
        paths = write_report(report, comps, profile, all_frames, fitted_on=tuple(i for i in idx if i < len(all_frames)))
        for c in comps:
            s = c.scores()
            met = sum(1 for v in s.values() if v["met"])
            tot = sum(1 for v in s.values() if v["met"] is not None)
            out.print(f"  frame {c.index}: {met}/{tot} targets met; contrast {c.real.contrast:.3g} vs {c.sim.contrast:.3g}, "
                      f"KS {c.ks:.3g}")
        out.print(f"report: {len(paths)} files in {report}")
