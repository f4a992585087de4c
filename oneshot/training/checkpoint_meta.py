"""What a checkpoint's metadata may hold (`oneshot.training.checkpoint`): its format version, the fields of
its configs (those added or renamed since the first checkpoints), and the checks that read them from JSON
into `TrainConfig` and `NetworkConfig`, and a recorded world's fields (`world_fields`), each naming the file
and what is wrong (`CheckpointError`).
"""
import dataclasses
import json
import math

from oneshot.tools.files import loads_json
from oneshot.world.palette import saved_config

FORMAT_VERSION = 1
FIX = "move it aside and train it again (with the train or fig2 command that made it), or use another checkpoint"

# Config fields added after the first checkpoints were written: older files lack them, and their
# defaults are what those runs used. Every other field must be recorded. (A field added to TrainConfig
# or NetworkConfig goes here, or the shipped policy stops loading: tests/test_train.py says so.)
ADDED_LATER = {"config": ("method", "lstm_units", "random_stds", "palette", "tasks", "demos", "test_data",
                          "test_demos", "never_adapt", "inner_clip", "inner_loss_scale", "layer_norm", "init",
                          "channels", "hidden"),
               "network": ("image_channels", "layer_norm", "init")}
# Config fields renamed since: what older checkpoints call them; and the old default path of the
# validation colours' dataset (the same data: 12 colours x 10 demos, seed 1), under its new name.
RENAMED = {"config": {"heldout_data": "validation_data", "heldout_demos": "validation_demos"}, "network": {}}
RENAMED_PATHS = {"data/heldout.npz": "data/validation.npz"}


class CheckpointError(ValueError):
    """A checkpoint file is damaged or was edited, or does not fit a dataset; the message says which
    file, what is wrong, and what to do."""


def read_meta(path, meta):
    """The metadata dict of a checkpoint, its keys and their types checked (not yet their contents)."""
    if meta is None:
        raise CheckpointError(f"{path!r} has no metadata, so oneshot did not write it; {FIX}")
    try:
        meta = loads_json(str(meta)) if meta.dtype.kind == "U" and meta.ndim == 0 else None
    except json.JSONDecodeError as e:
        raise CheckpointError(f"{path!r} has corrupt metadata ({e}); {FIX}") from e
    if not isinstance(meta, dict):
        raise CheckpointError(f"{path!r}: its metadata is not a JSON object; {FIX}")
    meta = {"world": None, "state_layout": None, "seconds": None, **meta}   # older checkpoints lack them
    types = {"iteration": int, "rng": dict, "config": dict, "network": dict, "world": (dict, type(None)),
             "state_layout": (list, type(None)), "seconds": (float, int, type(None)), "checksum": str,
             "format_version": int}
    for key, kind in types.items():
        if key not in meta and key != "checksum":                 # older checkpoints have no checksum
            raise CheckpointError(f"{path!r}: its metadata has no {key!r}; {FIX}")
        if key in meta and (not isinstance(meta[key], kind) or isinstance(meta[key], bool)):
            names = " or ".join(k.__name__ for k in (kind if isinstance(kind, tuple) else (kind,)))
            raise CheckpointError(f"{path!r}: meta {key!r} is {meta[key]!r}, not {names}; {FIX}")
    unknown = sorted(set(meta) - set(types))
    if unknown:
        raise CheckpointError(f"{path!r}: its metadata has an unknown key {unknown[0]!r}; {FIX}")
    if meta["format_version"] != FORMAT_VERSION:
        raise CheckpointError(f"{path!r} has format version {meta['format_version']}; this oneshot reads "
                              f"version {FORMAT_VERSION}; {FIX}")
    if meta["iteration"] < 0:
        raise CheckpointError(f"{path!r}: meta 'iteration' is {meta['iteration']}, not >= 0; {FIX}")
    if meta["seconds"] is not None and not 0 <= meta["seconds"] < math.inf:
        raise CheckpointError(f"{path!r}: meta 'seconds' is {meta['seconds']}, not a time >= 0; {FIX}")
    return meta


def read_config(path, key, cls, fields):
    """cls(**fields) for a config dict read from JSON (key: "config" or "network"): every field known,
    every field of the first checkpoints present, each of its dataclass's type (lists back to tuples)."""
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    fields = {RENAMED[key].get(name, name): RENAMED_PATHS.get(v, v) if name in RENAMED[key] else v
              for name, v in fields.items()}
    for name in fields:
        if name not in defaults:
            raise CheckpointError(f"{path!r}: meta {key!r} has an unknown field {name!r}; {FIX}")
    for name in defaults:
        if name not in fields and name not in ADDED_LATER[key]:
            raise CheckpointError(f"{path!r}: meta {key!r} has no field {name!r}; {FIX}")
    values = {}
    for name, v in fields.items():
        v = tuple(v) if isinstance(v, list) else v
        if not _same_kind(v, defaults[name]):
            raise CheckpointError(f"{path!r}: meta {key!r} field {name!r} is {v!r}, not "
                                  f"{_kind_of(defaults[name])}; {FIX}")
        values[name] = v
    try:
        return cls(**values)
    except (ValueError, TypeError) as e:               # the dataclass's own checks (__post_init__)
        raise CheckpointError(f"{path!r}: meta {key!r}: {e}; {FIX}") from e


def _same_kind(value, default):
    """Is a JSON value of the default's type? bool is not a number here, a float field takes an int,
    numbers are finite, and a tuple's items are of its default's items' type."""
    if isinstance(default, tuple):
        return isinstance(value, tuple) and (not default or all(_same_kind(v, default[0]) for v in value))
    if isinstance(default, bool) or isinstance(value, bool):
        return isinstance(value, bool) and isinstance(default, bool)
    if isinstance(default, float):
        return isinstance(value, (int, float)) and math.isfinite(value)
    return isinstance(value, type(default))


def _kind_of(default):
    """What a config field takes, in words, from its default."""
    if isinstance(default, tuple):
        return f"a list of {_kind_of(default[0])[2:]}s" if default else "a list"
    kinds = {bool: "a bool (true or false)", int: "a whole number", float: "a finite number", str: "a string"}
    return kinds[type(default)]


def world_fields(world, where, fix=FIX):
    """The fields of a world dict that a checkpoint depends on: {"image_size", "horizon", "max_torque",
    "palette" (a PaletteConfig)}. Raises CheckpointError naming `where` (and `fix`) if one is missing
    or malformed."""
    try:
        out = {"image_size": world["image_size"], "horizon": world["horizon"],
               "max_torque": world["arm"]["max_torque"], "palette": saved_config(world["palette"])}
    except (KeyError, TypeError, ValueError) as e:
        raise CheckpointError(f"{where} is not a world config ({e!r}); {fix}") from e
    for key, like in (("image_size", 0), ("horizon", 0), ("max_torque", 0.0)):
        if not _same_kind(out[key], like):
            raise CheckpointError(f"{where} is not a world config ({key} {out[key]!r}, not {_kind_of(like)}); {fix}")
    return out
