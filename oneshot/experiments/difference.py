"""The paired difference between two lines' one-shot success (Section IV's comparisons), from results
folders: a - b at each size both lines were run, with its 95% interval paired over the scored colours
and each line's seeds resampled (`stats.difference_interval`), as a sweep's summary pairs every line
that adapts with every line that does not. For the pairs a summary does not hold: two lines that both
adapt, or lines of two sweeps (one line in two, too), scored on the same colours.

    python -m oneshot.experiments difference results/fig2_paper-2304 mil-released+widths-flat mil-conv0
    python -m oneshot.experiments difference results/fig2_lstm-2048 lstm-2048 lstm --b-results results/fig2_paper --seeds 0
"""
import json
import os

from oneshot.experiments import stats
from oneshot.experiments.rows import read_rows
from oneshot.experiments.summary import check_point


def line_rows(folder, line):
    """The runs.csv rows of `line` in the results folder `folder` (a sweep's, finished or not).
    FileNotFoundError or ValueError names what the folder holds instead."""
    path = os.path.join(folder, "runs.csv")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{folder} holds no runs.csv: name a sweep's results folder, e.g. results/fig2_paper")
    rows = read_rows(path, fix="restore it (git checkout), or name another results folder")
    mine = [r for r in rows if r["method"] == line]
    if not mine:
        held = ", ".join(sorted({r["method"] for r in rows}))
        raise ValueError(f"{path} holds no runs of line {line!r} ({f'its lines: {held}' if held else 'no runs yet'}); "
                         f"name a line it holds, or another results folder")
    return mine


def _point(rows, line, size, seeds):
    """(successes, trials) per seed and colour (`stats.counts`) of `line`'s runs at `size`, only `seeds`
    if given, and its colours: one configuration, each seed once, counted per colour; else ValueError."""
    here = sorted((r for r in rows if r["size"] == size), key=lambda r: r["seed"])
    if seeds is not None:
        missing = sorted(set(seeds) - {r["seed"] for r in here})
        if missing:
            raise ValueError(f"{line} has no run of seed(s) {', '.join(map(str, missing))} at {size} demonstrations "
                             f"(its seeds there: {', '.join(str(r['seed']) for r in here)}); name seeds both lines have")
        here = [r for r in here if r["seed"] in seeds]
    check_point(line, size, here, "name results of one configuration, each seed once (one sweep's runs.csv)")
    colours = {tuple(sorted(json.loads(r["notes"]).get("per_colour", {}), key=int)) for r in here}
    counts = stats.counts(here)
    if len(colours) != 1 or counts[0].shape[1] != len(next(iter(colours))):
        raise ValueError(f"{line}'s runs at {size} demonstrations hold no per-colour counts of one set of colours "
                         f"(runs.csv notes' per_colour): their difference cannot be paired over colours")
    return counts, next(iter(colours)), here[0]["iterations"], [r["seed"] for r in here]


def differences(a_rows, b_rows, seeds=None):
    """[{"size", "difference", "ci_low", "ci_high", "a", "b"}] of a's rows minus b's at each size both have,
    "a" and "b" each {"seeds", "iterations"}: the two scored per colour on the same colours (so on one
    split), `seeds` only if given; else ValueError saying what does not pair."""
    a, b = a_rows[0]["method"], b_rows[0]["method"]
    sizes = sorted({r["size"] for r in a_rows} & {r["size"] for r in b_rows})
    if not sizes:
        raise ValueError(f"{a} and {b} share no size: {a} at {sorted({r['size'] for r in a_rows})}, {b} at "
                         f"{sorted({r['size'] for r in b_rows})} demonstrations; name lines run at one size")
    out = []
    for size in sizes:
        ca, colours_a, ia, sa = _point(a_rows, a, size, seeds)
        cb, colours_b, ib, sb = _point(b_rows, b, size, seeds)
        if colours_a != colours_b:
            raise ValueError(f"{a} and {b} were scored on other colours ({len(colours_a)} and {len(colours_b)}"
                             f"{', not the same ones' if len(colours_a) == len(colours_b) else ''}): name results "
                             f"scored on one split")
        d, lo, hi = stats.difference_interval(ca, cb)
        out.append({"size": size, "difference": d, "ci_low": lo, "ci_high": hi,
                    "a": {"seeds": sa, "iterations": ia}, "b": {"seeds": sb, "iterations": ib}, "colours": len(colours_a)})
    return out


def add_difference_command(commands):
    """`python -m oneshot.experiments difference`'s parser, added to `commands` (argparse subparsers)."""
    d = commands.add_parser("difference", help="the paired difference a - b between two lines' success, with its "
                                               "interval, from results folders")
    d.add_argument("results", help="the results folder holding line a (and b, unless --b-results), e.g. "
                                   "results/fig2_paper")
    d.add_argument("a", help="a line, e.g. mil-released+widths-flat")
    d.add_argument("b", help="the line it is compared with, e.g. mil-conv0 (a's own line, with --b-results)")
    d.add_argument("--b-results", default=None, metavar="RESULTS",
                   help="the results folder holding line b, if another sweep's (scored on the same colours)")
    d.add_argument("--seeds", type=int, nargs="+", default=None, metavar="S",
                   help="only these training seeds, which both lines must have (default: every seed each has)")
    return d


def run_difference_command(args, parser):
    """Print a - b at each size both lines have; what does not pair is a one-line error (exit 2). Returns 0."""
    there = args.results if args.b_results is None else args.b_results
    if args.a == args.b and os.path.realpath(there) == os.path.realpath(args.results):
        parser.error(f"a and b are both {args.a} of {args.results}: name two lines, or b's results folder with "
                     f"--b-results")
    try:
        table = differences(line_rows(args.results, args.a), line_rows(there, args.b), args.seeds)
    except (FileNotFoundError, ValueError) as e:
        parser.error(str(e))
    pct = lambda x: f"{100 * x:+.1f}"
    name = lambda line, folder: line if args.a != args.b else f"{line} ({folder})"
    print(f"{name(args.a, args.results)} - {name(args.b, there)}, in points, on the same {table[0]['colours']} "
          f"colours (95% interval: colours paired, each line's seeds resampled):")
    for d in table:
        differ = d["a"]["iterations"] != d["b"]["iterations"]       # another training budget: say so
        runs = [", ".join(map(str, p["seeds"])) + (f" at {p['iterations']} iterations" if differ else "")
                for p in (d["a"], d["b"])]
        print(f"  {d['size']:5d} demos: {pct(d['difference'])} [{pct(d['ci_low'])}, {pct(d['ci_high'])}]  "
              f"(seeds {runs[0]} against {runs[1]})")
    return 0
