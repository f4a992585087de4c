"""Speed and quality benchmarks: `python -m oneshot.benchmark {expert,collect,maml,privileged} --help`.

These measure what tests should not time: medians of repeated runs on this machine.
    maml        seconds per meta-iteration, GFLOP/s against the machine's matrix-product ceiling measured
                in the same run, memory; the same work in PyTorch or JAX (--peer); where the time goes
                (--breakdown)
    expert      iLQG solve time (median over scenes) and the expert's success rate over many scenes
    collect     wall time to collect a dataset of demonstrations with all cores
    privileged  ceilings for the policy network: plain behavioural cloning on all meta-training
                demos when the policy is GIVEN what one-shot imitation must infer (the target's position,
                or its colour), scored on validation colours. If these are high, what remains hard is the
                one-shot identification of the colour, i.e. meta-learning itself.
"""
import argparse
import json
import os
import sys


from oneshot.maml import shards
from oneshot import methods
from oneshot.tools import cli, host
from oneshot.world import palette
from oneshot.methods.mil import INNER_PARAMS
from oneshot.experiments.lines import LINES
from oneshot.training.config import PROFILES
from oneshot.world.reach import WorldConfig


from oneshot.benchmark import peers
from oneshot.benchmark.expert import bench_collect, bench_expert
from oneshot.benchmark.breakdown import bench_breakdown
from oneshot.benchmark.maml import bench_meta_iteration
from oneshot.benchmark.privileged import bench_privileged


def _threads(text):
    """An argparse type: BLAS threads, 1 to this machine's cores (more would be recorded, not run)."""
    cores = os.cpu_count() or 1
    value = cli.positive_int(text)
    if value > cores:
        raise argparse.ArgumentTypeError(f"expected 1 to {cores} (this machine's cores); got {text!r}")
    return value


