"""Archives of named arrays (.npz, what np.savez writes and np.load reads): written so that the same
arrays are the same bytes, read without trusting the file. Datasets (data/datasets.py) and checkpoints
(training/checkpoint.py) are such files.

    npz.write(f, {"x": x, "y": y})                 # f: a binary file; one .npy member per array
    npz.checksum({"x": x, "y": y}, ["x", "y"])     # what the file records of its arrays
    arrays = npz.read("a.npz")                     # {"x": x, "y": y}
    npz.members("a.npz")                           # {"x", "y"}: what it holds, no array read
    npz.kind({"meta", "params/w"})                 # "checkpoint" ("dataset", or None: neither)
    with npz.Reader("a.npz") as archive:           # to look before reading gigabytes:
        dtype, shape = archive.layout["x"]         # from the .npy header alone, nothing read yet
        x = archive.read("x")

`write` dates every member 1980-01-01 00:00 (zip's first day) instead of the hour it is written, so
the file's bytes depend on the arrays only. `Reader` checks every member before reading any array:
its name is unique, its .npy header (format 1.0 or 2.0, no Python objects) describes exactly the bytes
the zip's directory says the member holds, and those fit in the file (deflate compresses at most
MAX_DEFLATE_RATIO:1), so a flipped bit cannot make numpy allocate terabytes. Each array is read to
its member's end, where zipfile checks the CRC-32. Whatever is wrong with the file, the error is
`Damaged` (a ValueError) saying what, for the caller to name the file and the fix.
"""
import contextlib
import hashlib
import math
import os
import warnings
import zipfile

import numpy as np

from oneshot.tools import files

# Deflate compresses at most 1032:1, so a member of c compressed bytes holds at most 1032 c bytes: a
# bound on what a (damaged) zip directory can make a Reader allocate, checked before anything is read.
MAX_DEFLATE_RATIO = 1032

DATE = (1980, 1, 1, 0, 0, 0)          # every member's date: zip's first day, not the clock

ZIP_MAGIC = b"PK\x03\x04"           # how a zip (an .npz) starts

CHUNK = 1 << 18                       # bytes read at a time into an array (as np.load reads)


class Damaged(ValueError):
    """An .npz file is truncated, corrupt or was not written as an .npz of arrays; the message says
    what is wrong (not which file: the caller knows that, and the fix)."""


def checksum(arrays, names):
    """SHA-256 over the arrays `names` of `arrays`, in that order: each one's name, dtype, shape and bytes.
    -> hex str. What a dataset or checkpoint records, to tell its arrays changed since it was written."""
    h = hashlib.sha256()
    for name in names:
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.data)
    return h.hexdigest()


def write(file, arrays, compress=True):
    """Write `arrays` ({name: array}) to the binary file `file` as an .npz that np.load reads: one .npy
    member per array, in the order given, deflated (compress=True) or stored as they are. The bytes
    depend on the arrays only (and on zlib's version, if compressed)."""
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(file, "w", method) as z:
        for name, array in arrays.items():
            info = zipfile.ZipInfo(name + ".npy", date_time=DATE)
            info.compress_type = method
            with z.open(info, "w", force_zip64=True) as member:    # zip64: members may pass 2 GB
                np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)


def read(path):
    """{name: array} of every member of the .npz file at `path`, checked as `Reader` checks them.
    Raises Damaged if the file is not a sound .npz of arrays."""
    with Reader(path) as archive:
        return {name: archive.read(name) for name in archive.layout}


def members(path):
    """The names of the arrays in the .npz file at `path` (a set; none read): to tell what kind of file an
    output would replace (`kind`). An empty set if the file is no zip at all (a text file, say), None if
    it is a zip too damaged to list (or an empty file): then it cannot be told."""
    try:
        with Reader(path) as archive:
            return set(archive.layout)
    except (ValueError, OSError):                # Damaged and files.RefusedPath are ValueErrors
        pass
    try:
        with files.open_read(path) as f:
            start = f.read(len(ZIP_MAGIC))
    except (ValueError, OSError):
        return set()
    return None if start in (b"", ZIP_MAGIC) else set()


def kind(names):
    """What an .npz holding the arrays `names` (a set) is: "dataset" (data/datasets.py), "checkpoint"
    (training/checkpoint.py), or None (neither)."""
    if {"metadata", "images"} <= names:
        return "dataset"
    if "meta" in names and any(name.startswith("params/") for name in names):
        return "checkpoint"
    return None


