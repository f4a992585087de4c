"""The datasets of a run's protocol: its meta-training colours, the validation colours every choice reads
(training's checks, early stopping, hyperparameters, the random policy's std), and the test colours
scored once per trained policy; found, or collected with the profile's settings, and checked to be
what the profile asks for.

    train_set, validation_set = run_data.ensure(cfg)                # collected first if missing
    test_set = run_data.load(cfg, "test")                            # evaluation only: never collected here
    train_set = run_data.subset(train_set, tasks=72, demos=12)
"""
import dataclasses
import os
import re
import shlex
import sys

from oneshot.data import collection, datasets
from oneshot.expert.controller import ExpertConfig
from oneshot.world import palette
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import WorldConfig

# split -> the collect seed of every profile's datasets
SEEDS = {"train": 0, "validation": 1, "test": 2}


class DataMismatch(ValueError):
    """A dataset at a profile's path was collected with other settings than the profile's."""


def spec(cfg, split):
    """(path, demos per colour, collect seed) of a TrainConfig's dataset of `split`."""
    path, demos = {"train": (cfg.train_data, cfg.train_demos), "validation": (cfg.validation_data, cfg.validation_demos),
                   "test": (cfg.test_data, cfg.test_demos)}[split]
    return path, demos, SEEDS[split]


def tasks(cfg, split):
    """How many colours a TrainConfig's `split` holds in its palette."""
    return len(palette.split_colours(split, PaletteConfig(mode=cfg.palette)))


def file_name(palette_mode, split, colours, demos):
    """The name of a dataset of `colours` x `demos` of `split` collected with the split's seed, as a
    Figure 2 sweep names its datasets (`oneshot.experiments.fig2.data_paths`): grid_test_c48_d10_s2.npz.
    Such a name is a promise: `collected_size` collects what it says, `check` holds the file to it."""
    return f"{palette_mode}_{split}_c{colours}_d{demos}_s{SEEDS[split]}.npz"


def _named_size(cfg, split):
    """(colours, demos) a `file_name`-named dataset path of `split` says it holds, else None."""
    pattern = re.escape(file_name(cfg.palette, split, "COLOURS", "DEMOS")).replace("COLOURS", r"(\d+)")
    pattern = pattern.replace("DEMOS", r"(\d+)")
    named = re.fullmatch(pattern, os.path.basename(spec(cfg, split)[0]))
    return (int(named[1]), int(named[2])) if named else None


def collected_size(cfg, split):
    """(colours, demos per colour) that collecting a TrainConfig's dataset of `split` makes: what its file
    name says if named by `file_name` (a Figure 2 run's), else every colour of the split x the profile's
    demos. Raises DataMismatch if the name says fewer demos than the profile needs, or more colours than
    the split has."""
    path, demos, _ = spec(cfg, split)
    named = _named_size(cfg, split)
    if named is None:
        return tasks(cfg, split), demos
    if not (1 <= named[0] <= tasks(cfg, split) and named[1] >= demos):
        raise DataMismatch(f"{path} is named for {named[0]} {split} colours x {named[1]} demos, but this run needs "
                           f"at least {demos} demos of at most {tasks(cfg, split)} colours; name another file")
    return named


def collect_command(cfg, split):
    """The `python -m oneshot.collect` command that makes a TrainConfig's dataset of `split`
    (`collected_size`: a Figure 2 file's colours and demos, else every colour of the split and the
    profile's demos per colour), with the split's seed and the profile's noise and palette."""
    path, _, seed = spec(cfg, split)
    colours, demos = collected_size(cfg, split)
    words = ["python", "-m", "oneshot.collect", "--out", path, "--split", split, "--tasks", str(colours),
             "--demos", str(demos), "--seed", str(seed), "--noise", f"{cfg.demo_noise:g}"]
    return shlex.join(words + (["--palette", cfg.palette] if cfg.palette != "hues" else []))


def missing(cfg, splits, flags=None):
    """None if every dataset of `splits` exists; else one message naming each missing file (and its flag,
    from `flags` {split: flag}) and the commands that make them all."""
    gone = [split for split in splits if not os.path.exists(spec(cfg, split)[0])]
    if not gone:
        return None
    named = ", ".join(f"{spec(cfg, s)[0]!r} ({s}{', ' + flags[s] if flags and s in flags else ''})" for s in gone)
    return (f"no dataset at {named}; make {'it' if len(gone) == 1 else 'them'} with: "
            + " && ".join(collect_command(cfg, s) for s in gone))


