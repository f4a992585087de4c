"""The demonstration dataset (paper Section IV): N tasks x K demos, saved as one compressed .npz.

A dataset is a plain dict of arrays plus a "metadata" dict (N tasks, K demos per task, T steps):

    images        (N, K, T, H, W, 3) uint8    what the camera saw before each action
    states        (N, K, T, 6)       float32  joint angles (rad), joint velocities (rad/s), end effector (m)
    actions       (N, K, T, 2)       float32  the expert's joint torques (N m)
    task_colours  (N,)               int16    palette index of each task's target colour
    colours       (N, K, n)          int16    palette indices of the n objects of each demo's scene
    positions     (N, K, n, 2)       float32  object centres (m)
    target_index  (N, K)             int8     which object is the target
    seeds         (N, K)             int64    the seed that reproduces each demo's scene
    metadata      dict                         format version, configs, split, counts, checksum

`save` writes atomically (a temporary file, then a rename), so a crash never leaves half a file;
`load` checks the format version, keys, dtypes, shapes and a SHA-256 checksum of the arrays, and
says exactly what is wrong with a bad or truncated file.
"""
import contextlib
import hashlib
import json
import os
import tempfile
import zipfile

import numpy as np

from oneshot.arm import ArmConfig
from oneshot.palette import PaletteConfig
from oneshot.world import WorldConfig

FORMAT_VERSION = 1

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


def validate(dataset, source="dataset"):
    """Raise DatasetError unless `dataset` has every array with the right dtype and consistent shapes."""
    fix = "re-create it with `python -m oneshot.collect`"
    for key, (dtype, ndim) in ARRAYS.items():
        if key not in dataset:
            raise DatasetError(f"{source} has no array {key!r}; {fix}")
        a = dataset[key]
        if a.dtype != dtype or a.ndim != ndim:
            raise DatasetError(f"{source}: {key} must be {ndim}-d {np.dtype(dtype).name}; "
                               f"got {a.ndim}-d {a.dtype.name} {a.shape}; {fix}")
    n, k, t = dataset["images"].shape[:3]
    h, w, c = dataset["images"].shape[3:]
    n_obj = dataset["colours"].shape[2]
    expected = {"images": (n, k, t, h, h, 3), "states": (n, k, t, 6), "actions": (n, k, t, 2),
                "task_colours": (n,), "colours": (n, k, n_obj), "positions": (n, k, n_obj, 2),
                "target_index": (n, k), "seeds": (n, k)}
    for key, shape in expected.items():
        if dataset[key].shape != shape:
            raise DatasetError(f"{source}: {key} has shape {dataset[key].shape}, expected {shape} "
                               f"(N={n} tasks, K={k} demos, T={t} steps); {fix}")
    for key in ("states", "actions", "positions"):
        if not np.all(np.isfinite(dataset[key])):
            raise DatasetError(f"{source}: {key} contains NaN or inf; {fix}")
    if np.any(dataset["target_index"] < 0) or np.any(dataset["target_index"] >= n_obj):
        raise DatasetError(f"{source}: target_index must lie in [0, {n_obj}); {fix}")
    picked = np.take_along_axis(dataset["colours"], dataset["target_index"][..., None].astype(int), 2)[..., 0]
    if np.any(picked != dataset["task_colours"][:, None]):
        raise DatasetError(f"{source}: some demo's target object does not have its task's colour; {fix}")


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
    """Write `dataset` (validated) to `path` (.npz), atomically. Adds the checksum to the metadata."""
    validate(dataset)
    arrays = {key: dataset[key] for key in ARRAYS}
    meta = dict(dataset.get("metadata", {}), format_version=FORMAT_VERSION, checksum=checksum(arrays))
    with atomic_write(path) as f:
        np.savez_compressed(f, metadata=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    return meta


def load(path):
    """Read and check a dataset written by `save`. Returns the dataset dict (with "metadata")."""
    path = os.fspath(path)
    fix = "re-create it with `python -m oneshot.collect`"
    if not os.path.exists(path):
        raise FileNotFoundError(f"no dataset at {path!r}; create one with `python -m oneshot.collect --out {path}`")
    try:
        with np.load(path, allow_pickle=False) as f:
            data = {key: f[key] for key in f.files}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
        raise DatasetError(f"{path!r} is not a readable .npz dataset (truncated or corrupt: {e}); {fix}") from e
    if "metadata" not in data:
        raise DatasetError(f"{path!r} has no metadata, so it was not written by oneshot; {fix}")
    try:
        meta = json.loads(str(data.pop("metadata")))
    except json.JSONDecodeError as e:
        raise DatasetError(f"{path!r} has corrupt metadata ({e}); {fix}") from e
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise DatasetError(f"{path!r} has format version {version}, this oneshot reads version "
                           f"{FORMAT_VERSION}; {fix}")
    validate(data, source=repr(path))
    if checksum(data) != meta.get("checksum"):
        raise DatasetError(f"{path!r} fails its checksum: the arrays were changed or damaged after "
                           f"saving; {fix}")
    data["metadata"] = meta
    return data


def demo(dataset, task, k):
    """The k-th demo of a task: (images (T, H, W, 3) uint8, states (T, 6), actions (T, 2))."""
    return dataset["images"][task, k], dataset["states"][task, k], dataset["actions"][task, k]


def world_config(metadata):
    """The WorldConfig a dataset was recorded in, rebuilt from its metadata (arm and palette too)."""
    def tuples(d):
        return {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
    world = tuples(metadata["world"])
    world["arm"] = ArmConfig(**tuples(metadata["world"]["arm"]))
    world["palette"] = PaletteConfig(**metadata["world"]["palette"])
    return WorldConfig(**world)
