"""Checkpoints of a meta-training run: parameters, their moving average, Adam's state, the iteration,
the random state and the configs, in one .npz file (no pickles), written atomically.

    ckpt = checkpoint.load("runs/default/checkpoint.npz")
    params = checkpoint.policy_params(ckpt)          # what the policy acts with

Saving then loading gives back the same arrays and random state, so a run resumed from a checkpoint
continues exactly as the uninterrupted run would have (`train.train(..., resume=True)`).
"""
import dataclasses
import json
import os

import numpy as np

from oneshot import optim
from oneshot.config import TrainConfig
from oneshot.data import atomic_write
from oneshot.network import STRIDE, NetworkConfig


def save(path, params, adam_state, iteration, rng, cfg, net_cfg, ema=None):
    """Write a checkpoint atomically (temporary file + rename): never half a file on disk.

    params: dict of arrays; adam_state: `optim.adam_init`'s dict; iteration: meta-iterations done;
    rng: the run's np.random.Generator; cfg: TrainConfig; net_cfg: NetworkConfig;
    ema: the moving average of the parameters (cfg.ema > 0), or None.
    """
    arrays = {f"params/{k}": v for k, v in params.items()}
    arrays.update({f"ema/{k}": v for k, v in (ema or {}).items()})
    arrays.update(optim.state_to_arrays(adam_state))
    meta = {"iteration": iteration, "rng": rng.bit_generator.state, "config": dataclasses.asdict(cfg),
            "network": dataclasses.asdict(net_cfg), "format_version": 1}
    with atomic_write(path) as f:
        np.savez(f, meta=np.array(json.dumps(meta)), **arrays)


def load(path):
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
    network = _tuples(meta["network"])
    if network.pop("stride", STRIDE) != STRIDE:      # older checkpoints record the (fixed) stride
        raise ValueError(f"{path!r} was trained with convolution stride {meta['network']['stride']}; "
                         f"this oneshot's network has stride {STRIDE}")
    return {"params": params, "ema": ema, "adam": optim.state_from_arrays(arrays),
            "iteration": meta["iteration"], "rng": rng, "config": TrainConfig(**_tuples(meta["config"])),
            "network": NetworkConfig(**network)}


def _tuples(fields):
    """A config dict read from JSON, its lists back to the tuples the dataclass holds."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()}


def policy_params(ckpt, raw=False):
    """The parameters a checkpoint's policy acts with: the moving average if the run kept one
    (cfg.ema > 0) and raw is False, else the parameters Adam trained."""
    return ckpt["params"] if raw or ckpt["ema"] is None else ckpt["ema"]


def update_ema(ema, params, decay):
    """Polyak averaging: ema <- decay * ema + (1 - decay) * params, key by key (float32 stays float32)."""
    d = float(decay)
    return {k: d * ema[k] + (1.0 - d) * params[k] for k in params}
