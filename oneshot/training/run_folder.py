"""A run folder around the meta-training loop (`training.loop`): `train(cfg, run_dir, resume)`.

A run folder holds `checkpoint.npz` (parameters, Adam state, iteration, random state, configs; written
atomically every `checkpoint_every` iterations and at the end) and `log.jsonl` (one JSON object per
line: meta-loss every `log_every` iterations, one-shot success on the validation colours every `eval_every`). One
process trains in a folder at a time (`lock_run`); Ctrl-C or a plain kill saves a checkpoint of the last
finished iteration before it exits, and `resume=True` continues from it exactly as if nothing had stopped.
Missing datasets are collected first with the profile's settings (`training.run_data`).
"""
import contextlib
import dataclasses
import fcntl
import glob
import json
import os
import shutil
import signal
import threading
import time

from tqdm import tqdm

from oneshot import methods
from oneshot.maml import imitation, optim
from oneshot.tools import files
from oneshot.training import checkpoint, fit_check, loop, run_data
from oneshot.training.loop import TrainingDiverged

# Fields of TrainConfig a resume may change: how long, how often to log, evaluate and save, and the
# step size (to retry a diverged run from its last good checkpoint with a smaller one). Anything else
# would make the resumed run a different experiment.
RUN_FILES = ("checkpoint.npz", "log.jsonl", ".lock")   # what a run folder holds (`train`)
RESUMABLE = ("iterations", "log_every", "eval_every", "eval_trials", "checkpoint_every", "lr")


class RunLocked(RuntimeError):
    """Another process is training in the same run folder."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM) stopped training; its message says where the checkpoint is."""


def diverged(what, ckpt_path, saved):
    """TrainingDiverged saying `what` happened and what to do: retry from the last good checkpoint
    (iteration `saved`) with a smaller step, or, if none was saved (`saved` is None), start again."""
    if saved is not None:
        return TrainingDiverged(f"{what}; the last good checkpoint ({ckpt_path}, iteration {saved}) is kept: "
                                f"--resume with a smaller --lr to retry from it, or start a new run with a "
                                f"smaller --lr or --alpha.")
    return TrainingDiverged(f"{what}; no checkpoint was saved before it. Start a new run with a smaller --lr "
                            f"or --alpha (or a smaller --checkpoint-every, to keep one).")


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


def train(cfg, run_dir, resume=False, progress=True, stop_after=None, on_start=None):
    """Meta-train a policy (Sections II-III) in a run folder: MAML on behavioural cloning, or a baseline
    of Section IV with the same data, loss, optimiser and checkpoints (cfg.method, `oneshot.methods`).

    run_dir: folder for checkpoint.npz and log.jsonl (locked while training: `lock_run`). resume:
    continue from its checkpoint (the rest of the run is then identical to an uninterrupted one).
    stop_after: leave after this many iterations of this call (to test resuming). on_start: called once
    the run folder is locked, before any data is read (a command's banner: none when another process
    has the folder). Ctrl-C saves a checkpoint of the last finished iteration and raises `Interrupted`.
    Returns the final parameters.
    """
    method = methods.of(cfg)                     # bad names fail here, not later
    loop.learning_rate(cfg, 0)
    if not 0.0 <= cfg.ema < 1.0:
        raise ValueError(f"ema is the moving average's decay, in [0, 1) (0: off; e.g. 0.999); got {cfg.ema!r}")
    with lock_run(run_dir):
        if on_start:
            on_start()
        return _train(method, cfg, run_dir, resume, progress, stop_after)


