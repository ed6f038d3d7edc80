"""Reading YAML and JSON configuration files (scenes, rigs) safely and fast.

One reader for every configuration file the project reads, so that each of them refuses the
same hostile or mistaken inputs with a message naming the file:

* a file larger than :data:`MAX_BYTES` (checked before reading it);
* a key given twice in one mapping (``radius: 5`` then ``radius: 0.1``: YAML and JSON
  parsers silently keep the last one);
* aliases that expand to more than :data:`MAX_NODES` values ("billion laughs": a few
  hundred bytes that expand exponentially when the document is walked), and aliases that
  refer to themselves;
* nesting deeper than :data:`MAX_DEPTH`.

Plain (unquoted) numbers in exponent notation are numbers, as in YAML 1.2 and JSON: ``1e9``
and ``2E-3`` are floats (PyYAML follows YAML 1.1, which reads them as text unless written
``1.0e+9``); quoted, they stay text.

YAML goes through libyaml's C parser (``yaml.CSafeLoader``) when PyYAML was built with it,
else the pure-Python ``SafeLoader``; both are safe loaders (no Python objects).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

__all__ = ["ConfigError", "MAX_BYTES", "MAX_DEPTH", "MAX_NODES", "load_config", "parse_config"]

MAX_BYTES = 64 * 2**20
MAX_DEPTH = 100
MAX_NODES = 10_000_000


class ConfigError(ValueError):
    """A configuration file that cannot be read as sane YAML/JSON (the message names the file)."""


_SCALARS: dict = {}
# a plain scalar in exponent notation without the dot or the exponent's sign YAML 1.1 requires
_EXPONENT = re.compile(r"[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)[eE][-+]?[0-9]+")
_TAGS = {"tag:yaml.org,2002:" + t for t in ("str", "int", "float", "bool", "null", "binary", "timestamp")}


def _scalar(event, base):
    """The Python value of a scalar event, as PyYAML's safe loader would make it (memoised: files repeat values)."""
    import yaml

    value, tag = event.value, event.tag
    if tag in (None, "!"):
        if event.style or tag == "!":  # quoted (or the non-specific '!'): a string
            return value
        hit = _SCALARS.get(value)
        if hit is not None or value in _SCALARS:
            return hit
        tag = base.resolve(yaml.ScalarNode, value, (True, False))
        if tag in ("tag:yaml.org,2002:merge", "tag:yaml.org,2002:value"):
            return value
        if tag == "tag:yaml.org,2002:str" and _EXPONENT.fullmatch(value):
            obj = float(value)  # YAML 1.2's float (1e9, 2E-3); YAML 1.1 wants 1.0e+9 and reads 1e9 as text
        else:
            obj = base.construct_object(yaml.ScalarNode(tag, value, style=event.style))
        if len(_SCALARS) < 100_000:
            _SCALARS[value] = obj
        return obj
    if tag not in _TAGS:
        raise ConfigError(f"tag {tag!r} is not supported (line {event.start_mark.line + 1})")
    return base.construct_object(yaml.ScalarNode(tag, value, style=event.style))


class _Open:
    """A mapping or sequence being filled while its events arrive."""

    __slots__ = ("obj", "anchor", "key", "has_key", "size", "merges", "key_mark", "line")

    def __init__(self, obj, anchor, line):
        self.obj, self.anchor, self.line = obj, anchor, line
        self.key, self.has_key, self.size, self.merges, self.key_mark = None, False, 1, [], None


