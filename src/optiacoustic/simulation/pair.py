"""A synchronised sonar + camera frame of an opti-acoustic rig, with ground truth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._atomic import ensure_dir, write_json
from ..frames import Pose
from ..optical import OpticalFrame, OpticalOptions, simulate_optical
from ..rig import Rig
from ..scene import Scene
from ..sonar import SonarFrame, simulate_sonar

__all__ = ["RigFrame", "simulate_rig"]


def _pose_dict(pose: Pose) -> dict:
    return {"R": pose.R.tolist(), "t": pose.t.tolist()}


@dataclass(frozen=True, eq=False)
class RigFrame:
    """What the two sensors of a rig see at one instant.

    Attributes
    ----------
    sonar : SonarFrame
        The sonar frame (its ``.pose`` is the sonar's world pose, sonar axes).
    optical : OpticalFrame
        The camera frame (its ``.pose`` is the camera's world pose, camera axes).
    rig : Rig
        ``P_s = R P_o + t``: camera -> sonar.
    scene_name : str
    """

    sonar: SonarFrame
    optical: OpticalFrame
    rig: Rig
    scene_name: str = ""

    def metadata(self) -> dict:
        """Both poses, the rig, the camera, the water and the lights as a JSON-ready dict."""
        cam = self.rig.camera
        o = self.optical
        return {
            "scene": self.scene_name,
            "convention": "poses map body to world, P_world = R P_body + t; sonar axes X right, Y forward, Z up; "
                          "camera axes X right, Y down, Z forward; rig P_sonar = R P_camera + t",
            "sonar_pose": _pose_dict(self.sonar.pose),
            "camera_pose": _pose_dict(o.pose),
            "rig": {"R": self.rig.R.tolist(), "t": self.rig.t.tolist(),
                    "baseline_m": self.rig.baseline, "vergence_deg": float(np.rad2deg(self.rig.vergence))},
            "camera": {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width,
                       "height": cam.height, "dist": list(cam.dist)},
            "sonar": {"preset": getattr(self.sonar.spec, "name", ""), "n_beams": self.sonar.spec.n_beams,
                      "n_bins": self.sonar.spec.n_bins, "fov_azimuth_deg": float(np.rad2deg(self.sonar.spec.fov_azimuth)),
                      "fov_elevation_deg": float(np.rad2deg(self.sonar.spec.fov_elevation)),
                      "range_min": self.sonar.spec.range_min, "range_max": self.sonar.spec.range_max,
                      "beam_model": getattr(self.sonar, "beam_model", "thesis")},
            "water": {"name": o.water.name, "a": list(o.water.a), "b": list(o.water.b), "c": o.water.c.tolist(),
                      "source": o.water.source},
            "lights": [{"position_world": list(lt.position), "intensity_w_per_sr": list(lt.intensity),
                        "direction_world": None if lt.direction is None else list(lt.direction),
                        "cone_deg": lt.cone_deg} for lt in o.lights],
            "body_names": list(o.body_names),
        }

    def save(self, out_dir) -> list[Path]:
        """Write ``sonar.npz`` + PNGs, ``optical.npz`` + PNGs, ``pair.png`` and ``pair.json``."""
        from ..sonar.display import save_png as save_sonar_png, to_display
        from .figures import save_pair_figure

        out = Path(out_dir)
        ensure_dir(out)
        s = self.sonar
        written = [s.save_npz(out / "sonar.npz")]
        ref = np.percentile(s.intensity[s.intensity > 0], 99.5) if np.any(s.intensity > 0) else 1.0
        p = out / "sonar_polar.png"
        save_sonar_png(p, to_display(s.image, reference=ref)[::-1])
        written.append(p)
        fan = s.fan("image")
        p = out / "sonar_fan.png"
        save_sonar_png(p, to_display(fan.data, reference=ref), mask=fan.mask)
        written.append(p)
        o = self.optical
        written.append(o.save_npz(out / "optical.npz"))
        e = o.exposure("image")
        for stage, exp in (("image", e), ("clear", o.exposure("clear")), ("attenuated", e), ("backscatter", None)):
            written.append(o.save_png(out / f"optical_{stage}.png", stage, exp))
        written.append(save_pair_figure(s, o, out / "pair.png", title=self.scene_name))
        meta = self.metadata()
        meta["files"] = [f.name for f in written]
        p = out / "pair.json"
        write_json(p, meta)
        written.append(p)
        return written


def simulate_rig(scene: Scene, rig: Rig, sonar_pose: Pose, *, water=None, lights=None, seed=None, sonar_noise=None,
                 optical_options: OpticalOptions | None = None) -> RigFrame:
    """Render what a rig's sonar and camera see from one sonar pose.

    Parameters
    ----------
    scene : Scene
    rig : Rig
        Must carry a sonar (``Rig.load`` of a rig file does).
    sonar_pose : Pose
        The sonar's world pose (sonar axes), e.g. ``Pose.look_at(eye, target)``; the
        camera's is ``rig.camera_pose(sonar_pose)``.
    water, lights : see :func:`simulate_optical`.
    seed : int, optional
        Seeds the sonar's noise and the camera's sensor noise.
    sonar_noise : NoiseModel, False or None
        Passed to :func:`~optiacoustic.simulate_sonar` (``None``: its default model).
    optical_options : OpticalOptions, optional
    """
    if not isinstance(rig, Rig):
        raise ValueError(f"rig: expected a Rig, got {type(rig).__name__}")
    if rig.sonar is None:
        raise ValueError("rig: has no sonar; load a rig file with a 'sonar' field or use rig.with_sonar(spec)")
    if not isinstance(sonar_pose, Pose):
        raise ValueError(f"sonar_pose: expected a Pose, got {type(sonar_pose).__name__}")
    sonar = simulate_sonar(scene, rig.sonar, sonar_pose, noise=sonar_noise, seed=seed)
    optical = simulate_optical(scene, rig.camera, rig.camera_pose(sonar_pose), water=water, lights=lights, seed=seed,
                               options=optical_options)
    return RigFrame(sonar, optical, rig, scene.name)
