"""The .npz file format (oneshot/npz.py): what np.load reads, the same arrays as the same bytes whatever
the hour, and files that lie refused as npz.Damaged before any data is read. (Datasets and checkpoints
turn Damaged into their named errors: tests/test_data.py and tests/test_checkpoint.py.)"""
import io
import re
import struct
import time
import tracemalloc
import zipfile

import numpy as np
import pytest

from oneshot.data import npz


def some_arrays():
    """Arrays of every kind a dataset or checkpoint holds, and a Fortran-ordered and an empty one."""
    rng = np.random.default_rng(0)
    return {"images": rng.integers(0, 256, (2, 3, 4, 4, 3), dtype=np.uint8),
            "params/fc0_w": rng.standard_normal((16, 5)).astype(np.float32),
            "adam/step": np.array(7, np.int64),
            "metadata": np.array('{"format_version": 1, "split": "train"}'),
            "fortran": np.asfortranarray(rng.standard_normal((3, 4))),
            "empty": np.zeros((0, 3), np.int8)}


def write_lying(path, arrays, name, descr, shape, compression=zipfile.ZIP_STORED):
    """Write `arrays` as an .npz, a valid zip (CRCs and all) whose member `name` has a .npy header
    claiming a `shape` array of dtype `descr` over its array's real bytes."""
    with zipfile.ZipFile(path, "w", compression) as z:
        for key, array in arrays.items():
            with z.open(key + ".npy", "w") as member:
                if key == name:
                    np.lib.format.write_array_header_1_0(member, {"descr": descr, "fortran_order": False,
                                                                  "shape": shape})
                    member.write(array.tobytes())
                else:
                    np.lib.format.write_array(member, array)


def assert_same(back, arrays):
    assert list(back) == list(arrays)
    for name, array in arrays.items():
        assert back[name].dtype == array.dtype and back[name].shape == array.shape, name
        assert np.array_equal(back[name], array), name


# --- written: what np.load reads, the same bytes for the same arrays -------------------------------------

@pytest.mark.parametrize("compress, method", [(True, zipfile.ZIP_DEFLATED), (False, zipfile.ZIP_STORED)])
def test_what_is_written_is_what_read_and_np_load_give_back(tmp_path, compress, method):
    arrays = some_arrays()
    path = tmp_path / "a.npz"
    with open(path, "wb") as f:
        npz.write(f, arrays, compress)
    assert_same(npz.read(path), arrays)
    with np.load(path, allow_pickle=False) as f:                 # plain numpy, e.g. in a notebook
        assert_same({name: f[name] for name in f.files}, arrays)
    with npz.Reader(path) as archive:
        assert archive.layout == {name: (a.dtype, a.shape) for name, a in arrays.items()}
    with zipfile.ZipFile(path) as z:
        assert {info.compress_type for info in z.infolist()} == {method}


def test_the_same_arrays_are_the_same_bytes_whatever_the_hour(monkeypatch):
    """Two writes, the clock moved on by eight years between them: the same bytes, each member dated
    npz.DATE (zipfile's writestr, which dates a member by the clock, writes other bytes: the clock
    really moved). Other arrays: other bytes."""
    def written(write):
        f = io.BytesIO()
        write(f)
        return f.getvalue()

    def stamped(f):
        with zipfile.ZipFile(f, "w") as z:
            z.writestr("x.npy", b"")

    arrays = some_arrays()
    first = {compress: written(lambda f: npz.write(f, arrays, compress)) for compress in (True, False)}
    clock = written(stamped)
    now = time.time()
    monkeypatch.setattr(time, "time", lambda: now + 8 * 365 * 24 * 3600)
    assert written(stamped) != clock
    for compress in (True, False):
        assert written(lambda f: npz.write(f, arrays, compress)) == first[compress]
        with zipfile.ZipFile(io.BytesIO(first[compress])) as z:
            assert {info.date_time for info in z.infolist()} == {npz.DATE}
    other = dict(arrays, **{"adam/step": np.array(8, np.int64)})
    assert written(lambda f: npz.write(f, other)) != first[True]


# --- read: nothing trusted -----------------------------------------------------------------------------

