"""``open_sonar``: one entry point for every sonar log format, chosen by content and name."""

from __future__ import annotations

from pathlib import Path

from .errors import ReadError

__all__ = ["open_sonar", "sniff"]


def sniff(path) -> str:
    """The format of a log: ``"aris"``, ``"oculus"``, ``"rosbag2"`` (folder, MCAP or SQLite), ``"mcap"``, ``"ros1"``.

    Decided by magic bytes where a format has them, else by name.
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such file or folder")
    if p.is_dir():
        if (p / "metadata.yaml").exists():
            return "rosbag2"
        raise ReadError(p, "a folder but not a rosbag2 bag (no metadata.yaml)")
    with open(p, "rb") as fh:
        head = fh.read(16)
    if len(head) == 0:
        raise ReadError(p, "empty file")
    if head[:4] == b"\x44\x44\x46\x05":  # 0x05464444 little-endian: "DDF\x05"
        return "aris"
    if head[:2] == b"\x53\x4f":  # 0x4f53 little-endian
        return "oculus"
    if head[:8] == b"\x89MCAP0\r\n":
        return "mcap"
    if head[:13] == b"#ROSBAG V2.0\n":
        return "ros1"
    if head[:16] == b"SQLite format 3\x00":
        return "rosbag2"
    suffix = p.suffix.lower()
    if suffix == ".aris":  # the ARIS reader names the bad signature itself
        return "aris"
    known = {".aris": "aris", ".bag": "ros1", ".mcap": "mcap", ".db3": "rosbag2"}
    if suffix in known:
        raise ReadError(p, f"named {suffix} but its first bytes {head[:8]!r} are not a {known[suffix]} file "
                           "(corrupt or truncated header)", offset=0)
    raise ReadError(p, f"unknown sonar log format (first bytes {head[:8]!r}); readable: ARIS .aris, Oculus "
                       "SimplePingResult streams, ROS 1 .bag, ROS 2 bags (MCAP or SQLite), .mcap", offset=0)


def open_sonar(path, *, topic: str | None = None, errors: str = "raise", **options):
    """A lazy sequence of measured sonar frames from a log (``len``, indexing, iteration).

    Parameters
    ----------
    path : path-like
        An ARIS ``.aris`` file, an Oculus ping stream (liboculus raw messages), a ROS 1
        ``.bag``, a ROS 2 bag folder (MCAP or SQLite storage) or a bare ``.mcap`` file.
    topic : str, optional
        For bags: the sonar topic (``marine_acoustic_msgs/ProjectedSonarImage``,
        ``sensor_msgs/Image`` or ``CompressedImage`` polar images). Default: the only
        sonar topic of the bag (an error names the choices when there are several).
    errors : {"raise", "skip"}
        What a damaged frame does while iterating; skipped frames are listed in
        ``.skipped`` and warned about.
    **options
        Reader options (Oculus: ``reading``, ``times``; bag image topics: ``spec``,
        ``encoding``).

    Returns
    -------
    FrameSequence
        Of :class:`optiacoustic.sonar.MeasuredSonarFrame`.
    """
    fmt = sniff(path)
    if topic is not None and fmt in ("aris", "oculus"):
        raise ValueError(f"{path}: topic={topic!r} given but this is a {fmt} file, which has no topics")
    if fmt == "aris":
        from .aris import open_aris

        return open_aris(path, errors=errors, **options)
    if fmt == "oculus":
        from .oculus import open_oculus

        return open_oculus(path, errors=errors, **options)
    from .rosbag import open_bag_sonar

    return open_bag_sonar(path, topic=topic, errors=errors, **options)
