"""What the workbench shows: a synchronised sonar frame and camera image with their rig.

A :class:`Pair` holds measurements only (the polar sonar image with its spec, the camera's
8-bit image, the rig) so that the rest of the workbench works the same on simulated and real
data. Sources:

* :func:`default_pair`: the thesis's scene 1 seen by its rig (BlueView P900-90 and the
  600 x 400 px camera 0.25 m to its left, toed in), noisy sonar, thesis water;
* :func:`simulated_pair`: any scene (built-in name or file given on the command line) and
  any rig file;
* :func:`real_pair`, :func:`dataset_pair`: through the readers of :mod:`optiacoustic.io`
  when they are installed; :class:`SourceUnavailable` (a ``ValueError``) says why not.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..rig import Rig

__all__ = ["Pair", "SourceUnavailable", "THESIS_RIG", "default_pair", "simulated_pair", "real_pair", "dataset_pair",
           "source_kinds", "matcher_available"]

#: The thesis's rig (examples/rig_thesis.yaml): camera 0.25 m to the sonar's left, toed in to
#: aim where the sonar aims from the scene-1 view, rolled level.
THESIS_RIG = {
    "sonar": "blueview-p900-90",
    "camera": {"width_px": 600, "height_px": 400, "sensor_mm": [36, 24], "focal_mm": 50},
    "camera_in_sonar": {"position": [-0.25, 0.0, 0.0], "rotation_deg": [0.0, 0.7543055, -2.2636361]},
}


class SourceUnavailable(ValueError):
    """A source the workbench cannot open here (a reader not installed, a file it cannot read)."""


@dataclass(frozen=True, eq=False)
class Pair:
    """One sonar frame and one camera image of a rig.

    Attributes
    ----------
    name : str
        Shown in the page's title.
    kind : str
        ``"simulated"``, ``"real"`` or ``"dataset"``.
    sonar_image : ndarray, shape (n_bins, n_beams)
        Linear sonar intensity (row = range bin near to far, column = beam left to right).
    spec : SonarSpec
        The sonar: range bins, beam azimuths, apertures.
    camera_rgb8 : ndarray, shape (H, W, 3), uint8
        The camera image, display-referred sRGB.
    rig : Rig
        ``P_s = R P_o + t``; carries the sonar spec.
    description : str
    truth : dict
        Optional ground truth (simulated sources), e.g. the sonar's world pose.
    camera_linear : ndarray, shape (H, W, 3), optional
        The camera image as linear radiance when the source has it (for the automatic matcher).
    frame, n_frames : int
        Which frame of the source this is, of how many (logs and datasets have several).
    beam_model : str
        The sonar's elevation beam (``SonarFrame.beam_model``): ``"aperture"`` (soft) for a real
        sonar, ``"thesis"`` for the simulator's default and the datasets it renders. The automatic
        matcher declines soft-beam frames (docs/matching.md, "Soft elevation beams").
    """

    name: str
    kind: str
    sonar_image: np.ndarray
    spec: object
    camera_rgb8: np.ndarray
    rig: Rig
    description: str = ""
    truth: dict = field(default_factory=dict)
    camera_linear: np.ndarray | None = None
    frame: int = 0
    n_frames: int = 1
    beam_model: str = "thesis"

    def sonar_frame(self):
        """The sonar measurements through the shared frame protocol (``image``, ``ranges``, ``azimuths``, ``spec``)."""
        from types import SimpleNamespace

        return SimpleNamespace(image=self.sonar_image, ranges=self.spec.ranges, azimuths=self.spec.azimuths,
                               spec=self.spec, time=float("nan"), beam_model=self.beam_model)

    def __post_init__(self):
        img = np.asarray(self.sonar_image, np.float32)
        if img.shape != (self.spec.n_bins, self.spec.n_beams):
            raise ValueError(f"sonar_image: expected shape (n_bins, n_beams) = {(self.spec.n_bins, self.spec.n_beams)}, "
                             f"got {img.shape}")
        cam = np.asarray(self.camera_rgb8)
        c = self.rig.camera
        if cam.shape != (c.height, c.width, 3) or cam.dtype != np.uint8:
            raise ValueError(f"camera_rgb8: expected uint8 shape {(c.height, c.width, 3)}, got {cam.dtype} {cam.shape}")
        object.__setattr__(self, "sonar_image", img)


def simulated_pair(scene, rig: Rig, *, eye=None, target=None, water="thesis", seed: int = 0,
                   sonar_noise: bool = True) -> Pair:
    """Simulate what a rig sees of a scene from the sonar pose ``look_at(eye, target)``.

    Parameters
    ----------
    scene : Scene
    rig : Rig
        Must carry a sonar.
    eye, target : array_like (3,), optional
        Sonar position and aim point (world, m); default the scene's suggested view.
    water : str
        Water preset (``oas waters``).
    seed : int
        Seed of the sonar noise and the camera's sensor noise.
    sonar_noise : bool
        The sonar's default noise model (speckle, reverberation) or a noise-free echo.
    """
    from .. import simulate_optical, simulate_sonar
    from ..frames import Pose
    from ..optical import Water

    if rig.sonar is None:
        raise ValueError("rig: has no sonar; give a rig file with a 'sonar' field")
    if eye is None:
        if scene.view is None:
            raise ValueError(f"scene '{scene.name}' has no suggested view: give the sonar's eye and target")
        eye = scene.view.eye
    if target is None:
        target = scene.view.target if scene.view is not None else (0.0, 0.0, 0.0)
    pose = Pose.look_at(np.asarray(eye, float), np.asarray(target, float), body="sonar")
    sonar = simulate_sonar(scene, rig.sonar, pose, noise=None if sonar_noise else False, seed=seed)
    w = Water.preset(water) if isinstance(water, str) else water
    optical = simulate_optical(scene, rig.camera, rig.camera_pose(pose), water=w, seed=seed)
    desc = (f"simulated: scene {scene.name}, sonar {getattr(rig.sonar, 'name', '')} at {np.round(pose.t, 3).tolist()}, "
            f"{w.name} water, seed {seed}{'' if sonar_noise else ', noise-free sonar'}")
    return Pair(scene.name, "simulated", sonar.image, rig.sonar, optical.to_srgb8("image"), rig, desc,
                {"sonar_pose_R": pose.R.tolist(), "sonar_pose_t": pose.t.tolist()}, optical.image)


def default_pair(seed: int = 0) -> Pair:
    """The thesis's scene 1 from its rig: noisy sonar, thesis water."""
    from .. import scenes

    return simulated_pair(scenes.get("thesis_scene1"), Rig.from_dict(THESIS_RIG, "thesis rig"), seed=seed)


