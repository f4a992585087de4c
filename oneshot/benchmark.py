"""Speed and quality benchmarks: `python -m oneshot.benchmark {expert,collect,maml} --help`.

These measure what tests should not time: medians of repeated runs on this machine.
    expert   iLQG solve time (median over scenes) and the expert's success rate over many scenes
    collect  wall time to collect a dataset of demonstrations with all cores
    maml     seconds per second-order meta-iteration, GFLOP/s and peak memory; with --breakdown, where
             the time of one process's part of it goes (its block of every demo's frames)
    privileged  ceilings for the policy network: plain behavioural cloning on all meta-training
             demos when the policy is GIVEN what one-shot imitation must infer (the target's position,
             or its colour), scored on held-out colours. If these are high, what remains hard is the
             one-shot identification of the colour, i.e. meta-learning itself.
"""
import argparse
import cProfile
import dataclasses
import json
import os
import pstats
import sys
import time

import numpy as np
from autograd import grad
from tqdm import tqdm

from oneshot.data import collection, datasets
from oneshot.expert import controller
from oneshot.maml import inner, imitation, optim, shards
from oneshot import methods
from oneshot.policy import layers, network
from oneshot.tools import cli, host
from oneshot.world import palette
from oneshot.methods.mil import INNER_PARAMS
from oneshot.training.config import PROFILES
from oneshot.training.scoring import wilson_interval
from oneshot.world.reach import ReachWorld, WorldConfig


# ----------------------------------------------------------------------------------------------------
# Meta-iterations: seconds, GFLOP/s, and where the time goes
# ----------------------------------------------------------------------------------------------------


def synthetic_demos(rng, tasks, T, image_size):
    """Random demos shaped like one side of a meta-batch, for timing: images (tasks, T, H, W, 3) in
    [0, 1), states (tasks, T, 6), torques (tasks, T, 2), all float32."""
    return (rng.random((tasks, T, image_size, image_size, 3), dtype=np.float32),
            rng.standard_normal((tasks, T, 6), dtype=np.float32),
            rng.standard_normal((tasks, T, 2), dtype=np.float32))


def bench_setup(profile, image_size, **overrides):
    """(method, net_cfg, params, rng) for timing a profile (with overridden fields) on synthetic data."""
    method = methods.of(dataclasses.replace(PROFILES[profile], **overrides))
    rng = np.random.default_rng(0)
    net_cfg = method.network_config(image_size)
    return method, net_cfg, method.init_params(net_cfg, rng), rng


def bench_meta_iteration(iterations=20, profile="default", T=20, image_size=32, **overrides):
    """Median seconds per meta-iteration (the gradient of one meta-batch: for mil second order, over
    cfg.shards processes) on synthetic data, and GFLOP/s (`meta_gradient_flops`)."""
    host.tune_malloc()
    method, net_cfg, params, rng = bench_setup(profile, image_size, **overrides)
    cfg = method.cfg
    if not method.learns:
        raise ValueError(f"the {cfg.method} policy has no meta-iteration to time")
    B = cfg.meta_batch
    times, pool = [], method.make_pool()
    try:
        for _ in range(iterations + 2):
            a, e = synthetic_demos(rng, B, T, image_size), synthetic_demos(rng, B, T, image_size)
            t = time.perf_counter()
            method.meta_gradient(params, a, e, pool)
            times.append(time.perf_counter() - t)
    finally:
        if pool is not None:
            pool.close()
    s = float(np.median(times[2:]))
    flops = method.meta_gradient_flops(net_cfg, T, B)
    return {"profile": profile, "method": cfg.method, "meta_batch": B, "inner_steps": cfg.inner_steps,
            "inner_params": cfg.inner_params, "T": T, "image_size": image_size, "first_order": cfg.first_order,
            "shards": method.shards,
            "seconds_per_iteration": round(s, 4),
            "gflop_per_iteration": round(flops / 1e9, 2), "gflop_per_second": round(flops / 1e9 / s, 1)}




