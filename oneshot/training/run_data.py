"""The datasets a run meta-trains and checks on: found, or collected with the profile's settings, and the
smaller meta-training sets of the data-size experiment.

    train_set, heldout_set = run_data.ensure(cfg)        # collected first if missing
    train_set = run_data.subset(train_set, tasks=72, demos=12)
"""
import os
import shlex
import sys

from oneshot.data import collection, datasets
from oneshot.expert.controller import ExpertConfig
from oneshot.world import palette
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import WorldConfig

# split -> the collect seed of the profile's datasets (the same seeds every profile uses)
SEEDS = {"train": 0, "heldout": 1}


def specs(cfg):
    """[(path, split, demos per colour, seed)] of the datasets a TrainConfig trains and checks on."""
    return [(cfg.train_data, "train", cfg.train_demos, SEEDS["train"]),
            (cfg.heldout_data, "heldout", cfg.heldout_demos, SEEDS["heldout"])]


def collect_command(path, split, demos, seed, cfg):
    """The `python -m oneshot.collect` command that makes the dataset at `path` for a TrainConfig:
    every colour of the split, `demos` demos each, the profile's seed, noise and palette."""
    tasks = len(palette.split_colours(split, PaletteConfig(mode=cfg.palette)))
    words = ["python", "-m", "oneshot.collect", "--out", path, "--split", split, "--tasks", str(tasks),
             "--demos", str(demos), "--seed", str(seed), "--noise", str(cfg.demo_noise)]
    return shlex.join(words + (["--palette", cfg.palette] if cfg.palette != "hues" else []))


def ensure(cfg, progress=True):
    """[meta-training set, held-out set] of a TrainConfig, each loaded, or collected first if missing
    (every colour of its split: 36 and 12 in the hues palette)."""
    out = []
    for path, split, demos, seed in specs(cfg):
        if not os.path.exists(path):
            print(f"{path} is missing: collecting it ({collect_command(path, split, demos, seed, cfg)})",
                  file=sys.stderr)
            world_cfg = WorldConfig(palette=PaletteConfig(mode=cfg.palette))
            tasks = len(palette.split_colours(split, world_cfg.palette))
            datasets.save(collection.collect(tasks, demos, split, seed, progress=progress, world_cfg=world_cfg,
                                             expert_cfg=ExpertConfig(action_noise=cfg.demo_noise)), path)
        out.append(datasets.load(path))
    return out


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
