"""Meta-training (paper Sections II and III): `python -m oneshot.train --help`.

    python -m oneshot.train --profile default --run runs/default      # fast profile, 2 CPU cores
    python -m oneshot.train --run runs/default --resume                # continue a stopped run exactly

A run folder holds `checkpoint.npz` (parameters, Adam state, iteration, random state, config; written
atomically every `checkpoint_every` iterations and at the end) and `log.jsonl` (one JSON object per
line: meta-loss every `log_every` iterations, held-out one-shot success every `eval_every`).
Missing datasets are collected first with `python -m oneshot.collect` settings from the profile.
"""
import argparse
import ctypes
import dataclasses
import json
import math
import os
import sys
import time
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from oneshot import collect, data, imitation, maml, network, optim, shards
from oneshot.evaluate import one_shot_success
from oneshot.expert import ExpertConfig


@dataclass(frozen=True)
class TrainConfig:
    """Everything a run depends on. The field defaults are MIL's meta-learning settings (3 inner steps
    of alpha = 0.001 on every parameter, the flattened network); PROFILES names the runs we use."""
    train_data: str = "data/train.npz"       # collected if missing: 36 colours x `train_demos`
    heldout_data: str = "data/heldout.npz"   # collected if missing: 12 colours x `heldout_demos`
    train_demos: int = 24                    # demos per meta-training colour when collecting
    heldout_demos: int = 10                  # demos per held-out colour when collecting
    demo_noise: float = 0.1                  # DART torque noise (N m) when collecting (docs/imitation.md)
    iterations: int = 2000                   # meta-iterations (one Adam step each)
    meta_batch: int = 5                      # tasks per meta-iteration (MIL: 5)
    inner_steps: int = 3                     # gradient steps of eq. (1) (MIL reaching: 3)
    alpha: float = 0.001                     # inner step size (MIL reaching: 0.001)
    lr: float = 1e-3                         # Adam step size (Adam's default)
    lr_schedule: str = "constant"            # "constant" (MIL) or "cosine": lr -> 0 over `iterations`
    clip: float = 10.0                       # meta-gradient clipped to [-clip, clip] (MIL: 10)
    first_order: bool = False                # first-order MAML approximation, for comparison
    bias_transform: int = 0                  # size of the bias-transformation vector (0: off)
    feature_points: bool = False             # spatial soft-argmax instead of flattening (an option)
    inner_params: str = "all"                # which parameters eq. (1) adapts: "all" (MIL), "conv" (the
                                             # convolutions) or "conv0" (the first convolution only)
    ema: float = 0.0                         # decay of a moving average of the parameters (Polyak
                                             # averaging; 0: off), which evaluation then uses
    learn_alpha: bool = False                # Meta-SGD: meta-learn one step size per adapted element,
                                             # starting at `alpha` (stored as maml.STEP_PREFIX params)
    seed: int = 0                            # parameters and meta-batch sampling
    log_every: int = 10
    eval_every: int = 500                    # held-out one-shot success during training
    eval_trials: int = 5                     # trials per held-out colour in those evaluations (60 in all)
    checkpoint_every: int = 100
    shards: int = 2                          # processes sharing each meta-gradient, each on its block of
                                             # every demo's frames (`oneshot.shards`; results depend on it)


# MIL's meta-learning settings (TrainConfig's defaults), 2000 iterations.
_MIL = TrainConfig()

PROFILES = {
    # The fast profile, and the one that works here (docs/training.md, "Adapting only the
    # convolutions"): feature points and a bias transformation (MIL's released code), and ONE inner
    # step of alpha = 0.3 on the FIRST convolution layer only, so that adaptation can change WHAT the
    # policy looks for (a colour) but not WHERE it goes (the demo's positions); adapting one layer
    # makes an iteration 1.2-1.3x faster than adapting all three. 10000 iterations: 14.9 min alone on 2
    # cores (up to 21 min on slow hours of the shared host); over ten training runs 90.9% held out (docs/training.md).
    # The policy acts with a moving average of the parameters (decay 0.999): 2-3 points held-out on
    # average over three training seeds, and a lower loss after adapting in each. Adam's step size is
    # 3e-3, three times Adam's (and MIL's) default: held-out success over three seeds rose from 85.0%
    # (1e-3) to 89.8% (2e-3) and 91.3% (3e-3), and the weak seeds caught up (docs/training.md).
    "default": dataclasses.replace(_MIL, bias_transform=10, feature_points=True, inner_params="conv0",
                                   inner_steps=1, alpha=0.3, iterations=10000, eval_every=1000, ema=0.999,
                                   lr=3e-3),
    "mil": _MIL,                                                     # the paper's inner loop, 2000 it.
    "bias": dataclasses.replace(_MIL, bias_transform=10),
    "points": dataclasses.replace(_MIL, bias_transform=10, feature_points=True),
    "paper": dataclasses.replace(_MIL, iterations=30000, eval_every=1000),
    "tiny": TrainConfig(train_data="data/tiny_train.npz", heldout_data="data/tiny_heldout.npz",
                        train_demos=3, heldout_demos=2, iterations=20, meta_batch=2, log_every=1, eval_every=0,
                        checkpoint_every=5, shards=1),
}


