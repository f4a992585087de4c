"""The paper's experiments (Section IV): `python -m oneshot.experiments fig2 --profile quick|paper|...`.

Figure 2: one-shot success against the size of the meta-training dataset, one line per method, each
run scored on the profile's split (`oneshot.experiments.fig2`):

    python -m oneshot.experiments fig2 --profile quick                    # 2 runs at a time, this machine
    python -m oneshot.experiments fig2 --profile paper --seeds 0          # one seed's figure first
    python -m oneshot.experiments fig2 --profile paper --sizes 2304       # one size's point first
    python -m oneshot.experiments fig2 --profile ablation --lines mil-released --seeds 0   # one run again
    python -m oneshot.experiments fig2 --profile paper --local-cluster 4   # Dask, pip install ".[cluster]"
    python -m oneshot.experiments fig2 --profile paper --scheduler tcp://host:8786
    python -m oneshot.experiments fig2 --profile paper --compare results/fig2_paper   # check a reproduction
    python -m oneshot.experiments summarise results/fig2_paper-validation   # summary, figure from runs.csv
    python -m oneshot.experiments seeds results/default_seeds/seed*_test.json   # one recipe over its seeds
    python -m oneshot.experiments difference results/fig2_paper-2304 mil-released+widths-flat mil-conv0  # a - b
    python -m oneshot.experiments fig2 --profile ablation --data-only     # its datasets only
    python -m oneshot.experiments ship --profile ablation --line L --seed 0 --out F.npz   # a run as a policy
    python -m oneshot.experiments scenes results/fig2_ablation/scenes   # learnt the task, or its scenes?

It writes `results/fig2_<profile>/` where it runs (or `--out`): runs.csv (one row per finished run),
summary.json (per line and size: the mean over seeds and its 95% interval over seeds and scored
colours, paired differences between lines; `oneshot.experiments.stats`) and fig2.png (pip install
".[plots]"), once every run of the profile has finished; `--seeds 0` does the runs of seed 0 alone and
writes summary_seeds0.json and fig2_seeds0.png, and `--lines L ...` (with `--seeds`: one run) its own
summary_<...>_L.json, and `--sizes N ...` (in demonstrations) its own summary_<...>_sizesN.json.
Each run works in `runs/fig2/<run id>/` (the run id names everything a run depends on). Run the
same command again to resume: done runs are skipped, interrupted ones continue from their own
checkpoints; rows this work folder did not produce (e.g. the committed ones of a clone) are run again,
never counted as done.

A sweep takes any `concurrent.futures.Executor` (a process pool by default; Dask's
`Client.get_executor()`), so the function that performs one run, `run_fn(spec, run_dir, context)`, must
be a module-level function (it is pickled) and write only inside its `run_dir` (Figure 2's `run_one`
also reads a sibling folder: the run a longer line continues, `lines.LONGER`).
"""
import argparse
import contextlib
import os
import shlex
import sys

from oneshot.experiments.difference import add_difference_command, run_difference_command
from oneshot.experiments.fig2 import PROFILES, ensure_data, load_results, plan, run_context, run_one
from oneshot.experiments.figure import PLOTS, plot
from oneshot.experiments.folders import check_comparable, check_data, check_finished, check_results_folder, check_work_data
from oneshot.experiments.lines import LABELS, LINES
from oneshot.experiments.parts import narrow
from oneshot import methods
from oneshot.experiments.rows import read_rows
from oneshot.experiments.scenes import add_scenes_command, run_scenes_command
from oneshot.experiments.ship import add_ship_command, run_ship_command
from oneshot.experiments.summary import compare, pool_evaluations, read_evaluations, summarise, write_summary
from oneshot.experiments.sweep import SweepLocked, done_rows, sweep
from oneshot.tools import cli, files

# Optional extras: the sweep runs without them and says which one a flag or the plot needs.
try:
    import distributed                         # pip install ".[cluster]": --scheduler, --local-cluster
except ImportError:
    distributed = None


SCHEDULER_TIMEOUT = "10s"     # how long to try a Dask scheduler before saying it cannot be reached


