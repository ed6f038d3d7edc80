"""The forward-looking imaging sonar: specs and presets, image formation, noise, display."""

from .display import polar_to_fan, save_png, to_display
from .distributions import (
    BOTTOM_TYPES,
    KDistribution,
    Rayleigh,
    RayleighMixture,
    Weibull,
    bottom_model,
    compare_models,
    goodness_of_fit,
)
from .formation import SonarOptions, caster_for, simulate_sonar
from .frame import FanImage, MeasuredSonarFrame, SonarFrame, SonarGroundTruth, SonarImageLike, SonarRays
from .noise import NoEchoWarning, NoiseModel
from .propagation import Seawater, absorption_db_per_m, two_way_gain
from .spec import PRESETS, SonarSpec

__all__ = [
    "BOTTOM_TYPES",
    "FanImage",
    "KDistribution",
    "MeasuredSonarFrame",
    "NoEchoWarning",
    "NoiseModel",
    "Rayleigh",
    "RayleighMixture",
    "Weibull",
    "bottom_model",
    "compare_models",
    "goodness_of_fit",
    "PRESETS",
    "Seawater",
    "SonarFrame",
    "SonarGroundTruth",
    "SonarImageLike",
    "SonarOptions",
    "SonarRays",
    "SonarSpec",
    "absorption_db_per_m",
    "caster_for",
    "polar_to_fan",
    "save_png",
    "simulate_sonar",
    "to_display",
    "two_way_gain",
]
