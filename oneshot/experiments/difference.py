"""The paired difference between two lines' one-shot success (Section IV's comparisons), from results
folders: a - b at each size both lines were run, with its 95% interval paired over the scored colours
and each line's seeds resampled (`stats.difference_interval`), as a sweep's summary pairs every line
that adapts with every line that does not. For the pairs a summary does not hold: two lines that both
adapt, or lines of two sweeps, scored on the same colours.

    python -m oneshot.experiments difference results/fig2_paper-2304 mil-released+widths-flat mil-conv0
    python -m oneshot.experiments difference results/fig2_lstm-2048 lstm-2048 lstm --b-results results/fig2_paper --seeds 0
"""
import json
import os

from oneshot.experiments.rows import read_rows
from oneshot.experiments.summary import summarise


def line_rows(folder, line, seeds=None):
    """The runs.csv rows of `line` in the results folder `folder` (a sweep's, finished or not), only
    `seeds` if given. ValueError names what the folder holds instead."""
    path = os.path.join(folder, "runs.csv")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"{folder} holds no runs.csv: name a sweep's results folder, e.g. results/fig2_paper")
    rows = read_rows(path, fix="restore it (git checkout), or name another results folder")
    mine = [r for r in rows if r["method"] == line]
    if not mine:
        held = sorted({r["method"] for r in rows})
        raise ValueError(f"{path} holds no runs of line {line!r} (its lines: {', '.join(held) or 'none'}); "
                         f"name one of them, or another results folder")
    if seeds is not None:
        mine = [r for r in mine if r["seed"] in seeds]
        if not mine:
            raise ValueError(f"{path} holds no runs of line {line!r} with seed(s) {', '.join(map(str, seeds))} "
                             f"(its seeds: {', '.join(map(str, sorted({r['seed'] for r in rows if r['method'] == line})))})")
    return mine


def _colours(rows):
    """The scored colours of rows (their notes' per_colour keys), as one sorted tuple per row."""
    return {tuple(sorted(json.loads(r["notes"]).get("per_colour", {}), key=int)) for r in rows}


def differences(a_rows, b_rows):
    """[{"a", "b", "size", "difference", "ci_low", "ci_high"}] of line a's rows minus line b's, at each
    size both have (`summary.summarise`'s pairs). The two must be different lines scored per colour on
    the same colours (so on one split); else ValueError saying so."""
    (a,), (b,) = {r["method"] for r in a_rows}, {r["method"] for r in b_rows}
    if a == b:
        raise ValueError(f"both are line {a!r}: to check one line's results against another sweep's, use fig2 "
                         f"--compare")
    colours = _colours(a_rows) | _colours(b_rows)
    if len(colours) != 1 or not next(iter(colours)):
        raise ValueError(f"{a} and {b} were not scored on the same colours, each counted per colour (runs.csv "
                         f"notes' per_colour), so their difference cannot be paired over colours: name results "
                         f"scored on one split (a validation and a test sweep never share a colour)")
    return summarise(a_rows + b_rows, pairs=[(a, b)])["differences"]


def add_difference_command(commands):
    """`python -m oneshot.experiments difference`'s parser, added to `commands` (argparse subparsers)."""
    d = commands.add_parser("difference", help="the paired difference a - b between two lines' success, with its "
                                               "interval, from results folders")
    d.add_argument("results", help="the results folder holding line a (and b, unless --b-results), e.g. "
                                   "results/fig2_paper")
    d.add_argument("a", help="a line, e.g. mil-released+widths-flat")
    d.add_argument("b", help="the line it is compared with, e.g. mil-conv0")
    d.add_argument("--b-results", default=None, metavar="RESULTS",
                   help="the results folder holding line b, if another sweep's (scored on the same colours)")
    d.add_argument("--seeds", type=int, nargs="+", default=None, metavar="S",
                   help="only these training seeds of both lines (default: every seed each has)")
    return d


def run_difference_command(args, parser):
    """Print a - b at each size both lines have; a missing line or seed, or lines scored on other colours,
    is a one-line error (exit 2). Returns 0."""
    try:
        a_rows = line_rows(args.results, args.a, args.seeds)
        b_rows = line_rows(args.b_results or args.results, args.b, args.seeds)
        table = differences(a_rows, b_rows)
    except (FileNotFoundError, ValueError) as e:
        parser.error(str(e))
    if not table:
        parser.error(f"{args.a} and {args.b} share no size: {args.a} at {sorted({r['size'] for r in a_rows})}, "
                     f"{args.b} at {sorted({r['size'] for r in b_rows})} demonstrations")
    pct = lambda x: f"{100 * x:+.1f}"
    seeds = lambda rows: ", ".join(str(r["seed"]) for r in sorted(rows, key=lambda r: r["seed"]))
    colours = len(json.loads(a_rows[0]["notes"])["per_colour"])
    print(f"{args.a} - {args.b}, in points, on the same {colours} colours (95% interval: colours paired, each "
          f"line's seeds resampled):")
    for d in table:
        print(f"  {d['size']:5d} demos: {pct(d['difference'])} [{pct(d['ci_low'])}, {pct(d['ci_high'])}]  "
              f"(seeds {seeds(r for r in a_rows if r['size'] == d['size'])} against "
              f"{seeds(r for r in b_rows if r['size'] == d['size'])})")
    return 0
