"""Reading and writing scene files (YAML or JSON), with errors that name file, body and field.

Schema (docs/conventions.md, "Scene files", has it in full)::

    name: my_scene                     # optional
    description: ...                   # optional
    view: {eye: [0, -6, 2], target: [0, 0, 0]}   # optional suggested sensor placement
    bodies:
      - name: seabed                   # unique
        shape: plane                   # plane | box | sphere | ellipsoid | cylinder | mesh | klein_bottle
        size: [60, 60]                 # shape parameters, see optiacoustic.scene.shapes
        pose: {position: [0, 0, 0], rotation_deg: [0, 0, 0]}   # about x, then y, then z
        material: {reflectivity: 0.5, color: [0.55, 0.5, 0.4], bottom_type: sand/shell}
"""

from __future__ import annotations

import collections
import dataclasses
import os
from pathlib import Path

import numpy as np
import yaml
from pydantic import ValidationError

from .._atomic import ensure_dir, write_json, write_text
from ..frames import Pose, euler_xyz_from_rotation
from .parts import Body, Material, SceneError, Texture, View
from .shapes import SHAPES, Mesh

__all__ = ["read_scene_parts", "save_scene", "scene_parts_from_dict", "scene_to_dict"]

_TOP_KEYS = {"bodies", "name", "description", "view"}
_BODY_KEYS = {"name", "shape", "pose", "material"}
_POSE_KEYS = {"position", "rotation_deg"}


def _fmt_loc(loc) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _fmt_validation(exc: ValidationError, prefix: str = "") -> tuple[str, str]:
    """(field, message) of the first error of a pydantic ValidationError."""
    err = exc.errors()[0]
    fld = _fmt_loc(err.get("loc", ()))
    if prefix:
        fld = f"{prefix}.{fld}" if fld and not fld.startswith("[") else prefix + fld
    msg = err.get("msg", "invalid").removeprefix("Value error, ")
    if "input" in err and err.get("type") != "missing":
        msg += f" (got {err['input']!r})"
    more = len(exc.errors()) - 1
    if more:
        msg += f"; and {more} more error(s)"
    return fld, msg


def _vec3(value, fld: str, ctx) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise SceneError(ctx(fld, f"expected 3 numbers, got {value!r}")) from None
    if arr.shape != (3,):
        raise SceneError(ctx(fld, f"expected 3 numbers, got {value!r}"))
    if not np.all(np.isfinite(arr)):
        raise SceneError(ctx(fld, f"must be finite, got {value!r}"))
    return arr


