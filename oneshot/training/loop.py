"""The meta-training loop (paper Sections II-III), as a function a notebook can call.

    state = loop.start(method, net_cfg, seed)                      # parameters, Adam, moving average, rng
    state, log = loop.meta_train(method, cfg, state, demos, end=100)

Each meta-iteration: sample a meta-batch of tasks (two demos of each), ask the method for the loss and
its gradient (for MIL: adapt on one demo by eq. (1), score the other by eq. (2), second order), clip,
take one Adam step, update the moving average. `steps` yields the state after every whole iteration,
which is what the run folder (`training.run_folder`) checkpoints and logs; `meta_train` runs it to the
end. A state continues exactly: the same state and data give the same iterations, bit for bit.
"""
import math
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from oneshot.maml import imitation, inner, optim


class TrainingDiverged(RuntimeError):
    """The meta-loss or meta-gradient became NaN or inf (or the policy's torques did)."""


@dataclass(frozen=True)
class State:
    """Everything meta-training carries from one iteration to the next (what a checkpoint saves).

    params: dict of arrays; adam: `optim.adam_init`'s state; ema: the moving average of the parameters
    (None: cfg.ema = 0); iteration: meta-iterations done; rng: the sampling generator's
    `bit_generator.state` after them."""
    params: dict
    adam: dict
    ema: dict
    iteration: int
    rng: dict

    def generator(self):
        """A np.random.Generator in this state's random state."""
        rng = np.random.default_rng()
        rng.bit_generator.state = self.rng
        return rng


def start(method, net_cfg, seed, ema=True):
    """The state of a fresh run: parameters from `seed` (the same generator then samples meta-batches),
    Adam at step 0, the moving average equal to the parameters (ema=False: none)."""
    rng = np.random.default_rng(seed)
    params = method.init_params(net_cfg, rng)
    return State(params, optim.adam_init(params), dict(params) if ema else None, 0, rng.bit_generator.state)


def learning_rate(cfg, iteration):
    """Adam's step size for meta-iteration `iteration` (0-based): cfg.lr, or with cfg.lr_schedule =
    "cosine" cfg.lr * (1 + cos(pi * iteration / cfg.iterations)) / 2, which ends near zero. (With
    "cosine", changing --iterations on --resume reshapes the rest of the schedule.)"""
    if cfg.lr_schedule == "constant":
        return cfg.lr
    if cfg.lr_schedule == "cosine":
        return cfg.lr * 0.5 * (1.0 + math.cos(math.pi * min(iteration, cfg.iterations) / cfg.iterations))
    raise ValueError(f"lr_schedule must be 'constant' or 'cosine'; got {cfg.lr_schedule!r}")


def update_ema(ema, params, decay):
    """Polyak averaging: ema <- decay * ema + (1 - decay) * params, key by key (float32 stays float32)."""
    d = float(decay)
    return {k: d * ema[k] + (1.0 - d) * params[k] for k in params}


def steps(method, cfg, state, demos, end=None, validation=None, pool=None):
    """Meta-train from `state` up to iteration `end` (default cfg.iterations); after every whole
    iteration yield (state, records): records are the log lines it made, dicts with "iteration" and
    "meta_loss" (every cfg.log_every) or "validation_success" and "trials" (every cfg.eval_every, if a
    `validation` dataset is given: one-shot success of the policy it would act with, on its colours).

    method: `methods.of(cfg)`, a method that learns by gradient. demos: (images (N, K, T, H, W, 3),
    states (N, K, T, 6), actions (N, K, T, 2)) in network units (`imitation.prepare_demos`).
    pool: `method.make_pool()` (the processes its meta-gradient shares), or None.
    Raises TrainingDiverged, naming the iteration, if the loss, a gradient or the policy's torques
    stop being finite.
    """
    end = cfg.iterations if end is None else end
    rng = state.generator()
    params, adam, ema = state.params, state.adam, state.ema
    for it in range(state.iteration, end):
        adapt, evaluate = imitation.sample_meta_batch(demos, rng, cfg.meta_batch)          # 1. tasks
        # A diverging run overflows: the check below says so, and numpy's warnings would only add noise.
        # (A pool's shard processes are forked inside this block at the first call, so keep its state.)
        with np.errstate(over="ignore", invalid="ignore"):
            loss, grads = method.meta_gradient(params, adapt, evaluate, pool)              # 2. eq. (1), (2)
        bad = [k for k, g in grads.items() if not np.all(np.isfinite(g))]
        if not np.isfinite(loss) or bad:
            raise TrainingDiverged(f"the meta-loss became {float(loss)} at iteration {it + 1}"
                                   f"{' (non-finite gradient of ' + ', '.join(bad) + ')' if bad else ''}")
        if cfg.clip:                                                                       # 3. clip, Adam
            grads = inner.clip_gradients(grads, cfg.clip)
        params, adam = optim.adam_step(params, grads, adam, learning_rate(cfg, it))
        if ema is not None:
            ema = update_ema(ema, params, cfg.ema)                                         # 4. average
        done, records = it + 1, []
        if done % cfg.log_every == 0:
            records.append({"iteration": done, "meta_loss": float(loss)})
        if validation is not None and cfg.eval_every and done % cfg.eval_every == 0:
            condition = method.conditioner(params if ema is None else ema, seed=done)
            try:
                r = imitation.one_shot_success(condition, validation, cfg.eval_trials, seed=done, progress=False)
            except imitation.PolicyDiverged:
                raise TrainingDiverged(f"the policy's torques became NaN or inf in the validation check at "
                                       f"iteration {done}") from None
            records.append({"iteration": done, "validation_success": r["rate"], "trials": r["trials"]})
        yield State(params, adam, ema, done, rng.bit_generator.state), records


def meta_train(method, cfg, state, demos, end=None, validation=None, pool=None, progress=True):
    """Run `steps` to the end: returns (the final state, every log record). Arguments as `steps`."""
    end = cfg.iterations if end is None else end
    log = []
    with tqdm(total=end, initial=state.iteration, desc="meta-training", disable=not progress) as bar:
        for state, records in steps(method, cfg, state, demos, end, validation, pool):
            log += records
            bar.update()
    return state, log
