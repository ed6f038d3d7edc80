"""Opti-acoustic geometry: epipolar curves, reconstruction, motion, calibration, two-view sonar.

Nothing here imports the simulators: it works on measurements (pixels, ranges, azimuths).
"""

__all__: list[str] = []
