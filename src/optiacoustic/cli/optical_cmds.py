"""``oas optical``, ``oas render`` (sonar + camera pair of a rig), ``oas waters``."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from .common import Vec3, app, out, reports_errors, resolve_input, resolve_scene, resolve_view


@app.command("waters")
def waters_cmd():
    """List the water types (optical presets) with their coefficients and sources."""
    from ..optical import Water

    t = Table(title="water types (R, G, B)", show_lines=True)
    for c in ("name", "a (1/m)", "b (1/m)", "c (1/m)", "source", "doubtful"):
        t.add_column(c)
    f = lambda v: ", ".join(f"{x:.3g}" for x in v)  # noqa: E731
    for n in Water.preset_names():
        w = Water.preset(n)
        t.add_row(n, f(w.a), f(w.b), f(w.c), w.source, "; ".join(w.doubtful) or "-")
    out.print(t)


@app.command("optical")
@reports_errors
def optical_cmd(
    scene_name: str = typer.Argument(..., metavar="SCENE", help="Built-in scene name or scene file (.yaml/.json)."),
    eye: Optional[Vec3] = typer.Option(None, "--eye", help="Camera position X Y Z (m); default: the scene's view."),
    target: Optional[Vec3] = typer.Option(None, "--target", help="Point the camera looks at X Y Z (m)."),
    out_dir: Path = typer.Option(Path("out/optical"), "--out", help="Output folder."),
    water: str = typer.Option("thesis", "--water", help="Water type (oas waters)."),
    width: int = typer.Option(600, "--width", min=1, help="Image width (px)."),
    height: int = typer.Option(400, "--height", min=1, help="Image height (px)."),
    focal_mm: float = typer.Option(50.0, "--focal-mm", help="Focal length (mm) on a 36 x 24 mm sensor."),
    slices: int = typer.Option(32, "--slices", min=1, help="Backscatter slices."),
    seed: Optional[int] = typer.Option(None, "--seed", min=0, help="Sensor-noise seed (no noise without it)."),
    figures: bool = typer.Option(True, "--figures/--no-figures", help="Write the stage figures."),
):
    """Render the underwater camera alone: NPZ (stages, depth, body ids) and PNGs."""
    from .._atomic import ensure_dir
    from ..camera import PinholeCamera
    from ..frames import Pose
    from ..optical import OpticalOptions, simulate_optical
    from ..optical.figures import save_ground_truth_figure, save_stage_figures

    scene = resolve_scene(scene_name)
    e, t = resolve_view(scene, eye, target)
    camera = PinholeCamera.from_sensor(width, height, (36.0, 24.0), focal_mm)
    pose = Pose.look_at(e, t, body="camera")
    t0 = time.perf_counter()
    frame = simulate_optical(scene, camera, pose, water=water, seed=seed, options=OpticalOptions(slices=slices))
    dt = time.perf_counter() - t0
    ensure_dir(out_dir)
    written = [frame.save_npz(out_dir / "optical.npz")]
    if figures:
        written += [p for p, _ in save_stage_figures(frame, out_dir)]
        written.append(save_ground_truth_figure(frame, out_dir / "optical_ground_truth.png"))
    else:
        written.append(frame.save_png(out_dir / "optical_image.png"))
        written.append(frame.save_png(out_dir / "optical_clear.png", "clear"))
    out.print(f"rendered {scene.name} ({width} x {height}, {frame.water.name} water) in {dt * 1e3:.0f} ms")
    for p in written:
        out.print(f"  {p}")


@app.command("render")
@reports_errors
def render_cmd(
    scene_name: str = typer.Argument(..., metavar="SCENE", help="Built-in scene name or scene file (.yaml/.json)."),
    rig_file: Path = typer.Option(..., "--rig", help="Rig file (YAML/JSON), e.g. examples/rig_thesis.yaml."),
    eye: Optional[Vec3] = typer.Option(None, "--eye", help="Sonar position X Y Z (m); default: the scene's view."),
    target: Optional[Vec3] = typer.Option(None, "--target", help="Point the sonar looks at X Y Z (m)."),
    out_dir: Path = typer.Option(Path("out/render"), "--out", help="Output folder."),
    water: str = typer.Option("thesis", "--water", help="Water type (oas waters)."),
    seed: int = typer.Option(0, "--seed", min=0, help="Seed of the sonar noise and the camera's sensor noise."),
    sonar_noise: bool = typer.Option(True, "--sonar-noise/--no-sonar-noise", help="Sonar noise and reverberation."),
):
    """Render a synchronised sonar + camera pair from a rig, with ground truth and both poses."""
    from ..frames import Pose
    from ..optical import Water
    from ..simulation import simulate_rig
    from ..rig import Rig

    scene = resolve_scene(scene_name)
    e, t = resolve_view(scene, eye, target)
    rig = Rig.load(resolve_input(rig_file))
    t0 = time.perf_counter()
    pair = simulate_rig(scene, rig, Pose.look_at(e, t, body="sonar"), water=Water.preset(water), seed=seed,
                        sonar_noise=None if sonar_noise else False)
    dt = time.perf_counter() - t0
    written = pair.save(out_dir)
    out.print(f"rendered {scene.name}: sonar {rig.sonar.name} + camera {rig.camera.width} x {rig.camera.height} "
              f"in {dt:.2f} s")
    for p in written:
        out.print(f"  {p}")
