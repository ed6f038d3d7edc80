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

import numpy as np

from ..rig import Rig

__all__ = ["Pair", "SourceUnavailable", "THESIS_RIG", "default_pair", "simulated_pair", "real_pair", "dataset_pair",
           "source_kinds"]

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
    """

    name: str
    kind: str
    sonar_image: np.ndarray
    spec: object
    camera_rgb8: np.ndarray
    rig: Rig
    description: str = ""
    truth: dict = field(default_factory=dict)

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
                {"sonar_pose_R": pose.R.tolist(), "sonar_pose_t": pose.t.tolist()})


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


def real_pair(sonar_log, camera_log, rig_file, *, index: int = 0, topic: str | None = None) -> Pair:
    """A real sonar + camera pair through the readers of :mod:`optiacoustic.io`."""
    ok, msg = source_kinds()["real"]
    if not ok:
        raise SourceUnavailable(msg)
    raise SourceUnavailable("not available: the real-pair source is not wired up yet")


def dataset_pair(path, *, index: int = 0) -> Pair:
    """A frame of a dataset written by ``oas dataset``."""
    ok, msg = source_kinds()["dataset"]
    if not ok:
        raise SourceUnavailable(msg)
    raise SourceUnavailable("not available: the dataset source is not wired up yet")