def _parse_yaml(text: str):
    """Build the document from libyaml's event stream, without recursion.

    The composer of PyYAML recurses once per nesting level (a few hundred kilobytes of ``[``
    crash the C one) and its constructor is slow; building from events keeps the C parser,
    checks depth, alias expansion and duplicate keys as it goes, and memoises scalars.
    """
    import yaml

    Loader = getattr(yaml, "CSafeLoader", None) or yaml.SafeLoader
    base = yaml.SafeLoader("")  # its resolver and scalar constructors, nothing else
    anchors: dict = {}  # anchor -> (object, expanded size)
    stack: list[_Open] = []
    docs = []
    total = 0

    def add(value, size, event):
        nonlocal total
        total += size
        if total > MAX_NODES:
            raise ConfigError(f"the document expands to more than {MAX_NODES:,} values (aliases?) "
                              f"(line {event.start_mark.line + 1}); refused")
        if not stack:
            docs.append(value)
            return
        top = stack[-1]
        top.size += size
        if isinstance(top.obj, list):
            top.obj.append(value)
        elif not top.has_key:
            if isinstance(value, (dict, list)):
                raise ConfigError(f"a mapping key must be a plain value, not a {type(value).__name__} "
                                  f"(line {event.start_mark.line + 1})")
            top.key, top.has_key, top.key_mark = value, True, event.start_mark
        else:
            key, mark, top.has_key = top.key, top.key_mark, False
            if key == "<<" and isinstance(event, (yaml.AliasEvent, yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                top.merges.append(value)  # merge key: explicit keys of this mapping win
                return
            if key in top.obj:
                raise ConfigError(f"key {key!r} given twice in one mapping (line {mark.line + 1}); keep one")
            top.obj[key] = value

    events = yaml.parse(text, Loader=Loader)
    for ev in events:
        if isinstance(ev, yaml.ScalarEvent):
            value = _scalar(ev, base)
            if ev.anchor:
                anchors[ev.anchor] = (value, 1)
            add(value, 1, ev)
        elif isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            if len(stack) >= MAX_DEPTH:
                raise ConfigError(f"nesting deeper than {MAX_DEPTH} levels (line {ev.start_mark.line + 1}); refused")
            if ev.tag not in (None, "!", "tag:yaml.org,2002:map", "tag:yaml.org,2002:seq"):
                raise ConfigError(f"tag {ev.tag!r} is not supported (line {ev.start_mark.line + 1})")
            obj = {} if isinstance(ev, yaml.MappingStartEvent) else []
            stack.append(_Open(obj, ev.anchor, ev.start_mark.line + 1))
            if ev.anchor:
                anchors[ev.anchor] = (obj, None)  # open: an alias to it now would refer to itself
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            done = stack.pop()
            for src in done.merges:
                for m in (src if isinstance(src, list) else [src]):
                    if not isinstance(m, dict):
                        raise ConfigError(f"a merge key '<<' needs a mapping (line {done.line})")
                    for k, v in m.items():
                        done.obj.setdefault(k, v)
            if done.anchor:
                anchors[done.anchor] = (done.obj, done.size)
            size, done.size = done.size, 0
            add(done.obj, size, ev)
        elif isinstance(ev, yaml.AliasEvent):
            if ev.anchor not in anchors:
                raise ConfigError(f"alias *{ev.anchor} has no anchor before it (line {ev.start_mark.line + 1})")
            obj, size = anchors[ev.anchor]
            if size is None:
                raise ConfigError(f"alias *{ev.anchor} refers to itself (line {ev.start_mark.line + 1}); refused")
            add(obj, size, ev)
    if len(docs) > 1:
        raise ConfigError(f"expected one document, found {len(docs)}")
    return docs[0] if docs else None


def _json_pairs(pairs):
    out = {}
    for k, v in pairs:
        if k in out:
            raise ConfigError(f"key {k!r} given twice in one object; keep one")
        out[k] = v
    return out


def _json_depth(text: str) -> int:
    """Deepest bracket nesting outside strings, without recursion (json.loads recurses)."""
    import re

    stripped = re.sub(r'"(?:[^"\\]|\\.)*"', '""', text)
    depth = best = 0
    for ch in stripped:
        if ch in "[{":
            depth += 1
            if depth > best:
                best = depth
        elif ch in "]}":
            depth -= 1
    return best


def parse_config(text: str, *, kind: str = "yaml"):
    """Parse YAML (``kind="yaml"``) or JSON text with the checks above; raise :class:`ConfigError`."""
    if kind == "json":
        if _json_depth(text) > MAX_DEPTH:
            raise ConfigError(f"nesting deeper than {MAX_DEPTH} levels; refused")
        try:
            return json.loads(text, object_pairs_hook=_json_pairs)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"not valid JSON: {exc}") from None
    import yaml

    try:
        return _parse_yaml(text)
    except yaml.YAMLError as exc:
        if "maximum nesting depth" in str(exc):  # PyYAML >= 6.0.4 stops at 1000 levels, ahead of the events
            mark = getattr(exc, "problem_mark", None)
            where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
            raise ConfigError(f"nesting deeper than {MAX_DEPTH} levels{where}; refused") from None
        raise ConfigError(f"not valid YAML: {exc}") from None


def load_config(path, *, what: str = "file"):
    """Read a YAML or JSON file (JSON by the ``.json`` suffix) with the checks above.

    Parameters
    ----------
    path : path-like
        The file.
    what : str
        What the file is ("scene file", "rig file"), for messages.

    Returns
    -------
    The parsed document (dicts, lists, scalars).

    Raises
    ------
    ConfigError
        A ``ValueError`` naming the file and what is wrong with it (missing, too big, not
        UTF-8, not valid YAML/JSON, a duplicate key, an alias bomb, too deep).
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: {what} not found" if not path.exists() else f"{path}: {what} is not a file")
    try:
        n = path.stat().st_size
        if n > MAX_BYTES:
            raise ConfigError(f"{path}: {what} is {n:,} bytes, over the limit of {MAX_BYTES:,} bytes "
                              f"({MAX_BYTES / 2**20:g} MiB; optiacoustic._config.MAX_BYTES)")
        text = path.read_bytes().decode("utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: {what} is not UTF-8 text (byte {exc.start})") from None
    try:
        return parse_config(text, kind="json" if path.suffix.lower() == ".json" else "yaml")
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