def _io():
    try:
        from .. import io  # noqa: F401  (the readers land with the real-data issue)
    except ImportError:
        return None
    return io


def matcher_available() -> tuple[bool, str]:
    """Whether the automatic matcher (``optiacoustic.matching.match``) is installed, and a message."""
    try:
        from .. import matching
    except ImportError:
        matching = None
    if matching is not None and hasattr(matching, "match"):
        return True, "optiacoustic.matching.match: sonar and camera features paired through the rig"
    return False, "not available: the automatic matcher (optiacoustic.matching.match) is not installed in this version"


def source_kinds() -> dict:
    """Which sources this installation can open: ``{kind: (available, message)}``."""
    io = _io()
    real = io is not None and all(hasattr(io, n) for n in ("open_sonar", "open_camera", "read_rig", "pair_frames"))
    data = io is not None and hasattr(io, "open_dataset")
    return {
        "simulated": (True, "a built-in scene or a scene file, through a rig"),
        "real": (real, "sonar log + camera log + rig file" if real else
                 "not available: the real-data readers (optiacoustic.io.open_sonar, open_camera, read_rig, "
                 "pair_frames) are not installed in this version"),
        "dataset": (data, "a frame of a dataset" if data else
                    "not available: the dataset reader (optiacoustic.io.open_dataset) is not installed in this version"),
    }


def _camera_srgb8(image, exposure: float | None = 1.0) -> np.ndarray:
    """A camera image as display sRGB: 8-bit as it is; linear values through the sRGB curve.

    ``exposure`` is the linear value shown white: 1 for a real camera's [0, 1] linear image,
    ``None`` (automatic) for simulated radiance.
    """
    from ..optical.frame import to_srgb8

    a = np.asarray(image)
    if a.dtype == np.uint8:
        return a
    return to_srgb8(np.asarray(a, np.float32), exposure=exposure)


def _rig_for(rig_file, camera):
    """The rig of a real pair: an ``oas`` rig file, else a transform file/bag through ``io.read_rig``."""
    from .. import io

    try:
        return Rig.load(rig_file)
    except ValueError as first:
        try:
            return io.read_rig(rig_file, camera=camera)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{rig_file}: neither an oas rig file ({first}) nor a transform file ({exc})") from None