# TrainConfig.inner_params -> `maml.inner_update`'s `only`: which parameters eq. (1) adapts.
INNER_PARAMS = {"all": None, "conv": ("conv",), "conv0": ("conv0_",)}


def inner_only(cfg):
    """cfg.inner_params as `maml.inner_update`'s `only`: None (every parameter) or key prefixes."""
    if cfg.inner_params not in INNER_PARAMS:
        raise ValueError(f"inner_params must be one of {sorted(INNER_PARAMS)}; got {cfg.inner_params!r}")
    return INNER_PARAMS[cfg.inner_params]


def learning_rate(cfg, iteration):
    """Adam's step size for meta-iteration `iteration` (0-based): cfg.lr, or with cfg.lr_schedule =
    "cosine" cfg.lr * (1 + cos(pi * iteration / cfg.iterations)) / 2, which ends near zero. (With
    "cosine", changing --iterations on --resume reshapes the rest of the schedule.)"""
    if cfg.lr_schedule == "constant":
        return cfg.lr
    if cfg.lr_schedule == "cosine":
        return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * min(iteration, cfg.iterations) / cfg.iterations))
    raise ValueError(f"lr_schedule must be 'constant' or 'cosine'; got {cfg.lr_schedule!r}")


def initial_params(cfg, net_cfg, rng):
    """The network's initial parameters, plus learnt inner step sizes (all `alpha`) if cfg.learn_alpha."""
    params = network.init_params(net_cfg, rng)
    if cfg.learn_alpha:
        params.update(maml.init_step_sizes(params, cfg.alpha, inner_only(cfg)))
    return params


class TrainingDiverged(RuntimeError):
    """The meta-loss or meta-gradient became NaN or inf."""


# --- checkpoints -----------------------------------------------------------------------------------

def save_checkpoint(path, params, adam_state, iteration, rng, cfg, net_cfg, ema=None):
    """Write a checkpoint atomically (temporary file + rename): never half a file on disk.
    ema: the moving average of the parameters (cfg.ema > 0), or None."""
    arrays = {f"params/{k}": v for k, v in params.items()}
    arrays.update({f"ema/{k}": v for k, v in (ema or {}).items()})
    arrays.update(optim.state_to_arrays(adam_state))
    meta = {"iteration": iteration, "rng": rng.bit_generator.state, "config": dataclasses.asdict(cfg),
            "network": dataclasses.asdict(net_cfg), "format_version": 1}
    with data.atomic_write(path) as f:
        np.savez(f, meta=np.array(json.dumps(meta)), **arrays)


def load_checkpoint(path):
    """Read a checkpoint. Returns {"params", "ema", "adam", "iteration", "rng", "config", "network"};
    "ema" is the moving average of the parameters, or None if the run kept none (cfg.ema = 0).
    `policy_params(ckpt)` picks the parameters to act with."""
    if not os.path.exists(path):
        raise FileNotFoundError(f"no checkpoint at {path!r}; train one with `python -m oneshot.train`")
    try:
        with np.load(path, allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}
        meta = json.loads(str(arrays.pop("meta")))
    except Exception as e:                   # zip, JSON or key errors: all mean a damaged file
        raise ValueError(f"{path!r} is not a readable oneshot checkpoint ({e}); "
                         f"re-train or restore it") from e
    params = {k[len("params/"):]: v for k, v in arrays.items() if k.startswith("params/")}
    ema = {k[len("ema/"):]: v for k, v in arrays.items() if k.startswith("ema/")} or None
    for name, v in arrays.items():
        if name.startswith(("params/", "ema/")) and not np.all(np.isfinite(v)):
            raise ValueError(f"{path!r}: {name!r} contains NaN or inf; use an earlier checkpoint")
    rng = np.random.default_rng()
    rng.bit_generator.state = meta["rng"]
    cfg = meta["config"]
    return {"params": params, "ema": ema, "adam": optim.state_from_arrays(arrays),
            "iteration": meta["iteration"],
            "rng": rng, "config": TrainConfig(**cfg), "network": network.NetworkConfig(**{
                k: tuple(v) if isinstance(v, list) else v for k, v in meta["network"].items()})}