def _body_from_dict(raw, index: int, source: str, base_dir: str) -> Body:
    label = f"body #{index}"
    if isinstance(raw, dict) and isinstance(raw.get("name"), str) and raw["name"].strip():
        label = f"body '{raw['name']}' (#{index})"

    def ctx(fld: str, msg: str) -> str:
        return f"{source}: {label}: field '{fld}': {msg}"

    if not isinstance(raw, dict):
        raise SceneError(f"{source}: {label}: expected a mapping of fields, got {type(raw).__name__}")
    for key in ("name", "shape"):
        if key not in raw:
            raise SceneError(ctx(key, "missing (required)"))
    name = raw["name"]
    if not isinstance(name, str) or not name.strip():
        raise SceneError(ctx("name", f"must be a non-empty string, got {name!r}"))
    shape_name = raw["shape"]
    if not isinstance(shape_name, str) or shape_name not in SHAPES:
        raise SceneError(ctx("shape", f"unknown shape {shape_name!r}; expected one of {sorted(SHAPES)}"))

    # pose
    pose_raw = raw.get("pose", {}) or {}
    if not isinstance(pose_raw, dict):
        raise SceneError(ctx("pose", f"expected a mapping with {sorted(_POSE_KEYS)}, got {pose_raw!r}"))
    extra = set(pose_raw) - _POSE_KEYS
    if extra:
        raise SceneError(ctx(f"pose.{sorted(extra)[0]}", f"unknown field; expected {sorted(_POSE_KEYS)}"))
    position = _vec3(pose_raw.get("position", [0, 0, 0]), "pose.position", ctx)
    rotation = _vec3(pose_raw.get("rotation_deg", [0, 0, 0]), "pose.rotation_deg", ctx)
    pose = Pose.from_euler_deg(position, rotation)

    # material
    mat_raw = raw.get("material", {}) or {}
    if not isinstance(mat_raw, dict):
        raise SceneError(ctx("material", f"expected a mapping, got {mat_raw!r}"))
    try:
        mat_kw = dict(mat_raw)
        if isinstance(mat_kw.get("texture"), dict):
            try:
                mat_kw["texture"] = Texture(**mat_kw["texture"])
            except ValidationError as exc:
                raise SceneError(ctx(*_fmt_validation(exc, "material.texture"))) from None
        material = Material(**mat_kw)
    except ValidationError as exc:
        raise SceneError(ctx(*_fmt_validation(exc, "material"))) from None

    # shape parameters: everything else
    params = {k: v for k, v in raw.items() if k not in _BODY_KEYS}
    cls = SHAPES[shape_name]
    if cls is Mesh:
        params.setdefault("base_dir", base_dir)
    try:
        shape = cls(**params)
    except ValidationError as exc:
        fld, msg = _fmt_validation(exc)
        if "Unexpected keyword argument" in msg:
            allowed = [f.name for f in dataclasses.fields(cls) if f.name != "base_dir"]
            msg = f"unknown field for shape '{shape_name}'; its fields are {allowed} plus {sorted(_BODY_KEYS)}"
        raise SceneError(ctx(fld, msg)) from None
    if cls is Mesh:
        try:
            shape.tessellate()
        except ValueError as exc:
            raise SceneError(ctx("file", str(exc))) from None
    return Body(name, shape, pose, material)


def scene_parts_from_dict(data, source: str = "<dict>", base_dir: str = ".") -> dict:
    """The keyword arguments of ``Scene(...)`` (bodies, name, description, view) from a scene file's contents."""
    if not isinstance(data, dict):
        raise SceneError(f"{source}: expected a mapping with a 'bodies' list at the top, got {type(data).__name__}")
    extra = set(data) - _TOP_KEYS
    if extra:
        raise SceneError(f"{source}: field '{sorted(extra)[0]}': unknown top-level field; expected {sorted(_TOP_KEYS)}")
    bodies_raw = data.get("bodies")
    if not isinstance(bodies_raw, list) or not bodies_raw:
        raise SceneError(f"{source}: field 'bodies': expected a non-empty list of bodies, got {bodies_raw!r}")
    bodies = [_body_from_dict(b, i, source, base_dir) for i, b in enumerate(bodies_raw)]
    names = [b.name for b in bodies]
    counts = collections.Counter(names)  # not names.count(n) per body: that is quadratic in the bodies
    dup = sorted(n for n, c in counts.items() if c > 1)
    if dup:
        i = names.index(dup[0], names.index(dup[0]) + 1)
        raise SceneError(f"{source}: body '{dup[0]}' (#{i}): field 'name': duplicate body name")
    view = None
    if data.get("view") is not None:
        v = data["view"]
        if not isinstance(v, (dict, list)):
            raise SceneError(f"{source}: field 'view': expected a mapping {{eye: [x, y, z], target: [x, y, z]}} or "
                             f"an eye position [x, y, z], got {v!r}")
        try:
            view = View(**v) if isinstance(v, dict) else View(eye=v)
        except (ValidationError, TypeError) as exc:
            if isinstance(exc, ValidationError):
                fld, msg = _fmt_validation(exc, "view" if isinstance(v, dict) else "")
                if not isinstance(v, dict):  # a list is the eye position: say so (not "view: Field required")
                    fld, msg = "view", f"expected an eye position of 3 numbers [x, y, z], got {v!r}"
            else:
                fld, msg = "view", str(exc)
            raise SceneError(f"{source}: field '{fld}': {msg}") from None
        if np.allclose(view.eye, view.target, rtol=0, atol=1e-12):
            raise SceneError(f"{source}: field 'view': eye == target ({list(view.eye)}); the view has no direction")
    for key in ("name", "description"):  # ["x"] was read as the name "['x']"
        if data.get(key) is not None and not isinstance(data[key], str):
            raise SceneError(f"{source}: field '{key}': expected a string, got {data[key]!r}")
    return dict(bodies=bodies, name=data.get("name") or "", description=data.get("description") or "",
                view=view)


