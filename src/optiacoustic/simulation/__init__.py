"""Rig simulation: both sensors of a rig on one scene, one ray caster, over time.

The layer above the two sibling simulators (:mod:`optiacoustic.sonar` and
:mod:`optiacoustic.optical`, which never import each other): a synchronised pair at one
pose (:func:`simulate_rig`), trajectories of the rig (:mod:`.trajectory`) and the frame
schedule of a sequence with per-sensor rates (:mod:`.sequence`).
"""

from .pair import RigFrame, simulate_rig
from .sequence import Sequence, SequenceConfig, frame_seed, load_config
from .trajectory import Orbit, Trajectory, WaypointTrajectory, frame_times, lawnmower, load_csv, look_rotations

__all__ = ["Orbit", "RigFrame", "Sequence", "SequenceConfig", "Trajectory", "WaypointTrajectory", "frame_seed",
           "frame_times", "lawnmower", "load_config", "load_csv", "look_rotations", "simulate_rig"]