HUGE = {"images": ("|u1", (2, 3, 4, 4, 3 * 10**12)), "metadata": ("<U100000000", (10**4,))}   # 0.3 TB, 4 TB


@pytest.mark.parametrize("compression", [zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED])
@pytest.mark.parametrize("name", HUGE)
def test_a_header_claiming_a_huge_array_is_refused_before_anything_is_allocated(tmp_path, compression, name):
    """A .npy header claims terabytes (a shape, or a string's length) over the member's real bytes.
    np.load would try to allocate them; Reader first compares the claim with the member's size in the
    zip's directory."""
    arrays = some_arrays()
    path = tmp_path / "huge.npz"
    write_lying(path, arrays, name, *HUGE[name], compression)
    descr, shape = HUGE[name]
    claim = (f"{name}.npy's header claims a {shape} {np.dtype(descr)} array, which is not the "
             f"{arrays[name].nbytes} bytes")
    tracemalloc.start()
    try:
        with pytest.raises(npz.Damaged, match=re.escape(claim)):
            npz.read(path)
        assert tracemalloc.get_traced_memory()[1] < 10_000_000
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("compress", [True, False])
def test_an_array_is_read_into_its_own_memory_not_copied(tmp_path, compress):
    """Reading a 25 MB array allocates the array and a chunk at a time (the largest dataset's images
    are 1.3 GB: a second copy would double what loading needs)."""
    big = np.tile(np.arange(250, dtype=np.uint8), 10**5)
    path = tmp_path / "big.npz"
    with open(path, "wb") as f:
        npz.write(f, {"big": big}, compress)
    tracemalloc.start()
    try:
        back = npz.read(path)["big"]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(back, big) and peak < big.nbytes + 4 * npz.CHUNK + 1_000_000, peak


@pytest.mark.parametrize("compress", [True, False])
def test_a_zip_directory_claiming_more_than_the_file_holds_is_refused(tmp_path, compress):
    """The directory's record of a member's uncompressed size, set to 4 GB: more than deflate makes of
    the member's compressed bytes, or (stored) more than they are. Refused before anything is read."""
    f = io.BytesIO()
    npz.write(f, some_arrays(), compress)
    raw = bytearray(f.getvalue())
    with zipfile.ZipFile(f) as z:
        entry = z.start_dir                                   # the directory's record of the first member
    raw[entry + 24:entry + 28] = struct.pack("<I", 2**32 - 2)  # its uncompressed size
    path = tmp_path / "sizes.npz"
    path.write_bytes(bytes(raw))
    tracemalloc.start()
    try:
        with pytest.raises(npz.Damaged, match=r"the zip's sizes of images\.npy \(\d+ bytes, compression \d, "
                                              rf"holding 4294967294\) are impossible in a {len(raw)}-byte file"):
            npz.Reader(path)
        assert tracemalloc.get_traced_memory()[1] < 10_000_000
    finally:
        tracemalloc.stop()


@pytest.mark.filterwarnings("ignore:Duplicate name")
@pytest.mark.parametrize("names", [("x.npy", "x.npy"), ("x", "x.npy")])
def test_two_members_of_one_name_are_refused(tmp_path, names):
    """np.load would give back one of them (which one is the zip's business): refused, however the name
    is spelt ("x" and "x.npy" are both np.load's "x")."""
    path = tmp_path / "twice.npz"
    with zipfile.ZipFile(path, "w") as z:
        for i, name in enumerate(names):
            with z.open(name, "w") as member:
                np.lib.format.write_array(member, np.full(3, i))
    with pytest.raises(npz.Damaged, match=r"it holds x\.npy twice"):
        npz.read(path)


def write_member(path, write):
    """An .npz of one array "x" and a member "y" whose content `write(file)` writes."""
    with zipfile.ZipFile(path, "w") as z:
        with z.open("x.npy", "w") as member:
            np.lib.format.write_array(member, np.arange(3))
        with z.open("y.npy", "w") as member:
            write(member)


# A header only Python 2 wrote ("3L": a long), which numpy reads with a warning that it parsed it again
PYTHON_2_HEADER = b"{'descr': '<i8', 'fortran_order': False, 'shape': (3L,), }".ljust(117) + b"\n"


