"""``oas match``: automatic opti-acoustic matches of a rig pair, drawn on both images."""

from __future__ import annotations

from pathlib import Path

import typer

from .common import app, out, reports_errors


@app.command("match")
@reports_errors
def match_cmd(
    pair_dir: Path = typer.Argument(..., metavar="PAIR", help="A rig pair folder written by 'oas render' "
                                    "(sonar.npz, optical.npz, pair.json)."),
    out_dir: Path = typer.Option(Path("out/match"), "--out", help="Output folder."),
    min_score: float = typer.Option(0.0, "--min-score", help="Keep matches with at least this score (0..1)."),
    truth: bool = typer.Option(True, "--truth/--no-truth", help="Mark wrong matches when the pair has a depth map."),
    second: Path = typer.Option(None, "--second", metavar="PAIR2", help="A second pair folder of the same rig after "
                                "it moved: two-view matching (the motion from the two folders' camera poses)."),
    seabed_z: float = typer.Option(None, "--seabed-z", metavar="Z", help="The seabed is the world plane z = Z (m): "
                                   "the matcher takes the seabed from pair.json's sonar_pose (navigation) instead of "
                                   "fitting it to the sonar image. Needed for soft-beam sonars (beam_model "
                                   "'aperture'), which are declined otherwise."),
    seabed_sigma_z: float = typer.Option(0.0, "--seabed-sigma-z", metavar="S", help="With --seabed-z: the altitude's "
                                         "standard deviation (m). The seabed points placed on the plane are scored "
                                         "by the chance that this error leaves them right."),
    seabed_sigma_tilt: float = typer.Option(0.0, "--seabed-sigma-tilt", metavar="DEG", help="With --seabed-z: roll "
                                            "and pitch standard deviation (deg), as --seabed-sigma-z."),
):
    """Match sonar and camera features of a pair; writes matches.png (colour = score) and matches.json.

    With --second, the motion between the pairs is taken from the camera poses their pair.json
    files record (P_camera2 = R_o P_camera1 + t_o): known motion, as a navigation system gives it.
    With --seabed-z, the seabed plane comes from the sonar pose pair.json records (the vehicle's
    attitude and altitude) instead of the sonar image (docs/matching.md, "Soft elevation beams").
    """
    import numpy as np

    from .._atomic import ensure_dir, write_json
    from ..matching import match
    from ..matching.figures import draw_matches
    from ..matching.pairdir import read_pair

    if not 0.0 <= min_score <= 1.0:
        raise ValueError(f"--min-score: must be in [0, 1], got {min_score}")
    if out_dir.exists() and not out_dir.is_dir():  # before the work, not after it
        ensure_dir(out_dir)
    res, bw = _preset_resolution(pair_dir)
    sonar, image, rig, depth = read_pair(pair_dir, range_resolution=res, beamwidth_azimuth=bw)
    kw = {}
    if second is not None:
        sonar2, image2, _, _ = read_pair(second, range_resolution=res, beamwidth_azimuth=bw)
        kw = dict(second=(sonar2, image2), motion=_motion(pair_dir, second))
    if seabed_z is not None:
        kw["seabed"] = _seabed(pair_dir, seabed_z, seabed_sigma_z, seabed_sigma_tilt)
    elif seabed_sigma_z or seabed_sigma_tilt:
        raise ValueError("--seabed-sigma-z and --seabed-sigma-tilt describe the plane of --seabed-z: give --seabed-z too")
    import warnings

    from ..matching import SeabedReliefWarning

    with warnings.catch_warnings():  # its note is in the message printed below
        warnings.simplefilter("ignore", SeabedReliefWarning)
        m = match(sonar, image, rig, min_score=min_score, **kw)
    correct = None
    if truth and depth is not None and m:
        from ..matching.truth import correct as is_correct

        correct = is_correct(rig, depth, m.pixels, m.ranges, m.azimuths,
                             bin_width=float(np.median(np.diff(sonar.ranges))),
                             beam_width=float(np.median(np.diff(sonar.azimuths))))
    ensure_dir(out_dir)
    fig = draw_matches(out_dir / "matches.png", sonar.image, sonar.ranges, sonar.azimuths, image, m,
                       title=pair_dir.name, correct=correct)
    data = {
        "pair": str(pair_dir), "second_pair": None if second is None else str(second), "message": m.message,
        "n_matches": len(m),
        "columns": ["u_px", "v_px", "range_m", "azimuth_rad", "X_cam_m", "Y_cam_m", "Z_cam_m", "score"],
        "matches": np.column_stack([m.pixels, m.ranges, m.azimuths, m.points, m.score]).tolist() if m else [],
    }
    plane = m.seabed
    if plane is not None and plane:
        # the seabed plane the matcher used (sonar frame), where it came from and its error
        data["seabed"] = {
            "source": "navigation (--seabed-z)" if seabed_z is not None else "fitted to the sonar image",
            "normal": [float(x) for x in plane.normal], "offset_m": float(plane.offset),
            "sigma_offset_m": float(plane.sigma_offset), "sigma_tilt_deg": float(np.rad2deg(plane.sigma_tilt)),
            "relief_ratio": None if not np.isfinite(plane.relief_ratio) else float(plane.relief_ratio),
        }
    if m and "face_source" in m.features:
        from ..matching.match import CANDIDATES

        data["candidate"] = [CANDIDATES[int(k)] for k in m.features["face_source"]]
    if correct is not None:
        data["correct_by_depth_map"] = np.asarray(correct).tolist()
        data["precision_by_depth_map"] = float(np.mean(correct))
    js = write_json(out_dir / "matches.json", data)
    out.print(f"{pair_dir}: {m.message}")
    if correct is not None:
        out.print(f"  correct by the pair's depth map: {int(np.sum(correct))} of {len(m)}")
    out.print(f"  {fig}\n  {js}")


