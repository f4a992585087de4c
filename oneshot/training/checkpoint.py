"""Checkpoints of a meta-training run: parameters, their moving average, Adam's state, the iteration,
the random state, the configs and the world the data was recorded in, in one .npz file (no pickles),
written atomically.

    ckpt = checkpoint.load("runs/default/checkpoint.npz")
    fit_check.check_data(ckpt, datasets.load(path)["metadata"], "runs/default/checkpoint.npz", path)
    params = checkpoint.policy_params(ckpt)          # what the policy acts with

Saving then loading gives back the same arrays and random state, so a run resumed from a checkpoint
continues exactly as the uninterrupted run would have (`run_folder.train(..., resume=True)`).

`load` trusts nothing in the file: a damaged or hand-edited checkpoint raises `CheckpointError`, which
names the file and what is wrong with it, never a KeyError three calls deeper or a policy missing a
parameter. It checks the file as `npz.Reader` does (each array's npy header against its zip member's
size before reading the data, so a damaged header cannot claim terabytes; the zip's CRCs), a SHA-256
checksum of the arrays (in checkpoints written since it was added), every field of the metadata, and
every array's name, shape and dtype against what the stored configs make (`methods.of(cfg).init_params`).
Whether a dataset is one the policy can be run on (the same image size, horizon, torque bound and
palette) is `training.fit_check.check_data`.
"""
import dataclasses
import json
import os

import numpy as np

from oneshot.data import datasets, npz
from oneshot.maml import optim
from oneshot import methods
from oneshot.policy import network
from oneshot.training.config import TrainConfig
from oneshot.tools.files import atomic_write
from oneshot.policy.network import STRIDE, NetworkConfig
from oneshot.training.checkpoint_meta import (FIX, FORMAT_VERSION, CheckpointError, read_config, read_meta,
                                              world_fields)


def checksum(arrays):
    """SHA-256 over a checkpoint's arrays, in name order (`npz.checksum`). -> hex str."""
    return npz.checksum(arrays, sorted(arrays))


