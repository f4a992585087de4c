"""Meta-training (paper Sections II and III): `python -m oneshot.train --help`.

    python -m oneshot.train --profile default --run runs/default      # fast profile, 2 CPU cores
    python -m oneshot.train --run runs/default --resume                # continue a stopped run exactly

A run folder holds `checkpoint.npz` (parameters, Adam state, iteration, random state, config; written
atomically every `checkpoint_every` iterations and at the end) and `log.jsonl` (one JSON object per
line: meta-loss every `log_every` iterations, held-out one-shot success every `eval_every`). One
process trains in a folder at a time (`lock_run`); Ctrl-C or a plain kill saves a checkpoint of the last
finished iteration before it exits (status 130), and `--resume` continues from it.
Missing datasets are collected first with `python -m oneshot.collect` settings from the profile.
"""
import contextlib
import dataclasses
import fcntl
import glob
import json
import math
import os
import shutil
import sys
import time

import numpy as np
from tqdm import tqdm

from oneshot.data import collection, datasets
from oneshot.maml import imitation, inner, optim, shards
from oneshot.methods import registry
from oneshot.training import checkpoint
from oneshot.world import palette
from oneshot.training.config import inner_only
from oneshot.tools import files
from oneshot.expert.controller import ExpertConfig
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import WorldConfig


def learning_rate(cfg, iteration):
    """Adam's step size for meta-iteration `iteration` (0-based): cfg.lr, or with cfg.lr_schedule =
    "cosine" cfg.lr * (1 + cos(pi * iteration / cfg.iterations)) / 2, which ends near zero. (With
    "cosine", changing --iterations on --resume reshapes the rest of the schedule.)"""
    if cfg.lr_schedule == "constant":
        return cfg.lr
    if cfg.lr_schedule == "cosine":
        return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * min(iteration, cfg.iterations) / cfg.iterations))
    raise ValueError(f"lr_schedule must be 'constant' or 'cosine'; got {cfg.lr_schedule!r}")


class TrainingDiverged(RuntimeError):
    """The meta-loss or meta-gradient became NaN or inf (or the policy's torques did)."""


def diverged(what, ckpt_path, saved):
    """TrainingDiverged saying `what` happened and what to do: retry from the last good checkpoint
    (iteration `saved`) with a smaller step, or, if none was saved (`saved` is None), start again."""
    if saved is not None:
        return TrainingDiverged(f"{what}; the last good checkpoint ({ckpt_path}, iteration {saved}) is kept: "
                                f"--resume with a smaller --lr to retry from it, or start a new run with a "
                                f"smaller --lr or --alpha.")
    return TrainingDiverged(f"{what}; no checkpoint was saved before it. Start a new run with a smaller --lr "
                            f"or --alpha (or a smaller --checkpoint-every, to keep one).")


# --- data ------------------------------------------------------------------------------------------

def ensure_datasets(cfg, progress=True):
    """Load the meta-training and held-out datasets, collecting any that is missing."""
    out = []
    for path, split, demos, seed in ((cfg.train_data, "train", cfg.train_demos, 0),
                                     (cfg.heldout_data, "heldout", cfg.heldout_demos, 1)):
        world_cfg = WorldConfig(palette=PaletteConfig(mode=cfg.palette))
        tasks = len(palette.split_colours(split, world_cfg.palette))   # every colour of the split: 36 and 12
        if not os.path.exists(path):
            print(f"{path} is missing: collecting it (python -m oneshot.collect --out {path} --split "
                  f"{split} --tasks {tasks} --demos {demos} --seed {seed} --noise {cfg.demo_noise}"
                  f"{' --palette ' + cfg.palette if cfg.palette != 'hues' else ''})", file=sys.stderr)
            datasets.save(collection.collect(tasks, demos, split, seed, progress=progress, world_cfg=world_cfg,
                                      expert_cfg=ExpertConfig(action_noise=cfg.demo_noise)), path)
        out.append(datasets.load(path))
    return out


# --- training --------------------------------------------------------------------------------------

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


# Fields of TrainConfig a --resume may change: how long, how often to log, evaluate and save, and the
# step size (to retry a diverged run from its last good checkpoint with a smaller one). Anything else
# would make the resumed run a different experiment.
RESUMABLE = ("iterations", "log_every", "eval_every", "eval_trials", "checkpoint_every", "lr")


class RunLocked(RuntimeError):
    """Another process is training in the same run folder."""


@contextlib.contextmanager
def lock_run(run_dir):
    """Own `run_dir` while the block runs: a second training process in it fails at once (RunLocked)
    instead of interleaving its checkpoints and log with ours. The lock (flock on run_dir/.lock) goes
    with the process, however it ends. Temporary files a killed process left are removed; a folder
    made here and left with nothing but the lock (the run failed before starting) is removed too."""
    if os.path.exists(run_dir) and not os.path.isdir(run_dir):
        raise FileExistsError(f"--run {run_dir!r} is a file; name a folder for the run")
    created = not os.path.exists(run_dir)
    os.makedirs(run_dir, exist_ok=True)
    with files.open_write(os.path.join(run_dir, ".lock"), "a+") as lock:
        _own(lock, run_dir)                      # RunLocked: the folder is the owner's, left alone
        try:
            yield
        except BaseException:
            if created and os.listdir(run_dir) == [".lock"]:
                shutil.rmtree(run_dir, ignore_errors=True)
            raise


