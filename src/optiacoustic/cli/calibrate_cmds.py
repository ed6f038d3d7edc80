"""``oas calibrate``: the rig's extrinsics from views of a planar grid (thesis appendix A)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer
from rich.table import Table

from .common import app, out, reports_errors, resolve_input, resolve_inputs


@app.command("calibrate")
@reports_errors
def calibrate_cmd(
    views: list[Path] = typer.Argument(..., help="One CSV (u,v,range,azimuth[_deg]) or NPZ file per view of the grid."),
    rig_file: Path = typer.Option(..., "--rig", help="Rig file (YAML/JSON) with the camera and the sonar; its R/t are the start only with --start-from-rig."),
    sigma_pixel: float = typer.Option(1.0, "--sigma-pixel", help="Pixel noise (px)."),
    sigma_range: float = typer.Option(0.01, "--sigma-range", help="Range noise (m)."),
    sigma_azimuth_deg: float = typer.Option(0.2, "--sigma-azimuth-deg", help="Azimuth noise (deg)."),
    start_from_rig: bool = typer.Option(False, "--start-from-rig", help="Start from the rig file's R, t instead of the closed form."),
    out_file: Optional[Path] = typer.Option(None, "--out", help="Write the calibrated rig file (YAML) here."),
    json_file: Optional[Path] = typer.Option(None, "--json", help="Write the full result (JSON) here."),
):
    """Calibrate the rig from matched grid corners: R, t, their uncertainty and the weak directions."""
    import numpy as np  # here, not at the top: `oas --help` must not pay for numpy

    import yaml

    from .._atomic import check_destination, write_json, write_text
    from .._config import load_config
    from ..geometry.calibrate import check_view, extrinsics, load_view
    from ..rig import Rig

    for dest in (out_file, json_file):  # before the solve, not after it
        if dest is not None:
            check_destination(dest)
    rig_file = resolve_input(rig_file)
    rig = Rig.load(rig_file)
    views = resolve_inputs(views)
    vs = [load_view(p) for p in views]
    for p, v in zip(views, vs):
        check_view(v, rig.camera, rig.sonar, name=str(p))
    initial = (rig.R, rig.t) if start_from_rig else None
    res = extrinsics(rig.camera, vs, sigma_pixel=sigma_pixel, sigma_range=sigma_range,
                     sigma_azimuth=float(np.deg2rad(sigma_azimuth_deg)), sonar=rig.sonar, initial=initial)
    if not res:
        raise ValueError(f"calibration failed: {res.message}")
    d = res.to_dict()
    t = Table(title=f"rig extrinsics from {len(vs)} views")
    for c in ("", "value", "std"):
        t.add_column(c)
    angles = d["rotation_about_sonar_xyz_deg"]
    for i, n in enumerate(("pitch (about sonar X)", "roll (about sonar Y)", "yaw (about sonar Z)")):
        t.add_row(n + ", deg", f"{angles[i]:.3f}", f"{d['std_deg_or_mm'][res.DOF_NAMES[i]]:.3f}")
    for i, n in enumerate(("t_x", "t_y", "t_z")):
        t.add_row(n + ", m", f"{res.t[i]:.4f}", f"{res.std[3 + i]:.4f}")
    out.print(t)
    out.print(res.message)
    if res.weak:
        out.print(f"weakly observed: {', '.join(res.weak)} (the sonar does not measure elevation; "
                  "views with the grid spanning the elevation aperture and tilted help)")
    if out_file is not None:
        src = load_config(rig_file, what="rig file")
        data = {k: v for k, v in (src or {}).items() if k in ("sonar", "camera")}
        data["R"] = np.round(res.R, 12).tolist()
        data["t"] = np.round(res.t, 12).tolist()
        write_text(out_file, yaml.safe_dump(data, sort_keys=False, default_flow_style=None))
        out.print(f"wrote {out_file}")
    if json_file is not None:
        write_json(json_file, d)
        out.print(f"wrote {json_file}")