def save(path, params, adam_state, iteration, rng, cfg, net_cfg, ema=None, world=None, seconds=None):
    """Write a checkpoint atomically (temporary file + rename): never half a file on disk.

    params: dict of arrays; adam_state: `optim.adam_init`'s dict; iteration: meta-iterations done;
    rng: the run's np.random.Generator; cfg: TrainConfig; net_cfg: NetworkConfig;
    ema: the moving average of the parameters (cfg.ema > 0), or None;
    world: the meta-training dataset's `metadata["world"]` (a dict, or a WorldConfig), which
    `check_data` compares other datasets with; None records nothing.
    seconds: the run's meta-training time so far, every sitting included (None: not known).
    The members are stored, not deflated (`npz.write`): deflate saves 10% of the shipped policy's
    1.1 MB and makes saving 4 times slower (13 -> 52 ms).
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"checkpoint.save needs the run's np.random.Generator as rng; got {type(rng).__name__}")
    arrays = {f"params/{k}": np.asarray(v) for k, v in params.items()}
    arrays.update({f"ema/{k}": np.asarray(v) for k, v in (ema or {}).items()})
    arrays.update(optim.state_to_arrays(adam_state))
    if dataclasses.is_dataclass(world):
        world = dataclasses.asdict(world)
    meta = {"iteration": iteration, "rng": rng.bit_generator.state, "config": dataclasses.asdict(cfg),
            "network": dataclasses.asdict(net_cfg), "world": world,
            "state_layout": list(datasets.STATE_LAYOUT), "seconds": seconds,
            "checksum": checksum(arrays), "format_version": FORMAT_VERSION}
    arrays["meta"] = np.array(json.dumps(meta))
    try:                                          # what load would refuse is not written; load's own advice
        _parse(os.fspath(path), dict(arrays))     # (re-train...) does not fit: the arguments do
    except CheckpointError as e:
        raise ValueError(f"checkpoint.save would write a file that checkpoint.load refuses: {str(e).rsplit('; ', 1)[0]}; "
                         f"fix what is passed to checkpoint.save (params, ema, net_cfg, cfg, iteration, world)") from None
    with atomic_write(path) as f:
        npz.write(f, arrays, compress=False)


def is_checkpoint(path):
    """May an output replace `path` as a policy: does it hold a checkpoint's arrays (what `save` writes;
    `load` checks the rest), or is it too damaged to tell?"""
    names = npz.members(path)
    return names is None or npz.kind(names) == "checkpoint"


def load(path):
    """Read and check a checkpoint. Returns {"params", "ema", "adam", "iteration", "rng", "config",
    "network", "world", "state_layout"}: "ema" is the moving average of the parameters, or None if the
    run kept none (cfg.ema = 0); "world" the meta-training data's world (a dict) and "state_layout"
    the robot state's layout (`datasets.STATE_LAYOUT` when saved; both None in older checkpoints);
    "seconds" the meta-training time up to this checkpoint, resumes included (None in older ones);
    "ln_offsets_drawn" True for a layer-normalised network saved before its offsets started at zero
    (before NetworkConfig recorded `init`: they began as random draws; such a run is not resumed).
    `policy_params(ckpt)` picks the parameters to act with. Raises CheckpointError if anything in the
    file is damaged or inconsistent."""
    path = os.fspath(path)
    if not os.path.exists(path):
        run = os.path.dirname(path) if os.path.basename(path) == "checkpoint.npz" else ""
        raise FileNotFoundError(f"no checkpoint at {path!r}; train one with `python -m oneshot.train"
                                f"{' --run ' + run if run else ''}`")
    if os.path.isdir(path):
        raise CheckpointError(f"{path!r} is a folder; name the checkpoint's .npz file")
    # 1. The arrays, each header checked before its data is read; zipfile checks the CRCs.
    try:
        arrays = npz.read(path)
    except npz.Damaged as e:
        raise CheckpointError(f"{path!r} is not a readable oneshot checkpoint ({e}); {FIX}") from e
    return _parse(path, arrays)


def _parse(path, arrays):
    """`load`'s checks and result, from the file's arrays ({"meta": the JSON metadata, name: array}; taken)."""
    if npz.kind(set(arrays)) == "dataset":
        raise CheckpointError(f"{path!r} is a dataset of demonstrations, not a checkpoint; load it with "
                              f"oneshot.data.datasets.load, or name a checkpoint of `python -m oneshot.train`")
    meta = read_meta(path, arrays.pop("meta", None))
    if "checksum" in meta and checksum(arrays) != meta["checksum"]:
        raise CheckpointError(f"{path!r} fails its checksum: its arrays were changed or damaged after "
                              f"saving; {FIX}")
    for name, v in arrays.items():
        if name.startswith(("params/", "ema/")) and v.dtype.kind == "f" and not np.all(np.isfinite(v)):
            raise CheckpointError(f"{path!r}: {name!r} contains NaN or inf; use an earlier checkpoint")

    # 2. The metadata, field by field.
    rng = np.random.default_rng()
    try:
        rng.bit_generator.state = meta["rng"]
    except (ValueError, TypeError, KeyError, OverflowError) as e:
        raise CheckpointError(f"{path!r}: meta 'rng' is not a random state ({e!r}); {FIX}") from e
    network_fields = dict(meta["network"])
    stride = network_fields.pop("stride", STRIDE)      # older checkpoints record the (fixed) stride
    if stride != STRIDE:
        raise CheckpointError(f"{path!r} was trained with convolution stride {stride}; this oneshot's "
                              f"network has stride {STRIDE}; {FIX}")
    cfg = read_config(path, "config", TrainConfig, meta["config"])
    net_cfg = read_config(path, "network", NetworkConfig, network_fields)
    try:
        method = methods.of(cfg)
        method.check(net_cfg)
    except ValueError as e:
        raise CheckpointError(f"{path!r}: meta 'config': {e}; {FIX}") from e
    world = meta["world"]
    if world is not None and world_fields(world, f"{path!r}: meta 'world'")["image_size"] != net_cfg.image_size:
        raise CheckpointError(f"{path!r}: meta 'world' has image_size {world['image_size']} but its "
                              f"network {net_cfg.image_size}; {FIX}")

    # 3. Every array: the names, shapes and dtypes the configs make, and nothing else.
    _check_arrays(path, arrays, method, net_cfg)
    params = {k[len("params/"):]: v for k, v in arrays.items() if k.startswith("params/")}
    ema = {k[len("ema/"):]: v for k, v in arrays.items() if k.startswith("ema/")} or None
    return {"params": params, "ema": ema, "adam": optim.state_from_arrays(arrays),
            "iteration": meta["iteration"], "rng": rng, "config": cfg, "network": net_cfg,
            "world": world, "state_layout": meta["state_layout"], "seconds": meta["seconds"],
            "ln_offsets_drawn": net_cfg.layer_norm and "init" not in network_fields}


def _check_arrays(path, arrays, method, net_cfg):
    """Raise CheckpointError, naming the first missing, unexpected, or wrongly shaped or typed array,
    unless `arrays` are exactly the parameters the method and net_cfg make (`method.init_params`), their
    moving average (cfg.ema > 0), and Adam's state of them."""
    if method.has_network:
        # The network's own shapes first, which costs nothing: a config claiming a giant network must
        # be refused before init_params below allocates it.
        _compare(path, arrays, {f"params/{k}": (s, None) for k, s in network.param_shapes(net_cfg).items()},
                 only_these=True)
    try:
        made = method.init_params(net_cfg, np.random.default_rng(0))
    except ValueError as e:                            # e.g. a negative alpha to learn (learn_alpha)
        raise CheckpointError(f"{path!r}: meta 'config': {e}; {FIX}") from e
    with_ema = (method.cfg.ema > 0 and method.learns) or any(k.startswith("ema/") for k in arrays)
    expected = {"adam/step": ((), np.dtype(np.int64))}
    for k, v in made.items():
        for prefix in ("params/",) + (("ema/",) if with_ema else ()) + ("adam/m/", "adam/v/"):
            expected[prefix + k] = (v.shape, v.dtype)
    _compare(path, arrays, expected)


def _compare(path, arrays, expected, only_these=False):
    """Raise CheckpointError unless arrays holds every name of `expected` {name: (shape, dtype or None)}
    with that shape and dtype, and (unless only_these) nothing else."""
    for name, (shape, dtype) in expected.items():
        if name not in arrays:
            raise CheckpointError(f"{path!r} has no array {name!r} (expected shape {shape}); {FIX}")
        a = arrays[name]
        if a.shape != tuple(shape):
            raise CheckpointError(f"{path!r}: {name!r} has shape {a.shape} but its network and method "
                                  f"need {tuple(shape)}; {FIX}")
        if dtype is not None and a.dtype != dtype:
            raise CheckpointError(f"{path!r}: {name!r} has dtype {a.dtype} but its method makes {dtype}; {FIX}")
    extra = sorted(set(arrays) - set(expected))
    if extra and not only_these:
        raise CheckpointError(f"{path!r} has an unexpected array {extra[0]!r} {arrays[extra[0]].shape}; {FIX}")


def policy_params(ckpt, raw=False):
    """The parameters a checkpoint's policy acts with: the moving average if the run kept one
    (cfg.ema > 0) and raw is False, else the parameters Adam trained."""
    return ckpt["params"] if raw or ckpt["ema"] is None else ckpt["ema"]

