"""Point lights (optionally spot lights) and where they sit.

A light has a position, a radiant intensity per channel ``I`` (W/sr, R G B) and an
optional spot cone. Its irradiance on a surface at distance ``R`` whose normal makes an
angle ``gamma`` with the direction to the light is ``I s(angle) cos(gamma) e^{-c R} / R^2``
(thesis eq. 3.8, with ``s`` the spot profile, 1 for a bare point light).

Lights are given in the camera frame (``frame="camera"``: they move with the vehicle, the
usual ROV case) or in the world (``frame="world"``). The default is one light 0.4 m to
the camera's right and 0.2 m above it, aimed along the optical axis, with a wide soft
spot (60 deg half-power half-angle): a typical ROV lamp beside the camera.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from .._validate import as_array, is_number
from ..frames import Pose

__all__ = ["Light", "default_lights", "resolve_lights", "MIN_LAMP_DISTANCE", "MIN_CONE_DEG"]

#: Default light position in the camera frame (m): 0.4 right, 0.2 up (camera Y is down).
DEFAULT_LIGHT_OFFSET = (0.4, -0.2, 0.0)

#: Closest a lamp may be to the camera's centre of projection in scattering water (m). The
#: single-scattering veil of a lamp at distance d grows as 1/d and is infinite at d = 0 (a lamp at
#: the camera centre gave a veil that grew with the number of slices: 95, 768, 6150 at 32, 256,
#: 2048); at 2 cm the default 32 slices agree with 2048 to 0.4 %. A real lamp sits outside the
#: camera's housing, centimetres from its lens.
MIN_LAMP_DISTANCE = 0.02

#: Narrowest spot (half-power half-angle, deg). Below about 1e-6 deg ``cos`` of the cone rounds to
#: 1 in float64 and the profile's exponent ``log(1/2) / log(cos cone)`` becomes infinite (NaN images);
#: 0.01 deg (0.17 mrad) is narrower than any lamp's beam.
MIN_CONE_DEG = 0.01


@dataclass(frozen=True)
class Light:
    """A point light.

    Parameters
    ----------
    position : (3,) floats
        Position (m) in ``frame``.
    intensity : (3,) floats or float
        Radiant intensity per channel (W/sr) on the spot's axis; a scalar means white.
    direction : (3,) floats, optional
        Spot axis in ``frame`` (normalised here). ``None``: an isotropic point light.
    cone_deg : float, optional
        Half-power half-angle of the spot (deg), in [MIN_CONE_DEG = 0.01, 90]. The spot profile is
        ``cos(angle)^m`` inside the forward hemisphere with ``m`` chosen so that it is
        1/2 at ``cone_deg``; zero behind the lamp. Needs ``direction``.
    frame : {"camera", "world"}
        Frame of ``position`` and ``direction``.
    """

    position: tuple = DEFAULT_LIGHT_OFFSET
    intensity: tuple = (100.0, 100.0, 100.0)
    direction: tuple | None = None
    cone_deg: float | None = None
    frame: Literal["camera", "world"] = "camera"

    def __post_init__(self):
        p = as_array(self.position, "Light.position", (3,))
        it = as_array(self.intensity, "Light.intensity", finite=False).reshape(-1)
        if it.size == 1:
            it = np.repeat(it, 3)
        if it.size != 3 or not np.all(np.isfinite(it)) or np.any(it < 0):
            raise ValueError(f"Light.intensity: expected 3 finite numbers >= 0 (W/sr), got {self.intensity!r}")
        object.__setattr__(self, "position", tuple(float(v) for v in p))
        object.__setattr__(self, "intensity", tuple(float(v) for v in it))
        if self.frame not in ("camera", "world"):
            raise ValueError(f"Light.frame: expected 'camera' or 'world', got {self.frame!r}")
        if self.direction is not None:
            d = as_array(self.direction, "Light.direction", (3,))
            n = np.linalg.norm(d)
            if n < 1e-12:
                raise ValueError("Light.direction: must be a non-zero vector")
            object.__setattr__(self, "direction", tuple(float(v) for v in d / n))
        if self.cone_deg is not None:
            if self.direction is None:
                raise ValueError("Light.cone_deg: a spot needs a direction")
            c = self.cone_deg
            if not is_number(c) or not (np.isfinite(c) and MIN_CONE_DEG <= c <= 90):
                raise ValueError(f"Light.cone_deg: expected a half-angle in [{MIN_CONE_DEG}, 90] deg, got {c!r}")
            object.__setattr__(self, "cone_deg", float(self.cone_deg))

    @property
    def spot_exponent(self) -> float:
        """``m`` of the profile ``cos^m``: ``cos(cone)^m = 1/2``; 0 for a bare point light."""
        if self.cone_deg is None:
            return 0.0
        cc = np.cos(np.deg2rad(self.cone_deg))
        return float(np.log(0.5) / np.log(cc)) if cc > 1e-9 else 0.0

    def in_world(self, camera_pose: Pose) -> "Light":
        """The same light with position and direction in the world frame."""
        if self.frame == "world":
            return self
        d = None if self.direction is None else tuple(camera_pose.directions_to_world(self.direction))
        return Light(tuple(camera_pose.to_world(self.position)), self.intensity, d, self.cone_deg, "world")

    def profile(self, directions_world) -> np.ndarray:
        """Spot profile ``s`` (0..1) for unit directions ``(..., 3)`` leaving the light (world frame)."""
        d = np.asarray(directions_world, float)
        if self.direction is None:
            return np.ones(d.shape[:-1])
        if self.frame != "world":
            raise ValueError("Light.profile: convert the light to the world frame first (in_world)")
        cosang = np.einsum("...i,i->...", d, np.asarray(self.direction, d.dtype))
        if self.cone_deg is None:
            return np.ones(d.shape[:-1])
        return np.where(cosang > 0, np.maximum(cosang, 0.0) ** self.spot_exponent, 0.0)


def default_lights() -> tuple[Light, ...]:
    """One lamp beside the camera: 0.4 m right, 0.2 m up, aimed along the optical axis,
    100 W/sr white on axis, 60 deg half-power half-angle (camera frame)."""
    return (Light(DEFAULT_LIGHT_OFFSET, (100.0, 100.0, 100.0), (0.0, 0.0, 1.0), 60.0, "camera"),)


def resolve_lights(lights, camera_pose: Pose) -> tuple[Light, ...]:
    """``None`` -> the default lamp; a Light or a sequence of Lights -> world-frame lights."""
    if lights is None:
        lights = default_lights()
    elif isinstance(lights, Light):
        lights = (lights,)
    lights = tuple(lights)
    for i, lt in enumerate(lights):
        if not isinstance(lt, Light):
            raise ValueError(f"lights[{i}]: expected a Light, got {type(lt).__name__}")
    return tuple(lt.in_world(camera_pose) for lt in lights)
