"""Figure 2 of the paper as a picture, from a sweep's summary (`summary.summarise`): one-shot success
against the meta-training data, a line per method with its interval over seeds and colours; a summary
of one size (a search, an ablation) as a row per line.

    plot(summary, "fig2.png", labels)                 # pip install ".[plots]"
"""
import textwrap

from oneshot.tools.files import atomic_write

try:
    from matplotlib.figure import Figure       # pip install ".[plots]": the figure (no pyplot, no global state)
except ImportError:
    Figure = None
PLOTS = Figure is not None                     # can `plot` draw here?
LEGEND_ROW = 0.16                              # inches of figure per row of the legend (`plot`)
LINE_ROW = 0.3                                 # inches of figure per row of a one-size figure (`plot`, scenes)


def plot(summary, path, labels, title="One-shot imitation of new colours vs. meta-training data"):
    """Figure 2 as a PNG at `path` (atomically): x the meta-training demonstrations (log scale), y the
    one-shot success on the scored colours (%), per method the mean over seeds with the 95% interval over
    seeds and colours as error bars (`stats`; the figure's footnote says so). labels: {method: legend label},
    in legend order. A summary of one size (a search, an ablation) is drawn one row per line instead
    (`_plot_one_size`): at one x, the lines would hide each other. Needs matplotlib (pip install ".[plots]")."""
    if Figure is None:
        raise RuntimeError('the plot needs matplotlib: pip install ".[plots]"')
    shown = [m for m in labels if m in summary["methods"]]
    split = (summary.get("config") or {}).get("score", "held-out")       # none recorded (absent or null)
    footnote = "error bars: " + summary.get("interval", "95% intervals")
    sizes = {p["size"] for m in shown for p in summary["methods"][m]}
    if len(sizes) == 1:
        return _plot_one_size(summary, path, {m: labels[m] for m in shown}, title, split, footnote, sizes.pop())
    legend_rows = -(-len(shown) // 2)              # the legend, below the axes in 2 columns: it hides no point
    height = 4.4 + LEGEND_ROW * legend_rows        # inches
    fig = Figure(figsize=(6.4, height), dpi=150)
    ax = fig.add_subplot()
    for i, method in enumerate(shown):
        points = summary["methods"][method]
        x = [p["size"] for p in points]
        y = [100 * p["mean_rate"] for p in points]
        below = [max(0.0, 100 * (p["mean_rate"] - p["ci_low"])) for p in points]
        above = [max(0.0, 100 * (p["ci_high"] - p["mean_rate"])) for p in points]
        ax.errorbar(x, y, yerr=[below, above], marker="osD^v"[i % 5], capsize=3, label=labels[method])
    ax.set_xscale("log")
    ax.set_xticks(sorted(sizes), [str(s) for s in sorted(sizes)])
    ax.minorticks_off()
    ax.set_ylim(0, 100)
    ax.set_xlabel("meta-training demonstrations (colours x demos per colour)")
    ax.set_ylabel(f"one-shot success, {split} colours (%)")
    fig.text(0.01, 0.005, footnote, fontsize=5, color="0.35")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    fig.legend(*ax.get_legend_handles_labels(), fontsize=7, loc="lower center", bbox_to_anchor=(0.5, 0.1 / height),
               ncol=2, frameon=False)
    fig.tight_layout(rect=(0, (0.15 + LEGEND_ROW * legend_rows) / height, 1, 1))   # room for legend and footnote
    with atomic_write(path) as f:
        fig.savefig(f, format="png", bbox_inches="tight")   # a long legend label is never cut


def _plot_one_size(summary, path, labels, title, split, footnote, size):
    """`plot` of a summary whose lines all have one `size`: a row per line, top to bottom in the labels'
    order, labelled on the y axis with its label and name (as `--lines` takes it); its mean over seeds with
    the interval as a horizontal error bar and, for two seeds or more, the lowest and highest seed as open
    circles (drawn over the mean)."""
    fig = Figure(figsize=(6.4, 1.4 + LINE_ROW * len(labels)), dpi=150)
    ax = fig.add_subplot()
    seeds_drawn = False
    for y, method in enumerate(reversed(labels)):
        points = summary["methods"][method]
        if len(points) != 1:
            raise ValueError(f"the summary has {len(points)} points of {method} at size {size}: one per line and "
                             f"size (write it with summarise)")
        p = points[0]
        mean = 100 * p["mean_rate"]
        ax.errorbar([mean], [y], xerr=[[max(0.0, mean - 100 * p["ci_low"])], [max(0.0, 100 * p["ci_high"] - mean)]],
                    fmt="o", color="C0", capsize=3, label=labels[method])
        if p["runs"] > 1:
            ax.plot([100 * p["min_rate"], 100 * p["max_rate"]], [y, y], "o", mfc="none", color="0.3", ms=6, zorder=4)
            seeds_drawn = True
    names = [textwrap.fill(label if label == m else f"{label} ({m})", 40, break_on_hyphens=False)
             for m, label in reversed(labels.items())]
    ax.set_yticks(range(len(labels)), names, fontsize=7)
    ax.set_ylim(-0.6, len(labels) - 0.4)
    ax.set_xlim(0, 100)
    ax.set_xlabel(f"one-shot success, {split} colours (%)\nat {size:,} meta-training demonstrations")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3, axis="x")
    fig.text(0.01, 0.005, footnote + "; open circles: the lowest and highest seed" * seeds_drawn, fontsize=5,
             color="0.35")
    fig.tight_layout(rect=(0, 0.12 / fig.get_figheight(), 1, 1))         # room for the footnote
    with atomic_write(path) as f:
        fig.savefig(f, format="png", bbox_inches="tight")   # a long label is never cut