def policy_params(ckpt, raw=False):
    """The parameters a checkpoint's policy acts with: the moving average if the run kept one
    (cfg.ema > 0) and raw is False, else the parameters Adam trained."""
    return ckpt["params"] if raw or ckpt["ema"] is None else ckpt["ema"]


def update_ema(ema, params, decay):
    """Polyak averaging: ema <- decay * ema + (1 - decay) * params, key by key (float32 stays float32)."""
    d = float(decay)
    return {k: d * ema[k] + (1.0 - d) * params[k] for k in params}


# --- data ------------------------------------------------------------------------------------------

def ensure_datasets(cfg, progress=True):
    """Load the meta-training and held-out datasets, collecting any that is missing."""
    out = []
    for path, split, tasks, demos, seed in ((cfg.train_data, "train", 36, cfg.train_demos, 0),
                                            (cfg.heldout_data, "heldout", 12, cfg.heldout_demos, 1)):
        if not os.path.exists(path):
            print(f"{path} is missing: collecting it (python -m oneshot.collect --out {path} --split "
                  f"{split} --tasks {tasks} --demos {demos} --seed {seed} --noise {cfg.demo_noise})",
                  file=sys.stderr)
            data.save(collect.collect(tasks, demos, split, seed, progress=progress,
                                      expert_cfg=ExpertConfig(action_noise=cfg.demo_noise)), path)
        out.append(data.load(path))
    return out


def _tune_malloc():
    """Keep freed memory in the process instead of returning it to the OS after every array.

    The network allocates and frees multi-megabyte arrays thousands of times per meta-iteration;
    glibc hands each back to the OS and page-faults it in again (~1000 faults per forward pass).
    Raising the mmap and trim thresholds stops that (measured: `python -m oneshot.benchmark maml`).
    A no-op where glibc is not the C library.
    """
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-1, 1 << 30)        # M_TRIM_THRESHOLD
        libc.mallopt(-3, 1 << 30)        # M_MMAP_THRESHOLD
    except (OSError, AttributeError):
        pass


# --- training --------------------------------------------------------------------------------------

