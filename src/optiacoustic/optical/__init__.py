"""The underwater camera: water types, lights and Jaffe-McGlamery rendering (thesis ch. 3).

``simulate_optical(scene, camera, pose, water=..., lights=...)`` renders an
:class:`OpticalFrame` with every stage of the model (clear, attenuated, forward scatter,
backscatter, final image) and ground truth (depth, body ids, normals). Derivations of
every formula: docs/derivations.md (ch. 3).
"""

from ._sanity import BlindCameraWarning
from .frame import STAGES, OpticalFrame, auto_exposure, save_png, to_srgb8
from .lights import Light, default_lights
from .render import OpticalOptions, SensorNoise, backscatter, forward_scatter, simulate_optical
from .water import JERLOV_KD, PhaseFunction, Water, jerlov_iops

__all__ = [
    "BlindCameraWarning",
    "JERLOV_KD",
    "Light",
    "OpticalFrame",
    "OpticalOptions",
    "PhaseFunction",
    "STAGES",
    "SensorNoise",
    "Water",
    "auto_exposure",
    "backscatter",
    "default_lights",
    "forward_scatter",
    "jerlov_iops",
    "save_png",
    "simulate_optical",
    "to_srgb8",
]
