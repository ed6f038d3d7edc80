"""Readers and writers: real logs in, datasets and ROS 2 messages out.

Names are imported lazily so that ``import optiacoustic.io`` stays cheap.
"""

from __future__ import annotations

__all__ = ["open_dataset", "write_dataset", "write_mcap"]


def __getattr__(name):
    if name in ("open_dataset", "write_dataset"):
        from . import dataset

        return getattr(dataset, name)
    if name == "write_mcap":
        from .mcap_writer import write_mcap

        return write_mcap
    raise AttributeError(f"module 'optiacoustic.io' has no attribute {name!r}")
