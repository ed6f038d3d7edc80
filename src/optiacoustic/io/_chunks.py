"""Whole-chunk writes into a local Zarr v3 array, in the calling thread.

A dataset worker writes each frame as one chunk of each of its arrays. Through
``zarr.Array.__setitem__`` every such write is dispatched to Zarr's event-loop thread and
from there to two more threads (the codec, then the file), about 1 ms of thread hand-offs
per array whatever its size (measured with py-spy on the worker's write path: 12 arrays
per sonar + camera pair, the hand-offs were most of the write time). A
:class:`ChunkWriter` encodes the chunk with the array's own codec configuration (the
Zarr v3 ``bytes`` codec, then ``blosc`` through numcodecs, the library Zarr itself calls)
and writes the file under the array's own chunk key (Zarr's ``chunk_key_encoding``)
atomically through :func:`optiacoustic._atomic.write_file_in_folder`. The bytes on disk are those Zarr writes
(tested against Zarr's writer); the metadata stays Zarr's. Arrays with any other store or
codec chain get no ChunkWriter (:meth:`ChunkWriter.for_array` returns None) and are
written through Zarr. A trailing ``crc32c`` codec appends the CRC-32C of the encoded bytes
(little-endian, 4 bytes; ``google_crc32c``, the library Zarr's codec calls), as Zarr does.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._atomic import write_file_in_folder

__all__ = ["ChunkWriter"]


class ChunkWriter:
    """Writes chunk ``k`` of a local Zarr v3 array chunked ``(1, *frame_shape)``.

    Build one with :meth:`for_array`; call :meth:`write` with frame index and value.
    """

    def __init__(self, folder: str, encode_key, frame_shape: tuple, dtype: np.dtype, compressor, crc32c: bool = False):
        self.folder = folder
        self._key = encode_key
        self.frame_shape = frame_shape
        self.dtype = dtype
        self._compressor = compressor
        self._crc32c = crc32c
        self._zeros = (0,) * len(frame_shape)

    @classmethod
    def for_array(cls, arr) -> ChunkWriter | None:
        """A writer for ``arr`` (a ``zarr.Array``), or None if it is not a case this class handles.

        Handled: Zarr format 3, a local store, chunks of one frame spanning the rest of the
        shape, codecs ``bytes`` (little-endian) optionally followed by ``blosc``, then optionally
        by ``crc32c``.
        """
        from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec
        from zarr.storage import LocalStore

        md = arr.metadata
        if getattr(md, "zarr_format", None) != 3 or not isinstance(arr.store, LocalStore):
            return None
        shape, chunks = tuple(arr.shape), tuple(md.chunk_grid.chunk_shape)
        if not shape or chunks != (1,) + shape[1:]:
            return None
        codecs = tuple(md.codecs)
        if not codecs or not isinstance(codecs[0], BytesCodec) or str(getattr(codecs[0].endian, "value", "little")) != "little":
            return None
        crc32c = len(codecs) >= 2 and isinstance(codecs[-1], Crc32cCodec)
        if crc32c:
            codecs = codecs[:-1]
        compressor = None
        if len(codecs) == 2 and isinstance(codecs[1], BloscCodec):
            import numcodecs

            c = codecs[1].to_dict()["configuration"]
            shuffle = {"noshuffle": numcodecs.Blosc.NOSHUFFLE, "shuffle": numcodecs.Blosc.SHUFFLE,
                       "bitshuffle": numcodecs.Blosc.BITSHUFFLE}[c["shuffle"]]
            compressor = numcodecs.Blosc(cname=c["cname"], clevel=c["clevel"], shuffle=shuffle,
                                         blocksize=c["blocksize"], typesize=c["typesize"])
        elif len(codecs) != 1:
            return None
        dtype = np.dtype(arr.dtype).newbyteorder("<")
        if dtype.kind not in "biuf":
            return None
        folder = str(Path(arr.store.root) / arr.path)
        return cls(folder, md.chunk_key_encoding.encode_chunk_key, shape[1:], dtype, compressor, crc32c)

    def write(self, k: int, value) -> None:
        """Write ``value`` (``frame_shape``, cast to the array's dtype) as chunk ``k``, atomically."""
        a = np.asarray(value, dtype=self.dtype)  # not ascontiguousarray: it makes a 0-d value 1-d
        if not a.flags.c_contiguous:
            a = a.copy()
        if a.shape != self.frame_shape:
            raise ValueError(f"{self.folder}: frame {k} has shape {a.shape}, the array's frames are {self.frame_shape}")
        data = self._compressor.encode(a) if self._compressor is not None else a.tobytes()
        if self._crc32c:
            import google_crc32c

            data = bytes(data) + int(google_crc32c.value(data)).to_bytes(4, "little")
        write_file_in_folder(os.path.join(self.folder, self._key((int(k),) + self._zeros)), data)
