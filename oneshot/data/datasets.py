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
of worker processes, is the same file (`npz.write`). `load` checks the file as `npz.Reader` does
(every .npy header before any array is read), then the format version, keys, dtypes, shapes, the
metadata the package reads and a SHA-256 checksum of the arrays, and says exactly what is wrong with
a bad, damaged or truncated file: every failure is a DatasetError naming the file. `read_metadata`
makes the same checks but for the arrays' contents, without reading them: a moment, for a command to
refuse a wrong file before its work.
"""
import contextlib
import json
import os

import numpy as np

from oneshot.data import npz
from oneshot.tools import files
from oneshot.world import palette
from oneshot.world.arm import ArmConfig
from oneshot.world.reach import WorldConfig

FORMAT_VERSION = 1


# What each of the 6 numbers of a state is (`reach.observation_state`; the angles and velocities are
# arm.py's x = (q1, q2, qd1, qd2)): radians, radians per second, metres. Saved in the metadata as
# "state_layout"; files written before it was recorded lack it, and have this layout.
STATE_LAYOUT = ("shoulder angle", "elbow angle", "shoulder velocity", "elbow velocity",
                "end effector x", "end effector y")

# What the package reads from a dataset's metadata, beyond what `world_config` needs to rebuild the
# world: imitation.py the split, training/run_folder.py the torque bound (the arrays' shapes are checked
# against the horizon, image size and number of objects).
REQUIRED_METADATA = (("split",), ("world", "horizon"), ("world", "image_size"), ("world", "n_objects"),
                     ("world", "arm", "max_torque"), ("world", "palette"))

FIX = "re-create it with `python -m oneshot.collect`"

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
    """SHA-256 over the arrays of ARRAYS, in that order (`npz.checksum`). -> hex str."""
    return npz.checksum(arrays, ARRAYS)


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
                               f"got {len(shape)}-d {_dtype_words(got)} {shape}; {FIX}")
    n, k, t, h = layout["images"][1][:4]
    n_obj = layout["colours"][1][2]
    expected = {"images": (n, k, t, h, h, 3), "states": (n, k, t, 6), "actions": (n, k, t, 2),
                "task_colours": (n,), "colours": (n, k, n_obj), "positions": (n, k, n_obj, 2),
                "target_index": (n, k), "seeds": (n, k)}
    for key, shape in expected.items():
        if tuple(layout[key][1]) != shape:
            raise DatasetError(f"{source}: {key} has shape {layout[key][1]}, expected {shape} "
                               f"(N={n} tasks, K={k} demos, T={t} steps); {FIX}")


def _dtype_words(dtype):
    """A dtype's name, with its byte order if it is not this machine's: "float32 in big-endian byte
    order (>f4; convert with .astype(np.float32))" (a dtype of another byte order has the same name)."""
    if dtype.isnative:
        return dtype.name
    order = "big" if dtype.byteorder == ">" else "little"
    return f"{dtype.name} in {order}-endian byte order ({dtype.str}; convert with .astype(np.{dtype.name}))"


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


def check_colours(dataset, metadata, source="dataset"):
    """Raise DatasetError unless every task's colour and every disc's is a colour of the metadata's split
    in its palette (a colour outside it would fail only at meta-test, or name another colour)."""
    world = world_config(metadata, source)
    allowed = palette.split_colours(world.split, world.palette)
    for key in ("task_colours", "colours"):
        outside = np.setdiff1d(dataset[key], allowed)
        if outside.size:
            raise DatasetError(f"{source}: {key} holds {outside[:5].tolist()}, not {world.split!r} colours of its "
                               f"{world.palette.mode!r} palette; {FIX}")


def save(dataset, path):
    """Write `dataset` (validated, arrays and metadata) to `path` (.npz), atomically, through a symbolic
    link and never over a device or a FIFO (`files.atomic_write`). Adds the format version, the state
    layout and the checksum to the metadata, and returns it. The file's bytes depend on the dataset
    only (`npz.write`), so the same data is the same file."""
    validate(dataset)
    arrays = {key: dataset[key] for key in ARRAYS}
    metadata = dataset.get("metadata", {})
    check_metadata(metadata, layout_of(arrays))
    check_colours(arrays, metadata)
    meta = dict(metadata, format_version=FORMAT_VERSION, state_layout=list(STATE_LAYOUT),
                checksum=checksum(arrays))
    with files.atomic_write(path) as f:
        npz.write(f, {"metadata": np.array(json.dumps(meta, sort_keys=True)), **arrays})
    return meta


