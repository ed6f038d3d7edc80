"""``oas workbench``: the local web page for matching, reconstruction, calibration and fusion."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import Vec3, app, console, quiet, reports_errors, resolve_input


@app.command("workbench")
@reports_errors
def workbench_cmd(
    source: Optional[str] = typer.Argument(None, metavar="[SOURCE]",
                                           help="Built-in scene or scene file to simulate (default: the thesis's "
                                                "scene 1), or a dataset folder."),
    rig_file: Optional[Path] = typer.Option(None, "--rig", help="Rig file (YAML/JSON); default: the thesis's rig."),
    eye: Optional[Vec3] = typer.Option(None, "--eye", help="Sonar position X Y Z (m); default: the scene's view."),
    target: Optional[Vec3] = typer.Option(None, "--target", help="Point the sonar looks at X Y Z (m)."),
    water: str = typer.Option("thesis", "--water", help="Water type (oas waters)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the simulated noise."),
    sonar_log: Optional[Path] = typer.Option(None, "--sonar-log", help="Real pair: the sonar log (with --camera-log, --rig)."),
    camera_log: Optional[Path] = typer.Option(None, "--camera-log", help="Real pair: the camera log or image folder."),
    frame: int = typer.Option(0, "--frame", help="Frame index of a real pair or dataset."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to serve on (loopback unless --allow-remote)."),
    port: int = typer.Option(8765, "--port", help="Port (0: any free port)."),
    allow_remote: bool = typer.Option(False, "--allow-remote",
                                      help="Allow a non-loopback --host; the page then needs a per-run token."),
    no_browser: bool = typer.Option(False, "--no-browser", help="Do not open the page in a browser."),
    seabed_altitude: Optional[float] = typer.Option(None, "--seabed-altitude", metavar="M", help="Real pair: the "
                                                    "sonar's height above a flat seabed (m), from the navigation. "
                                                    "'Suggest matches' needs it for a soft-beam sonar (every real one)."),
    seabed_pitch: float = typer.Option(0.0, "--seabed-pitch", metavar="DEG", help="With --seabed-altitude: the "
                                       "sonar's boresight pitch below horizontal (deg)."),
    seabed_roll: float = typer.Option(0.0, "--seabed-roll", metavar="DEG", help="With --seabed-altitude: the sonar's "
                                      "roll, right side down (deg)."),
    seabed_sigma_z: float = typer.Option(0.0, "--seabed-sigma-z", metavar="S", help="With --seabed-altitude: its "
                                         "standard deviation (m)."),
    seabed_sigma_tilt: float = typer.Option(0.0, "--seabed-sigma-tilt", metavar="DEG", help="With --seabed-altitude: "
                                            "pitch and roll standard deviation (deg)."),
):
    """Serve the opti-acoustic workbench: epipolar-guided matching, reconstruction, calibration, fusion."""
    from rich.markup import escape

    from ..rig import Rig
    from ..workbench import Session
    from ..workbench import sources as src
    from ..workbench.server import free_port, is_loopback, serve
    from .common import resolve_scene

    rig_file = resolve_input(rig_file) if rig_file is not None else None  # examples/... from any folder
    if port < 0 or port > 65535:
        raise ValueError(f"--port: expected 0-65535, got {port}")
    if not is_loopback(host) and not allow_remote:
        raise ValueError(f"--host {host}: not a loopback address; add --allow-remote to serve beyond this machine "
                         "(every request then needs the per-run token printed here)")
    if sonar_log is not None or camera_log is not None:
        if sonar_log is None or camera_log is None or rig_file is None:
            raise ValueError("a real pair needs --sonar-log, --camera-log and --rig")
        make = lambda k=None: src.real_pair(sonar_log, camera_log, rig_file, index=frame if k is None else k)  # noqa: E731
    elif source is not None and Path(source).is_dir():
        make = lambda k=None: src.dataset_pair(Path(source), index=frame if k is None else k)  # noqa: E731
    else:
        rig = Rig.load(rig_file) if rig_file is not None else Rig.from_dict(src.THESIS_RIG, "thesis rig")
        scene = resolve_scene(source or "thesis_scene1")
        make = lambda k=None: src.simulated_pair(scene, rig, eye=eye, target=target, water=water, seed=seed)  # noqa: E731
    seabed = _navigation_seabed(seabed_altitude, seabed_pitch, seabed_roll, seabed_sigma_z, seabed_sigma_tilt)
    if not quiet():
        console.print("preparing the pair ...")
    pair = make()
    session = Session(pair, seabed=seabed)
    if port == 0:
        port = free_port(host)
    if not is_loopback(host):
        console.print(f"[bold yellow]warning:[/] serving on {escape(host)}: anyone who can reach this address and has the "
                      "token URL can use the workbench (and see your data)", highlight=False)

    def ready(url):
        # printed under --quiet too: the address (with its token) is what the command gives, not a progress line
        print(f"optiacoustic workbench: {url}  (Ctrl+C stops it)", flush=True)

    serve(session, host=host, port=port, allow_remote=allow_remote, open_browser=not no_browser, on_ready=ready,
          sources={f"{pair.kind}: {pair.name} (as started)": make})


def _navigation_seabed(altitude, pitch_deg, roll_deg, sigma_z, sigma_tilt_deg):
    """The matcher's seabed from ``--seabed-altitude`` and its companions (``None`` without it)."""
    import math

    if altitude is None:
        if pitch_deg or roll_deg or sigma_z or sigma_tilt_deg:
            raise ValueError("--seabed-pitch, --seabed-roll, --seabed-sigma-z and --seabed-sigma-tilt describe the "
                             "seabed of --seabed-altitude: give --seabed-altitude too")
        return None
    from ..matching import SeabedPlane
    from ..matching.acoustic import check_sigma

    sigma_z, sigma_tilt_deg = check_sigma("--seabed-sigma-z", sigma_z), check_sigma("--seabed-sigma-tilt", sigma_tilt_deg)
    try:
        return SeabedPlane.from_attitude(altitude, pitch_deg, roll_deg, sigma_height=sigma_z,
                                         sigma_tilt=math.radians(sigma_tilt_deg))
    except ValueError as exc:
        raise ValueError(f"--seabed-altitude/--seabed-pitch/--seabed-roll: {exc}") from None
