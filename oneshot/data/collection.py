"""Collecting demonstrations (paper Section IV): the expert records N tasks (distinct target colours of
one split) x K demos per task on every core, `collect`; `python -m oneshot.collect` is the command.

Every demo's scene seed is derived from (seed, task, demo, attempt) (`scene_seed`), so the dataset is
the same whatever the number of worker processes. A demo the expert fails is retried on a fresh scene
and counted in the metadata; a horizon too short for the expert fails every scene (ExpertFailed).
"""
import contextlib
import dataclasses
import multiprocessing
import os
import signal

import numpy as np
from tqdm import tqdm

from oneshot.expert import controller
from oneshot.tools.host import die_with_parent
from oneshot.world import palette
from oneshot.world.reach import ReachWorld, WorldConfig

MAX_ATTEMPTS = 10


class ExpertFailed(ValueError):
    """The expert failed every scene of a demo (MAX_ATTEMPTS in a row): the horizon is too short for it
    to reach the target and stay there (bad input, so a ValueError: exit status 2 from the command)."""


def scene_seed(seed, task, k, attempt):
    """The seed of demo k of task `task` at the given attempt: an int64 derived from all four."""
    return int(np.random.SeedSequence([seed, 1, task, k, attempt]).generate_state(1, np.uint64)[0] >> 1)


def task_colours(n_tasks, split, seed, palette_cfg=palette.PaletteConfig()):
    """n_tasks distinct colours of the split, in a seeded random order. -> (n_tasks,) int."""
    colours = palette.split_colours(split, palette_cfg)
    if not 1 <= n_tasks <= len(colours):
        raise ValueError(f"the {split!r} split has {len(colours)} colours, so 1 to {len(colours)} tasks; "
                         f"got {n_tasks} (collect more demos per task instead)")
    return np.random.default_rng([seed, 0]).permutation(colours)[:n_tasks]


_WORLD = {}


def _demo_job(job):
    """Worker: record demo k of a task, retrying on failure. Returns (task, k, demo, seed, failures)."""
    world_cfg, expert_cfg, colour, task, k, seed = job
    world = _WORLD.get(world_cfg) or _WORLD.setdefault(world_cfg, ReachWorld(world_cfg))
    for attempt in range(MAX_ATTEMPTS):
        s = scene_seed(seed, task, k, attempt)
        d = controller.demonstrate(world, seed=s, options={"target_colour": int(colour)}, cfg=expert_cfg)
        if d["success"]:
            return task, k, d, s, attempt
    noise = " or a smaller --noise" if expert_cfg.action_noise > 0 else ""
    raise ExpertFailed(f"the expert failed {MAX_ATTEMPTS} scenes in a row for task {task} (colour {colour}): "
                       f"in {world_cfg.horizon} steps it cannot reach the target and stay there; "
                       f"use a longer --horizon (the default is {WorldConfig().horizon}){noise}")


def _worker_start(parent):
    """Pool initializer: workers end with the parent however it ends (`host.die_with_parent`), and ignore
    Ctrl-C (the terminal sends it to the whole process group), so only the parent stops, and terminates
    them, instead of every worker printing a traceback."""
    die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)        # terminate() ends them quietly, whatever the parent's handler


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM, handled as Ctrl-C) while `collect` ran: its message says how far it got
    (`unwritten` adds what a command should say)."""


@contextlib.contextmanager
def unwritten(path):
    """Around collecting a dataset and saving it at `path` (whole, atomically): Interrupted also says that
    `path` was not written, and to run the same command again."""
    try:
        yield
    except Interrupted as e:
        raise Interrupted(f"{e}; {path} was not written: run the same command again") from None


def collect(n_tasks, demos_per_task, split="train", seed=0, workers=None, world_cfg=None,
            expert_cfg=controller.ExpertConfig(), progress=True):
    """Record a dataset (see `oneshot.data.datasets`). workers: processes (default: all cores); the dataset is the
    same for any number. Raises ExpertFailed if the expert fails every scene of a demo."""
    if demos_per_task < 2:
        raise ValueError(f"MAML needs at least 2 demos per task (one to adapt on, one to evaluate); "
                         f"got {demos_per_task}")
    world_cfg = dataclasses.replace(world_cfg or WorldConfig(), split=split)
    colours = task_colours(n_tasks, split, seed, world_cfg.palette)
    jobs = [(world_cfg, expert_cfg, colours[i], i, k, seed)
            for i in range(n_tasks) for k in range(demos_per_task)]
    N, K, T, S = n_tasks, demos_per_task, world_cfg.horizon, world_cfg.image_size
    n_obj = world_cfg.n_objects
    out = {"images": np.zeros((N, K, T, S, S, 3), np.uint8), "states": np.zeros((N, K, T, 6), np.float32),
           "actions": np.zeros((N, K, T, 2), np.float32), "task_colours": colours.astype(np.int16),
           "colours": np.zeros((N, K, n_obj), np.int16), "positions": np.zeros((N, K, n_obj, 2), np.float32),
           "target_index": np.zeros((N, K), np.int8), "seeds": np.zeros((N, K), np.int64)}
    failures, iterations = 0, []
    workers = workers or os.cpu_count() or 1
    bar = tqdm(total=len(jobs), desc=f"collecting {split} demos", unit="demo", disable=not progress)
    try:
        # leaving the `with` on an error or Ctrl-C terminates the pool's workers and waits for them
        pool = (multiprocessing.get_context("fork").Pool(workers, _worker_start, (os.getpid(),)) if workers > 1
                else _Serial())
        with pool:
            for i, k, d, s, failed in pool.imap_unordered(_demo_job, jobs, chunksize=8):
                out["images"][i, k], out["states"][i, k], out["actions"][i, k] = d["images"], d["states"], d["actions"]
                scene = d["scene"]
                out["colours"][i, k], out["positions"][i, k] = scene.colours, scene.positions
                out["target_index"][i, k], out["seeds"][i, k] = scene.target, s
                failures += failed
                iterations.append(d["ilqg_iterations"])
                bar.update()
    except BaseException as e:
        bar.leave = False              # wipe the half-drawn bar, so the error is the one line left
        if isinstance(e, KeyboardInterrupt):
            raise Interrupted(f"interrupted while collecting {split} demos ({len(iterations)} of {len(jobs)} "
                              f"recorded)") from None
        raise
    finally:
        bar.close()
    out["metadata"] = {
        "split": split, "seed": seed, "n_tasks": N, "demos_per_task": K,
        "world": dataclasses.asdict(world_cfg), "expert": dataclasses.asdict(expert_cfg),
        "failed_attempts": failures, "dropped": 0, "max_attempts": MAX_ATTEMPTS,
        "expert_success_rate": N * K / (N * K + failures),
        "ilqg_iterations_median": float(np.median(iterations)),
    }
    return out


class _Serial:
    """Stand-in for a process pool when workers == 1 (easier to debug and profile)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def imap_unordered(self, f, jobs, chunksize=1):
        return map(f, jobs)
