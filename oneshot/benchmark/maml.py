"""Meta-iterations: seconds, GFLOP/s, and where the time of one goes (`python -m oneshot.benchmark maml`).

Timed on synthetic demos shaped like a meta-batch; the matrix-product ceiling of this machine's BLAS
(`sgemm_rate`) is measured in the same run, so a GFLOP/s figure can be read against it.
"""
import cProfile
import dataclasses
import pstats
import time

import numpy as np

from oneshot.maml import inner, imitation, shards
from oneshot import methods
from oneshot.policy import layers
from oneshot.tools import host
from oneshot.training.config import PROFILES



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


def bench_breakdown(iterations=10, profile="default", T=20, image_size=32, **overrides):
    """Where the time of one process's part of a meta-gradient goes: the training process's block of
    frames of every task of the profile's meta-batch (`oneshot.maml.shards`), computed in this process
    alone (without the exchanges with the other processes) with one BLAS thread, as during training.

    The part is computed `iterations` times as it is (median wall time) and, alternately with those,
    `iterations` times under Python's cProfile, which gives the time spent inside each of the network's
    primitives (`oneshot.policy.layers`, `oneshot.maml.inner`; medians): the matrix products, im2col/col2im and the
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
    result["blas_sgemm_1024_gflop_per_second"] = round(sgemm_rate(), 1)
    return result


def sgemm_rate(n=1024, repeats=10):
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
