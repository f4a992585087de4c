"""Meta-training (paper Sections II and III): `python -m oneshot.train --help`.

    python -m oneshot.train --profile default --run runs/default      # the shipped policy's profile, 2 cores
    python -m oneshot.train --run runs/default --resume                # continue a stopped run exactly

A run folder holds checkpoint.npz (parameters, Adam state, iteration, random state, config) and log.jsonl
(the meta-loss and validation checks as they come). `--resume` continues the run with the config its
checkpoint records (only how long, how often and the step size may change), exactly as if it had not
stopped. Ctrl-C or a plain kill saves a checkpoint of the last finished iteration first (exit 130).
Missing datasets are collected first with the profile's settings. The command around
`oneshot.training.run_folder.train` (the run folder), which wraps `oneshot.training.loop` (the loop).
"""
import argparse
import dataclasses
import json
import os
import signal
import time

import numpy as np

from oneshot import methods
from oneshot.maml import inner, shards
from oneshot.methods.mil import INNER_PARAMS
from oneshot.policy import network
from oneshot.policy.network import INITS
from oneshot.tools import cli, host
from oneshot.training import checkpoint, run_data
from oneshot.training.config import PROFILES, TrainConfig
from oneshot.training.run_folder import RESUMABLE, RUN_FILES, RunLocked, TrainingDiverged, nothing_to_train, train
from oneshot.world import palette
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import WorldConfig