def bench_expert(scenes=500, seed=0):
    """iLQG plan times and expert success over `scenes` random scenes (both colour splits)."""
    plan_s, iterations, successes = [], [], 0
    for i in tqdm(range(scenes), desc="expert", unit="scene"):
        world = ReachWorld(WorldConfig(split="train" if i % 4 else "heldout"))
        _, info = world.reset(seed=seed + i)
        t0 = time.perf_counter()
        result = controller.plan(world.state, info["target_position"], world.config.arm, world.config.horizon)
        plan_s.append(time.perf_counter() - t0)
        iterations.append(result.iterations)
        successes += controller.demonstrate(world, seed=seed + i)["success"]
    return {"scenes": scenes, "expert_success_rate": successes / scenes,
            "ilqg_solve_s_median": float(np.median(plan_s)), "ilqg_solve_s_p90": float(np.percentile(plan_s, 90)),
            "ilqg_iterations_median": float(np.median(iterations))}


def bench_collect(demos=1000, workers=None):
    """Wall time to collect about `demos` demonstrations (every training colour) with `workers` processes."""
    tasks = len(palette.split_colours("train"))
    per_task = -(-demos // tasks)
    t0 = time.perf_counter()
    d = collection.collect(tasks, per_task, "train", 0, workers, progress=True)
    seconds = time.perf_counter() - t0
    return {"demos": tasks * per_task, "workers": workers or os.cpu_count(), "seconds": round(seconds, 2),
            "demos_per_second": round(tasks * per_task / seconds, 1),
            "expert_success_rate": d["metadata"]["expert_success_rate"]}


def bench_privileged(given="colour", steps=3000, batch=16, trials=60, feature_points=False, seed=0,
                     train_data="data/train.npz", lr=1e-3):
    """Behavioural cloning with privileged inputs: the ceiling of the network, not a method.

    given="position": the target's position (m / 0.2) is appended to the robot state.
    given="colour":   the target colour's RGB in [0, 1] is appended to every pixel (3 more input
                      channels to the first convolution; MIL's contextual policy gets a demo image there).
    Trains the policy network (`oneshot.policy.network`) on all demos of `train_data` with Adam, `batch`
    demos per step, then runs it in `trials` new scenes of held-out colours.
    """
    if given not in ("position", "colour"):
        raise ValueError(f"given must be 'position' or 'colour'; got {given!r}")
    ds = datasets.load(train_data)
    world_cfg = datasets.world_config(ds["metadata"])
    max_torque = world_cfg.arm.max_torque
    rgb = palette.palette_rgb(world_cfg.palette).astype(np.float32) / 255     # (colours, 3)
    images, states, actions = imitation.prepare_demos(ds["images"], ds["states"], ds["actions"], max_torque)
    n, k, T = states.shape[:3]
    target = ds["positions"][np.arange(n)[:, None], np.arange(k), ds["target_index"].astype(int)]  # (N, K, 2)
    rng = np.random.default_rng(seed)
    net_cfg = network.NetworkConfig(image_size=images.shape[-2], feature_points=feature_points,
                                    state_dim=8 if given == "position" else 6)
    params = network.init_params(net_cfg, rng)
    if given == "colour":                                      # first convolution sees 6 channels
        w = params["conv0_w"]
        params["conv0_w"] = (rng.standard_normal((*w.shape[:2], 6, w.shape[3])) *
                             np.sqrt(2 / (9 * 6))).astype(np.float32)

    def inputs(im, st, tgt, colour):
        """im (B, H, W, 3), st (B, 6), tgt (B, 2) m, colour (B, 3) -> network inputs."""
        if given == "position":
            return im, np.concatenate([st, tgt / np.float32(0.2)], -1).astype(np.float32)
        return np.concatenate([im, np.broadcast_to(colour[:, None, None, :], im.shape)], -1), st

    def loss(p, im, st, act):
        return imitation.imitation_loss(p, (im, st, act)) / len(act)     # eq. (2), per frame

    def policy(im, st, scene):
        """The network given a trial scene's target position or colour (`imitation.rollout`)."""
        im, st = inputs(im, st, scene.target_position.astype(np.float32)[None], rgb[scene.target_colour][None])
        return network.forward(params, im, st)

    g, adam = grad(loss), optim.adam_init(params)
    colours = rgb[ds["task_colours"].astype(int)]
    for _ in tqdm(range(steps), desc=f"BC, {given} given"):
        ti, ki = rng.integers(n, size=batch), rng.integers(k, size=batch)
        im, st = inputs(images[ti, ki].reshape(-1, *images.shape[-3:]), states[ti, ki].reshape(-1, 6),
                        np.repeat(target[ti, ki], T, 0), np.repeat(colours[ti], T, 0))
        params, adam = optim.adam_step(params, g(params, im, st, actions[ti, ki].reshape(-1, 2)), adam, lr)
    world = ReachWorld(dataclasses.replace(world_cfg, split="heldout"))
    wins = sum(imitation.rollout(policy, world, imitation.trial_seed(0, 0, j))["success"]
               for j in tqdm(range(trials), desc="held-out trials"))
    return {"given": given, "feature_points": feature_points, "steps": steps, "batch_demos": batch,
            "seed": seed, "heldout_trials": trials, "heldout_success": wins / trials,
            "ci95": wilson_interval(wins, trials)}


def bench_breakdown(iterations=10, profile="default", T=20, image_size=32, **overrides):
    """Where the time of one process's part of a meta-gradient goes: the training process's block of
    frames of every task of the profile's meta-batch (`oneshot.maml.shards`), computed in this process
    alone (without the exchanges with the other processes) with one BLAS thread, as during training.

    The part is computed `iterations` times as it is (median wall time) and, alternately with those,
    `iterations` times under Python's cProfile, which gives the time spent inside each of the network's
    primitives (`oneshot.policy.layers`, `oneshot.maml.batched`; medians): the matrix products, im2col/col2im and the
    rest of the layer primitives (bias, ReLU, masks, concatenation, eq. (1)). The remainder of the wall
    time is autograd's own Python bookkeeping, its sums of gradients and NumPy's small operations (the
    loss, reshapes). Returns milliseconds per part.
    """
    host.tune_malloc()
    host.blas_threads(1)
    method, net_cfg, params, rng = bench_setup(profile, image_size, **overrides)
    cfg = method.cfg
    if not method.adapts:
        raise ValueError("--breakdown times MIL's meta-gradient on frame shards; drop --method")
    batch = [synthetic_demos(rng, cfg.meta_batch, T, image_size) for _ in range(2)]
    adapt, evaluate = (shards.split_frames(demos, cfg.shards)[-1] for demos in batch)  # the training process's part
    B, frames = adapt[0].shape[:2]
    settings = (imitation.imitation_loss, method.inner)

    def compute():
        return shards.part(params, adapt, evaluate, settings)

    groups = {"matrix_products": ("matmul", "matmul_dx", "matmul_dw"), "im2col_col2im": ("im2col", "col2im")}
    keys = {}                                             # cProfile's key of each primitive -> its group
    for module in (layers, inner):
        for name, f in vars(module).items():
            if getattr(f, "_is_autograd_primitive", False):
                code = f.fun.__code__
                keys[(code.co_filename, code.co_firstlineno, code.co_name)] = next(
                    (g for g, names in groups.items() if name in names), "other_layer_primitives")
    for _ in range(2):
        compute()
    times, parts = [], []
    for _ in range(iterations):                           # plain and profiled runs alternate: the host's
        t = time.perf_counter()                           # speed drifts, and both should see the same
        compute()
        times.append(time.perf_counter() - t)
        profiler = cProfile.Profile()
        profiler.enable()
        compute()
        profiler.disable()
        stats = pstats.Stats(profiler).stats              # key -> (calls, calls, tottime, cumtime, callers)
        part = dict.fromkeys([*groups, "other_layer_primitives"], 0.0)
        for key, group in keys.items():
            part[group] += 1e3 * stats[key][3] if key in stats else 0.0
        parts.append(part)
    ms = {k: float(np.median([p[k] for p in parts])) for k in parts[0]}
    wall = 1e3 * float(np.median(times))
    flops = method.meta_gradient_flops(net_cfg, frames, B)
    result = {"profile": profile, "tasks": int(B), "frames": int(frames), "inner_steps": cfg.inner_steps,
              "inner_params": cfg.inner_params, "first_order": cfg.first_order, "part_ms": round(wall, 1)}
    result.update({k + "_ms": round(v, 1) for k, v in ms.items()})
    result["autograd_and_small_ops_ms"] = round(wall - sum(ms.values()), 1)
    result["matrix_products_gflop_per_second"] = round(flops / 1e6 / ms["matrix_products"], 1)
    result["blas_sgemm_1024_gflop_per_second"] = round(_sgemm_rate(), 1)
    return result


def _sgemm_rate(n=1024, repeats=10):
    """GFLOP/s of one float32 (n, n) @ (n, n) product in this process (median): what BLAS reaches on
    a large square product, against which to read the network's thin ones (40 output channels)."""
    rng = np.random.default_rng(0)
    a, b = rng.random((n, n), dtype=np.float32), rng.random((n, n), dtype=np.float32)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        a @ b
        times.append(time.perf_counter() - t)
    return 2 * n ** 3 / float(np.median(times)) / 1e9


def main(argv=None):
    p = cli.Parser(prog="python -m oneshot.benchmark", description=__doc__,
                   formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    e = sub.add_parser("expert", help="iLQG solve time and expert success rate")
    e.add_argument("--scenes", type=cli.positive_int, default=500)
    c = sub.add_parser("collect", help="time to collect demonstrations")
    c.add_argument("--demos", type=cli.positive_int, default=1000)
    c.add_argument("--workers", type=cli.positive_int, default=None, help="processes (default and at most: the cores)")
    m = sub.add_parser("maml", help="seconds per second-order meta-iteration")
    m.add_argument("--iterations", type=cli.positive_int, default=20)
    m.add_argument("--profile", choices=sorted(PROFILES), default="default")
    m.add_argument("--method", choices=[n for n in methods.NAMES if methods.REGISTRY[n].learns], default=None,
                   help="time a baseline's iteration (same meta-batch, trunk and widths) instead of MIL's")
    m.add_argument("--lstm-units", type=cli.positive_int, default=None, help="override the LSTM baseline's width")
    m.add_argument("--first-order", action="store_true", help="time the first-order approximation")
    m.add_argument("--inner-steps", type=cli.non_negative_int, default=None, help="override the profile's inner steps")
    m.add_argument("--inner-params", choices=sorted(INNER_PARAMS), default=None,
                   help="override which parameters the inner steps adapt")
    m.add_argument("--meta-batch", type=cli.positive_int, default=None, help="override the profile's meta-batch")
    m.add_argument("--shards", type=cli.positive_int, default=None,
                   help="override the profile's shards (processes sharing each meta-gradient; 1 = one process)")
    m.add_argument("--breakdown", action="store_true",
                   help="instead: where the time of the training process's part goes (matrix products, "
                        "im2col/col2im, other layer primitives, autograd's Python)")
    v = sub.add_parser("privileged", help="ceiling: behavioural cloning given the target's position or colour")
    v.add_argument("--given", choices=("position", "colour"), default="colour")
    v.add_argument("--steps", type=cli.positive_int, default=3000)
    v.add_argument("--trials", type=cli.positive_int, default=60)
    v.add_argument("--feature-points", action="store_true")
    v.add_argument("--train-data", default="data/train.npz")
    v.add_argument("--seed", type=cli.non_negative_int, default=0)
    args = p.parse_args(argv)
    world = WorldConfig()                    # the frames and images the benchmarks time
    try:                                     # what must fit in memory, before the work
        if args.what == "collect":
            tasks = len(palette.split_colours("train"))
            cli.check_memory(cli.dataset_bytes(tasks, -(-args.demos // tasks), world.horizon, world.image_size,
                                               world.n_objects), f"{args.demos} demos", "use fewer --demos")
        if args.what == "maml" and args.meta_batch:
            cli.check_memory(2 * args.meta_batch * world.horizon * world.image_size ** 2 * 3 * 4,
                             f"a meta-batch of {args.meta_batch} tasks (its synthetic images alone)",
                             "use a smaller --meta-batch")
    except ValueError as error:
        sub.choices[args.what].error(str(error))
    if args.what == "expert":
        result = bench_expert(args.scenes)
    elif args.what == "collect":
        cores = os.cpu_count() or 1
        result = bench_collect(args.demos, min(args.workers or cores, cores))
    elif args.what == "privileged":
        result = bench_privileged(args.given, args.steps, trials=args.trials, feature_points=args.feature_points,
                                  seed=args.seed, train_data=args.train_data)
    else:
        overrides = {k: v for k, v in (("first_order", args.first_order or None), ("inner_steps", args.inner_steps),
                                       ("inner_params", args.inner_params), ("meta_batch", args.meta_batch),
                                       ("shards", args.shards), ("method", args.method),
                                       ("lstm_units", args.lstm_units)) if v is not None}
        bench = bench_breakdown if args.breakdown else bench_meta_iteration
        result = bench(args.iterations, args.profile, **overrides)
    main_mb, worker_mb = host.peak_memory_mb()
    result["peak_memory_mb"] = round(main_mb, 1)
    result["peak_worker_memory_mb"] = round(worker_mb, 1)
    result["machine"] = host.machine()
    json.dump(result, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    cli.run(main, failures=(shards.ShardError,))