@pytest.mark.parametrize("write, reason", [
    (lambda f: np.lib.format.write_array(f, np.array([{"a": 1}], object)), r"y\.npy holds Python objects"),
    (lambda f: np.lib.format.write_array(f, np.arange(3), version=(3, 0)), r"y\.npy has \.npy format version \(3, 0\)"),
    (lambda f: f.write(b"x,y\n1,2\n"), r"y\.npy: the magic string is not correct"),
    (lambda f: f.write(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(PYTHON_2_HEADER)) + PYTHON_2_HEADER + bytes(24)),
     r"y\.npy: Reading .* Python 2"),
])
def test_members_that_are_not_plain_npy_arrays_are_refused(tmp_path, write, reason):
    """Pickled objects (which np.load(allow_pickle=True) would run), .npy versions other than 1.0 and 2.0,
    and members that are not .npy at all: refused from the header, as Damaged saying which member."""
    path = tmp_path / "odd.npz"
    write_member(path, write)
    with pytest.raises(npz.Damaged, match=reason):
        npz.read(path)


@pytest.mark.parametrize("compress", [True, False])
def test_damaged_data_behind_a_sound_header_is_refused_by_its_crc(tmp_path, compress):
    """One bit flipped near the end of a 400 kB member's data: its layout still reads from its header,
    the other members read, and reading the array (to the member's end, where zipfile checks the
    CRC-32) raises Damaged."""
    arrays = {"big": np.random.default_rng(0).standard_normal(100_000).astype(np.float32), "small": np.arange(3)}
    path = tmp_path / "a.npz"
    with open(path, "wb") as f:
        npz.write(f, arrays, compress)
    raw = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.getinfo("big.npy")
    name_length, extra_length = struct.unpack("<HH", raw[info.header_offset + 26:info.header_offset + 30])
    end = info.header_offset + 30 + name_length + extra_length + info.compress_size    # of its data
    raw[end - 100] ^= 0x10
    path.write_bytes(bytes(raw))
    with npz.Reader(path) as archive:
        assert archive.layout["big"] == (np.dtype(np.float32), (100_000,))
        assert np.array_equal(archive.read("small"), arrays["small"])
        with pytest.raises(npz.Damaged, match=r"Bad CRC-32 for file 'big\.npy'"):
            archive.read("big")


def test_what_is_not_the_files_fault_is_not_damage(tmp_path, monkeypatch):
    """No file: the file system's OSError. Out of memory, Ctrl-C: themselves. Not a zip, or a truncated
    one: Damaged."""
    with pytest.raises(FileNotFoundError):
        npz.read(tmp_path / "missing.npz")
    path = tmp_path / "a.npz"
    with open(path, "wb") as f:
        npz.write(f, some_arrays())
    with npz.Reader(path) as archive:
        for error in (MemoryError, KeyboardInterrupt):
            def fail(*args, **kwargs):
                raise error()
            monkeypatch.setattr(zipfile.ZipExtFile, "read", fail)     # while reading an array, or opening
            with pytest.raises(error):
                archive.read("images")
            with pytest.raises(error):
                npz.Reader(path)
            monkeypatch.undo()
    raw = path.read_bytes()
    for content, reason in ((b"not a zip", "File is not a zip file"), (raw[:len(raw) // 2], "File is not a zip file"),
                            (b"", "File is not a zip file")):
        path.write_bytes(content)
        with pytest.raises(npz.Damaged, match=reason):
            npz.read(path)


def test_the_checksum_covers_each_arrays_name_dtype_and_shape_not_only_its_bytes():
    """The same bytes under another name, as another dtype or in another shape: another checksum (a file
    whose header was rewritten to reinterpret its data must not pass)."""
    a = np.arange(12, dtype=np.int32)
    base = npz.checksum({"x": a}, ["x"])
    assert npz.checksum({"x": a.copy()}, ["x"]) == base
    for other, name in (({"y": a}, "y"), ({"x": a.reshape(3, 4)}, "x"), ({"x": a.view(np.float32)}, "x"),
                        ({"x": a.view(np.uint32)}, "x")):
        assert npz.checksum(other, [name]) != base
