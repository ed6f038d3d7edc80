"""``oas info FILE``: what a sonar log or bag holds (format, topics, frame counts, device settings)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .common import app, out, reports_errors


@app.command("info")
@reports_errors
def info(
    path: Path = typer.Argument(..., help="Sonar log: .aris, Oculus ping stream, ROS 1 .bag, ROS 2 bag folder or .mcap."),
    topic: Optional[str] = typer.Option(None, "--topic", help="Bag topic to describe (default: every topic, and the sonar topic if there is one)."),
):
    """List the format, topics, frame counts and device settings of a log."""
    from ..io.sonar import sniff

    fmt = sniff(path)
    if fmt in ("aris", "oculus"):
        if topic is not None:
            raise ValueError(f"{path}: --topic given but a {fmt} file has no topics")
        _print_sonar(path, None)
        return
    from ..io.rosbag import bag_topics, open_bag

    reader = open_bag(path)
    try:
        topics = bag_topics(reader)
        out.print(f"{path}: ROS bag, {len(topics)} topics, {sum(n for _, n in topics.values())} messages",
                  highlight=False)
        for t, (m, n) in sorted(topics.items()):
            out.print(f"  {t}  {m}  {n} msgs", highlight=False)
    finally:
        reader.close()
    if topic is not None or any(m.endswith("ProjectedSonarImage") for m, _ in topics.values()):
        _print_sonar(path, topic)


def _print_sonar(path, topic):
    from ..io import open_sonar

    with open_sonar(path, topic=topic) as seq:
        d = seq.info()
    d.pop("topics", None)
    for k, v in d.items():
        out.print(f"  {k}: {v}", highlight=False)
