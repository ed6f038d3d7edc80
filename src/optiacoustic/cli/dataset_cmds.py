"""``oas dataset`` (simulated sequences to Zarr on Dask), ``oas export`` (Zarr to MCAP), ``oas convert``."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import app, console, out, quiet as quiet_all, reports_errors, resolve_input


def _progress_bar():
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn,
                               TimeElapsedColumn, TimeRemainingColumn)
    from rich.text import Text

    class Rate(ProgressColumn):
        def render(self, task):
            speed = task.finished_speed or task.speed
            return Text("  -  frames/s" if speed is None else f"{speed:6.2f} frames/s")

    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), Rate(),
                    TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(), console=console, transient=False,
                    refresh_per_second=4)  # the scheduler shares this process: redraw sparingly


@app.command("dataset")
@reports_errors
def dataset_cmd(
    config: Path = typer.Argument(..., metavar="CONFIG.yaml", help="Dataset configuration (docs/datasets.md)."),
    out_path: Path = typer.Option(..., "--out", help="Output Zarr store (DATA.zarr); rerun to resume."),
    workers: Optional[int] = typer.Option(None, "--workers", min=0,
                                          help="Local Dask worker processes (default: all cores; 0: no Dask)."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Address of an existing Dask scheduler."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar (as `oas -q dataset`)."),
):
    """Render a synchronised sonar + camera sequence with ground truth into Zarr, on Dask; resumable."""
    from ..io.dataset import write_dataset

    config = resolve_input(config)  # examples/... works from any folder
    bar = None
    task = None

    def progress(done, total):
        nonlocal bar, task
        if bar is None:  # started only once the config and the output are accepted
            bar = _progress_bar()
            bar.start()
            task = bar.add_task("frames", total=total)
        bar.update(task, completed=done, total=total)

    try:
        rep = write_dataset(config, out_path, workers=workers, scheduler=scheduler,
                            progress=None if quiet or quiet_all() else progress)
    finally:
        if bar is not None:
            bar.stop()
    busy, busy_cpu = rep.render_s + rep.write_s, rep.render_cpu_s + rep.write_cpu_s
    share = f", {100 * rep.write_s / busy:.0f} % of frame time writing" if busy > 0 else ""
    if busy_cpu > 0:
        share += f" ({100 * rep.write_cpu_s / busy_cpu:.0f} % of its CPU)"
    out.print(f"{rep.path}: wrote {rep.written}, already done {rep.skipped} in {rep.elapsed:.1f} s{share}",
              highlight=False)


@app.command("export")
@reports_errors
def export_cmd(
    dataset: Path = typer.Argument(..., metavar="DATA.zarr", help="A dataset written by `oas dataset`."),
    mcap: Path = typer.Option(..., "--mcap", help="Output MCAP file (ROS 2 messages)."),
    sonar_dtype: str = typer.Option("float32", "--sonar-dtype", help="float32, uint8 or uint16 sonar data."),
    full_scale: Optional[float] = typer.Option(None, "--full-scale",
                                               help="Intensity of the top count for uint8/uint16 (default: 99.9th pct)."),
    sonar_encoding: Optional[str] = typer.Option(None, "--sonar-encoding",
                                                 help="Device units for the sonar: oculus_gamma8 or aris_db."),
    camera_encoding: str = typer.Option("32FC3", "--camera-encoding", help="32FC3 (linear) or rgb8 (sRGB)."),
    start_time: float = typer.Option(0.0, "--start-time", help="ROS time (s) of dataset time 0."),
    ground_truth: bool = typer.Option(True, "--ground-truth/--no-ground-truth", help="Ground-truth topics."),
):
    """Write a dataset as ROS 2 messages (ProjectedSonarImage, Image, CameraInfo, TF) into an MCAP file."""
    from ..io.mcap_writer import StartTimeError, write_mcap

    try:
        p = write_mcap(dataset, mcap, sonar_dtype=sonar_dtype, full_scale=full_scale, sonar_encoding=sonar_encoding,
                       camera_encoding=camera_encoding, start_time=start_time, ground_truth=ground_truth)
    except StartTimeError as exc:  # the library names its argument; here the user typed the option
        raise ValueError(f"--start-time: {exc.reason}") from None
    out.print(f"wrote {p} ({p.stat().st_size / 1e6:.1f} MB)", highlight=False)


@app.command("convert")
@reports_errors
def convert_cmd(
    log: Path = typer.Argument(..., metavar="LOG", help="ARIS, Oculus, ROS 1 .bag, ROS 2 bag folder or .mcap."),
    out_path: Path = typer.Option(..., "--out", help="Output Zarr store (DATA.zarr); must not exist."),
    topic: Optional[str] = typer.Option(None, "--topic", help="Sonar topic of a bag (default: its only one)."),
    camera: Optional[Path] = typer.Option(None, "--camera", help="Camera bag or image folder (default: LOG with --camera-topic)."),
    camera_topic: Optional[str] = typer.Option(None, "--camera-topic", help="Camera image topic of a bag."),
    skip_damaged: bool = typer.Option(False, "--skip-damaged", help="Leave damaged frames out instead of stopping."),
):
    """Turn a real log into the dataset layout (sonar image, raw values, time, ranges, azimuths; camera images)."""
    from ..io.convert import convert_log

    res = convert_log(log, out_path, topic=topic, camera=camera, camera_topic=camera_topic,
                      errors="skip" if skip_damaged else "raise")
    skipped = f", skipped frames {res['skipped']}" if res["skipped"] else ""
    cams = f", {res['camera_frames']} camera frames" if res["camera_frames"] else ""
    out.print(f"{res['path']}: {res['frames']} sonar frames{cams}{skipped}", highlight=False)
