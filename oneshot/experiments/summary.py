"""The summary of a sweep's rows (per method and size, over seeds) and its figure, Figure 2 of the paper.

    summary = summarise(rows, config, command)        # what summary.json holds
    plot(summary, "fig2.png", labels)                 # pip install ".[plots]"
"""
import dataclasses
import json

from oneshot.tools.files import atomic_write
from oneshot.training.scoring import wilson_interval

try:
    from matplotlib.figure import Figure       # pip install ".[plots]": the figure (no pyplot, no global state)
except ImportError:
    Figure = None
PLOTS = Figure is not None                     # can `plot` draw here?


def summarise(rows, config=None, command=None):
    """Per method and size: the runs (seeds), their mean success rate, the 95% Wilson interval of the
    pooled successes / trials, and the lowest and highest rate over seeds.

    -> {"methods": {method: [{"size", "colours", "demos_per_colour", "runs", "seeds", "successes",
    "trials", "mean_rate", "ci_low", "ci_high", "min_rate", "max_rate"}, ... by size]}, "runs": n,
    "config": asdict(config), "command": command} (the last two when given).
    """
    groups = {}
    for row in rows:
        groups.setdefault((row["method"], row["size"]), []).append(row)
    methods = {}
    for (method, size), group in sorted(groups.items()):
        shapes = {(r["colours"], r["demos_per_colour"], r["iterations"]) for r in group}
        if len(shapes) > 1:
            raise ValueError(f"{method} at size {size} mixes runs of (colours, demos, iterations) {sorted(shapes)}; "
                             f"summarise one configuration per size")
        seeds = sorted(r["seed"] for r in group)
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"{method} at size {size} has seed(s) repeated: {seeds}")
        successes, trials = sum(r["successes"] for r in group), sum(r["trials"] for r in group)
        rates = [r["successes"] / r["trials"] for r in group]
        lo, hi = wilson_interval(successes, trials)
        methods.setdefault(method, []).append({
            "size": size, "colours": group[0]["colours"], "demos_per_colour": group[0]["demos_per_colour"],
            "runs": len(group), "seeds": seeds, "successes": successes, "trials": trials,
            "mean_rate": sum(rates) / len(rates), "ci_low": lo, "ci_high": hi,
            "min_rate": min(rates), "max_rate": max(rates)})
    summary = {"methods": methods, "runs": len(rows)}
    if config is not None:
        summary["config"] = dataclasses.asdict(config)
    if command is not None:
        summary["command"] = command
    return summary


def write_summary(summary, path):
    """summary.json, atomically."""
    with atomic_write(path) as f:
        f.write((json.dumps(summary, indent=1) + "\n").encode("utf-8"))


def plot(summary, path, labels, title="One-shot imitation of new colours vs. meta-training data"):
    """Figure 2 as a PNG at `path` (atomically): x the meta-training demonstrations (log scale), y the
    one-shot success on held-out colours (%), per method the mean over seeds with the 95% interval of
    the pooled trials as error bars. labels: {method: legend label}, in legend order. Needs matplotlib
    (pip install ".[plots]")."""
    if Figure is None:
        raise RuntimeError('the plot needs matplotlib: pip install ".[plots]"')
    fig = Figure(figsize=(6.4, 4.4), dpi=150)
    ax = fig.add_subplot()
    sizes = set()
    for i, method in enumerate(m for m in labels if m in summary["methods"]):
        points = summary["methods"][method]
        x = [p["size"] for p in points]
        y = [100 * p["mean_rate"] for p in points]
        below = [max(0.0, 100 * (p["mean_rate"] - p["ci_low"])) for p in points]
        above = [max(0.0, 100 * (p["ci_high"] - p["mean_rate"])) for p in points]
        ax.errorbar(x, y, yerr=[below, above], marker="osD^v"[i % 5], capsize=3, label=labels[method])
        sizes.update(x)
    ax.set_xscale("log")
    ax.set_xticks(sorted(sizes), [str(s) for s in sorted(sizes)])
    ax.minorticks_off()
    ax.set_ylim(0, 100)
    ax.set_xlabel("meta-training demonstrations (colours x demos per colour)")
    ax.set_ylabel("one-shot success, held-out colours (%)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    with atomic_write(path) as f:
        fig.savefig(f, format="png")
