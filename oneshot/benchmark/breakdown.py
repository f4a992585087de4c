"""Where the time of a meta-iteration goes, by operation (`python -m oneshot.benchmark maml --breakdown`),
and what the exchanges between processes and the evaluation rollouts of a Figure 2 run cost.

The training process's part of a meta-gradient (its block of frames of every task, `oneshot.maml.shards`)
is computed in this process alone with one BLAS thread, as during training, `iterations` times as it is
(median wall time) and, alternately with those, under Python's cProfile, which gives the time spent in
each function of the network (`oneshot.policy.conv`, `.affine`, `.layers`, `.norm`, `oneshot.maml.inner`):

    conv_products          the convolutions' matrix products (`conv`) and the dense layers' (`matmul`)
    transposed_products    their transposes: the gradients with respect to activations and weights
                           (`conv_dx`, `conv_dw`, `matmul_dx`, `matmul_dw`)
    im2col_col2im          gathering patches into rows and scattering them back (`im2col`, `col2im`, the
                           blocks of patches of `conv`)
    other_layer_primitives bias, ReLU and its mask, concatenation, layer norm, eq. (1)'s step
    autograd_python        the rest of the wall time: autograd's tape (boxing, nodes, the backward pass's
                           order and sums of gradients) and NumPy's small operations (loss, reshapes,
                           feature points); below zero when the parts, timed under cProfile, outran
                           the plain runs (other work on the cores): then "note" says it is not measured

With shards > 1, the whole meta-iteration also runs on its processes, and the training process's time
inside the exchanges (`shards.allreduce` and the final sum, waiting for the others included) is
`exchange_ms`. The evaluation rollouts: one step of the policy in the world (a forward pass on one
frame, the physics and the camera image), and eq. (1) on one demo, as `imitation.one_shot_success`.
"""
import cProfile
import pstats
import time

import numpy as np

from oneshot.benchmark.maml import bench_setup, synthetic_demos, timed_key
from oneshot.experiments.fig2 import PROFILES
from oneshot.maml import imitation, inner, shards
from oneshot.policy import affine, conv, layers, network, norm
from oneshot.tools import host
from oneshot.world.reach import ReachWorld, WorldConfig

GROUPS = {
    "conv_products": [(conv, "conv"), (affine, "matmul")],
    "transposed_products": [(conv, "conv_dx"), (conv, "conv_dw"), (affine, "matmul_dx"), (affine, "matmul_dw")],
    "im2col_col2im": [(conv, "im2col"), (conv, "col2im"), (conv, "_patches"), (conv, "_col2im_3x3_stride2"),
                      (conv, "_col2im_any"), (conv, "_col2im_into")],
}
EXCHANGE = [shards.Exchange.sum]
PAPER = PROFILES["paper"]
FIGURE2_TRIALS = PAPER.test[0] * PAPER.trials   # scored trials of a Figure 2 run, each adapted and not (MIL)


def _code_key(f):
    code = getattr(f, "fun", f).__code__                  # an autograd primitive's own function, or f
    return code.co_filename, code.co_firstlineno, code.co_name


def _function_groups():
    """cProfile's key of every function timed -> its group (`GROUPS`, else "other_layer_primitives")."""
    keys = {_code_key(getattr(module, name)): group for group, members in GROUPS.items() for module, name in members}
    for module in (affine, conv, layers, norm, inner):
        for f in vars(module).values():
            if getattr(f, "_is_autograd_primitive", False) and _code_key(f) not in keys:
                keys[_code_key(f)] = "other_layer_primitives"
    return keys


def _grouped_ms(stats, keys):
    """Milliseconds per group: each function's cumulative time, less what its callees in a group took
    (those count in their own group)."""
    ms = dict.fromkeys([*GROUPS, "other_layer_primitives"], 0.0)
    for key, group in keys.items():
        if key in stats:
            ms[group] += 1e3 * stats[key][3]
            for caller, (_, _, _, cumulative) in stats[key][4].items():
                if caller in keys:
                    ms[keys[caller]] -= 1e3 * cumulative
    return ms


