"""The expert and data collection: iLQG solve times, the expert's success, collection wall time
(`python -m oneshot.benchmark expert|collect`)."""
import os
import time

import numpy as np
from tqdm import tqdm

from oneshot.data import collection
from oneshot.expert import controller
from oneshot.world import palette
from oneshot.world.reach import ReachWorld, WorldConfig



def bench_expert(scenes=500, seed=0):
    """iLQG plan times and expert success over `scenes` random scenes (both colour splits)."""
    plan_s, iterations, successes = [], [], 0
    for i in tqdm(range(scenes), desc="expert", unit="scene"):
        world = ReachWorld(WorldConfig(split="train" if i % 4 else "validation"))
        _, info = world.reset(seed=seed + i)
        t0 = time.perf_counter()
        result = controller.plan(world.state, info["target_position"], world.config.arm, world.config.horizon)
        plan_s.append(time.perf_counter() - t0)
        iterations.append(result.iterations)
        successes += controller.demonstrate(world, seed=seed + i)["success"]
    return {"scenes": scenes, "expert_successes": int(successes), "expert_success_rate": successes / scenes,
            "ilqg_solve_s_median": float(np.median(plan_s)), "ilqg_solve_s_p90": float(np.percentile(plan_s, 90)),
            "ilqg_iterations_median": float(np.median(iterations))}


def bench_collect(demos=1000, workers=None):
    """Wall time to collect about `demos` demonstrations (every training colour, at least 2 demos each, as a
    dataset needs) with `workers` processes."""
    tasks = len(palette.split_colours("train"))
    per_task = max(2, -(-demos // tasks))
    t0 = time.perf_counter()
    d = collection.collect(tasks, per_task, "train", 0, workers, progress=True)
    seconds = time.perf_counter() - t0
    return {"demos": tasks * per_task, "workers": workers or os.cpu_count(), "seconds": round(seconds, 2),
            "demos_per_second": round(tasks * per_task / seconds, 1),
            "expert_success_rate": d["metadata"]["expert_success_rate"]}
