"""Has a policy learnt the task, or its meta-training scenes? (docs/results.md, section 10.) A scene check
scores a policy on its own training colours twice, each trial adapted on one demonstration:

    python -m oneshot.evaluate CKPT --trials 5 --unadapted --demo-scenes --json X_demo_scenes.json
    python -m oneshot.evaluate CKPT --trials 5 --unadapted --json X_new_scenes.json

acting in the recorded scene of one of the demonstrations it meta-trained on, and in new scenes of the
same colours. A policy that learnt the task scores alike in both; one that memorised its scenes scores
high in them and low in new ones. This module pairs a folder's files by name (X_demo_scenes[S].json with
X_new_scenes[S].json, labelled X[S]) and draws the pairs, one row each:

    python -m oneshot.experiments scenes results/fig2_ablation/scenes     # -> results/fig2_ablation/scenes.png
"""
import os
import textwrap

from oneshot.experiments.figure import LINE_ROW, Figure
from oneshot.experiments.summary import read_evaluations
from oneshot.tools import cli
from oneshot.tools.files import atomic_write

DEMO, NEW = "_demo_scenes", "_new_scenes"


def read_pairs(folder):
    """([{"label", "demo": (successes, trials), "new": (successes, trials)}], unpaired): the training
    colours' scores of each pair of scene-check files in `folder`, in name order, and the names of the JSON
    files left unpaired (e.g. evaluate's --other-colour-demo control, which has no new-scene twin).
    ValueError names a file that is not the check its name says, or a pair that is not one policy's two
    checks (one command, but --demo-scenes)."""
    names = sorted(n for n in os.listdir(folder) if n.endswith(".json") and os.path.isfile(os.path.join(folder, n)))
    for name in names:
        if name.count(DEMO) + name.count(NEW) > 1:
            raise ValueError(f"{name} names its check twice: name each check X{DEMO}[S].json or X{NEW}[S].json")
    firsts = [n for n in names if DEMO in n and n.replace(DEMO, NEW) in names]
    twins = [n.replace(DEMO, NEW) for n in firsts]
    pairs = []
    for name, twin in zip(firsts, twins):
        demo, new = read_evaluations([os.path.join(folder, n) for n in (name, twin)])
        (demo_counts, demo_policy), (new_counts, new_policy) = _check(demo, name, True), _check(new, twin, False)
        if demo_policy != new_policy:
            differ = sorted(k for k in {**demo_policy, **new_policy} if demo_policy.get(k) != new_policy.get(k))
            raise ValueError(f"{name} and {twin} differ in {', '.join(differ)}: a pair is one policy's two checks, "
                             f"one evaluate command but --demo-scenes")
        pairs.append({"label": name.replace(DEMO, "")[:-len(".json")] or name, "demo": demo_counts, "new": new_counts})
    return pairs, [n for n in names if n not in firsts and n not in twins]


def _check(result, name, demo_scenes):
    """((successes, trials) on the training colours, the policy it records but --demo-scenes) of an
    evaluate --json result, checked to be the check its name says (in the demonstrations' scenes or not,
    not the other-colour control); else ValueError."""
    try:
        policy, train = dict(result["policy"]), result["train"]
        recipe = {k: v for k, v in policy["recipe"].items() if k != "demo_scenes"}
        counts = train["successes"], train["trials"]
        if not all(type(c) is int for c in counts) or not 0 <= counts[0] <= counts[1] or counts[1] < 1 \
                or not isinstance(policy.get("checkpoint"), str) or not policy["checkpoint"]:
            raise ValueError(counts)
    except (AttributeError, KeyError, TypeError, ValueError):
        raise ValueError(f"{name} holds no training-colour score of a checkpoint: write it with `python -m "
                         f"oneshot.evaluate CKPT --trials 5 --unadapted{' --demo-scenes' * demo_scenes} --json "
                         f"{name}`") from None
    if recipe.get("other_colour_demo"):
        raise ValueError(f"{name} is the other-colour control (evaluate --other-colour-demo), not a scene check: "
                         f"name it ..._other_colour.json")
    if bool(policy["recipe"].get("demo_scenes")) != demo_scenes:
        raise ValueError(f"{name} was scored {'in new scenes' if demo_scenes else 'in its demonstrations scenes'}, "
                         f"not as its name says: name it ...{NEW if demo_scenes else DEMO}.json")
    return counts, {**policy, "recipe": recipe}


