"""The demonstration dataset (paper Section IV): N tasks x K demos, saved as one compressed .npz.

A dataset is a plain dict of arrays plus a "metadata" dict (N tasks, K demos per task, T steps):

    images        (N, K, T, H, W, 3) uint8    what the camera saw before each action
    states        (N, K, T, 6)       float32  joint angles (rad), joint velocities (rad/s), end effector (m):
                                              the order of STATE_LAYOUT
    actions       (N, K, T, 2)       float32  the expert's joint torques (N m)
    task_colours  (N,)               int16    palette index of each task's target colour
    colours       (N, K, n)          int16    palette indices of the n objects of each demo's scene
    positions     (N, K, n, 2)       float32  object centres (m)
    target_index  (N, K)             int8     which object is the target
    seeds         (N, K)             int64    the seed that reproduces each demo's scene
    metadata      dict                         format version, configs, split, counts, state layout, checksum

`save` writes atomically (a temporary file, then a rename), so a crash never leaves half a file, and
its bytes depend on the content only: the same dataset saved twice, or collected with another number
of worker processes, is the same file. `load` checks the format version, keys, dtypes, shapes, the
metadata the package reads and a SHA-256 checksum of the arrays, and says exactly what is wrong with
a bad, damaged or truncated file: every failure is a DatasetError naming the file.
"""
import contextlib
import hashlib
import json
import math
import os
import tempfile
import warnings
import zipfile

import numpy as np

from oneshot.arm import ArmConfig
from oneshot.palette import PaletteConfig
from oneshot.world import WorldConfig

FORMAT_VERSION = 1

# What each of the 6 numbers of a state is (`world.observation_state`; the angles and velocities are
# arm.py's x = (q1, q2, qd1, qd2)): radians, radians per second, metres. Saved in the metadata as
# "state_layout"; files written before it was recorded lack it, and have this layout.
STATE_LAYOUT = ("shoulder angle", "elbow angle", "shoulder velocity", "elbow velocity",
                "end effector x", "end effector y")

# What the package reads from a dataset's metadata, beyond what `world_config` needs to rebuild the
# world: imitation.py the split, train.py the torque bound (the arrays' shapes are checked against
# the horizon, image size and number of objects).
REQUIRED_METADATA = (("split",), ("world", "horizon"), ("world", "image_size"), ("world", "n_objects"),
                     ("world", "arm", "max_torque"), ("world", "palette"))

FIX = "re-create it with `python -m oneshot.collect`"

# Deflate compresses at most 1032:1, so a member of c compressed bytes holds at most 1032 c bytes: a
# bound on what a (damaged) zip directory can make `load` allocate, checked before anything is read.
MAX_DEFLATE_RATIO = 1032

# key: (dtype, number of dimensions)
ARRAYS = {
    "images": (np.uint8, 6),
    "states": (np.float32, 4),
    "actions": (np.float32, 4),
    "task_colours": (np.int16, 1),
    "colours": (np.int16, 3),
    "positions": (np.float32, 4),
    "target_index": (np.int8, 2),
    "seeds": (np.int64, 2),
}


class DatasetError(ValueError):
    """A dataset file or dict is malformed; the message says what and how to fix it."""