def bench_breakdown(iterations=10, profile="default", T=20, image_size=32, rollouts=4, **overrides):
    """Milliseconds per operation of the training process's part of a meta-gradient, the exchanges of a
    whole meta-iteration (shards > 1) and the evaluation rollouts (module docstring)."""
    host.tune_malloc()
    host.blas_threads(1)
    method, net_cfg, params, rng = bench_setup(profile, image_size, T, **overrides)
    cfg = method.cfg
    if not method.adapts:
        raise ValueError(f"--breakdown times MIL's meta-gradient on frame shards, not the {cfg.method} baseline's: "
                         f"time a profile or a line of MIL")
    batch = [synthetic_demos(rng, cfg.meta_batch, T, image_size) for _ in range(2)]
    adapt, evaluate = (shards.split_frames(demos, cfg.shards)[-1] for demos in batch)  # the training process's part
    B, frames = adapt[0].shape[:2]
    settings = (imitation.imitation_loss, method.inner)
    keys = _function_groups()
    for _ in range(2):
        shards.part(params, adapt, evaluate, settings)
    times, parts = [], []
    for _ in range(iterations):                           # plain and profiled runs alternate: the host's
        t = time.perf_counter()                           # speed drifts, and both should see the same
        shards.part(params, adapt, evaluate, settings)
        times.append(time.perf_counter() - t)
        profiler = cProfile.Profile()
        profiler.enable()
        shards.part(params, adapt, evaluate, settings)
        profiler.disable()
        parts.append(_grouped_ms(pstats.Stats(profiler).stats, keys))
    ms = {k: float(np.median([p[k] for p in parts])) for k in parts[0]}
    wall = 1e3 * float(np.median(times))
    result = {timed_key(profile): profile, "tasks": int(B), "frames": int(frames), "inner_steps": cfg.inner_steps,
              "inner_params": cfg.inner_params, "first_order": cfg.first_order, "part_ms": round(wall, 1)}
    result.update({k + "_ms": round(v, 1) for k, v in ms.items()})
    result["autograd_python_ms"] = round(wall - sum(ms.values()), 1)
    if result["autograd_python_ms"] < 0:                  # the parts, timed under cProfile, outran the plain runs
        result["note"] = ("the profiled parts took longer than the plain runs (cProfile's overhead, or other work "
                          "on the cores): autograd_python_ms is not measured here; time it on idle cores, with "
                          "more --iterations")
    if method.shards > 1:
        result.update(_exchanges(method, params, rng, T, image_size, iterations))
    result.update(_rollouts(method, params, net_cfg, batch[0], rollouts))
    return result


def _exchanges(method, params, rng, T, image_size, iterations):
    """The whole meta-iteration on its processes: median wall time and the training process's time
    inside the exchanges (cProfile on every other iteration), after a warm-up of each kind."""
    keys, B = [_code_key(f) for f in EXCHANGE], method.cfg.meta_batch
    times, inside, pool = [], [], method.make_pool()
    try:
        for i in range(2 * iterations + 2):
            a, e = synthetic_demos(rng, B, T, image_size), synthetic_demos(rng, B, T, image_size)
            profiler = cProfile.Profile() if i % 2 else None
            t = time.perf_counter()
            if profiler:
                profiler.enable()
            method.meta_gradient(params, a, e, pool)
            if profiler:
                profiler.disable()
            if i < 2:                                     # the warm-ups: one plain, one profiled
                continue
            if profiler:
                stats = pstats.Stats(profiler).stats
                inside.append((sum(1e3 * stats[k][3] for k in keys if k in stats),
                               sum(stats[k][1] for k in keys if k in stats)))
            else:
                times.append(time.perf_counter() - t)
    finally:
        pool.close()
    return {"iteration_ms": round(1e3 * float(np.median(times)), 1),
            "exchange_ms": round(float(np.median([m for m, _ in inside])), 1),
            "exchanges_per_iteration": int(np.median([n for _, n in inside]))}


def _rollouts(method, params, net_cfg, demos, count):
    """Milliseconds per step of an evaluation rollout (forward pass, physics, camera image) and per
    adaptation to one demo, and the seconds they add to one Figure 2 run of this method."""
    world = ReachWorld(WorldConfig(image_size=net_cfg.image_size))
    demo = tuple(a[0] for a in demos)
    condition = method.conditioner(params)
    t = time.perf_counter()
    for _ in range(count):
        policy = condition(demo)
    adapt_ms = 1e3 * (time.perf_counter() - t) / count
    image, state = demo[0][:1], demo[1][:1]                   # (1, H, W, 3), (1, 6): one frame
    t = time.perf_counter()
    for _ in range(count * world.config.horizon):
        policy(image, state, None) if callable(policy) else network.forward(policy, image, state)
    forward_ms = 1e3 * (time.perf_counter() - t) / (count * world.config.horizon)
    t = time.perf_counter()
    for i in range(count):
        imitation.rollout(policy, world, i)
    step_ms = 1e3 * (time.perf_counter() - t) / (count * world.config.horizon)
    scored = 2 if method.adapts else 1                   # MIL is scored adapted and unadapted
    run_s = (scored * FIGURE2_TRIALS * world.config.horizon * step_ms + FIGURE2_TRIALS * adapt_ms) / 1e3
    return {"rollout_step_ms": round(step_ms, 2), "rollout_forward_ms": round(forward_ms, 2),
            "adapt_one_demo_ms": round(adapt_ms, 1), "figure2_run_rollouts_s": round(run_s, 1)}