def _is_png(path):
    """Does the file at `path` begin as a PNG does (the only file the command replaces)?"""
    with open(path, "rb") as f:
        return f.read(8) == b"\x89PNG\r\n\x1a\n"


def figure(pairs, title="Learnt the task, or its meta-training scenes?"):
    """The picture of `pairs` (`read_pairs`), a matplotlib Figure: a row per pair, top to bottom in order,
    the training colours' success in the demonstrations' scenes (filled) and in new scenes (open), joined:
    a long bar is memorising. In a notebook it shows itself; `plot_scenes` saves it."""
    if Figure is None:
        raise RuntimeError('the plot needs matplotlib: pip install ".[plots]"')
    fig = Figure(figsize=(6.4, 1.5 + LINE_ROW * len(pairs)), dpi=150)
    ax = fig.add_subplot()
    for y, p in enumerate(reversed(pairs)):
        demo, new = (100 * s / t for s, t in (p["demo"], p["new"]))
        ax.plot([new, demo], [y, y], color="0.6", zorder=1)
        ax.plot([demo], [y], "o", color="C3", label="in scenes it meta-trained on" * (y == 0), zorder=2, clip_on=False)
        ax.plot([new], [y], "o", mfc="none", color="C0", label="in new scenes" * (y == 0), zorder=3, clip_on=False)
    labels = [textwrap.fill(p["label"], 40, break_on_hyphens=False) for p in reversed(pairs)]
    ax.set_yticks(range(len(pairs)), labels, fontsize=7)
    ax.set_ylim(-0.6, len(pairs) - 0.4)
    ax.set_xlim(0, 100)
    ax.set_xlabel("one-shot success on its training colours (%)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, axis="x")
    fig.legend(*ax.get_legend_handles_labels(), fontsize=7, loc="lower center", ncol=2, frameon=False)
    fig.tight_layout(rect=(0, 0.35 / fig.get_figheight(), 1, 1))          # room for the legend
    return fig


def plot_scenes(pairs, path):
    """`figure(pairs)` as a PNG at `path` (atomically)."""
    with atomic_write(path) as f:
        figure(pairs).savefig(f, format="png", bbox_inches="tight")


def add_scenes_command(commands):
    """`python -m oneshot.experiments scenes`'s parser, added to `commands` (argparse subparsers)."""
    s = commands.add_parser("scenes", help="a folder of scene checks (evaluate --demo-scenes and not) as a table "
                                           "and a picture: learnt the task, or its meta-training scenes?")
    s.add_argument("folder", help="a folder of X_demo_scenes.json / X_new_scenes.json pairs, e.g. "
                                  "results/fig2_ablation/scenes")
    s.add_argument("--out", type=cli.writable_file, default=None,
                   help="the picture, a PNG (default: the folder's name + .png, beside it)")
    return s


def run_scenes_command(args, parser):
    """Print each pair's two scores and draw them; a folder without pairs is a one-line error (exit 2)."""
    if not os.path.isdir(args.folder):
        parser.error(f"no folder {args.folder}: name a folder of scene checks, e.g. results/fig2_ablation/scenes")
    beside = os.path.abspath(args.folder) + ".png"                     # beside it, even for "." or "FOLDER/"
    out = args.out or (beside if os.path.isabs(args.folder) else os.path.relpath(beside))
    try:
        cli.replaces_only(out, _is_png, "--out", "a PNG picture")
        pairs, unpaired = read_pairs(args.folder)
    except (OSError, ValueError) as e:
        parser.error(str(e))
    if not pairs:
        parser.error(f"{args.folder} holds no pair of X{DEMO}.json and X{NEW}.json (evaluate --json files)")
    pct = lambda c: f"{100 * c[0] / c[1]:5.1f}% ({c[0]}/{c[1]})"
    print("training colours, adapted on one demonstration: in its demonstrations' scenes / in new scenes")
    for p in pairs:
        print(f"  {p['label']:44s} {pct(p['demo'])}  {pct(p['new'])}")
    if unpaired:
        print(f"not paired: {', '.join(unpaired)}")
    if Figure is None:
        print('no picture: it needs matplotlib (pip install ".[plots]")')
        return 0
    plot_scenes(pairs, out)
    print(f"picture: {out}")
    return 0
