"""A synchronised sequence of a rig along a trajectory: its configuration, its schedule and its frames.

:class:`SequenceConfig` is the validated form of a dataset configuration file (YAML or
JSON; see docs/datasets.md). :class:`Sequence` resolves it once (scene, rig, sonar spec,
water, trajectory) and renders frame ``k`` of either sensor on demand. A frame's noise
depends only on ``(seed, sensor, k)``, so a sequence renders identically whatever the
order or the process its frames are rendered in.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Optional, Union

import numpy as np
from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, ValidationInfo, field_validator,
                      model_validator)

from .._validate import is_integer, strict_number
from ..frames import Pose
from ..rig import Rig
from ..scene import Scene
from .trajectory import Orbit, Trajectory, WaypointTrajectory, frame_times, lawnmower, lawnmower_legs, load_csv

__all__ = ["SequenceConfig", "Sequence", "SENSORS", "BUILTIN_RIGS", "load_config", "frame_seed"]

SENSORS = ("sonar", "camera")

# Built-in rigs (rig-file mappings, see Rig.load). "thesis" is examples/rig_thesis.yaml:
# the BlueView P900-90 and the thesis's 600 x 400 camera 0.25 m to its left, toed in to
# meet the boresight 6.32 m ahead.
BUILTIN_RIGS = {
    "thesis": {
        "sonar": "blueview-p900-90",
        "camera": {"width_px": 600, "height_px": 400, "sensor_mm": [36, 24], "focal_mm": 50},
        "camera_in_sonar": {"position": [-0.25, 0.0, 0.0], "rotation_deg": [0.0, 0.7543055, -2.2636361]},
    },
}

_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)  # every number finite: NaN and inf named by field
MAX_FRAMES = 10_000_000  # per sensor: a run this long is a mistyped duration or rate (~50 TB at 5 MB a pair)


def _whole(v):
    if not is_integer(v):
        raise ValueError(f"expected an integer, not {type(v).__name__}")
    return int(v)


def _flag(v):
    if not isinstance(v, (bool, np.bool_)):
        raise ValueError(f"expected true or false, not {type(v).__name__}")
    return bool(v)


Float = Annotated[float, BeforeValidator(strict_number)]
Int = Annotated[int, BeforeValidator(_whole)]
Bool = Annotated[bool, BeforeValidator(_flag)]
Vec3 = tuple[Float, Float, Float]


class OrbitConfig(BaseModel):
    model_config = _STRICT
    kind: Literal["orbit"]
    center: Vec3 = (0.0, 0.0, 0.0)
    radius: Float = Field(6.0, gt=0, description="m")
    height: Float = Field(2.0, description="sonar height above the centre (m)")
    period: Float = Field(60.0, description="s per revolution; negative turns clockwise")
    phase_deg: Float = Field(-90.0, description="angle of the start position about the centre (deg)")
    target_height: Float = Field(0.0, description="height of the looked-at point above the centre (m)")

    @field_validator("period")
    @classmethod
    def _period(cls, v):
        if not np.isfinite(v) or v == 0:
            raise ValueError("must be finite and non-zero")
        return v

    def build(self, base: Path) -> Trajectory:
        return Orbit(self.center, self.radius, self.height, self.period, float(np.deg2rad(self.phase_deg)),
                     self.target_height)


class LawnmowerConfig(BaseModel):
    model_config = _STRICT
    kind: Literal["lawnmower"]
    area: tuple[Float, Float, Float, Float] = Field(description="x_min, x_max, y_min, y_max (m)")
    height: Float
    spacing: Float = Field(gt=0)
    speed: Float = Field(gt=0)
    tilt_deg: Float = Field(30.0, gt=0, lt=90)
    turn_time: Float = Field(2.0, gt=0)

    @field_validator("area")
    @classmethod
    def _area(cls, v):
        if not (v[1] > v[0] and v[3] >= v[2]):
            raise ValueError("expected x_min < x_max and y_min <= y_max")
        return v

    @field_validator("spacing")
    @classmethod
    def _legs(cls, v, info: ValidationInfo):
        if "area" in info.data:  # a survey of more than MAX_LEGS legs is a mistyped spacing (it hung)
            lawnmower_legs(info.data["area"], v)
        return v

    def build(self, base: Path) -> Trajectory:
        return lawnmower(self.area, self.height, self.spacing, self.speed, tilt=float(np.deg2rad(self.tilt_deg)),
                         turn_time=self.turn_time)


class WaypointConfig(BaseModel):
    model_config = _STRICT
    time: Float
    position: Vec3
    target: Optional[Vec3] = Field(None, description="world point the sonar looks at")
    quaternion: Optional[tuple[Float, Float, Float, Float]] = Field(None, description="x, y, z, w; sonar to world")

    @model_validator(mode="after")
    def _one_orientation(self):
        if (self.target is None) == (self.quaternion is None):
            raise ValueError("give exactly one of 'target' or 'quaternion'")
        if self.target is not None and np.allclose(self.target, self.position, rtol=0, atol=1e-12):
            raise ValueError(f"target == position ({list(self.position)}): the sonar cannot look at its own position")
        if self.quaternion is not None and abs(np.linalg.norm(self.quaternion) - 1) > 1e-3:
            raise ValueError(f"quaternion: norm {np.linalg.norm(self.quaternion):.6g}, expected 1")
        return self


class WaypointsConfig(BaseModel):
    model_config = _STRICT
    kind: Literal["waypoints"]
    interpolation: Literal["cubic", "linear"] = "cubic"
    points: list[WaypointConfig] = Field(min_length=2)

    def build(self, base: Path) -> Trajectory:
        from scipy.spatial.transform import Rotation

        from .trajectory import look_rotations

        t = np.array([p.time for p in self.points])
        pos = np.array([p.position for p in self.points])
        R = np.empty((len(t), 3, 3))
        for i, p in enumerate(self.points):
            R[i] = (look_rotations(np.subtract(p.target, p.position)) if p.target is not None
                    else Rotation.from_quat(p.quaternion).as_matrix())
        return WaypointTrajectory(t, pos, R, interpolation=self.interpolation)


class CsvConfig(BaseModel):
    model_config = _STRICT
    kind: Literal["csv"]
    path: str = Field(description="CSV of time,x,y,z,qx,qy,qz,qw (relative to the config file)")

    def build(self, base: Path) -> Trajectory:
        return load_csv(base / self.path)


class Rates(BaseModel):
    model_config = _STRICT
    sonar: Float = Field(5.0, ge=0, description="Hz; 0 leaves the sonar out")
    camera: Float = Field(1.0, ge=0, description="Hz; 0 leaves the camera out")

    @model_validator(mode="after")
    def _some_sensor(self):
        if self.sonar == 0 and self.camera == 0:
            raise ValueError("both rates are 0; nothing to simulate")
        return self


class NoiseConfig(BaseModel):
    model_config = _STRICT
    sonar: Bool = True
    camera: Bool = True


class OpticalConfig(BaseModel):
    model_config = _STRICT
    slices: Int = Field(32, ge=1, le=512)
    backscatter_step: Int = Field(16, ge=1, le=64)
    shadows: Bool = True


class SequenceConfig(BaseModel):
    """A dataset configuration (docs/datasets.md). Unknown fields are errors."""

    model_config = _STRICT
    scene: str = Field(description="built-in scene name or scene file (relative to the config file)")
    rig: Union[str, dict] = Field("thesis", description="built-in rig name, rig file, or an inline rig mapping")
    sonar: Union[str, dict, None] = Field(None, description="overrides the rig's sonar: preset or mapping")
    water: str = "thesis"
    seed: Int = Field(0, ge=0)
    duration: Float = Field(gt=0, description="s")
    start: Float = Field(0.0, description="time of the first frame on the trajectory (s)")
    rates: Rates = Rates()
    trajectory: Annotated[Union[OrbitConfig, LawnmowerConfig, WaypointsConfig, CsvConfig], Field(discriminator="kind")]
    noise: NoiseConfig = NoiseConfig()
    optical: OpticalConfig = OpticalConfig()
    ground_truth: Bool = True


def _fmt_error(exc: ValidationError, source: str) -> str:
    err = exc.errors()[0]
    loc = [str(p) for p in err.get("loc", ()) if p not in ("orbit", "lawnmower", "waypoints", "csv")]
    fld = ".".join(loc)
    msg = err.get("msg", "invalid").removeprefix("Value error, ")
    if "input" in err and err.get("type") not in ("missing",) and not isinstance(err["input"], dict):
        msg += f" (got {err['input']!r})"
    more = len(exc.errors()) - 1
    return f"{source}: field '{fld}': {msg}" + (f"; and {more} more error(s)" if more else "")


def load_config(source, *, base_dir=None) -> tuple[SequenceConfig, Path]:
    """Validate a dataset configuration from a YAML/JSON file or a mapping.

    Returns ``(config, base_dir)``; relative paths in it are relative to ``base_dir``
    (the file's folder). Raises ``ValueError`` naming the file and the field.
    """
    if isinstance(source, SequenceConfig):
        return source, Path(base_dir or ".").resolve()
    if isinstance(source, dict):
        data, name, base = source, "<config>", Path(base_dir or ".")
    else:
        from .._config import load_config as read_config_file

        path = Path(source)
        # the project's one YAML reader: size limit, duplicate keys, alias bombs, depth; names the file
        data = read_config_file(path, what="config file")
        name, base = str(path), path.parent
    if not isinstance(data, dict):
        raise ValueError(f"{name}: expected a mapping at the top level, got {type(data).__name__}")
    try:
        return SequenceConfig.model_validate(data), base.resolve()
    except ValidationError as exc:
        raise ValueError(_fmt_error(exc, name)) from None


def _schedule_times(c: SequenceConfig, sensor: str) -> np.ndarray:
    """Frame times of ``sensor`` under ``c``, refusing more than :data:`MAX_FRAMES` frames and a ``start``
    so large that float64 times could not keep the frames apart (they would all fall on one time)."""
    rate = getattr(c.rates, sensor)
    n = c.duration * rate
    if n > MAX_FRAMES:
        raise ValueError(f"fields 'duration' and 'rates.{sensor}': {c.duration:g} s at {rate:g} Hz is {n:.3g} "
                         f"{sensor} frames; at most {MAX_FRAMES:g} per sensor")
    if rate > 0 and np.spacing(abs(c.start) + c.duration) * rate > 1e-3:
        raise ValueError(f"field 'start': {c.start:g} s is too large for float64 times to hold frames "
                         f"{1 / rate:g} s apart (rounding {np.spacing(abs(c.start) + c.duration):g} s)")
    return frame_times(rate, c.duration, c.start)


def frame_seed(seed: int, sensor: str, index: int) -> np.random.Generator:
    """The noise generator of frame ``index`` of ``sensor``: a function of these three alone."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), SENSORS.index(sensor), int(index)]))


@dataclass(frozen=True, eq=False)
class SensorSchedule:
    """Frame times ``(n,)`` (s) and sensor-to-world poses ``(n, 4, 4)`` of one sensor."""

    times: np.ndarray
    poses: np.ndarray

    def __len__(self) -> int:
        return len(self.times)

    def pose(self, k: int) -> Pose:
        return Pose(self.poses[k, :3, :3], self.poses[k, :3, 3])


class Sequence:
    """A configuration resolved: scene, rig, sonar spec, water, trajectory and both schedules.

    Parameters
    ----------
    config : SequenceConfig, mapping, or path of a YAML/JSON file
    base_dir : path, optional
        Folder that relative paths in a mapping config are relative to.
    """

    def __init__(self, config, *, base_dir=None):
        self.config, self.base_dir = load_config(config, base_dir=base_dir)
        source = str(config) if isinstance(config, (str, Path)) else "<config>"
        try:
            self._resolve()
        except ValueError as exc:
            msg = str(exc)
            raise ValueError(msg if msg.startswith(source) else f"{source}: {msg}") from None

    def _resolve(self):
        from .. import scenes
        from ..optical import Water
        from ..sonar import SonarSpec

        c = self.config
        # scene: a file (relative to the config) or a built-in
        p = self.base_dir / c.scene
        if p.suffix.lower() in (".yaml", ".yml", ".json") or p.is_file():
            self.scene = Scene.load(p)
        elif c.scene in scenes.names():
            self.scene = scenes.get(c.scene)
        else:
            raise ValueError(f"field 'scene': {c.scene!r} is neither a scene file nor a built-in scene {scenes.names()}")
        if isinstance(c.rig, dict):
            rig = Rig.from_dict(dict(c.rig), "field 'rig'")
        elif c.rig in BUILTIN_RIGS:
            rig = Rig.from_dict(BUILTIN_RIGS[c.rig], f"rig '{c.rig}'")
        else:
            rp = self.base_dir / c.rig
            if not rp.is_file():
                raise ValueError(f"field 'rig': {c.rig!r} is neither a rig file nor a built-in rig {sorted(BUILTIN_RIGS)}")
            rig = Rig.load(rp)
        if c.sonar is not None:
            rig = rig.with_sonar(SonarSpec.from_dict(c.sonar if isinstance(c.sonar, str) else dict(c.sonar),
                                                     "field 'sonar'"))
        self.rig = rig
        try:
            self.water = Water.preset(c.water)
        except (KeyError, ValueError) as exc:
            raise ValueError(f"field 'water': {exc.args[0] if exc.args else exc}") from None
        try:
            self.trajectory = c.trajectory.build(self.base_dir)
        except ValueError as exc:
            raise ValueError(f"field 'trajectory': {exc}") from None
        t_rig = np.eye(4)
        t_rig[:3, :3], t_rig[:3, 3] = rig.R, rig.t
        sched = {}
        for sensor in SENSORS:
            times = _schedule_times(c, sensor)
            try:
                T = self.trajectory.matrices(times) if len(times) else np.zeros((0, 4, 4))
            except ValueError as exc:
                msg = str(exc)
                if msg.startswith("times:"):  # the frames fall outside the trajectory's time span
                    msg = msg.removeprefix("times:").strip().replace(" lies ", " lie ", 1)
                    raise ValueError(f"fields 'start' and 'duration': the {sensor}'s frame times {msg}") from None
                raise ValueError(f"field 'trajectory': at the {sensor}'s frames: {msg}") from None
            # the rig moves as one body: camera_to_world = sonar_to_world @ camera_to_sonar
            sched[sensor] = SensorSchedule(times, T if sensor == "sonar" else T @ t_rig)
        self.sonar, self.camera = sched["sonar"], sched["camera"]

    # ------------------------------------------------------------------ identity
    def canonical(self) -> dict:
        """The configuration as plain data, with the resolved scene, for comparing runs."""
        from ..scene.io import scene_to_dict

        return {"config": self.config.model_dump(mode="json"), "scene": scene_to_dict(self.scene, str(self.base_dir))}

    def fingerprint(self) -> str:
        """SHA-256 of :meth:`canonical` (what must match for a run to resume an output)."""
        return hashlib.sha256(json.dumps(self.canonical(), sort_keys=True).encode()).hexdigest()

    def schedule(self, sensor: str) -> SensorSchedule:
        return {"sonar": self.sonar, "camera": self.camera}[sensor]

    # ------------------------------------------------------------------ frames
    def prepare(self) -> None:
        """Build the scene's ray caster (its BVH) now rather than on the first frame."""
        from ..raycast import caster_for

        caster_for(self.scene)

    def render_sonar(self, k: int):
        """Sonar frame ``k``: a :class:`~optiacoustic.SonarFrame` (noise from :func:`frame_seed`)."""
        from ..sonar import simulate_sonar

        noise = None if self.config.noise.sonar else False
        return simulate_sonar(self.scene, self.rig.sonar, self.sonar.pose(k), noise=noise,
                              seed=frame_seed(self.config.seed, "sonar", k))

    def render_camera(self, k: int):
        """Camera frame ``k``: an :class:`~optiacoustic.OpticalFrame` (noise from :func:`frame_seed`)."""
        from ..optical import OpticalOptions, simulate_optical

        o = self.config.optical
        opts = OpticalOptions(slices=o.slices, backscatter_step=o.backscatter_step, shadows=o.shadows,
                              noise=None if self.config.noise.camera else False)
        return simulate_optical(self.scene, self.rig.camera, self.camera.pose(k), water=self.water,
                                seed=frame_seed(self.config.seed, "camera", k), options=opts)