def _train(method, cfg, run_dir, resume, progress, stop_after):
    ckpt_path, log_path = os.path.join(run_dir, "checkpoint.npz"), os.path.join(run_dir, "log.jsonl")
    ckpt = _resumable(cfg, ckpt_path) if resume else None    # before any data is collected for it
    if not resume and os.path.exists(ckpt_path):
        raise FileExistsError(f"{run_dir!r} already holds a run; use --resume, or another --run folder (or move "
                              f"its checkpoint.npz aside to start afresh)")
    # 1. Data: both splits, in network units (images in [0, 1], states and torques of order one).
    train_set, validation_set = run_data.ensure(cfg, progress=progress)
    train_set = run_data.subset(train_set, cfg.tasks, cfg.demos)
    world = train_set["metadata"]["world"]       # what the checkpoint records, to be checked against data

    # 2. Parameters, optimiser and random state: fresh, or exactly as the checkpoint left them.
    if resume:
        state, net_cfg, before = _resume(ckpt, cfg, ckpt_path, log_path, train_set, validation_set)
    else:
        fit_check.check_same_world(train_set["metadata"], validation_set["metadata"], cfg.train_data,
                                   cfg.validation_data)   # its checks (and the random policy's fit) act in it
        net_cfg = method.network_config(train_set["images"].shape[-2])
        state, before = loop.start(method, net_cfg, cfg.seed, ema=cfg.ema > 0 and method.learns), 0.0
        files.open_write(log_path, "w").close()
    # The run's meta-training seconds, every sitting included (unknown if an older checkpoint did not say).
    t0 = time.perf_counter() - (before or 0.0)
    seconds = lambda: round(time.perf_counter() - t0, 2)
    recorded = lambda: None if before is None else seconds()
    save = lambda s: checkpoint.save(ckpt_path, s.params, s.adam, s.iteration, s.generator(), cfg, net_cfg,
                                     s.ema, world, recorded())
    if not method.learns:                        # nothing to train by gradient: choose on validation, save
        params, scores = method.fit(state.params, validation_set, cfg.eval_trials, cfg.seed)
        _log_now(log_path, {"iteration": 0, "fit_on_validation_colours": scores})
        save(loop.State(params, optim.adam_init(params), None, cfg.iterations, state.rng))
        return params

    # 3. Meta-training: the loop, its state checkpointed and its records logged as it goes.
    max_torque = world["arm"]["max_torque"]
    demos = imitation.prepare_demos(train_set["images"], train_set["states"], train_set["actions"], max_torque)
    end = cfg.iterations if stop_after is None else min(cfg.iterations, state.iteration + stop_after)
    pool = method.make_pool()
    saved = state.iteration if resume else None   # the iteration of the checkpoint on disk, if any
    finished = state                              # the state after the last whole iteration
    bar = tqdm(total=cfg.iterations, initial=state.iteration, desc="meta-training", disable=not progress)
    shown = {}
    try:
        with files.open_write(log_path) as log:
            for finished, records in loop.steps(method, cfg, state, demos, end, validation_set, pool):
                for record in records:
                    _log(log, dict(record, seconds=seconds()) if "meta_loss" in record else record)
                shown.update({k: f"{v:.3f}" for r in records for k, v in r.items()     # the latest of each,
                              if k in ("meta_loss", "validation_success")})                # kept between logs
                bar.set_postfix(shown, refresh=False)
                bar.update()
                if finished.iteration % cfg.checkpoint_every == 0 or finished.iteration == end:
                    save(finished)
                    saved = finished.iteration
    except TrainingDiverged as e:
        raise diverged(str(e), ckpt_path, saved) from None
    except KeyboardInterrupt:
        bar.close()
        if finished.iteration != saved:           # save where it stopped; resume goes on from there
            with _signals_ignored():              # a second Ctrl-C must not lose it
                save(finished)
        raise Interrupted(f"interrupted at iteration {finished.iteration}; checkpoint: {ckpt_path} "
                          f"(continue with --resume)") from None
    finally:
        if pool is not None:
            pool.close()
        bar.close()
    return finished.params


