"""Atomic file output: every file the project writes appears complete or not at all.

A writer gets a temporary path in the destination's own folder (same file system, so the
final ``os.replace`` is atomic), with the destination's suffix so that libraries that pick a
format from the name (OpenCV, matplotlib, numpy) still do; the temporary file is renamed onto
the destination only when the writer returned without error, and removed otherwise. A run
killed at any moment therefore leaves only complete files (and at worst a stray
``.NAME.tmp-*`` file, never a truncated ``NAME``).

Errors about the destination (a folder where a file should be, no permission, a missing
parent) are raised as :class:`OutputError`, a ``ValueError`` whose message names the path.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import tempfile
from pathlib import Path
from typing import Iterator

__all__ = ["OutputError", "atomic_path", "check_destination", "jsonable", "ensure_dir", "write_text", "write_bytes", "write_json", "save_npz",
           "savefig", "imwrite"]


class OutputError(ValueError):
    """An output path cannot be written (names the path and the reason)."""


def _check_destination(path: Path) -> None:
    if path.exists() and path.is_dir():
        raise OutputError(f"cannot write {path}: it is a folder, a file was expected")
    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise OutputError(f"cannot write {path}: {parent} is a file, a folder was expected")
    if str(path) in (os.devnull,) or (path.exists() and not path.is_file()):
        raise OutputError(f"cannot write {path}: not a regular file")


def check_destination(path: str | os.PathLike) -> Path:
    """Raise :class:`OutputError` now if file ``path`` could not be written (it is a folder, or a
    parent is a file): for commands that check their outputs before long work. Returns the path."""
    path = Path(path)
    _check_destination(path)
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(f"cannot write {path}: {parent} is a file, a folder was expected")
            break
    return path


@functools.lru_cache(maxsize=1)
def _umask() -> int:
    # Linux shows the umask in /proc; elsewhere os.umask can only be read by setting it (restored at once)
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def ensure_dir(path: str | os.PathLike) -> Path:
    """Create folder ``path`` (and its parents) if missing; return it.

    Raises
    ------
    OutputError
        When ``path`` or one of its parents is a file, or the folder cannot be made (names the path).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"cannot write into {path}: it is a file, a folder was expected")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot make folder {path}: {exc.strerror or exc}") from None
    return path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, make_parents: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` when the block succeeds.

    Parameters
    ----------
    path : path-like
        The destination file.
    make_parents : bool
        Create missing parent folders.
    """
    path = Path(path)
    _check_destination(path)
    if make_parents:
        ensure_dir(path.parent)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.tmp-", suffix=path.suffix, dir=path.parent)
        os.close(fd)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp makes the file private (0600); give the result the mode a plain open() would
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; return the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically; return the path."""
    return write_bytes(path, text.encode("utf-8"))


def jsonable(x):
    """``x`` with numpy scalars and arrays, tuples and paths made JSON-ready (non-finite floats as strings)."""
    import numpy as np

    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if np.isfinite(v) else str(v)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    return x


def write_json(path: str | os.PathLike, obj, *, indent: int = 2) -> Path:
    """Write ``obj`` as JSON (with a final newline) atomically; return the path."""
    return write_text(path, json.dumps(obj, indent=indent) + "\n")


def save_npz(path: str | os.PathLike, *, compressed: bool = True, **arrays) -> Path:
    """``numpy.savez_compressed`` (or ``savez``) to ``path`` atomically; return the path."""
    import numpy as np

    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:  # a file object: numpy must not append ".npz" to the temp name
            (np.savez_compressed if compressed else np.savez)(fh, **arrays)
    return Path(path)


def savefig(fig, path: str | os.PathLike, **kwargs) -> Path:
    """``fig.savefig`` to ``path`` atomically (format from the suffix); return the path."""
    path = Path(path)
    kwargs.setdefault("format", path.suffix.lstrip(".") or None)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return path


def imwrite(path: str | os.PathLike, image) -> Path:
    """``cv2.imwrite`` (BGR or grey ``uint8``/``uint16``) to ``path`` atomically; return the path."""
    import cv2

    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image):
            raise OutputError(f"cannot write {path}: OpenCV could not encode a {getattr(image, 'shape', '?')} "
                              f"{getattr(image, 'dtype', '?')} image as {Path(path).suffix or 'an image'}")
    return Path(path)


def write_file_in_folder(path: str | os.PathLike, data) -> None:
    """Write ``data`` (bytes-like) to ``path`` atomically, for many files into a folder that exists.

    The same guarantee as :func:`write_bytes` (a ``.NAME.tmp-*`` file beside ``path``,
    renamed onto it once complete, removed on error) without its checks of the
    destination, which cost more than writing a small file: the caller writes regular files
    it names itself (a dataset's chunk files). A missing folder is created.
    """
    path = os.fspath(path)
    folder, name = os.path.split(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.tmp-", dir=folder)
    except FileNotFoundError:
        ensure_dir(folder)
        fd, tmp = tempfile.mkstemp(prefix=f".{name}.tmp-", dir=folder)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes the file private (0600)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
        raise
