"""ChunkWriter: the dataset workers' chunk writes give the very bytes Zarr's own writer gives."""

import numpy as np
import pytest
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec, ZstdCodec

from optiacoustic.io._chunks import ChunkWriter

CASES = [  # (dtype, frame shape, fill value)
    ("float32", (7, 5), np.nan),
    ("float32", (4, 6, 3), np.nan),
    ("int16", (7, 5), -1),
    ("bool", (7, 5), False),
    ("bool", (), False),
]
COMPRESSORS = {
    "none": lambda: None,
    "blosc lz4 shuffle": lambda: [BloscCodec(cname="lz4", clevel=5, shuffle="shuffle")],
    "blosc lz4 noshuffle": lambda: [BloscCodec(cname="lz4", clevel=5, shuffle="noshuffle")],
    "blosc zstd bitshuffle": lambda: [BloscCodec(cname="zstd", clevel=3, shuffle="bitshuffle")],
    "blosc lz4 shuffle + crc32c": lambda: [BloscCodec(cname="lz4", clevel=5, shuffle="shuffle"), Crc32cCodec()],
    "crc32c alone": lambda: [Crc32cCodec()],
}


def _frames(dtype, shape, n, rng):
    x = rng.normal(size=(n,) + shape)
    if dtype == "bool":
        return x > 0
    if dtype == "int16":
        return np.round(100 * x).astype("int16")
    x = x.astype(dtype)
    x[..., 0] = np.nan  # NaN (the fill value) inside a frame must survive
    return x


@pytest.mark.parametrize("separator", ["/", "."])
@pytest.mark.parametrize("comp", sorted(COMPRESSORS))
@pytest.mark.parametrize("dtype,shape,fill", CASES)
def test_same_bytes_as_zarr_and_read_back_by_zarr(tmp_path, dtype, shape, fill, comp, separator):
    rng = np.random.default_rng(7)
    n = 4
    frames = _frames(dtype, shape, n, rng)
    root = zarr.open_group(str(tmp_path / "d.zarr"), mode="w", zarr_format=3)
    kw = dict(shape=(n,) + shape, chunks=(1,) + shape, dtype=dtype, fill_value=fill, compressors=COMPRESSORS[comp](),
              chunk_key_encoding={"name": "default", "separator": separator})
    by_zarr = root.create_array("by_zarr", **kw).with_config({"write_empty_chunks": True})
    ours = root.create_array("ours", **kw)
    w = ChunkWriter.for_array(ours)
    assert w is not None
    for k in (2, 0, 3):  # frame 1 left unwritten: it must read as the fill value
        by_zarr[k] = frames[k]
        w.write(k, frames[k].astype("float64") if dtype == "float32" else frames[k])  # cast like Zarr casts
    files = sorted(p.relative_to(tmp_path / "d.zarr" / "ours")
                   for p in (tmp_path / "d.zarr" / "ours").rglob("*") if p.is_file() and p.name != "zarr.json")
    assert len(files) == 3
    for f in files:  # the very bytes of Zarr's writer, file by file
        assert (tmp_path / "d.zarr" / "ours" / f).read_bytes() == (tmp_path / "d.zarr" / "by_zarr" / f).read_bytes(), f
    back = zarr.open_group(str(tmp_path / "d.zarr"), mode="r")["ours"][:]
    for k in (0, 2, 3):
        assert np.array_equal(back[k], frames[k], equal_nan=dtype == "float32"), k
    expect1 = np.full(shape, fill, dtype=dtype)
    assert np.array_equal(back[1], expect1, equal_nan=dtype == "float32")
    assert not list((tmp_path / "d.zarr").rglob(".*.tmp-*"))  # no temporary file left


def test_cases_it_does_not_handle_go_through_zarr(tmp_path):
    root = zarr.open_group(str(tmp_path / "d.zarr"), mode="w", zarr_format=3)
    zstd = root.create_array("zstd", shape=(3, 4), chunks=(1, 4), dtype="float32", compressors=[ZstdCodec(level=1)])
    two = root.create_array("two", shape=(4, 4), chunks=(2, 4), dtype="float32", compressors=None)
    split = root.create_array("split", shape=(3, 4), chunks=(1, 2), dtype="float32", compressors=None)
    mem = zarr.open_group(zarr.storage.MemoryStore(), mode="w").create_array("m", shape=(3, 4), chunks=(1, 4),
                                                                            dtype="float32", compressors=None)
    assert [ChunkWriter.for_array(a) for a in (zstd, two, split, mem)] == [None] * 4


def test_wrong_frame_shape_names_array_and_frame(tmp_path):
    root = zarr.open_group(str(tmp_path / "d.zarr"), mode="w", zarr_format=3)
    w = ChunkWriter.for_array(root.create_array("img", shape=(3, 4, 5), chunks=(1, 4, 5), dtype="float32",
                                                compressors=None))
    with pytest.raises(ValueError, match=r"img: frame 2 has shape \(5, 4\), the array's frames are \(4, 5\)"):
        w.write(2, np.zeros((5, 4)))


def test_write_file_in_folder_is_atomic_and_names_the_path(tmp_path):
    import os

    from optiacoustic._atomic import OutputError, write_file_in_folder

    target = tmp_path / "a" / "b" / "c.3.0"  # missing folders are made
    write_file_in_folder(target, b"\x01\x02")
    assert target.read_bytes() == b"\x01\x02"
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask  # as a plain open() would make it
    write_file_in_folder(target, memoryview(b"xyz"))  # replaces, any bytes-like
    assert target.read_bytes() == b"xyz"
    with pytest.raises(TypeError):  # a writer failing mid-way leaves the old file and no temporary one
        write_file_in_folder(target, object())
    assert target.read_bytes() == b"xyz"
    assert sorted(p.name for p in target.parent.iterdir()) == ["c.3.0"]
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="file/c.0"):
        write_file_in_folder(tmp_path / "file" / "c.0", b"1")