def _preset_resolution(pair_dir: Path):
    """Range resolution and beamwidth of the sonar preset named in pair.json, if it is one."""
    import json

    try:
        name = json.loads((pair_dir / "pair.json").read_text())["sonar"]["preset"]
        from ..sonar import SonarSpec

        spec = SonarSpec.preset(name)
        return float(spec.range_resolution), float(spec.beamwidth_azimuth)
    except Exception:  # noqa: BLE001 - no preset: read_pair falls back to the bin and beam spacing
        return None, None


def _pair_pose(folder: Path, key: str, needed_for: str):
    """``(R, t)`` of the pose ``key`` (``"sonar_pose"``, ``"camera_pose"``) a pair folder's pair.json records."""
    import json

    import numpy as np

    path = folder / "pair.json"
    try:
        p = json.loads(path.read_text())[key]
        return np.asarray(p["R"], float).reshape(3, 3), np.asarray(p["t"], float).reshape(3)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: field '{key}' (R, t) needed for {needed_for}: {exc!r}") from None


def _seabed(pair_dir: Path, seabed_z: float, sigma_z: float = 0.0, sigma_tilt_deg: float = 0.0):
    """The seabed plane ``z_world = seabed_z`` in the sonar frame, from pair.json's ``sonar_pose``, with the
    navigation's declared errors (altitude in m, roll and pitch in deg)."""
    import math

    from ..frames import Pose
    from ..matching import SeabedPlane
    from ..matching.acoustic import check_sigma

    sigma_z, sigma_tilt_deg = check_sigma("--seabed-sigma-z", sigma_z), check_sigma("--seabed-sigma-tilt", sigma_tilt_deg)

    R, t = _pair_pose(pair_dir, "sonar_pose", "--seabed-z")
    try:
        pose = Pose(R, t)
    except ValueError as exc:
        raise ValueError(f"{pair_dir / 'pair.json'}: field 'sonar_pose': {exc}") from None
    return SeabedPlane.from_pose(pose, seabed_z=seabed_z, sigma_height=sigma_z,
                                 sigma_tilt=math.radians(sigma_tilt_deg))


def _motion(pair_1: Path, pair_2: Path):
    """``(R_o, t_o)`` with ``P_camera2 = R_o P_camera1 + t_o`` from the camera poses of two pair folders."""
    (R1, t1), (R2, t2) = (_pair_pose(folder, "camera_pose", "--second") for folder in (pair_1, pair_2))
    return R2.T @ R1, R2.T @ (t1 - t2)