def read_scene_parts(path) -> dict:
    """Read a scene file into ``Scene(...)``'s keyword arguments; mesh paths inside are relative to its folder."""
    from .._config import ConfigError, load_config

    path = Path(path)
    source = str(path)
    try:
        data = load_config(path, what="scene file")
    except ConfigError as exc:
        raise SceneError(str(exc)) from None
    parts = scene_parts_from_dict(data, source, str(path.parent.resolve()))
    parts["name"] = parts["name"] or path.stem
    return parts


def _clean(x):
    if isinstance(x, (tuple, list, np.ndarray)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        if v.is_integer() and abs(v) < 1e9:
            return int(v)
        # 12 significant digits tidy 19.999999999999996 into 20 but never turn a small value into 0
        return float(f"{v:.12g}")
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


def scene_to_dict(scene, base_dir: str | None = None) -> dict:
    """The scene as plain data in the file schema (mesh paths relative to ``base_dir``)."""
    bodies = []
    for b in scene:
        d = {"name": b.name, "shape": b.shape.kind}
        for f in dataclasses.fields(b.shape):
            if f.name == "base_dir":
                continue
            val = getattr(b.shape, f.name)
            if f.name == "file" and isinstance(b.shape, Mesh):
                val = b.shape.path
                if base_dir is not None:
                    val = os.path.relpath(os.path.abspath(val), os.path.abspath(base_dir))
            if f.default is not dataclasses.MISSING and val == f.default and f.name not in ("size",):
                continue
            d[f.name] = _clean(val)
        d["pose"] = {
            "position": _clean(b.pose.t),
            "rotation_deg": _clean(np.rad2deg(euler_xyz_from_rotation(b.pose.R))),
        }
        mat = {"reflectivity": b.material.reflectivity, "color": list(b.material.color)}
        if b.material.texture is not None:
            t = b.material.texture
            mat["texture"] = {"kind": t.kind, "size": t.size, "color2": list(t.color2), "line_width": t.line_width}
        if b.material.bottom_type is not None:
            mat["bottom_type"] = b.material.bottom_type
        d["material"] = _clean(mat)
        bodies.append(d)
    out: dict = {}
    if scene.name:
        out["name"] = scene.name
    if scene.description:
        out["description"] = scene.description
    if scene.view is not None:
        out["view"] = {"eye": _clean(scene.view.eye), "target": _clean(scene.view.target)}
    out["bodies"] = bodies
    return out


def save_scene(scene, path) -> None:
    path = Path(path)
    if path.suffix.lower() not in (".yaml", ".yml", ".json"):
        raise SceneError(f"cannot export the scene to {path}: expected a .yaml, .yml or .json file name "
                         f"(the format follows the suffix)")
    data = scene_to_dict(scene, str(path.parent))
    ensure_dir(path.parent)  # mesh paths like "../rock.obj" resolve only through an existing folder
    try:  # what is written must load again: check before writing, not when a user next reads it
        scene_parts_from_dict(data, str(path), str(path.parent.resolve()))
    except SceneError as exc:
        raise SceneError(f"cannot export the scene to {path}: the written file would not load: {exc}") from None
    if path.suffix.lower() == ".json":
        write_json(path, data)
    else:
        write_text(path, yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100))