@contextlib.contextmanager
def _signals_ignored():
    """SIGINT and SIGTERM ignored while the block runs, in the main thread (the one Python delivers
    signals to): for the checkpoint an interrupted run saves, since the run is stopping already. A
    handler set outside Python (getsignal None) is left alone: it could not be put back."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    ours = [sig for sig in (signal.SIGINT, signal.SIGTERM) if signal.getsignal(sig) is not None]
    previous = {sig: signal.signal(sig, signal.SIG_IGN) for sig in ours}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _resumable(cfg, ckpt_path):
    """The run's checkpoint, checked to be one this config continues: trained with this config (but
    RESUMABLE fields), from zero layer-norm offsets, and not past cfg.iterations."""
    ckpt = checkpoint.load(ckpt_path)
    if ckpt["ln_offsets_drawn"]:
        raise ValueError(f"{ckpt_path!r} began with random layer-norm offsets (saved before they started at "
                         f"zero, as in MIL's released code): resuming it would mix two initialisations; start a "
                         f"new run folder (the checkpoint still scores as it is)")
    stored = dataclasses.replace(ckpt["config"], **{name: getattr(cfg, name) for name in RESUMABLE})
    if stored != cfg:
        differ = ", ".join(f"{f.name}: checkpoint {getattr(stored, f.name)!r}, now {getattr(cfg, f.name)!r}"
                           for f in dataclasses.fields(cfg) if getattr(stored, f.name) != getattr(cfg, f.name))
        raise ValueError(f"{ckpt_path!r} was trained with a different config ({differ}); resume with the "
                         f"same profile and options (only {', '.join(RESUMABLE)} may change), or start a "
                         f"new run folder")
    start = ckpt["iteration"]
    if cfg.iterations < start:
        raise ValueError(nothing_to_train(ckpt_path, start, cfg.iterations, ckpt["config"].iterations))
    return ckpt


def nothing_to_train(ckpt_path, start, iterations, own):
    """What resuming a run at iteration `start` with --iterations `iterations` <= start says, and how to
    train on: --iterations above `start`, or none where the checkpoint's own count `own` is above it."""
    where = f"past --iterations {iterations}" if iterations < start else f"which --iterations {iterations} asks for"
    bare = f", or without --iterations (to its {own})" if own > start else ""
    return (f"{ckpt_path!r} is at iteration {start}, {where}: nothing to train; resume with --iterations above "
            f"{start}{bare}")


def _resume(ckpt, cfg, ckpt_path, log_path, *data):
    """(state, network config, meta-training seconds so far) from the run's checkpoint (`_resumable`),
    after checking that it was trained on data like `data`."""
    for dataset, path in zip(data, (cfg.train_data, cfg.validation_data)):
        fit_check.check_data(ckpt, dataset["metadata"], ckpt_path, path)   # e.g. the file was replaced
    start = ckpt["iteration"]
    state = loop.State(ckpt["params"], ckpt["adam"], ckpt["ema"], start, ckpt["rng"].bit_generator.state)
    _truncate_log(log_path, start)
    if ckpt["config"].lr != cfg.lr:
        _log_now(log_path, {"iteration": start, "lr": cfg.lr, "lr_before": ckpt["config"].lr,
                            "step_now": loop.learning_rate(cfg, start)})
    return state, ckpt["network"], ckpt["seconds"]


def _log(f, record):
    f.write(json.dumps(record) + "\n")
    f.flush()                                    # `tail -f log.jsonl` shows each line as it is written


def _log_now(path, record):
    with files.open_write(path) as f:
        _log(f, record)


def _truncate_log(path, iteration):
    """Drop log lines past the checkpoint's iteration (a killed run wrote some before dying). A torn
    last line (what a kill or a full disk leaves) is dropped too; any other line that is not a JSON
    record with an "iteration" is an error naming the file, the line and the fix."""
    if not os.path.exists(path):
        return
    with files.open_read(path) as f:
        lines = f.read().split(b"\n")
    keep = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
            step = record["iteration"]
            if isinstance(step, bool) or not isinstance(step, int):
                raise TypeError(step)
        except (ValueError, KeyError, TypeError):
            if number == len(lines):             # the last line, without its newline: torn by a kill
                continue
            raise ValueError(f"{path}:{number} is not a log record (a JSON object with an integer "
                             f"\"iteration\"); the checkpoint is fine: move {path} away (or delete that line) "
                             f"and --resume again") from None
        if step <= iteration:
            keep.append(line + b"\n")
    with files.atomic_write(path) as f:
        f.write(b"".join(keep))