def _own(lock, run_dir):
    """Take `lock` (an open file) without waiting, write our pid in it, remove stale temporary files."""
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.seek(0)
        owner = lock.read().strip() or "unknown"
        raise RunLocked(f"another process (pid {owner}) is training in {run_dir!r}; wait for it to end, "
                        f"or use another --run folder") from None
    lock.seek(0)
    lock.truncate()
    lock.write(f"{os.getpid()}\n")
    lock.flush()
    for stale in glob.glob(os.path.join(glob.escape(run_dir), ".tmp-*.npz")):   # a checkpoint write a kill
        with contextlib.suppress(FileNotFoundError):                               # interrupted
            os.remove(stale)


def train(cfg, run_dir, resume=False, progress=True, stop_after=None):
    """Meta-train a policy (Sections II-III): MAML on behavioural cloning, or a baseline of Section IV
    with the same data, loss, optimiser and checkpoints (cfg.method, `oneshot.methods.registry`).

    run_dir: folder for checkpoint.npz and log.jsonl (locked while training: `lock_run`). resume:
    continue from its checkpoint (the rest of the run is then identical to an uninterrupted one).
    stop_after: leave after this many iterations of this call (to test resuming). Ctrl-C saves a
    checkpoint of the last finished iteration and raises `Interrupted`. Returns the final parameters.
    """
    registry.check(cfg), inner_only(cfg), learning_rate(cfg, 0)    # bad names fail here, not later
    if not 0.0 <= cfg.ema < 1.0:
        raise ValueError(f"ema is the moving average's decay, in [0, 1) (0: off; e.g. 0.999); got {cfg.ema!r}")
    with lock_run(run_dir):
        return _train(cfg, run_dir, resume, progress, stop_after)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM) stopped training; its message says where the checkpoint is."""


def _train(cfg, run_dir, resume, progress, stop_after):
    ckpt_path, log_path = os.path.join(run_dir, "checkpoint.npz"), os.path.join(run_dir, "log.jsonl")
    # 1. Data: both splits, in network units (images in [0, 1], states and torques of order one).
    train_set, heldout_set = ensure_datasets(cfg, progress)
    train_set = subset(train_set, cfg.tasks, cfg.demos)
    image_size = train_set["images"].shape[-2]

    # 2. Parameters, optimiser and random state: fresh, or exactly as the checkpoint left them.
    world = train_set["metadata"]["world"]       # what the checkpoint records, to be checked against data
    if resume:
        ckpt = checkpoint.load(ckpt_path)
        for dataset, path in ((train_set, cfg.train_data), (heldout_set, cfg.heldout_data)):
            checkpoint.check_data(ckpt, dataset["metadata"], ckpt_path, path)   # e.g. the file was replaced
        stored = dataclasses.replace(ckpt["config"], **{name: getattr(cfg, name) for name in RESUMABLE})
        if stored != cfg:
            differ = ", ".join(f"{f.name}: checkpoint {getattr(stored, f.name)!r}, now {getattr(cfg, f.name)!r}"
                               for f in dataclasses.fields(cfg) if getattr(stored, f.name) != getattr(cfg, f.name))
            raise ValueError(f"{ckpt_path!r} was trained with a different config ({differ}); resume with the "
                             f"same profile and options (only {', '.join(RESUMABLE)} may change), or start a "
                             f"new run folder")
        params, adam, start, rng, net_cfg = (ckpt["params"], ckpt["adam"], ckpt["iteration"],
                                             ckpt["rng"], ckpt["network"])
        ema, before = ckpt["ema"], ckpt["seconds"]
        _truncate_log(log_path, start)
        if ckpt["config"].lr != cfg.lr:
            _log_now(log_path, {"iteration": start, "lr": cfg.lr, "lr_before": ckpt["config"].lr,
                                "step_now": learning_rate(cfg, start)})
    else:
        if os.path.exists(ckpt_path):
            raise FileExistsError(f"{run_dir!r} already holds a run; use --resume, or another --run folder")
        rng = np.random.default_rng(cfg.seed)
        net_cfg = registry.network_config(cfg, image_size)
        params = registry.init_params(cfg, net_cfg, rng)
        adam, start, before = optim.adam_init(params), 0, 0.0
        ema = dict(params) if cfg.ema else None
        files.open_write(log_path, "w").close()
    # The run's meta-training seconds, every sitting included (unknown if an older checkpoint did not say).
    t0 = time.perf_counter() - (before or 0.0)
    seconds = lambda: round(time.perf_counter() - t0, 2)
    recorded = lambda: None if before is None else seconds()
    if cfg.method == "random":                   # nothing to train by gradient: pick the std, save, done
        params, scores = random_std(cfg, train_set)
        _log_now(log_path, {"iteration": 0, "random_std_success_on_training_colours": scores})
        checkpoint.save(ckpt_path, params, optim.adam_init(params), cfg.iterations, rng, cfg, net_cfg,
                        world=world, seconds=recorded())
        return params

    # 3. Meta-training loop: sample tasks, adapt (eq. 1), score (eq. 2), meta-gradient, clip, Adam.
    max_torque = train_set["metadata"]["world"]["arm"]["max_torque"]
    demos = imitation.prepare_demos(train_set["images"], train_set["states"], train_set["actions"], max_torque)
    end = cfg.iterations if stop_after is None else min(cfg.iterations, start + stop_after)
    bar = tqdm(range(start, end), initial=start, total=cfg.iterations, desc="meta-training",
               disable=not progress)
    pool = shards.make_pool(cfg.shards if cfg.method == "mil" else 1)
    saved = start if resume else None            # the iteration of the checkpoint on disk, if any
    finished = (params, adam, ema, start, rng.bit_generator.state)   # the state after the last whole iteration
    try:
        with files.open_write(log_path) as log:
            for it in bar:
                adapt_demos, eval_demos = imitation.sample_meta_batch(demos, rng, cfg.meta_batch)
                loss, grads = registry.meta_gradient(cfg, params, adapt_demos, eval_demos, pool)
                bad = [k for k, g in grads.items() if not np.all(np.isfinite(g))]
                if not np.isfinite(loss) or bad:
                    raise diverged(f"the meta-loss became {float(loss)} at iteration {it + 1}"
                                   f"{' (non-finite gradient of ' + ', '.join(bad) + ')' if bad else ''}",
                                   ckpt_path, saved)
                params, adam = optim.adam_step(params, inner.clip_gradients(grads, cfg.clip), adam,
                                              learning_rate(cfg, it))
                if ema is not None:
                    ema = checkpoint.update_ema(ema, params, cfg.ema)
                done = it + 1
                if done % cfg.log_every == 0:
                    _log(log, {"iteration": done, "meta_loss": float(loss),
                               "seconds": seconds()})
                    bar.set_postfix(meta_loss=f"{float(loss):.3f}")
                if cfg.eval_every and done % cfg.eval_every == 0:
                    condition = registry.conditioner(cfg, params if ema is None else ema, seed=done)
                    try:
                        r = imitation.one_shot_success(condition, heldout_set, cfg.eval_trials, seed=done,
                                                       progress=False)
                    except imitation.PolicyDiverged:
                        raise diverged(f"the policy's torques became NaN or inf in the held-out check at "
                                       f"iteration {done}", ckpt_path, saved) from None
                    _log(log, {"iteration": done, "heldout_success": r["rate"], "trials": r["trials"]})
                    bar.set_postfix(meta_loss=f"{float(loss):.3f}", heldout=f"{r['rate']:.2f}")
                finished = (params, adam, ema, done, rng.bit_generator.state)   # iteration `done` is whole
                if done % cfg.checkpoint_every == 0 or done == end:
                    checkpoint.save(ckpt_path, params, adam, done, rng, cfg, net_cfg, ema, world, recorded())
                    saved = done
    except KeyboardInterrupt:
        bar.close()
        params, adam, ema, done, rng_state = finished
        if done != saved:                         # save where it stopped; resume goes on from there
            rng.bit_generator.state = rng_state
            checkpoint.save(ckpt_path, params, adam, done, rng, cfg, net_cfg, ema, world, recorded())
        raise Interrupted(f"interrupted at iteration {done}; checkpoint: {ckpt_path} "
                          f"(continue with --resume)") from None
    finally:
        if pool is not None:
            pool.close()
        bar.close()
    return params


def random_std(cfg, train_set):
    """The random baseline's training: one-shot success on (at most 36 of) the meta-training colours
    for each torque std of cfg.random_stds (cfg.eval_trials trials each); the best is kept, as the
    paper reports the best. Returns ({"std": (1,)}, {std: success rate})."""
    scores, colours = {}, subset(train_set, min(36, len(train_set["images"])))
    for std in cfg.random_stds:
        condition = registry.conditioner(cfg, {"std": np.array([std], np.float32)}, seed=cfg.seed)
        scores[std] = imitation.one_shot_success(condition, colours, cfg.eval_trials, seed=cfg.seed,
                                                 progress=False)["rate"]
    best = max(cfg.random_stds, key=lambda s: scores[s])
    return {"std": np.array([best], np.float32)}, scores


def _log(f, record):
    f.write(json.dumps(record) + "\n")
    f.flush()                                    # `tail -f log.jsonl` shows each line as it is written


def _log_now(path, record):
    with files.open_write(path) as f:
        _log(f, record)


def _truncate_log(path, iteration):
    """Drop log lines past the checkpoint's iteration (a killed run wrote some before dying)."""
    if not os.path.exists(path):
        return
    with files.open_read(path, "r") as f:
        keep = [line for line in f if line.strip() and json.loads(line)["iteration"] <= iteration]
    with files.atomic_write(path) as f:
        f.write("".join(keep).encode())