def real_pair(sonar_log, camera_log, rig_file, *, index: int = 0, sonar_topic: str | None = None,
              camera_topic: str | None = None, max_dt: float = 0.1) -> Pair:
    """A real sonar + camera pair through the readers of :mod:`optiacoustic.io`.

    The sonar and camera frames are paired by time (``io.pair_frames``, within ``max_dt``
    seconds); ``index`` picks the pair. When the logs carry no times (an image folder), the
    frames are paired by their order, and the description says so.
    """
    ok, msg = source_kinds()["real"]
    if not ok:
        raise SourceUnavailable(msg)
    from .. import io

    sonar = io.open_sonar(sonar_log, topic=sonar_topic)
    camera = io.open_camera(camera_log, topic=camera_topic)
    if len(sonar) == 0 or len(camera) == 0:
        raise ValueError(f"no frames: {len(sonar)} sonar frames in {sonar_log}, {len(camera)} camera frames in {camera_log}")
    pairs = io.pair_frames(sonar, camera, max_dt)
    how = f"paired by time within {max_dt} s"
    if len(pairs) == 0:
        n = min(len(sonar), len(camera))
        si, ci, how = np.arange(n), np.arange(n), "paired by order (no common times)"
    else:
        si, ci = pairs.sonar, pairs.camera
    if not 0 <= index < len(si):
        raise ValueError(f"--frame {index}: there are {len(si)} sonar-camera pairs ({how})")
    s, c = sonar[int(si[index])], camera[int(ci[index])]
    rig = _rig_for(rig_file, c.camera)
    if c.camera is not None and (c.camera.width, c.camera.height) != (rig.camera.width, rig.camera.height):
        rig = Rig(rig.R, rig.t, c.camera, rig.sonar)
    rig = rig.with_sonar(s.spec)
    desc = (f"real: sonar {Path(sonar_log).name} frame {int(si[index])}, camera {Path(camera_log).name} frame "
            f"{int(ci[index])}, {how}")
    img = np.asarray(c.image, np.float32)
    return Pair(f"{Path(sonar_log).stem} + {Path(camera_log).stem}", "real", np.asarray(s.image, np.float32), s.spec,
                _camera_srgb8(img), rig, desc, {}, img, index, len(si),
                beam_model=getattr(s, "beam_model", "aperture"))


def dataset_pair(path, *, index: int = 0) -> Pair:
    """Sonar frame ``index`` of a dataset written by ``oas dataset``, with the camera frame nearest in time."""
    ok, msg = source_kinds()["dataset"]
    if not ok:
        raise SourceUnavailable(msg)
    from .. import io
    from ..camera import PinholeCamera
    from ..sonar.frame import spec_from_dict

    tree = io.open_dataset(path)
    meta = tree.attrs.get("optiacoustic", {})
    if "sonar" not in tree.children or "camera" not in tree.children:
        raise ValueError(f"{path}: the workbench needs a dataset with both a sonar and a camera")
    try:
        spec = spec_from_dict(meta["sonar_spec"])
        c = meta["camera"]
        cam = PinholeCamera(fx=c["fx"], fy=c["fy"], cx=c["cx"], cy=c["cy"], width=c["width"], height=c["height"],
                            dist=tuple(c.get("dist", ())))
        rig = Rig(meta["rig"]["R_sonar_from_camera"], meta["rig"]["t_camera_in_sonar"], cam, spec)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: cannot rebuild the rig from the dataset's metadata ({exc})") from None
    son, camd = tree["sonar"], tree["camera"]
    n = int(son.sizes["frame"])
    if not 0 <= index < n:
        raise ValueError(f"--frame {index}: the dataset has {n} sonar frames")
    if not bool(son["done"][index].values):
        raise ValueError(f"{path}: sonar frame {index} was never rendered (an interrupted run); resume it first")
    ts = float(son["time"][index].values)
    tc = np.asarray(camd["time"].values, float)
    done = np.asarray(camd["done"].values, bool)
    if not done.any():
        raise ValueError(f"{path}: no camera frame was rendered")
    j = int(np.flatnonzero(done)[np.argmin(np.abs(tc[done] - ts))])
    img = np.asarray(camd["image"][j].values, np.float32)
    desc = (f"dataset: {Path(path).name}, sonar frame {index} (t = {ts:.3f} s), camera frame {j} "
            f"(t = {tc[j]:.3f} s)")
    return Pair(Path(path).name, "dataset", np.asarray(son["image"][index].values, np.float32), spec,
                _camera_srgb8(img, exposure=None), rig, desc, {}, img, index, n)