def is_dataset(path):
    """May an output replace `path` as a dataset: does it hold a dataset's arrays (what `save` writes;
    `load` checks the rest), or is it too damaged to tell (which `load` says to re-create)?"""
    names = npz.members(path)
    return names is None or npz.kind(names) == "dataset"


def load(path):
    """Read and check a dataset written by `save`. Returns the dataset dict (with "metadata").

    Raises FileNotFoundError if there is no file, else DatasetError (a ValueError) naming the file,
    what is wrong with it and the fix, whatever the damage. A device, a FIFO or a socket is refused
    before it is read (`files.open_read`), whatever its name or links. Each array's .npy header is checked
    against the zip's record of the member's size, and the metadata and shapes against each other,
    before any array is read: a flipped bit cannot make numpy allocate what the file does not hold.
    """
    path = os.fspath(path)
    source = repr(path)
    with _opened(path) as (archive, meta):
        data = {key: archive.read(key) for key in ARRAYS}
    validate(data, source)
    if checksum(data) != meta.get("checksum"):
        raise DatasetError(f"{path!r} fails its checksum: the arrays were changed or damaged after "
                           f"saving; {FIX}")
    check_colours(data, meta, source)
    data["metadata"] = meta
    return data


def read_metadata(path):
    """The metadata of the dataset at `path`, checked against its arrays' shapes as `load` checks it,
    without reading the arrays (a moment, where loading the largest dataset takes seconds): to refuse a
    damaged or wrong file before work that would load it. Raises as `load` does; damage inside an
    array, which only reading it finds, is left to `load`."""
    with _opened(os.fspath(path)) as (_, meta):
        return meta


@contextlib.contextmanager
def _opened(path):
    """(the open npz.Reader, the checked metadata) of the dataset file at `path`: every .npy header,
    the layout and the metadata checked, no array read yet. A damaged file, read then or while open,
    raises DatasetError naming it; no file, FileNotFoundError."""
    source = repr(path)
    if not os.path.exists(path):
        raise FileNotFoundError(f"no dataset at {path!r}; create one with `python -m oneshot.collect --out {path}`")
    if os.path.isdir(path):
        raise DatasetError(f"{path!r} is a folder; name the dataset's .npz file")
    try:
        with npz.Reader(path) as archive:          # every .npy header checked, no array read yet
            meta = _read_metadata(path, archive)
            layout = {key: archive.layout[key] for key in ARRAYS if key in archive.layout}
            check_layout(layout, source)
            check_metadata(meta, layout, source)        # all before reading what may be gigabytes
            yield archive, meta
    except npz.Damaged as e:
        raise DatasetError(f"{path!r} is not a readable .npz dataset (truncated or corrupt: {e}); {FIX}") from e
    except files.RefusedPath as e:
        raise DatasetError(str(e)) from None


def _read_metadata(path, archive):
    """The metadata dict of the dataset file at `path` (its open `npz.Reader`), of this format version."""
    if "metadata" not in archive.layout:
        if npz.kind(set(archive.layout)) == "checkpoint":
            raise DatasetError(f"{path!r} is a checkpoint (a trained policy), not a dataset; load it with "
                               f"oneshot.training.checkpoint.load, or name a dataset of `python -m oneshot.collect`")
        raise DatasetError(f"{path!r} has no metadata, so it was not written by oneshot; {FIX}")
    if archive.layout["metadata"][0].kind != "U" or archive.layout["metadata"][1] != ():
        raise DatasetError(f"{path!r}: its metadata is not a JSON string; {FIX}")
    try:
        meta = files.loads_json(str(archive.read("metadata")))
    except json.JSONDecodeError as e:
        raise DatasetError(f"{path!r} has corrupt metadata ({e}); {FIX}") from e
    if not isinstance(meta, dict):
        raise DatasetError(f"{path!r}: its metadata must be a JSON object; got {type(meta).__name__}; {FIX}")
    if meta.get("format_version") != FORMAT_VERSION:
        raise DatasetError(f"{path!r} has format version {meta.get('format_version')}, this oneshot reads "
                           f"version {FORMAT_VERSION}; {FIX}")
    for holder in (meta, meta.get("world")):   # older datasets call the validation split "heldout"
        if isinstance(holder, dict) and holder.get("split") in palette.LEGACY_SPLITS:
            holder["split"] = palette.LEGACY_SPLITS[holder["split"]]
    return meta


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
        world["palette"] = palette.saved_config(metadata["world"]["palette"])
        return WorldConfig(**world)
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise DatasetError(f"{source}: its metadata does not describe a world ({type(e).__name__}: {e}); "
                           f"{FIX}") from e
