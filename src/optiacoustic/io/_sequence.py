"""The lazy frame sequence every reader returns: ``len``, indexing, slicing, iteration.

A reader builds a small index (byte offsets or message references) when opened and
decodes a frame only when it is asked for; a log larger than memory is never read whole.
Vendor files are memory-mapped; bags are read message by message through rosbags.
"""

from __future__ import annotations

import mmap
import os
import warnings
import weakref
from collections.abc import Sequence
from pathlib import Path

from .errors import ReadError, SkippedFrame

__all__ = ["FrameSequence", "MappedFile"]

_ERRORS = ("raise", "skip")


class FrameSequence(Sequence):
    """A lazy sequence of frames from one file (or one topic of a bag).

    Subclasses set ``path`` and implement ``__len__`` and ``_read(i)`` (raising
    :class:`ReadError` for a damaged frame).

    ``errors="raise"`` (default): a damaged frame raises :class:`ReadError` (naming file,
    topic, frame and byte offset) when it is read. ``errors="skip"``: iteration skips it,
    appends a :class:`SkippedFrame` to ``.skipped`` and warns; indexing a damaged frame
    still raises (there is nothing to return).
    """

    path: Path
    topic: str | None = None

    def __init__(self, errors: str = "raise"):
        if errors not in _ERRORS:
            raise ValueError(f"errors must be one of {_ERRORS}, got {errors!r}")
        self.errors = errors
        self.skipped: list[SkippedFrame] = []

    def _read(self, i: int):  # pragma: no cover - abstract
        raise NotImplementedError

    def _frame(self, k: int):
        """``_read(k)``, with a ``ValueError`` of the frame's own checks (a :class:`SonarSpec` the
        header's values do not describe: one beam, bearings past 90 deg, say) turned into a
        :class:`ReadError` naming file, topic and frame, so that ``errors="skip"`` can skip it."""
        try:
            return self._read(k)
        except ReadError:
            raise
        except ValueError as exc:
            raise ReadError(self.path, str(exc), topic=self.topic, frame=k) from None

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        if isinstance(i, bool) or not hasattr(i, "__index__"):
            raise TypeError(f"frame index must be an integer or a slice, got {type(i).__name__}")
        n = len(self)
        k = i.__index__()
        k = k + n if k < 0 else k
        if not 0 <= k < n:
            raise IndexError(f"{self.path}: frame {i} out of range ({n} frames)")
        return self._frame(k)

    def __iter__(self):
        for k in range(len(self)):
            try:
                yield self._frame(k)
            except ReadError as exc:
                if self.errors == "raise":
                    raise
                self.skipped.append(SkippedFrame(k, str(exc)))
                warnings.warn(f"skipped damaged frame: {exc}", stacklevel=2)

    def times(self):
        """Times (s since the epoch) of every frame; readers override this to skip decoding images."""
        import numpy as np

        return np.array([f.time for f in self], float)

    def info(self) -> dict:
        """What the file says about itself (device settings of the first good frame, counts)."""
        return {"path": str(self.path), "frames": len(self)}

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self):
        topic = f", topic={self.topic!r}" if self.topic else ""
        return f"{type(self).__name__}({str(self.path)!r}{topic}, {len(self)} frames)"


class MappedFile:
    """A read-only memory map of a file, with bounds-checked views that name the byte offset."""

    def __init__(self, path):
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"{self.path}: no such file")
        if self.path.is_dir():
            raise ReadError(self.path, "is a folder, a file was expected")
        self.size = os.path.getsize(self.path)
        self._fh = open(self.path, "rb")
        self._mm = mmap.mmap(self._fh.fileno(), 0, access=mmap.ACCESS_READ) if self.size else b""
        # closed with the reader or, at the latest, when it is garbage-collected
        self._finalizer = weakref.finalize(self, _close, self._mm, self._fh)

    def view(self, offset: int, nbytes: int, what: str, frame=None) -> memoryview:
        """``nbytes`` bytes at ``offset``; a :class:`ReadError` if the file ends first."""
        if offset < 0 or offset + nbytes > self.size:
            raise ReadError(self.path, f"truncated: {what} needs {nbytes} bytes at byte offset {offset}, "
                                       f"the file has {self.size} bytes", frame=frame, offset=offset)
        return memoryview(self._mm)[offset:offset + nbytes]

    def close(self):
        self._finalizer()


def _close(mm, fh):
    if mm:
        try:
            mm.close()
        except BufferError:  # a view is still alive somewhere; the OS frees it with the process
            pass
    fh.close()