def train(cfg, run_dir, resume=False, progress=True, stop_after=None):
    """Meta-train a policy with MAML (Section II) on behavioural cloning (Section III).

    run_dir: folder for checkpoint.npz and log.jsonl. resume: continue from its checkpoint (the
    rest of the run is then identical to an uninterrupted one). stop_after: leave after this many
    iterations of this call (to test resuming). Returns the final parameters.
    """
    ckpt_path, log_path = os.path.join(run_dir, "checkpoint.npz"), os.path.join(run_dir, "log.jsonl")
    inner_only(cfg), learning_rate(cfg, 0)    # unknown inner_params / lr_schedule fail here, not later
    if not 0.0 <= cfg.ema < 1.0:
        raise ValueError(f"ema is the moving average's decay, in [0, 1) (0: off; e.g. 0.999); got {cfg.ema!r}")
    # 1. Data: both splits, in network units (images in [0, 1], states and torques of order one).
    train_set, heldout_set = ensure_datasets(cfg, progress)
    max_torque = train_set["metadata"]["world"]["arm"]["max_torque"]
    demos = imitation.prepare_demos(train_set["images"], train_set["states"], train_set["actions"], max_torque)
    image_size = train_set["images"].shape[-2]

    # 2. Parameters, optimiser and random state: fresh, or exactly as the checkpoint left them.
    if resume:
        ckpt = load_checkpoint(ckpt_path)
        schedule = dict(iterations=cfg.iterations, log_every=cfg.log_every, eval_every=cfg.eval_every,
                        eval_trials=cfg.eval_trials, checkpoint_every=cfg.checkpoint_every)
        stored = dataclasses.replace(ckpt["config"], **schedule)
        if stored != cfg:
            differ = ", ".join(f"{f.name}: checkpoint {getattr(stored, f.name)!r}, now {getattr(cfg, f.name)!r}"
                               for f in dataclasses.fields(cfg) if getattr(stored, f.name) != getattr(cfg, f.name))
            raise ValueError(f"{ckpt_path!r} was trained with a different config ({differ}); resume with the "
                             f"same profile and options (only iterations and the log/eval/checkpoint cadence "
                             f"may change), or start a new run folder")
        params, adam, start, rng, net_cfg = (ckpt["params"], ckpt["adam"], ckpt["iteration"],
                                             ckpt["rng"], ckpt["network"])
        ema = ckpt["ema"]
        _truncate_log(log_path, start)
    else:
        if os.path.exists(ckpt_path):
            raise FileExistsError(f"{run_dir!r} already holds a run; use --resume, or another --run folder")
        rng = np.random.default_rng(cfg.seed)
        net_cfg = network.NetworkConfig(image_size=image_size, bias_transform=cfg.bias_transform,
                                        feature_points=cfg.feature_points)
        params = initial_params(cfg, net_cfg, rng)
        adam, start = optim.adam_init(params), 0
        ema = dict(params) if cfg.ema else None
        os.makedirs(run_dir, exist_ok=True)
        open(log_path, "w").close()
    last_good = start

    # 3. Meta-training loop: sample tasks, adapt (eq. 1), score (eq. 2), meta-gradient, clip, Adam.
    end = cfg.iterations if stop_after is None else min(cfg.iterations, start + stop_after)
    bar = tqdm(range(start, end), initial=start, total=cfg.iterations, desc="meta-training",
               disable=not progress)
    t0 = time.perf_counter()
    pool = shards.make_pool(cfg)
    try:
        with open(log_path, "a") as log:
            for it in bar:
                adapt_demos, eval_demos = imitation.sample_meta_batch(demos, rng, cfg.meta_batch)
                loss, grads = shards.meta_gradient(params, adapt_demos, eval_demos, cfg, pool)
                bad = [k for k, g in grads.items() if not np.all(np.isfinite(g))]
                if not np.isfinite(loss) or bad:
                    raise TrainingDiverged(
                        f"the meta-loss became {float(loss)} at iteration {it + 1}"
                        f"{' (non-finite gradient of ' + ', '.join(bad) + ')' if bad else ''}; the last good "
                        f"checkpoint ({ckpt_path}, iteration {last_good}) is kept. Lower --lr or --alpha "
                        f"and start a new run from scratch, or --resume to retry from it.")
                params, adam = optim.adam_step(params, maml.clip_gradients(grads, cfg.clip), adam,
                                              learning_rate(cfg, it))
                if ema is not None:
                    ema = update_ema(ema, params, cfg.ema)
                done = it + 1
                if done % cfg.log_every == 0:
                    _log(log, {"iteration": done, "meta_loss": float(loss),
                               "seconds": round(time.perf_counter() - t0, 2)})
                    bar.set_postfix(meta_loss=f"{float(loss):.3f}")
                if cfg.eval_every and done % cfg.eval_every == 0:
                    r = one_shot_success(params if ema is None else ema, heldout_set, cfg.eval_trials,
                                         cfg.alpha, cfg.inner_steps, only=inner_only(cfg), seed=done,
                                         progress=False)
                    _log(log, {"iteration": done, "heldout_success": r["rate"], "trials": r["trials"]})
                    bar.set_postfix(meta_loss=f"{float(loss):.3f}", heldout=f"{r['rate']:.2f}")
                if done % cfg.checkpoint_every == 0 or done == end:
                    log.flush()
                    save_checkpoint(ckpt_path, params, adam, done, rng, cfg, net_cfg, ema)
                    last_good = done
    finally:
        if pool is not None:
            pool.close()
        bar.close()
    return params


def _log(f, record):
    f.write(json.dumps(record) + "\n")


def _truncate_log(path, iteration):
    """Drop log lines past the checkpoint's iteration (a killed run wrote some before dying)."""
    if not os.path.exists(path):
        return
    with open(path) as f:
        keep = [line for line in f if line.strip() and json.loads(line)["iteration"] <= iteration]
    with open(path + ".tmp", "w") as f:
        f.writelines(keep)
    os.replace(path + ".tmp", path)


# --- benchmark ---------------------------------------------------------------------------------------

