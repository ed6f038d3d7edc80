"""The one error type of the readers: a ``ValueError`` that names where the input is bad."""

from __future__ import annotations

__all__ = ["ReadError", "SkippedFrame", "read_yaml_mapping"]

from dataclasses import dataclass


class ReadError(ValueError):
    """Bad input to a reader: names the file and, where known, the topic, frame and byte offset.

    Attributes
    ----------
    path : str
    topic : str or None
    frame : int or None
        Index of the frame (message) in the file or topic.
    offset : int or None
        Byte offset in the file where the bad field starts.
    reason : str
    """

    def __init__(self, path, reason: str, *, topic=None, frame=None, offset=None):
        self.path = str(path)
        self.reason = reason
        self.topic = topic
        self.frame = frame
        self.offset = offset
        where = [self.path]
        if topic is not None:
            where.append(f"topic {topic}")
        if frame is not None:
            where.append(f"frame {frame}")
        if offset is not None:
            where.append(f"byte offset {offset}")
        super().__init__(f"{', '.join(where)}: {reason}")


@dataclass(frozen=True)
class SkippedFrame:
    """A frame a reader skipped under ``errors="skip"``, and why."""

    index: int
    reason: str


def read_yaml_mapping(path, expected: str) -> dict:
    """A YAML file that must hold a mapping, through the project's one config reader.

    Duplicate keys, alias bombs and deep nesting are refused like in scene files; every
    problem is a :class:`ReadError` naming ``path`` (``expected`` says what the mapping is).
    """
    import yaml

    from .._config import ConfigError, parse_config

    try:
        data = parse_config(path.read_text())
    except (ConfigError, yaml.YAMLError) as exc:
        raise ReadError(path, str(exc)) from None
    if not isinstance(data, dict):
        raise ReadError(path, f"expected {expected}")
    return data