def checksum(arrays):
    """SHA-256 over the arrays of ARRAYS (dtype, shape and bytes, in a fixed order). -> hex str."""
    h = hashlib.sha256()
    for key in ARRAYS:
        a = np.ascontiguousarray(arrays[key])
        h.update(f"{key}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.data)
    return h.hexdigest()


def layout_of(arrays):
    """{key: (dtype, shape)} of the arrays of ARRAYS among `arrays` (what check_layout checks)."""
    return {key: (arrays[key].dtype, arrays[key].shape) for key in ARRAYS if key in arrays}


def check_layout(layout, source="dataset"):
    """Raise DatasetError unless `layout`, {key: (dtype, shape)} of a dataset's arrays (or of a file's
    .npy headers, before the arrays are read), has every array of ARRAYS with its dtype and number of
    dimensions, and shapes that agree with each other."""
    for key, (dtype, ndim) in ARRAYS.items():
        if key not in layout:
            raise DatasetError(f"{source} has no array {key!r}; {FIX}")
        got, shape = layout[key]
        if got != dtype or len(shape) != ndim:
            raise DatasetError(f"{source}: {key} must be {ndim}-d {np.dtype(dtype).name}; "
                               f"got {len(shape)}-d {got.name} {shape}; {FIX}")
    n, k, t, h = layout["images"][1][:4]
    n_obj = layout["colours"][1][2]
    expected = {"images": (n, k, t, h, h, 3), "states": (n, k, t, 6), "actions": (n, k, t, 2),
                "task_colours": (n,), "colours": (n, k, n_obj), "positions": (n, k, n_obj, 2),
                "target_index": (n, k), "seeds": (n, k)}
    for key, shape in expected.items():
        if tuple(layout[key][1]) != shape:
            raise DatasetError(f"{source}: {key} has shape {layout[key][1]}, expected {shape} "
                               f"(N={n} tasks, K={k} demos, T={t} steps); {FIX}")


def validate(dataset, source="dataset"):
    """Raise DatasetError unless `dataset` has every array with the right dtype and consistent shapes,
    and values that make sense (finite, each demo's target of its task's colour)."""
    check_layout(layout_of(dataset), source)
    n_obj = dataset["colours"].shape[2]
    for key in ("states", "actions", "positions"):
        if not np.all(np.isfinite(dataset[key])):
            raise DatasetError(f"{source}: {key} contains NaN or inf; {FIX}")
    if np.any(dataset["target_index"] < 0) or np.any(dataset["target_index"] >= n_obj):
        raise DatasetError(f"{source}: target_index must lie in [0, {n_obj}); {FIX}")
    picked = np.take_along_axis(dataset["colours"], dataset["target_index"][..., None].astype(int), 2)[..., 0]
    if np.any(picked != dataset["task_colours"][:, None]):
        raise DatasetError(f"{source}: some demo's target object does not have its task's colour; {FIX}")


def check_metadata(metadata, layout, source="dataset"):
    """Raise DatasetError unless `metadata` holds what the package reads (REQUIRED_METADATA, and a world
    that `world_config` rebuilds), its world's horizon, image size and number of objects are those of
    the arrays (`layout`, as check_layout takes it), and its state layout, if it records one (files
    written before it was recorded do not), is STATE_LAYOUT."""
    if not isinstance(metadata, dict):
        raise DatasetError(f"{source}: its metadata must be a JSON object; got {type(metadata).__name__}; {FIX}")
    for keys in REQUIRED_METADATA:
        d = metadata
        for depth, key in enumerate(keys, 1):
            if not isinstance(d, dict) or key not in d:
                raise DatasetError(f"{source}: its metadata has no {'.'.join(keys[:depth])}; {FIX}")
            d = d[key]
    world = world_config(metadata, source)
    recorded = {"horizon": world.horizon, "image_size": world.image_size, "n_objects": world.n_objects}
    actual = {"horizon": layout["images"][1][2], "image_size": layout["images"][1][3],
              "n_objects": layout["colours"][1][2]}
    for name in recorded:
        if recorded[name] != actual[name]:
            raise DatasetError(f"{source}: its metadata says world.{name} = {recorded[name]!r}, but its arrays "
                               f"have {actual[name]}; {FIX}")
    if metadata["split"] != world.split:
        raise DatasetError(f"{source}: its metadata says split {metadata['split']!r}, but its world's split is "
                           f"{world.split!r}; {FIX}")
    states = metadata.get("state_layout", list(STATE_LAYOUT))
    if not isinstance(states, (list, tuple)) or tuple(states) != STATE_LAYOUT:
        raise DatasetError(f"{source}: its states are laid out as {states!r}, and this oneshot reads "
                           f"{list(STATE_LAYOUT)}; {FIX}")


@contextlib.contextmanager
def atomic_write(path):
    """Open a temporary file beside `path` for binary writing; on success fsync it and rename it to
    `path` (with the usual permissions), on failure remove it: never half a file at `path`."""
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=os.path.splitext(path)[1])
    try:
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)          # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def save(dataset, path):
    """Write `dataset` (validated, arrays and metadata) to `path` (.npz), atomically. Adds the format
    version, the state layout and the checksum to the metadata, and returns it. The file's bytes depend
    on the dataset only (see write_npz), so the same data is the same file."""
    validate(dataset)
    arrays = {key: dataset[key] for key in ARRAYS}
    metadata = dataset.get("metadata", {})
    check_metadata(metadata, layout_of(arrays))
    meta = dict(metadata, format_version=FORMAT_VERSION, state_layout=list(STATE_LAYOUT),
                checksum=checksum(arrays))
    with atomic_write(path) as f:
        write_npz(f, {"metadata": np.array(json.dumps(meta, sort_keys=True)), **arrays})
    return meta


