"""The forward-looking imaging sonar: specs and presets, image formation, noise, display."""

from .display import polar_to_fan, save_png, to_display
from .formation import SonarOptions, caster_for, simulate_sonar
from .frame import FanImage, SonarFrame, SonarGroundTruth, SonarRays
from .propagation import Seawater, absorption_db_per_m, two_way_gain
from .spec import PRESETS, SonarSpec

__all__ = [
    "FanImage",
    "PRESETS",
    "Seawater",
    "SonarFrame",
    "SonarGroundTruth",
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
