"""Meta-iterations: seconds and GFLOP/s against the machine's ceiling (`python -m oneshot.benchmark maml`);
where the time goes is `oneshot.benchmark.breakdown` (--breakdown).

Timed on synthetic demos shaped like a meta-batch; the matrix-product ceiling of this machine's BLAS
(`sgemm_rate`) is measured in the same run, so a GFLOP/s figure can be read against it.
"""
import dataclasses
import os
import time

import numpy as np
from tqdm import tqdm

from oneshot.benchmark import peers
from oneshot import methods
from oneshot.tools import cli, host
from oneshot.experiments.lines import LINES
from oneshot.training.config import PROFILES


def timed_config(name):
    """The TrainConfig timed under a name: a training profile (`oneshot.training.config.PROFILES`) or a
    line of the Figure 2 sweeps (`oneshot.experiments.lines.LINES`, e.g. mil-released+widths-flat)."""
    return PROFILES[name] if name in PROFILES else LINES[name]


def timed_key(name):
    """The results' key for what was timed: "profile" (a training profile's name) or "line"."""
    return "profile" if name in PROFILES else "line"


def synthetic_demos(rng, tasks, T, image_size):
    """Random demos shaped like one side of a meta-batch, for timing: images (tasks, T, H, W, 3) in
    [0, 1), states (tasks, T, 6), torques (tasks, T, 2), all float32."""
    return (rng.random((tasks, T, image_size, image_size, 3), dtype=np.float32),
            rng.standard_normal((tasks, T, 6), dtype=np.float32),
            rng.standard_normal((tasks, T, 2), dtype=np.float32))


def bench_setup(profile, image_size, T=20, **overrides):
    """(method, net_cfg, params, rng) for timing a profile or line (`timed_config`, with overridden fields)
    on synthetic data of T frames; ValueError if its meta-iteration would not fit in memory."""
    method = methods.of(dataclasses.replace(timed_config(profile), **overrides))
    method.refuse_ignored(overrides)           # --inner-steps for the LSTM would be timed and do nothing
    rng = np.random.default_rng(0)
    net_cfg = method.network_config(image_size)
    method.check(net_cfg)
    cli.check_memory(method.memory_bytes(net_cfg), f"the {method.cfg.method} policy's "
                     f"{method.parameter_count(net_cfg):,} parameters and what a meta-iteration keeps of them",
                     "use a smaller --lstm-units" if "--lstm-units" in method.width_flags else
                     "time a smaller profile or line")
    tasks = method.cfg.meta_batch
    holds, less = method.meta_batch_words(net_cfg)
    cli.check_memory(method.memory_bytes(net_cfg) + tasks * method.task_bytes(net_cfg, T),
                     f"a meta-batch of {tasks} tasks ({holds}), beside the parameters", f"use a smaller --meta-batch{less}")
    return method, net_cfg, method.init_params(net_cfg, rng), rng


def bench_meta_iteration(iterations=20, profile="default", T=20, image_size=32, blas_threads=None, peer=None,
                         **overrides):
    """Median seconds per meta-iteration (the gradient of one meta-batch: for mil second order, over
    cfg.shards processes) on synthetic data, and GFLOP/s (`meta_gradient_flops`) beside the ceiling:
    the rate of a float32 1024 x 1024 matrix product (`sgemm_rate`) on as many cores as the iteration
    uses (its processes x their BLAS threads), the median of products timed just before and just after
    the iterations. (Not between them: OpenBLAS's threads spin for a while after a product, and would
    take a core from the next iteration's other process.)

    blas_threads: BLAS threads of this process (default 1, as every training process keeps: `train`,
        each shard of `oneshot.maml.shards`, Figure 2's runs); more, to see what they would buy.
    peer: None, or "torch" or "jax": time the same meta-gradient in that library (`peers`) instead of
        ours, on all the cores. (Not alternately in one process: each one's threads spin for a while
        after its work and slow the other down; run the two commands alternately instead.)
    """
    host.tune_malloc()
    method, net_cfg, params, rng = bench_setup(profile, image_size, T, **overrides)
    cfg = method.cfg
    if not method.learns:
        raise ValueError(f"the {cfg.method} policy has no meta-iteration to time")
    cores = os.cpu_count() or 1
    threads = blas_threads or 1
    host.blas_threads(threads)
    ceiling_threads = min(cores, method.shards * threads)
    B, pool = cfg.meta_batch, None
    if peer is not None:
        if not method.adapts:
            raise ValueError("--peer times MIL's meta-gradient, not a baseline's (drop --method, or time a "
                             "line of MIL)")
        peer_step, ceiling_threads = peers.meta_gradient(peer, net_cfg, method.inner), cores

    def step(a, e):
        return peer_step(params, a, e) if peer else method.meta_gradient(params, a, e, pool)

    host.blas_threads(ceiling_threads)
    ceilings = [sgemm_rate()]
    host.blas_threads(threads)
    if peer is None:
        pool = method.make_pool()
    times = []
    try:
        for _ in tqdm(range(iterations + 2), desc="meta-iterations (2 to warm up)", leave=False):
            a, e = synthetic_demos(rng, B, T, image_size), synthetic_demos(rng, B, T, image_size)
            t = time.perf_counter()
            step(a, e)
            times.append(time.perf_counter() - t)
    finally:
        if pool is not None:
            pool.close()
    host.blas_threads(ceiling_threads)
    ceilings.append(sgemm_rate())
    s, ceiling = float(np.median(times[2:])), float(np.median(ceilings))
    flops = method.meta_gradient_flops(net_cfg, T, B)
    inner_loop = {"inner_steps": cfg.inner_steps, "inner_params": cfg.inner_params,
                  "first_order": cfg.first_order} if method.adapts else {}          # a baseline has none
    result = {timed_key(profile): profile, "method": cfg.method, "meta_batch": B, **inner_loop, "T": T,
              "image_size": image_size, "shards": method.shards, "blas_threads": threads,
              "seconds_per_iteration": round(s, 4),
              "gflop_per_iteration": round(flops / 1e9, 2), "gflop_per_second": round(flops / 1e9 / s, 1),
              "ceiling_gflop_per_second": round(ceiling, 1), "ceiling_cores": ceiling_threads,
              "percent_of_ceiling": round(100 * flops / 1e9 / s / ceiling, 1)}
    if result["percent_of_ceiling"] > 100:
        result["warning"] = (f"above 100% of the ceiling: other work shared the cores while it was measured "
                             f"({', '.join(f'{c:.0f}' for c in ceilings)} GFLOP/s before and after); time it "
                             f"with the cores otherwise idle")
    if peer is not None:
        result.update({"peer": peer, "shards": 1, "blas_threads": None})
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