def write_npz(file, arrays):
    """Write `arrays` ({name: array}) to the binary file `file` as a compressed .npz that np.load reads:
    one deflated .npy per array, in the order given. Each member's date is 1980-01-01 00:00 (zip's
    first day), written here rather than left to numpy's and zipfile's versions (older ones stamped
    the clock), so the bytes depend on the arrays only."""
    with zipfile.ZipFile(file, "w", zipfile.ZIP_DEFLATED) as z:
        for name, array in arrays.items():
            info = zipfile.ZipInfo(name + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with z.open(info, "w", force_zip64=True) as member:    # zip64: members may pass 2 GB
                np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)


def load(path):
    """Read and check a dataset written by `save`. Returns the dataset dict (with "metadata").

    Raises FileNotFoundError if there is no file, else DatasetError (a ValueError) naming the file,
    what is wrong with it and the fix, whatever the damage. Each array's .npy header is checked
    against the zip's record of the member's size, and the metadata and shapes against each other,
    before any array is read: a flipped bit cannot make numpy allocate what the file does not hold.
    """
    path = os.fspath(path)
    source = repr(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no dataset at {path!r}; create one with `python -m oneshot.collect --out {path}`")
    if os.path.isdir(path):
        raise DatasetError(f"{path!r} is a folder; name the dataset's .npz file")
    with open(path, "rb") as file, _damaged(path), zipfile.ZipFile(file) as z:
        members = _members(z)
        if "metadata" not in members:
            raise DatasetError(f"{path!r} has no metadata, so it was not written by oneshot; {FIX}")
        size = os.fstat(file.fileno()).st_size
        headers = {key: _npy_header(z, info, size) for key, info in members.items()}
        if headers["metadata"][0].kind != "U" or headers["metadata"][1] != ():
            raise DatasetError(f"{path!r}: its metadata is not a JSON string; {FIX}")
        try:
            meta = json.loads(str(_read_npy(z, members["metadata"])))
        except json.JSONDecodeError as e:
            raise DatasetError(f"{path!r} has corrupt metadata ({e}); {FIX}") from e
        if not isinstance(meta, dict):
            raise DatasetError(f"{path!r}: its metadata must be a JSON object; got {type(meta).__name__}; {FIX}")
        version = meta.get("format_version")
        if version != FORMAT_VERSION:
            raise DatasetError(f"{path!r} has format version {version}, this oneshot reads version "
                               f"{FORMAT_VERSION}; {FIX}")
        shapes = {key: header for key, header in headers.items() if key in ARRAYS}
        check_layout(shapes, source)
        check_metadata(meta, shapes, source)
        data = {key: _read_npy(z, members[key]) for key in ARRAYS}
    validate(data, source)
    if checksum(data) != meta.get("checksum"):
        raise DatasetError(f"{path!r} fails its checksum: the arrays were changed or damaged after "
                           f"saving; {FIX}")
    data["metadata"] = meta
    return data


@contextlib.contextmanager
def _damaged(path):
    """Turn any error of the zip and .npy readers inside the block into a DatasetError naming `path`: a
    flipped bit can raise nearly anything (zlib.error, NotImplementedError, SyntaxError, EOFError, ...).
    Not MemoryError, nor KeyboardInterrupt (not an Exception): they are not the file's fault."""
    try:
        yield
    except (DatasetError, MemoryError):
        raise
    except Exception as e:
        detail = " ".join(str(e).split()) or type(e).__name__
        raise DatasetError(f"{path!r} is not a readable .npz dataset (truncated or corrupt: {detail}); "
                           f"{FIX}") from e


def _members(z):
    """{key: ZipInfo} of the .npy members of zip `z` that `load` reads: "metadata" and ARRAYS'."""
    members = {}
    for info in z.infolist():
        key = info.filename.removesuffix(".npy")
        if info.filename.endswith(".npy") and (key == "metadata" or key in ARRAYS):
            if key in members:
                raise ValueError(f"it holds {info.filename} twice")
            members[key] = info
    return members


def _npy_header(z, info, file_bytes):
    """(dtype, shape) of a .npy member of zip `z`, from its header alone. Raises ValueError unless the
    array it describes is exactly the member's uncompressed size as the zip records it, and that size
    fits in the member's share of the file's `file_bytes` (at most MAX_DEFLATE_RATIO times its
    compressed size)."""
    if info.compress_type == zipfile.ZIP_DEFLATED:
        fits = info.compress_size <= file_bytes and info.file_size <= MAX_DEFLATE_RATIO * info.compress_size
    else:
        fits = info.compress_type == zipfile.ZIP_STORED and info.file_size == info.compress_size <= file_bytes
    if not fits:
        raise ValueError(f"the zip's sizes of {info.filename} ({info.compress_size} bytes, compression "
                         f"{info.compress_type}, holding {info.file_size}) are impossible in a "
                         f"{file_bytes}-byte file")
    with z.open(info) as f, warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)      # numpy's warning about a header only Python 2 wrote
        version = np.lib.format.read_magic(f)
        read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                       (2, 0): np.lib.format.read_array_header_2_0}.get(version)
        if read_header is None:
            raise ValueError(f"{info.filename} has .npy format version {version}, not 1.0 or 2.0")
        shape, _, dtype = read_header(f)                 # (the order, C or Fortran, read_array follows)
        start = f.tell()
    if dtype.hasobject or min(shape, default=0) < 0 or start + math.prod(shape) * dtype.itemsize != info.file_size:
        raise ValueError(f"{info.filename}'s header claims a {shape} {dtype} array, which is not the "
                         f"{info.file_size - start} bytes the member holds")
    return dtype, shape


def _read_npy(z, info):
    """The array of a .npy member of zip `z` (its header checked by _npy_header). Reading it to its end
    makes zipfile check its CRC-32."""
    with z.open(info) as f:
        return np.lib.format.read_array(f, allow_pickle=False)


def demo(dataset, task, k):
    """The k-th demo of a task: (images (T, H, W, 3) uint8, states (T, 6), actions (T, 2))."""
    return dataset["images"][task, k], dataset["states"][task, k], dataset["actions"][task, k]


def world_config(metadata, source="dataset"):
    """The WorldConfig a dataset was recorded in, rebuilt from its metadata (arm and palette too).
    Raises DatasetError if the metadata does not describe one."""
    def tuples(d):
        return {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
    try:
        world = tuples(metadata["world"])
        world["arm"] = ArmConfig(**tuples(metadata["world"]["arm"]))
        world["palette"] = PaletteConfig(**metadata["world"]["palette"])
        return WorldConfig(**world)
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise DatasetError(f"{source}: its metadata does not describe a world ({type(e).__name__}: {e}); "
                           f"{FIX}") from e