class Reader:
    """The .npz file at `path`, open for reading, every member's header checked (see the module's
    docstring) when it is opened. `layout`: {name: (dtype, shape)} of its arrays, in the file's order
    (names without ".npy"); `read(name)`: one array. Raises Damaged, opening or reading, whatever is
    wrong with the file; an OSError opening it (no such file, no permission) is the file system's, and
    a path that names no regular file (a device, a FIFO, a folder) is `files.RefusedPath`, unread."""

    def __init__(self, path):
        self._file = files.open_read(path)
        try:
            with _damage():
                size = os.fstat(self._file.fileno()).st_size
                self._zip = zipfile.ZipFile(self._file)
                self._npy = {name: _header(self._zip, info, size) for name, info in _members(self._zip).items()}
        except BaseException:
            self._file.close()
            raise
        self.layout = {name: (dtype, shape) for name, (_, dtype, shape, _, _) in self._npy.items()}

    def read(self, name):
        """The array `name` (a key of `layout`), of the dtype and shape `layout` says. Raises Damaged if
        its data is damaged."""
        # Into an array of the checked layout (np.lib.format.read_array would parse the header again: twice
        # the time for a checkpoint's 74 members), a chunk at a time: loading the largest dataset in data/
        # peaks at 323 MB for its 318 MB of images. To the member's end, where zipfile checks its CRC-32.
        info, dtype, shape, order, start = self._npy[name]
        with _damage(info.filename), self._zip.open(info) as f:
            array = np.empty(shape, dtype, order)
            f.read(start)                                # past the header
            data = array.reshape(-1, order="A").view(np.uint8)
            for i in range(0, data.size, CHUNK):
                data[i:i + CHUNK] = np.frombuffer(f.read(CHUNK), np.uint8)
        return array

    def close(self):
        self._zip.close()
        self._file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@contextlib.contextmanager
def _damage(member=None):
    """Any error of the zip and .npy readers inside the block, as Damaged naming the `member` (a name in
    the zip) it concerns: a flipped bit can raise nearly anything (zlib.error, NotImplementedError,
    SyntaxError, EOFError, ...). Not MemoryError, nor KeyboardInterrupt (not an Exception): they are
    not the file's fault."""
    try:
        yield
    except (Damaged, MemoryError):
        raise
    except Exception as e:
        detail = " ".join(str(e).split()) or type(e).__name__
        raise Damaged(detail if member is None or member in detail else f"{member}: {detail}") from e


def _members(z):
    """{name: ZipInfo} of zip `z`'s members, names without ".npy" (as np.load names them). Raises
    Damaged if two have the same name."""
    members = {}
    for info in z.infolist():
        name = info.filename.removesuffix(".npy")
        if name in members:
            raise Damaged(f"it holds {info.filename} twice")
        members[name] = info
    return members


def _header(z, info, file_bytes):
    """(info, dtype, shape, order "C" or "F", where its data starts) of a .npy member of zip `z`, from
    its header alone. Raises Damaged unless the array it describes is exactly the member's uncompressed
    size as the zip records it, and that size fits in the member's share of the file's `file_bytes`
    (at most MAX_DEFLATE_RATIO times its compressed size)."""
    if info.compress_type == zipfile.ZIP_DEFLATED:
        fits = info.compress_size <= file_bytes and info.file_size <= MAX_DEFLATE_RATIO * info.compress_size
    else:
        fits = info.compress_type == zipfile.ZIP_STORED and info.file_size == info.compress_size <= file_bytes
    if not fits:
        raise Damaged(f"the zip's sizes of {info.filename} ({info.compress_size} bytes, compression "
                      f"{info.compress_type}, holding {info.file_size}) are impossible in a {file_bytes}-byte file")
    with _damage(info.filename), z.open(info) as f, warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)      # numpy's warning about a header only Python 2 wrote
        version = np.lib.format.read_magic(f)
        read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                       (2, 0): np.lib.format.read_array_header_2_0}.get(version)
        if read_header is None:
            raise Damaged(f"{info.filename} has .npy format version {version}, not 1.0 or 2.0")
        shape, fortran_order, dtype = read_header(f)
        start = f.tell()
    if dtype.hasobject:
        raise Damaged(f"{info.filename} holds Python objects, which only a pickle can read")
    if min(shape, default=0) < 0 or start + math.prod(shape) * dtype.itemsize != info.file_size:
        raise Damaged(f"{info.filename}'s header claims a {shape} {dtype} array, which is not the "
                      f"{info.file_size - start} bytes the member holds")
    return info, dtype, shape, "F" if fortran_order else "C", start