def main(argv=None):
    p = cli.Parser(prog="python -m oneshot.train", description=__doc__,
                   formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--profile", choices=sorted(PROFILES), default=None,
                   help="named configuration (default: 'default', the shipped policy's; with --resume: the "
                        "checkpoint's own config)")
    p.add_argument("--run", default=None, help="run folder (default: runs/<profile>)")
    p.add_argument("--resume", action="store_true", help="continue the run in --run from its checkpoint")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (e.g. when the output goes to a log file)")
    # Each field's type says what it accepts (argparse names the flag when a value is refused); the
    # ints not listed here are counts where 0 is meaningful (eval_every, bias_transform, tasks, demos:
    # 0 is off or all; inner_steps: 0 is no adaptation; seed).
    kinds = {int: cli.non_negative_int, float: cli.finite_non_negative_float, bool: cli.boolean,
             tuple: cli.finite_non_negative_floats, str: str}
    kinds_of = {name: cli.positive_int for name in ("iterations", "meta_batch", "log_every", "eval_trials",
                                                    "checkpoint_every", "shards", "lstm_units")}
    kinds_of.update(never_adapt=_prefixes, channels=cli.positive_ints, hidden=cli.positive_ints)
    kinds_of.update(train_demos=cli.at_least(2, " (MAML adapts on one demo and scores another)"),
                    validation_demos=cli.at_least(2, " (one to adapt on, another to evaluate)"))
    choices = {"lr_schedule": ("constant", "cosine"), "inner_params": sorted(INNER_PARAMS), "method": list(methods.REGISTRY),
               "palette": palette.MODES, "init": INITS}
    for field in dataclasses.fields(TrainConfig):
        text = f"override the profile's {field.name}" + (" (true/false)" if field.type is bool else "")
        kind = kinds_of.get(field.name, kinds.get(field.type, field.type))
        p.add_argument("--" + field.name.replace("_", "-"), type=kind, choices=choices.get(field.name), default=None,
                       help=text)
    args = p.parse_args(argv)
    overrides = {f.name: getattr(args, f.name) for f in dataclasses.fields(TrainConfig)
                 if getattr(args, f.name) is not None}
    profile = args.profile or "default"
    run = args.run or os.path.join("runs", profile)
    try:                                       # before any work: a run folder that can be made
        cli.writable_folder(run)
    except argparse.ArgumentTypeError as e:
        p.error(f"argument --run: {e}")
    ckpt_path = os.path.join(run, "checkpoint.npz")
    saved = checkpoint.load(ckpt_path) if args.resume else None
    stored, start = (saved["config"], saved["iteration"]) if saved else (None, 0)
    if args.resume and args.profile is None:   # the run's own config; flags may change only RESUMABLE fields
        cfg = dataclasses.replace(stored, **overrides)
    elif args.resume:                          # the profile named, as the checkpoint has what may change
        cfg = dataclasses.replace(PROFILES[profile], **overrides)
        cfg = dataclasses.replace(cfg, **{k: getattr(stored, k) for k in RESUMABLE if k not in overrides})
    else:
        cfg = dataclasses.replace(PROFILES[profile], **overrides)
    try:
        method = methods.of(cfg)
    except ValueError as e:                    # its inner loop's fields, as the flags that set them
        p.error(f"{e} (the flags: --alpha >= 0, --inner-steps >= 0, --inner-clip >= 0, --inner-loss-scale > 0)")
    try:
        method.refuse_ignored(overrides)         # a flag the method never reads: recorded, and nothing done
    except ValueError as e:
        p.error(str(e))
    # Before any work: what must fit in memory (the datasets to collect, a meta-batch's images) and
    # how many processes share the frames. Frames and image size: the training set's, if it exists.
    world = WorldConfig(palette=PaletteConfig(mode=cfg.palette))
    frames, size = world.horizon, world.image_size
    if os.path.isfile(cfg.train_data):           # a regular file: np.load would wait on a FIFO
        try:
            with np.load(cfg.train_data, allow_pickle=False) as f:
                recorded = json.loads(str(f["metadata"]))["world"]
            frames, size = int(recorded["horizon"]), int(recorded["image_size"])
        except Exception:                        # a damaged file: train() says what is wrong with it
            pass
    data = {split: run_data.spec(cfg, split)[0] for split in ("train", "validation")}
    if os.path.realpath(data["train"]) == os.path.realpath(data["validation"]):
        p.error(f"the validation data {data['validation']} is also the meta-training data; the validation colours "
                f"need a file of their own (--validation-data)")
    test = run_data.spec(cfg, "test")[0]                  # recorded for `evaluate --split test`, not read here
    for split, path in data.items():
        if test and os.path.realpath(test) == os.path.realpath(path):
            p.error(f"the test data {test} is also the {split} data; the test colours need a file of their own "
                    f"(--test-data)")
    for split, path in data.items():         # the run writes these: a dataset there would be overwritten
        if os.path.realpath(path) in {os.path.realpath(os.path.join(run, name)) for name in RUN_FILES}:
            p.error(f"the {split} data {path} is one of the run's own files in {run}; keep datasets outside "
                    f"them (--{split}-data, or another --run)")
    try:
        for split in ("train", "validation"):
            path, demos, _ = run_data.spec(cfg, split)
            flag = f"--{split}-demos"
            if not os.path.exists(path):
                try:                           # a dataset to collect: where it goes must take it
                    cli.writable_file(path)
                except argparse.ArgumentTypeError as e:
                    p.error(f"argument --{split}-data: {e}")
                tasks = run_data.tasks(cfg, split)
                cli.check_memory(cli.dataset_bytes(tasks, demos, world.horizon, world.image_size, world.n_objects),
                                 f"collecting the missing {path} ({tasks} tasks x {demos} demos)",
                                 f"use a smaller {flag}")
        net_cfg = method.network_config(size)
        method.check(net_cfg)
        typos = inner.unmatched(network.param_shapes(net_cfg), overrides.get("never_adapt", ()))
        if typos and method.adapts:            # a prefix naming no parameter would adapt everything
            p.error(f"argument --never-adapt: {', '.join(map(repr, typos))} starts no parameter's name; the "
                    f"parameters are {', '.join(network.param_shapes(net_cfg))} (--never-adapt '' for none)")
        cli.check_memory(method.memory_bytes(net_cfg),
                         f"the {cfg.method} policy's {method.parameter_count(net_cfg):,} parameters (with their "
                         f"gradient, Adam's moments and the moving average)",
                         f"use smaller {', '.join(method.width_flags[:-1])} or {method.width_flags[-1]}")
        holds, less = method.meta_batch_words(net_cfg)
        if method.learns:                      # the random policy draws no meta-batch (it is fitted: `fit`)
            cli.check_memory(method.memory_bytes(net_cfg) + cfg.meta_batch * method.task_bytes(net_cfg, frames),
                             f"a meta-batch of {cfg.meta_batch} tasks ({holds}; {frames} frames a demo), beside the "
                             f"parameters", f"use a smaller --meta-batch (the profile's: "
                             f"{PROFILES[profile].meta_batch}){less}, or a smaller network")
    except ValueError as e:
        p.error(str(e))
    if method.shards > frames:
        p.error(f"argument --shards: the processes share each demo's {frames} frames, so 1 to {frames}; "
                f"got {cfg.shards}")
    if saved and method.learns and start == cfg.iterations:     # a finished run resumed: say so, and do nothing
        print(nothing_to_train(ckpt_path, start, cfg.iterations, stored.iterations))    # (not "trained 0")
        return None
    banner = []                                # printed once the run folder is ours (not if another run has it)
    if start < cfg.iterations or not method.learns:     # (else train() says there is nothing to train)
        work = (f"fitting the {cfg.method} policy" if not method.learns else
                f"training {_iterations(cfg.iterations - start)}" + (f" (from {start})" if start else ""))
        settings = "the run's own settings" if args.resume and args.profile is None else f"profile {profile}"
        banner.append(f"{work}: {settings}, seed {cfg.seed}, into {ckpt_path}"
                      + (" (Ctrl-C saves it; --resume continues)" if method.learns else ""))
        banner += [method.describe()] if method.describe() else []
    host.tune_malloc()
    # One BLAS thread, in this process as in every shard (`oneshot.tools.host`): the products are small, so
    # a second thread gains at most a few percent on idle cores (default profile on one process: 0.0454 s
    # against 0.0437-0.0476 s), while with other work on the machine its spinning made the smoke profile's
    # iterations 65x slower (4.6 s against 0.07 s).
    host.blas_threads(1)
    t0 = time.perf_counter()
    previous = signal.signal(signal.SIGTERM, _terminate)    # a plain kill stops training as Ctrl-C does
    try:
        train(cfg, run, resume=args.resume, progress=not args.no_progress,
              on_start=lambda: print(*banner, sep="\n") if banner else None)
    finally:
        signal.signal(signal.SIGTERM, previous)
    done = (f"fitted the {cfg.method} policy" if not method.learns else
            f"trained {_iterations(cfg.iterations - start)}" + (f" (from {start} to {cfg.iterations})" if start else ""))
    print(f"{done} in {time.perf_counter() - t0:.0f} s; checkpoint: {ckpt_path}")


def _iterations(n):
    """"1 meta-iteration", "20 meta-iterations"."""
    return f"{n} meta-iteration{'s' * (n != 1)}"


def _prefixes(text):
    """An argparse type: comma-separated parameter-name prefixes ("ln,fp_" -> ("ln", "fp_")); "" for none."""
    return tuple(p.strip() for p in text.split(",") if p.strip())


def _terminate(signum, frame):
    raise KeyboardInterrupt


if __name__ == "__main__":
    cli.run(main, failures=(TrainingDiverged, RunLocked, shards.ShardError))
