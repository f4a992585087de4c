"""Collect expert demonstrations into a dataset: `python -m oneshot.collect --help`.

N tasks (distinct target colours of one split) x K demos per task, each demo a fresh scene. Every
demo's scene seed is derived from (seed, task, demo, attempt), so the dataset, and the saved file
byte for byte, is the same whatever the number of worker processes (the time taken and the workers
are printed, not stored). A demo the expert fails is retried on a fresh scene and counted in the
metadata ("failed_attempts"); a horizon too short for the expert fails every scene, which is an
error (ExpertFailed) that asks for a longer one. Ctrl-C stops the workers and writes nothing.
"""
import argparse
import os
import time
from oneshot.expert import controller
from oneshot.tools import cli
from oneshot.world import palette
from oneshot.world.reach import WorldConfig
from oneshot.data import datasets
from oneshot.data.collection import collect, task_colours, unwritten


def main(argv=None):
    p = cli.Parser(prog="python -m oneshot.collect", description=__doc__,
                   formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True, type=cli.writable_file,
                   help="output .npz path (written atomically; checked before collecting)")
    p.add_argument("--split", choices=palette.SPLITS, default="train",
                   help="colours to draw tasks from: meta-training, validation or test (default: train)")
    p.add_argument("--tasks", type=cli.positive_int, default=36, help="number of tasks (distinct target colours)")
    p.add_argument("--demos", type=cli.at_least(2, " (MAML adapts on one demo and scores another)"), default=8,
                   help="demonstrations per task (at least 2)")
    p.add_argument("--seed", type=cli.non_negative_int, default=0,
                   help="seed; the same seed gives the same dataset")
    p.add_argument("--workers", type=cli.positive_int, default=None,
                   help="processes (default and at most: the cores, and the demos)")
    p.add_argument("--image-size", type=cli.at_least(8), default=32,
                   help="image side in pixels (default 32, the shipped policies' size)")
    p.add_argument("--palette", choices=palette.MODES, default="hues",
                   help="the colours: 'hues' (default: 36 meta-training, 12 validation, 24 test) or 'grid' (324, 108, 48; "
                        "oneshot.world.palette)")
    p.add_argument("--horizon", type=cli.at_least(5, " (success is judged on the final fifth)"), default=20,
                   help="time steps per demonstration")
    p.add_argument("--noise", type=cli.finite_non_negative_float, default=0.0,
                   help="DART noise: std (N m) of torque noise executed but not recorded (default 0)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (e.g. when the output goes to a log file)")
    args = p.parse_args(argv)
    # Everything that can be checked is checked before the work: the task count against the split,
    # and that the dataset fits in memory (not after building a job list and allocating terabytes).
    world_cfg = WorldConfig(image_size=args.image_size, horizon=args.horizon,
                            palette=palette.PaletteConfig(mode=args.palette))
    try:
        task_colours(args.tasks, args.split, args.seed, world_cfg.palette)
    except ValueError as e:
        p.error(f"argument --tasks: {e}")
    try:
        cli.replaces_only(args.out, datasets.is_dataset, "--out", "a dataset of demonstrations")
    except ValueError as e:
        p.error(str(e))
    try:
        cli.check_memory(cli.dataset_bytes(args.tasks, args.demos, args.horizon, args.image_size, world_cfg.n_objects),
                         f"{args.tasks} tasks x {args.demos} demos x {args.horizon} steps of "
                         f"{args.image_size}x{args.image_size} images",
                         "collect fewer --tasks or --demos, or use a smaller --horizon or --image-size")
    except ValueError as e:
        p.error(str(e))
    cores = os.cpu_count() or 1
    workers = min(args.workers or cores, cores, args.tasks * args.demos)   # more would only wait
    start = time.perf_counter()
    with unwritten(args.out):
        dataset = collect(args.tasks, args.demos, args.split, args.seed, workers, world_cfg,
                          controller.ExpertConfig(action_noise=args.noise),
                          progress=not args.no_progress)
    seconds = time.perf_counter() - start
    meta = datasets.save(dataset, args.out)
    print(f"wrote {args.out}: {args.tasks} tasks x {args.demos} demos ({args.split} colours) with {workers} "
          f"process{'es' if workers > 1 else ''} in {seconds:.2f} s; expert success "
          f"{meta['expert_success_rate']:.3f} ({meta['failed_attempts']} failed attempts retried)")


if __name__ == "__main__":
    cli.run(main)        # ExpertFailed is a ValueError: exit status 2, with its one line