def main(argv=None):
    p = cli.Parser(prog="python -m oneshot.benchmark", description=__doc__,
                   formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="what", required=True)
    e = sub.add_parser("expert", help="iLQG solve time and expert success rate")
    e.add_argument("--scenes", type=cli.positive_int, default=500,
                   help="random scenes to plan and run the expert in (default 500)")
    c = sub.add_parser("collect", help="time to collect demonstrations")
    c.add_argument("--demos", type=cli.positive_int, default=1000, help="demonstrations to collect (default 1000; at least 2 per training "
                                                                        "colour are collected)")
    c.add_argument("--workers", type=cli.positive_int, default=None, help="processes (default and at most: the cores)")
    m = sub.add_parser("maml", help="seconds per second-order meta-iteration")
    m.add_argument("--iterations", type=cli.positive_int, default=20,
                   help="meta-iterations timed; the median is reported (default 20)")
    timed = m.add_mutually_exclusive_group()
    timed.add_argument("--profile", choices=sorted(PROFILES), default=None,
                       help="the training profile whose meta-iteration is timed (default: default)")
    timed.add_argument("--line", choices=[n for n, c in sorted(LINES.items()) if methods.REGISTRY[c.method].learns],
                       default=None, metavar="LINE",
                       help="time a line of the Figure 2 sweeps instead (oneshot/experiments/lines.py, e.g. "
                            "mil-released+widths-flat), as a sweep trains it: one process, one BLAS thread")
    m.add_argument("--method", choices=[n for n, m in methods.REGISTRY.items() if m.learns], default=None,
                   help="time a baseline's iteration (same meta-batch, trunk and widths) instead of MIL's")
    m.add_argument("--lstm-units", type=cli.positive_int, default=None, help="override the LSTM baseline's width")
    m.add_argument("--first-order", action="store_true", help="time the first-order approximation")
    m.add_argument("--inner-steps", type=cli.non_negative_int, default=None, help="override the profile's inner steps")
    m.add_argument("--inner-params", choices=sorted(INNER_PARAMS), default=None,
                   help="override which parameters the inner steps adapt")
    m.add_argument("--meta-batch", type=cli.positive_int, default=None,
                   help="override the profile's (line's) meta-batch")
    m.add_argument("--shards", type=cli.positive_int, default=None,
                   help="override the profile's (line's) shards (processes sharing each meta-gradient; "
                        "1 = one process)")
    m.add_argument("--blas-threads", type=_threads, default=None,
                   help="BLAS threads of the training process (default 1, as training keeps; more, up to the "
                        "cores, to see what they would buy)")
    m.add_argument("--peer", choices=sorted(peers.PEERS), default=None,
                   help="time the same second-order meta-gradient in PyTorch or JAX instead of ours, on all the "
                        "cores (pip install -e .[peers]); run it and ours alternately to compare")
    m.add_argument("--breakdown", action="store_true",
                   help="instead: where the time of one process goes (the convolutions' matrix products and "
                        "their transposes, im2col/col2im, other layer primitives, autograd's Python, the "
                        "exchanges between processes, the evaluation rollouts)")
    v = sub.add_parser("privileged", help="ceiling: behavioural cloning given the target's position or colour")
    v.add_argument("--given", choices=("position", "colour"), default="colour",
                   help="what the policy is given that one-shot imitation must infer (default: colour)")
    v.add_argument("--steps", type=cli.positive_int, default=3000, help="behavioural-cloning steps (default 3000)")
    v.add_argument("--trials", type=cli.positive_int, default=60, help="trials on validation colours (default 60)")
    v.add_argument("--feature-points", action="store_true", help="feature points instead of a flattened trunk")
    v.add_argument("--train-data", default="data/train.npz", help="meta-training demonstrations (default data/train.npz)")
    v.add_argument("--seed", type=cli.non_negative_int, default=0, help="parameters, batches and scenes (default 0)")
    sub.metavar = "{" + ",".join(sub.choices) + "}"      # named so in the error when none is given
    args = p.parse_args(argv)
    world = WorldConfig()                    # the frames and images the benchmarks time
    try:                                     # what must fit in memory, before the work
        if args.what == "collect":
            tasks = len(palette.split_colours("train"))
            cli.check_memory(cli.dataset_bytes(tasks, -(-args.demos // tasks), world.horizon, world.image_size,
                                               world.n_objects), f"{args.demos} demos", "use fewer --demos")
        # (maml's meta-batch, images and activations: `bench_setup`, once the timed config is known)
    except ValueError as error:
        sub.choices[args.what].error(str(error))
    if args.what == "expert":
        result = bench_expert(args.scenes)
    elif args.what == "collect":
        cores = os.cpu_count() or 1
        result = bench_collect(args.demos, min(args.workers or cores, cores))
    elif args.what == "privileged":
        host.blas_threads(1)                 # as training keeps (`oneshot.tools.host`)
        result = bench_privileged(args.given, args.steps, trials=args.trials, feature_points=args.feature_points,
                                  seed=args.seed, train_data=args.train_data)
    else:
        overrides = {k: v for k, v in (("first_order", args.first_order or None), ("inner_steps", args.inner_steps),
                                       ("inner_params", args.inner_params), ("meta_batch", args.meta_batch),
                                       ("shards", args.shards), ("method", args.method),
                                       ("lstm_units", args.lstm_units)) if v is not None}
        timed = args.line or args.profile or "default"
        if args.line and args.method:          # a line names its method
            m.error(f"argument --method: the line {args.line} names its method; drop --method (or --line)")
        if args.line:                        # as fig2 trains a line: one process (of one BLAS thread)
            overrides.setdefault("shards", 1)
        if args.breakdown:
            if args.peer:
                m.error("--peer times whole meta-iterations; drop --breakdown")
            result = bench_breakdown(args.iterations, timed, **overrides)
        else:
            try:
                peers.require(args.peer) if args.peer else None
            except ValueError as error:
                m.error(f"argument --peer: {error}")
            result = bench_meta_iteration(args.iterations, timed, blas_threads=args.blas_threads,
                                          peer=args.peer, **overrides)
    main_mb, worker_mb = host.peak_memory_mb()
    result["peak_memory_mb"] = round(main_mb, 1)
    result["peak_worker_memory_mb"] = round(worker_mb, 1)
    result["machine"] = host.machine()
    json.dump(result, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    cli.run(main, failures=(shards.ShardError,))
