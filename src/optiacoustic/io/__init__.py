"""Real data in and out: vendor sonar files, ROS 1/2 bags and MCAP, cameras, rigs.

Names are imported lazily (``oas --help`` stays fast and rosbags/cv2 load only when used).
Each public name maps to the module that defines it, one line per name, sorted, so that
adding a reader or writer is a one-line change.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "MeasuredSonarFrame": "optiacoustic.sonar.frame",
    "DatasetError": "optiacoustic.io.dataset",
    "ReadError": "optiacoustic.io.errors",
    "open_aris": "optiacoustic.io.aris",
    "open_camera": "optiacoustic.io.camera",
    "open_dataset": "optiacoustic.io.dataset",
    "local_cluster": "optiacoustic.io.dataset",
    "open_oculus": "optiacoustic.io.oculus",
    "open_sonar": "optiacoustic.io.sonar",
    "pair_frames": "optiacoustic.io.pairing",
    "read_camera_info": "optiacoustic.io.camera_info",
    "read_rig": "optiacoustic.io.rig",
    "typestore": "optiacoustic.io.rosmsg",
    "write_dataset": "optiacoustic.io.dataset",
    "write_mcap": "optiacoustic.io.mcap_writer",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'optiacoustic.io' has no attribute {name!r}") from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