def check(cfg, split, metadata, path, whose="this run's", another="another file"):
    """Raise DataMismatch unless a dataset (its metadata) holds what the profile's `split` asks for: that
    split's colours of the profile's palette, collected with the profile's seed and DART noise, with at
    least the profile's demos per colour. `whose` and `another` word the message for its caller (a
    sweep: "this sweep's", "another --data")."""
    _, demos, seed = spec(cfg, split)
    wanted = {"split": split, "palette": cfg.palette, "seed": seed, "noise": cfg.demo_noise}
    held = {"split": metadata.get("split"), "palette": metadata.get("world", {}).get("palette", {}).get("mode"),
            "seed": metadata.get("seed"), "noise": metadata.get("expert", {}).get("action_noise")}
    differ = [f"{k} {held[k]!r}, not {wanted[k]!r}" for k in wanted if held[k] != wanted[k]]
    if metadata.get("demos_per_task", 0) < demos:
        differ.append(f"{metadata.get('demos_per_task')} demos per colour, not {demos}")
    named = _named_size(cfg, split)             # a Figure 2 file holds what its name says
    if named and (metadata.get("n_tasks"), metadata.get("demos_per_task")) != named:
        differ.append(f"{metadata.get('n_tasks')} colours x {metadata.get('demos_per_task')} demos, not the "
                      f"{named[0]} x {named[1]} its name says")
    if differ:
        if held["split"] not in (split, None):  # another split's file: most likely the wrong file was named,
            fresh = dataclasses.replace(cfg, **{f"{split}_data": "FILE"})     # and it is not to be moved or replaced
            fix = f"name a {split} dataset instead (to make one: {collect_command(fresh, split)})"
        else:
            fix = (f"move it away (this command then collects the right one: {collect_command(cfg, split)}), "
                   f"or name {another}")
        raise DataMismatch(f"{path} was collected with other settings than {whose} {split} data: "
                           f"{'; '.join(differ)}; {fix}")


def load(cfg, split):
    """The profile's dataset of `split`, loaded and checked (`check`)."""
    path = spec(cfg, split)[0]
    dataset = datasets.load(path)
    check(cfg, split, dataset["metadata"], path)
    return dataset


def ensure(cfg, splits=("train", "validation"), progress=True):
    """[the dataset of each split] of a TrainConfig, loaded and checked, each collected first if missing
    (`collected_size`: every colour of its split, 36 and 12 in the hues palette, or what a Figure 2 file
    name says). A file of fewer colours than that is used, and a note on stderr says so (but for the
    meta-training set of a config that asks for its first `tasks` colours)."""
    out = []
    for split in splits:
        path, _, seed = spec(cfg, split)
        if not os.path.exists(path):
            print(f"{path} is missing: collecting it ({collect_command(cfg, split)})", file=sys.stderr)
            world_cfg = WorldConfig(palette=PaletteConfig(mode=cfg.palette))
            colours, demos = collected_size(cfg, split)
            with collection.unwritten(path):
                data = collection.collect(colours, demos, split, seed, progress=progress, world_cfg=world_cfg,
                                          expert_cfg=ExpertConfig(action_noise=cfg.demo_noise))
            datasets.save(data, path)
        out.append(load(cfg, split))
        note = fewer_colours(cfg, split, len(out[-1]["task_colours"]), "the run uses")
        if note and not (split == "train" and cfg.tasks):   # a small or stale file: said, not refused
            print(note, file=sys.stderr)
    return out


def fewer_colours(cfg, split, held, uses):
    """A note if a dataset of `split` holds fewer colours, `held`, than the profile collects
    (`collected_size`), else None; `uses` words what is done with those ("the run uses")."""
    path = spec(cfg, split)[0]
    try:
        whole = collected_size(cfg, split)[0]
    except DataMismatch:                        # a file named for other sizes: `check`'s to refuse, not a note's
        return None
    if held < whole:
        return (f"note: {path} holds {held} of the {whole} {split} colours this profile collects; {uses} those "
                f"{held} (the whole set: move it away, or {collect_command(cfg, split)})")
    return None


def subset(dataset, tasks=0, demos=0):
    """The first `tasks` tasks and first `demos` demos of each (0: all) of a dataset: the smaller
    meta-training sets of the data-size experiment (`oneshot.experiments.fig2`)."""
    n, k = dataset["images"].shape[:2]
    if not (0 <= tasks <= n and 0 <= demos <= k) or demos == 1:
        raise ValueError(f"the dataset has {n} tasks x {k} demos: need 0 <= tasks <= {n} and demos 0 or "
                         f"2..{k} (0: all); got tasks={tasks}, demos={demos}")
    tasks, demos = tasks or n, demos or k
    out = {key: v[:tasks, :demos] if v.ndim >= 2 and key != "task_colours" else v[:tasks]
           for key, v in dataset.items() if key != "metadata"}
    return dict(out, metadata=dataset["metadata"])