def _executor(args, stack):
    """The executor the flags ask for (None: the sweep's own process pool)."""
    if args.scheduler or args.local_cluster:
        cluster = args.scheduler or stack.enter_context(
            distributed.LocalCluster(n_workers=args.local_cluster, threads_per_worker=1, processes=True))
        client = stack.enter_context(distributed.Client(cluster, timeout=SCHEDULER_TIMEOUT))
        print(f"Dask scheduler {client.scheduler.address}: {len(client.scheduler_info()['workers'])} workers",
              file=sys.stderr)
        return client.get_executor(pure=False)
    return None


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    p = cli.Parser(prog="python -m oneshot.experiments", description=__doc__,
                formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = p.add_subparsers(dest="experiment", required=True)
    f = commands.add_parser("fig2", help="one-shot success vs. meta-training dataset size, per method")
    f.add_argument("--profile", choices=sorted(PROFILES), default="quick", help="named sweep (default: quick)")
    f.add_argument("--out", type=cli.writable_folder, default=None,
                   help="results folder (default: results/fig2_<profile>, here)")
    f.add_argument("--work", type=cli.writable_folder, default=os.path.join("runs", "fig2"),
                   help="runs' work folders (default: runs/fig2)")
    f.add_argument("--data", type=cli.writable_folder, default="data/fig2",
                   help="datasets folder, given to every run (default: data/fig2)")
    f.add_argument("--seeds", type=int, nargs="+", default=None, metavar="S",
                   help="only these of the profile's seeds (default: all of them); their summary and figure "
                        "are summary_seeds<S>.json and fig2_seeds<S>.png, beside the whole profile's")
    f.add_argument("--lines", nargs="+", default=None, metavar="LINE",
                   help="only these of the profile's lines (default: all of them), e.g. to reproduce one run: "
                        "--lines mil-released --seeds 0; their summary and figure are summary[_seeds<S>]_<line>_"
                        "<line>....json and fig2[...]_<line>....png (many lines: _<N>lines-<hash>)")
    f.add_argument("--sizes", type=int, nargs="+", default=None, metavar="N",
                   help="only these of the profile's sizes, in demonstrations (colours x demos per colour; "
                        "default: all of them), e.g. --sizes 2304 to do one point's runs first; their summary and "
                        "figure are summary[_seeds<S>][_<line>...]_sizes<N>.json and fig2[...]_sizes<N>.png")
    f.add_argument("--no-progress", action="store_true", help="no progress bar")
    f.add_argument("--data-only", action="store_true",
                   help="collect the profile's datasets into --data and stop (e.g. to evaluate a shipped policy)")
    f.add_argument("--keep-rows", action="store_true",
                   help="count the rows already in the results folder as done, though this work folder did not "
                        "produce them: to continue your own sweep after its work folder is gone (never to reproduce)")
    f.add_argument("--compare", default=None, metavar="RESULTS",
                   help="after the sweep, compare its results point by point with another results folder (e.g. "
                        "the committed results/fig2_<profile> of a clone): does each point agree within its interval?")
    where = f.add_mutually_exclusive_group()
    where.add_argument("--workers", type=cli.positive_int, default=None,
                       help="runs at a time in a process pool (default 2; at most the cores)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help='run on a running Dask scheduler, e.g. tcp://host:8786 (pip install ".[cluster]")')
    where.add_argument("--local-cluster", type=int, default=None, metavar="N",
                       help='start a Dask cluster of N one-thread worker processes here (pip install ".[cluster]")')
    r = commands.add_parser("summarise", help="the summary and figure of a results folder from its runs.csv, "
                                              "with today's intervals (no run is done)")
    r.add_argument("results", help="a results folder holding runs.csv and summary.json, e.g. results/fig2_paper-validation")
    s = commands.add_parser("seeds", help="one recipe's policies, trained with different seeds and scored by "
                                          "evaluate --json on one split: their mean with its interval over seeds "
                                          "and colours")
    s.add_argument("evaluations", nargs="+", metavar="JSON",
                   help="`python -m oneshot.evaluate CKPT --split S --json FILE` results, one per training seed")
    s.add_argument("--out", type=cli.writable_file, default=None, help="also write the summary here (JSON)")
    extra = {name: (add(commands), run) for name, add, run in [("ship", add_ship_command, run_ship_command), (
        "difference", add_difference_command, run_difference_command), ("scenes", add_scenes_command, run_scenes_command)]}
    commands.metavar = "{" + ",".join(commands.choices) + "}"    # named so in the error when none is given
    args = p.parse_args(argv)
    if args.experiment in extra:                # a command of its own module: its parser says its errors
        parser, run = extra[args.experiment]
        return run(args, parser)
    if args.experiment == "summarise":
        return _summarise(args.results, argv)
    if args.experiment == "seeds":
        return _seeds(args.evaluations, args.out, argv)
    if args.local_cluster is not None and not 1 <= args.local_cluster <= (os.cpu_count() or 1):
        f.error(f"argument --local-cluster: this machine has {os.cpu_count() or 1} cores: 1 to that many workers "
                f"(a cluster of more machines: --scheduler); got {args.local_cluster}")
    if (args.scheduler or args.local_cluster) and distributed is None:
        f.error(f"{'--scheduler' if args.scheduler else '--local-cluster'} needs Dask: pip install \".[cluster]\"")
    try:
        cfg, part, words = narrow(PROFILES[args.profile], args.seeds, args.lines, args.sizes)
    except ValueError as e:
        f.error(str(e))
    if args.compare:                           # before the sweep: a compare folder to read afterwards
        if not os.path.isfile(os.path.join(args.compare, "runs.csv")):
            f.error(f"argument --compare: {args.compare} holds no runs.csv; name a sweep's results folder, e.g. "
                    f"results/fig2_{cfg.name}")
        try:
            check_comparable(cfg, args.compare, read_rows(os.path.join(args.compare, "runs.csv"),
                                                          fix="name another results folder to compare with"))
        except ValueError as e:
            f.error(f"argument --compare: {e}")
    out = args.out or os.path.join("results", f"fig2_{cfg.name}")
    try:
        cli.writable_folder(out)
        check_results_folder(PROFILES[args.profile], out)
    except (argparse.ArgumentTypeError, ValueError) as e:
        f.error(f"argument --out: {e}")
    if os.path.commonpath([os.path.realpath(out), os.path.realpath(args.work)]) == os.path.realpath(args.work):
        f.error(f"argument --out: {out} is in the sweep's work folder {args.work} (its runs' folders); "
                f"name a results folder outside it")
    runs = plan(cfg)
    done = done_rows(out, args.work, args.keep_rows)
    try:                                       # before collecting data that the runs would not use
        check_work_data(runs, args.work, run_context(cfg, args.data), done)
    except ValueError as e:
        f.error(f"argument --data: {e}")
    workers = min(args.workers or 2, os.cpu_count() or 1, len(runs))      # more would only share the cores
    sweeping = False
    try:                                       # (a plain kill stops the sweep as Ctrl-C does: `cli.run`)
        with contextlib.ExitStack() as stack:
            try:
                executor = _executor(args, stack)  # before any work: an unreachable scheduler fails now
            except (OSError, ValueError) as e:
                f.error(f"argument --scheduler: no Dask scheduler at {args.scheduler!r} ({e}); start one, or "
                        f"drop --scheduler to run here")
            check_data(cfg, args.data)         # before collecting the others: one wrong file is said at once
            ensure_data(cfg, args.data, progress=not args.no_progress)
            if args.data_only:
                print(f"the {cfg.name} profile's datasets are in {args.data}")
                return 0
            sweeping = True
            try:
                rows = sweep(runs, out, args.work, run_context(cfg, args.data), run_one, executor=executor,
                             progress=not args.no_progress, workers=workers, keep_rows=args.keep_rows)
            except SweepLocked as e:
                sys.exit(f"error: {e}")
    except KeyboardInterrupt as e:
        if not sweeping:                       # no run had started: collecting data (it says how far) or a cluster
            raise KeyboardInterrupt(str(e) or "interrupted before any run started: run the same command again") \
                from None
        done = done_rows(out, args.work, args.keep_rows)
        print(f"error: interrupted; {sum(r.run_id in done for r in runs)} of {len(runs)} runs finished "
              f"({os.path.join(out, 'runs.csv')}), the others continue from their checkpoints: run the same "
              f"command to resume", file=sys.stderr)
        return 130
    if len(rows) < len(runs):                  # a summary is of the whole sweep: the notebooks trust it
        print(f"{len(rows)} of {len(runs)} runs finished ({os.path.join(out, 'runs.csv')}); run the same "
              f"command again to finish the others: no summary or figure until then")
        return 1
    summary = summarise(rows, cfg, "python -m oneshot.experiments " + shlex.join(argv), _pairs(cfg.methods))
    write_summary(summary, os.path.join(out, f"summary{part}.json"))
    print(f"{len(rows)} of {len(runs)} runs finished: {os.path.join(out, 'runs.csv')}, "
          f"{os.path.join(out, f'summary{part}.json')}")
    if not PLOTS:
        print('fig2.png not drawn: the plot needs matplotlib (pip install ".[plots]")')
    elif rows:
        plot(summary, os.path.join(out, f"fig2{part}.png"), _labels(cfg.methods),
             title=f"Figure 2 ({cfg.name} profile, {words})")
        print(f"figure: {os.path.join(out, f'fig2{part}.png')}")
    if args.compare:
        return _compare(rows, args.compare)
    return 0


def _pairs(lines):
    """The paired differences a summary reports: every line that adapts minus every line that does not."""
    adapts = {line: methods.of(LINES[line]).adapts for line in lines}
    return [(a, b) for a in lines if adapts[a] for b in lines if not adapts[b]]


def _labels(lines=()):
    """The figure's legend: each line's label, or its name; `lines` (a profile's) first, in their order."""
    return {m: LABELS.get(m, m) for m in [*lines, *(m for m in LINES if m not in lines)]}


def _summarise(folder, argv):
    """Summarise a results folder again from its runs.csv, keeping its summary's config and command and
    recording this one (`summarise`, `plot`)."""
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"no such folder: {folder} (summarise takes a finished sweep's results folder, "
                                f"e.g. results/fig2_quick)")
    if not os.path.isfile(os.path.join(folder, "summary.json")):
        raise ValueError(f"{folder} holds no summary.json: summarise redoes a finished sweep's summary; finish the "
                         f"sweep first (run its fig2 command again)")
    rows, before = load_results(folder)
    if not rows:
        print(f"error: {folder} holds no runs.csv rows to summarise", file=sys.stderr)
        return 2
    config = dict(before.get("config") or {})          # none recorded (absent or null): {}
    check_finished(folder, rows, before)       # as fig2 does: a summary is of the whole sweep
    lines = [m for m in config.get("methods", LINES) if m in LINES]
    summary = summarise(rows, None, before.get("command"), _pairs(lines))
    config.setdefault("score", "validation")   # a sweep from before the test split scored what is now validation
    summary.update(config=config, summarised_by="python -m oneshot.experiments " + shlex.join(argv))
    write_summary(summary, os.path.join(folder, "summary.json"))
    print(f"{len(rows)} runs: {os.path.join(folder, 'summary.json')}")
    if PLOTS:
        n = len({r["seed"] for r in rows})
        name = f"{config['name']} profile, " if config.get("name") else ""     # none recorded: no name
        plot(summary, os.path.join(folder, "fig2.png"), _labels(lines),
             title=f"Figure 2 ({name}{n} seed{'s' * (n > 1)})")
        print(f"figure: {os.path.join(folder, 'fig2.png')}")
    return 0


def _seeds(paths, out, argv):
    """Print (and with --out write) the pooled evaluate results of one recipe's seeds (`pool_evaluations`)."""
    if out:
        cli.not_an_input(out, paths, "--out", "one of the results to pool")
        cli.replaces_only(out, lambda path: files.is_json_with(path, ("policies",)), "--out", "a summary of seeds --out")
    pooled = pool_evaluations(read_evaluations(paths), paths)
    pct = lambda x: f"{100 * x:.1f}%"
    for p in pooled["policies"]:
        print(f"training seed {p['training_seed']}: {pct(p['rate'])} ({p['successes']}/{p['trials']})  {p['file']}")
    print(f"{pooled['method']}, {pooled['split']} split ({pooled['colours']} colours x {pooled['trials_per_colour']} "
          f"trials), mean over {len(paths)} seeds: {pct(pooled['mean_rate'])} [{pct(pooled['ci_low'])}, "
          f"{pct(pooled['ci_high'])}] ({pooled['successes']}/{pooled['trials']}; seeds from {pct(pooled['min_rate'])} "
          f"to {pct(pooled['max_rate'])}; {pooled['interval']})")
    if out:
        write_summary(dict(pooled, command="python -m oneshot.experiments " + shlex.join(argv)), out)
        print(f"summary: {out}")
    return 0


def _compare(rows, folder):
    """Print, point by point, whether a sweep's rows agree with the results in `folder` within their
    interval (`summary.compare`); 0 if every shared point agrees, 1 if any does not, 2 if none is shared."""
    theirs = read_rows(os.path.join(folder, "runs.csv"), fix="name another results folder to compare with")
    table = compare(rows, theirs)
    if not table:
        print(f"error: {folder} holds no point of this sweep (no runs.csv rows of its lines and sizes)", file=sys.stderr)
        return 2
    pct = lambda x: f"{100 * x:5.1f}"
    print(f"\ncompared with {folder} (95% interval of the difference, seeds resampled, colours paired):")
    print(f"{'line':12s} {'size':>5s} {'here %':>7s} {'there %':>8s} {'difference':>24s}  verdict")
    for p in table:
        print(f"{p['method']:12s} {p['size']:5d} {pct(p['mine']):>7s} {pct(p['theirs']):>8s} "
              f"{pct(p['difference'])} [{pct(p['ci_low'])}, {pct(p['ci_high'])}]  "
              f"{'agrees' if p['agree'] else 'DIFFERS'}")
    differ = sum(not p["agree"] for p in table)
    print(f"{len(table) - differ} of {len(table)} points agree" + (f"; {differ} differ" if differ else ""))
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(cli.run(main))
