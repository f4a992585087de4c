"""Whether a dataset is one a checkpoint's policy can run on: the images it was trained on, its horizon,
state layout, torque bound and palette (`check_data`); that two datasets are of one world
(`check_same_world`); and the world a checkpoint's policy acts in.

    ckpt = checkpoint.load(path)
    fit_check.check_data(ckpt, datasets.load(data_path)["metadata"], path, data_path)   # or CheckpointError
"""
import dataclasses
import json

from oneshot.data import datasets
from oneshot.training.checkpoint_meta import CheckpointError, world_fields
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import WorldConfig


def _plain(x):
    """x as JSON gives it back: tuples become lists (so a recorded value compares with a read one)."""
    return json.loads(json.dumps(x))


def world_config(ckpt):
    """The WorldConfig a checkpoint's policy was trained in (its image size, horizon, arm, palette), or
    for older checkpoints, which record only the network's image size and their config's palette mode,
    the default world of that size and palette."""
    if ckpt["world"] is None:
        return WorldConfig(image_size=ckpt["network"].image_size,
                           palette=PaletteConfig(mode=ckpt["config"].palette))
    return datasets.world_config({"world": ckpt["world"]})


def check_data(ckpt, metadata, ckpt_path, data_path, palette=True):
    """Raise CheckpointError unless a dataset (`metadata`: `datasets.load(data_path)["metadata"]`) is one
    the checkpoint's policy can run on: images of the size it was trained on, demos of its horizon, its
    state layout, the same torque bound (the policy's actions are torques divided by it) and, with
    palette=True, the same palette (a task is a palette index: in another palette it is another
    colour). Older checkpoints record no world: then only the image size (the network's) and the
    palette's mode (their config's; "hues", the only one, before configs recorded it) are checked. (For
    twelve commits of 2026-11-23 a config's palette was not checked against its training data's: such a
    checkpoint may record "hues" for grid data; --any-palette scores it.)
    A state layout is compared when both record one (datasets and checkpoints recording none have
    `datasets.STATE_LAYOUT`)."""
    trained = ckpt["world"]
    mine = world_fields(trained, f"{ckpt_path}: meta 'world'") if trained is not None else \
        {"image_size": ckpt["network"].image_size, "palette": world_config(ckpt).palette}
    _compare(mine, ckpt["state_layout"], metadata, f"{ckpt_path} was trained on", data_path, palette)


def check_same_world(reference, metadata, reference_path, data_path):
    """Raise DatasetError unless two datasets (their metadata) were collected in the same world: image
    size, horizon, state layout, torque bound and palette (`check_data`'s checks). A fresh run checks its
    validation data against its meta-training data, before training on them."""
    mine = world_fields(reference["world"], f"{reference_path}: metadata 'world'")
    _compare(mine, reference.get("state_layout"), metadata, f"{reference_path} holds", data_path, True,
             same=f"collect {data_path} in the meta-training data's world (python -m oneshot.collect with the "
                  f"same --image-size, --horizon and --palette), or name another file",
             error=datasets.DatasetError)


def _compare(mine, layout, metadata, subject, data_path, palette, same=None, error=CheckpointError):
    """check_data's comparisons of `mine` (world_fields; only "image_size" and "palette" for an old
    checkpoint) and `layout` (a state layout or None) with a dataset's metadata; `subject` opens the
    message ("X was trained on", "X holds"). same: one fix for every difference, instead of each
    one's; error: the exception raised."""
    remake = "re-create it with `python -m oneshot.collect`"
    if not isinstance(metadata.get("world"), dict):
        raise error(f"{data_path} records no world config in its metadata; {remake}")
    theirs = world_fields(metadata["world"], f"{data_path}: metadata 'world'", remake)

    def refuse(was, holds, fix):
        raise error(f"{subject} {was} but {data_path} holds {holds}; {same or fix}")

    a, b = mine["image_size"], theirs["image_size"]
    if a != b:
        refuse(f"{a}x{a} images", f"{b}x{b} images", f"use data collected with --image-size {a}")
    a, b = layout, metadata.get("state_layout")
    if a is not None and b is not None and _plain(a) != _plain(b):
        refuse(f"states laid out as {a}", f"states laid out as {b}",
               "use data collected by the oneshot that trained it, or re-train on this data")
    if "horizon" in mine:                        # (an old checkpoint records only its image size and palette)
        a, b = mine["horizon"], theirs["horizon"]
        if a != b:
            refuse(f"{a}-step demos", f"{b}-step demos", f"use data collected with --horizon {a}")
        a, b = mine["max_torque"], theirs["max_torque"]
        if a != b:
            refuse(f"torques of at most {a} N m", f"torques of at most {b} N m",
                   f"use data recorded with an arm of max_torque {a} (the policy's actions are divided by it)")
    a, b = mine["palette"], theirs["palette"]
    if palette and (a.mode != b.mode or ("horizon" in mine and a != b)):   # an old checkpoint: its mode only
        field = "mode" if a.mode != b.mode else next(f.name for f in dataclasses.fields(PaletteConfig)
                                                     if getattr(a, f.name) != getattr(b, f.name))
        fix = (f"use data collected with --palette {a.mode} (or, to test the policy on other colours, "
               f"python -m oneshot.evaluate --any-palette)")
        if field == "mode":
            refuse(f"the {a.mode!r} palette", f"the {b.mode!r} palette", fix)
        refuse(f"the {a.mode!r} palette with {field} {getattr(a, field)}",
               f"the {b.mode!r} palette with {field} {getattr(b, field)}", fix)