def synthetic_demos(rng, tasks, T, image_size):
    """Random demos shaped like one side of a meta-batch, for timing: images (tasks, T, H, W, 3) in
    [0, 1), states (tasks, T, 6), torques (tasks, T, 2), all float32."""
    return (rng.random((tasks, T, image_size, image_size, 3), dtype=np.float32),
            rng.standard_normal((tasks, T, 6), dtype=np.float32),
            rng.standard_normal((tasks, T, 2), dtype=np.float32))


def meta_gradient_flops(cfg, net_cfg, T, tasks):
    """Estimated floating-point operations of the meta-gradient over `tasks` tasks of T frames.

    3 (3 s + 1) forward passes per task for s inner steps: each inner step records a forward and a
    backward pass (~3 forward passes), the outer loss one more, and the meta-gradient's backward pass
    costs about twice the recorded forward graph. First order: the inner steps are not recorded, so
    3 s + 3 (inner forward+backward, outer forward+backward). Matrix products only (`count_flops`).
    """
    passes = 3 * cfg.inner_steps + 3 if cfg.first_order else 3 * (3 * cfg.inner_steps + 1)
    return tasks * passes * network.count_flops(net_cfg, T)


def bench_setup(profile, image_size, **overrides):
    """(cfg, net_cfg, params, rng) for timing a profile (with overridden fields) on synthetic data."""
    cfg = dataclasses.replace(PROFILES[profile], **overrides)
    rng = np.random.default_rng(0)
    net_cfg = network.NetworkConfig(image_size=image_size, bias_transform=cfg.bias_transform,
                                    feature_points=cfg.feature_points)
    return cfg, net_cfg, initial_params(cfg, net_cfg, rng), rng


def bench_meta_iteration(iterations=20, profile="default", T=20, image_size=32, **overrides):
    """Median seconds per second-order meta-iteration on synthetic data, and GFLOP/s
    (`meta_gradient_flops`)."""
    _tune_malloc()
    cfg, net_cfg, params, rng = bench_setup(profile, image_size, **overrides)
    B = cfg.meta_batch
    times, pool = [], shards.make_pool(cfg)
    try:
        for _ in range(iterations + 2):
            a, e = synthetic_demos(rng, B, T, image_size), synthetic_demos(rng, B, T, image_size)
            t = time.perf_counter()
            shards.meta_gradient(params, a, e, cfg, pool)
            times.append(time.perf_counter() - t)
    finally:
        if pool is not None:
            pool.close()
    s = float(np.median(times[2:]))
    flops = meta_gradient_flops(cfg, net_cfg, T, B)
    return {"profile": profile, "meta_batch": B, "inner_steps": cfg.inner_steps, "inner_params": cfg.inner_params,
            "T": T, "image_size": image_size, "first_order": cfg.first_order, "shards": cfg.shards,
            "seconds_per_iteration": round(s, 4),
            "gflop_per_iteration": round(flops / 1e9, 2), "gflop_per_second": round(flops / 1e9 / s, 1)}


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m oneshot.train", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--profile", choices=sorted(PROFILES), default="default",
                   help="named configuration (default: the fast profile; 'paper': MIL's iteration count)")
    p.add_argument("--run", default=None, help="run folder (default: runs/<profile>)")
    p.add_argument("--resume", action="store_true", help="continue the run in --run from its checkpoint")
    for field in dataclasses.fields(TrainConfig):
        kind = {bool: lambda s: s.lower() in ("1", "true", "yes")}.get(field.type, field.type)
        p.add_argument("--" + field.name.replace("_", "-"), type=kind, default=None,
                       help=f"override the profile's {field.name}")
    args = p.parse_args(argv)
    overrides = {f.name: getattr(args, f.name) for f in dataclasses.fields(TrainConfig)
                 if getattr(args, f.name) is not None}
    cfg = dataclasses.replace(PROFILES[args.profile], **overrides)
    run = args.run or os.path.join("runs", args.profile)
    _tune_malloc()
    t0 = time.perf_counter()
    try:
        train(cfg, run, resume=args.resume)
    except (TrainingDiverged, FileExistsError, ValueError, FileNotFoundError, shards.ShardError) as e:
        sys.exit(f"error: {e}")
    print(f"trained {cfg.iterations} meta-iterations in {time.perf_counter() - t0:.0f} s; "
          f"checkpoint: {os.path.join(run, 'checkpoint.npz')}")


if __name__ == "__main__":
    main()
