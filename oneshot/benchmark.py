"""Speed and quality benchmarks: `python -m oneshot.benchmark {expert,collect,maml} --help`.

These measure what tests should not time: medians of repeated runs on this machine.
    expert   iLQG solve time (median over scenes) and the expert's success rate over many scenes
    collect  wall time to collect a dataset of demonstrations with all cores
    maml     seconds per second-order meta-iteration, GFLOP/s and peak memory
"""
import argparse
import json
import os
import resource
import sys
import time

import numpy as np
from tqdm import tqdm

from oneshot import collect, expert
from oneshot.world import ReachWorld, WorldConfig


def bench_expert(scenes=500, seed=0):
    """iLQG plan times and expert success over `scenes` random scenes (both colour splits)."""
    plan_s, iterations, successes = [], [], 0
    for i in tqdm(range(scenes), desc="expert", unit="scene"):
        world = ReachWorld(WorldConfig(split="train" if i % 4 else "heldout"))
        _, info = world.reset(seed=seed + i)
        t0 = time.perf_counter()
        result = expert.plan(world.state, info["target_position"], world.config.arm, world.config.horizon)
        plan_s.append(time.perf_counter() - t0)
        iterations.append(result.iterations)
        successes += expert.demonstrate(world, seed=seed + i)["success"]
    return {"scenes": scenes, "expert_success_rate": successes / scenes,
            "ilqg_solve_s_median": float(np.median(plan_s)), "ilqg_solve_s_p90": float(np.percentile(plan_s, 90)),
            "ilqg_iterations_median": float(np.median(iterations))}


def bench_collect(demos=1000, workers=None):
    """Wall time to collect about `demos` demonstrations (all 36 training colours) with `workers` processes."""
    tasks = 36
    per_task = -(-demos // tasks)
    t0 = time.perf_counter()
    d = collect.collect(tasks, per_task, "train", 0, workers, progress=True)
    seconds = time.perf_counter() - t0
    return {"demos": tasks * per_task, "workers": workers or os.cpu_count(), "seconds": round(seconds, 2),
            "demos_per_second": round(tasks * per_task / seconds, 1),
            "expert_success_rate": d["metadata"]["expert_success_rate"]}


def peak_memory_mb():
    """Peak resident memory (MB) of this process and of the largest of its finished worker processes."""
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024)


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m oneshot.benchmark", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    e = sub.add_parser("expert", help="iLQG solve time and expert success rate")
    e.add_argument("--scenes", type=int, default=500)
    c = sub.add_parser("collect", help="time to collect demonstrations")
    c.add_argument("--demos", type=int, default=1000)
    c.add_argument("--workers", type=int, default=None)
    m = sub.add_parser("maml", help="seconds per second-order meta-iteration")
    m.add_argument("--iterations", type=int, default=20)
    m.add_argument("--profile", default="default")
    m.add_argument("--first-order", action="store_true", help="time the first-order approximation")
    args = p.parse_args(argv)
    if args.what == "expert":
        result = bench_expert(args.scenes)
    elif args.what == "collect":
        result = bench_collect(args.demos, args.workers)
    else:
        from oneshot.train import bench_meta_iteration
        result = bench_meta_iteration(args.iterations, args.profile,
                                      **({"first_order": True} if args.first_order else {}))
    main_mb, worker_mb = peak_memory_mb()
    result["peak_memory_mb"] = round(main_mb, 1)
    result["peak_worker_memory_mb"] = round(worker_mb, 1)
    json.dump(result, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
