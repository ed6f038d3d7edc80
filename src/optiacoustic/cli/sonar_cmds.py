"""``oas scenes``, ``oas scene``, ``oas presets``, ``oas sonar``."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from .common import Vec3, app, console, out, quiet, reports_errors, resolve_scene, resolve_view


@app.command("scenes")
def scenes_cmd():
    """List the built-in scenes."""
    from .. import scenes

    t = Table(title="built-in scenes")
    t.add_column("name", no_wrap=True)
    t.add_column("bodies", justify="right")
    t.add_column("description")
    for n in scenes.names():
        s = scenes.get(n)
        t.add_row(n, str(len(s)), s.description)
    out.print(t)


@app.command("scene")
@reports_errors
def scene_cmd(
    name: str = typer.Argument(..., help="Built-in scene name or scene file."),
    export: Optional[Path] = typer.Option(None, "--export", help="Write the scene to this .yaml/.json file."),
):
    """Show a scene, or export it as a starting point for your own (--export FILE)."""
    import yaml

    scene = resolve_scene(name)
    if export is not None:
        scene.save(export)
        out.print(f"wrote {export}")
    else:
        out.print(yaml.safe_dump(scene.to_dict(), sort_keys=False, default_flow_style=None, width=100))


@app.command("presets")
def presets_cmd():
    """List the sonar presets with their sources and unverified values."""
    import numpy as np  # here, not at the top: `oas --help` must not pay for numpy

    from ..sonar import SonarSpec

    t = Table(title="sonar presets", show_lines=True)
    t.add_column("name", no_wrap=True)
    for c in ("kHz", "beams", "fov (deg)", "range (m) / bins", "beam width", "source", "unverified"):
        t.add_column(c)
    for n in SonarSpec.preset_names():
        s = SonarSpec.preset(n)
        t.add_row(
            n,
            f"{s.frequency / 1e3:g}",
            str(s.n_beams),
            f"{np.rad2deg(s.fov_azimuth):.4g} x {np.rad2deg(s.fov_elevation):.4g}",
            f"{s.range_min:g}-{s.range_max:g} / {s.n_bins}",
            f"{np.rad2deg(s.beamwidth_azimuth):.3g} deg",
            s.source,
            "; ".join(s.unverified) or "-",
        )
    out.print(t)


@app.command("sonar")
@reports_errors
def sonar_cmd(
    scene_name: str = typer.Argument(..., metavar="SCENE", help="Built-in scene name or scene file (.yaml/.json)."),
    preset: str = typer.Option("blueview-p900-90", "--preset", help="Sonar preset (oas presets)."),
    eye: Optional[Vec3] = typer.Option(None, "--eye", help="Sonar position X Y Z (m); default: the scene's view."),
    target: Optional[Vec3] = typer.Option(None, "--target", help="Point the sonar looks at X Y Z (m)."),
    out_dir: Path = typer.Option(Path("out/sonar"), "--out", help="Output folder."),
    seed: int = typer.Option(0, "--seed", min=0, help="Noise seed (frame k draws from its own stream, as frame k of a "
                                                      "dataset with this seed)."),
    no_noise: bool = typer.Option(False, "--no-noise", help="Image without noise and reverberation."),
    elevation_samples: Optional[int] = typer.Option(None, "--elevation-samples", min=1, help="Rays per beam across the elevation aperture."),
    spreading: bool = typer.Option(False, "--spreading", help="Simulate spreading and absorption instead of ideal TVG."),
    azimuth_pattern: bool = typer.Option(False, "--azimuth-pattern", help="Cross-beam leakage from the azimuth beam pattern."),
    frames: int = typer.Option(1, "--frames", min=1, help="Render this many frames (different noise seeds)."),
    figures: bool = typer.Option(True, "--figures/--no-figures", help="Write the stage figures."),
    profile_path: Optional[str] = typer.Option(None, "--profile", help="Sensor profile YAML (oas sensor-fit) or a shipped profile's name: renders as that device."),
):
    """Simulate a sonar frame: NPZ (intensity, image, ranges, azimuths, ground truth) and PNGs."""
    import numpy as np  # here, not at the top: `oas --help` must not pay for numpy

    import dataclasses

    from rich.progress import Progress

    from .._atomic import ensure_dir, write_json
    from ..frames import Pose
    from ..sonar import SonarOptions, SonarSpec, simulate_sonar
    from ..sonar.display import save_png, to_display
    from ..sonar.figures import save_stage_figures

    scene = resolve_scene(scene_name)
    e, t = resolve_view(scene, eye, target)
    spec = SonarSpec.preset(preset)
    if elevation_samples is not None:
        spec = dataclasses.replace(spec, elevation_samples=elevation_samples)
    options = SonarOptions(propagation="spreading" if spreading else "tvg", azimuth_pattern=azimuth_pattern)
    profile = None
    if profile_path is not None:
        from ..sonar.profile import SensorProfile

        if Path(profile_path).suffix.lower() in (".yaml", ".yml") or Path(profile_path).exists():
            profile = SensorProfile.load(profile_path)
        else:
            profile = SensorProfile.preset(profile_path)
        options = None  # the profile's image model
    pose = Pose.look_at(e, t)
    from ..simulation.sequence import frame_seed

    ensure_dir(out_dir)
    with Progress(console=console, transient=True, disable=quiet()) as progress:
        task = progress.add_task("simulating", total=frames)
        for k in range(frames):
            t0 = time.perf_counter()
            # frame k's own stream, as a dataset's (was seed + k: frame 1 of --seed 5 was frame 0 of --seed 6)
            frame = simulate_sonar(scene, spec, pose, noise=False if no_noise else None, seed=frame_seed(seed, "sonar", k),
                                   options=options, profile=profile)
            dt = time.perf_counter() - t0
            stem = "frame" if frames == 1 else f"frame_{k:04d}"
            frame.save_npz(out_dir / f"{stem}.npz")
            ref = np.percentile(frame.intensity[frame.intensity > 0], 99.5) if np.any(frame.intensity > 0) else 1.0
            save_png(out_dir / f"{stem}_polar.png", to_display(frame.image, reference=ref)[::-1])
            fan = frame.fan("image")
            save_png(out_dir / f"{stem}_fan.png", to_display(fan.data, reference=ref), mask=fan.mask)
            progress.advance(task)
    written = [out_dir / "frame.npz"] if frames == 1 else [out_dir / "frame_0000.npz"]
    if figures:
        written += [p for p, _ in save_stage_figures(frame, out_dir)]
    meta = {
        "scene": scene.name,
        "preset": spec.name,
        "spec": {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(spec).items()},
        "eye": e.tolist(),
        "target": t.tolist(),
        "pose_R": pose.R.tolist(),
        "pose_t": pose.t.tolist(),
        "seed": seed,
        "noise": not no_noise,
        "profile": profile_path,
        "seconds_last_frame": dt,
        "body_names": list(frame.body_names),
    }
    write_json(out_dir / "frame.json", meta)
    out.print(f"{scene.name} with {spec.name}: {frames} frame(s), last in {dt * 1e3:.0f} ms -> {out_dir}")
