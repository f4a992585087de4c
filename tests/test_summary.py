"""A sweep's summary and its figure, as the commands report them (oneshot/experiments/summary.py, the
summarise, seeds and compare commands, parts' file names, folders' checks): each against numbers
worked out by hand from a few hand-written rows, and the figure read back from its matplotlib Axes
(line data, error bars, labels), not from its pixels."""
import json
import os

import pytest

from oneshot.experiments import __main__ as command, figure, folders, parts, summary
from oneshot.experiments import rows as sweep_rows
from oneshot.experiments.fig2 import PROFILES
from oneshot.experiments.rows import RunSpec
from helpers import keep_figures
from test_experiments import tiny_argv  # noqa: F401 (a fixture)
from test_seeds import _write


def _row(method, seed, successes, trials=8, size=(3, 3), iterations=2, per_colour=None):
    """A runs.csv row by hand (`row_of`'s); per_colour: successes on each scored colour, in its notes."""
    result = {"successes": successes, "trials": trials}
    if per_colour is not None:
        result["per_colour"] = {str(c): n for c, n in enumerate(per_colour)}
    return sweep_rows.row_of(RunSpec(method, *size, seed, iterations), result, 1.0)


def test_a_summarys_paired_difference_is_a_minus_b():
    rows = [_row("good", 0, 8), _row("good", 1, 6), _row("bad", 0, 2), _row("bad", 1, 0)]
    (diff,) = summary.summarise(rows, pairs=[("good", "bad")])["differences"]
    assert (diff["a"], diff["b"]) == ("good", "bad")
    assert diff["difference"] == pytest.approx((1.0 + 0.75) / 2 - (0.25 + 0.0) / 2)   # +0.75, not -0.75 (mutant S10)
    assert diff["ci_low"] > 0


def test_a_reproduction_with_identical_numbers_agrees():
    """One seed each, the same counts: the difference is exactly 0 with interval [0, 0], which holds 0
    (mutant S11, strict inequalities, said they disagree)."""
    rows = [_row("mil", 0, 5)]
    (point,) = summary.compare(rows, [dict(r) for r in rows])
    assert (point["difference"], point["ci_low"], point["ci_high"]) == (0.0, 0.0, 0.0) and point["agree"] is True


def test_a_point_of_two_iteration_counts_or_a_seed_twice_is_refused():
    """A point (line, size) is one configuration's seeds: runs of 2 and of 4 iterations at the same size
    are two configurations, and a seed twice would count one policy twice in the mean over seeds."""
    with pytest.raises(ValueError, match=r"mixes runs of \(colours, demos, iterations\) \[\(3, 3, 2\), \(3, 3, 4\)\]"):
        summary.summarise([_row("lstm", 0, 1), _row("lstm", 1, 1, iterations=4)])
    with pytest.raises(ValueError, match=r"lstm at size 9 has seed\(s\) repeated: \[0, 0, 1\]"):
        summary.summarise([_row("lstm", 0, 1), _row("lstm", 0, 2), _row("lstm", 1, 1)])


def test_a_points_seeds_are_summarised_in_seed_order_whatever_the_rows_order():
    """Seeds 2, 0, 1 scoring 7, 1, 4 of 8: seeds [0, 1, 2], mean (1 + 4 + 7) / 24 = 0.5, from 1/8 to 7/8,
    and the same interval as the rows in seed order (the bootstrap draws seeds by their index)."""
    rows = [_row("lstm", 2, 7), _row("lstm", 0, 1), _row("lstm", 1, 4)]
    (point,) = summary.summarise(rows)["methods"]["lstm"]
    assert point["seeds"] == [0, 1, 2]
    assert (point["mean_rate"], point["min_rate"], point["max_rate"]) == (0.5, 0.125, 0.875)
    assert point == summary.summarise(sorted(rows, key=lambda r: r["seed"]))["methods"]["lstm"][0]


def test_a_difference_is_reported_at_the_sizes_both_lines_have():
    """mil at 9 and 12 demonstrations, lstm at 9 only: one difference, at 9: 6/8 - 2/8 = 0.5 (one seed,
    one colour: every replicate is 0.5)."""
    rows = [_row("mil", 0, 6), _row("mil", 0, 8, size=(3, 4)), _row("lstm", 0, 2)]
    (d,) = summary.summarise(rows, pairs=[("mil", "lstm")])["differences"]
    assert (d["a"], d["b"], d["size"], d["difference"], d["ci_low"], d["ci_high"]) == ("mil", "lstm", 9, 0.5, 0.5, 0.5)


def test_runs_scored_on_other_colours_count_as_one_colour_each():
    """Seed 0 scored on colours 0 and 1 (4 and 0 of 4), seed 1 on colours 0 and 2 (2 and 2): no column pairs
    their colours, so each run is its totals, 4/8 and 4/8: the mean 0.5 and, seeds alone resampled,
    every replicate 0.5."""
    rows = [_row("lstm", 0, 4, per_colour=[4, 0]), _row("lstm", 1, 4)]
    rows[1]["notes"] = json.dumps({"per_colour": {"0": 2, "2": 2}})
    (point,) = summary.summarise(rows)["methods"]["lstm"]
    assert (point["mean_rate"], point["ci_low"], point["ci_high"]) == (0.5, 0.5, 0.5)


def test_compare_is_mine_minus_theirs_at_the_shared_points_on_any_colours():
    """Mine: mil at 9 scoring 4 and 2 of 4 on two colours (75%), and an lstm point theirs lacks; theirs: mil
    at 9 scoring 2 and 0 (25%), and a point at 12 mine lacks. One point, 75% - 25%: each colour is 2/4
    better, so every paired replicate is +0.5. Theirs scored on 3 other colours (3 of 12): the totals
    compare, one colour each, the same +0.5."""
    mine = [_row("mil", 0, 6, per_colour=[4, 2]), _row("lstm", 0, 1, per_colour=[1, 0])]
    theirs = [_row("mil", 0, 2, per_colour=[2, 0]), _row("mil", 0, 8, size=(3, 4), per_colour=[4, 4])]
    expected = {"method": "mil", "size": 9, "mine": 0.75, "theirs": 0.25, "difference": 0.5, "ci_low": 0.5,
                "ci_high": 0.5, "agree": False}
    assert summary.compare(mine, theirs) == [expected]
    assert summary.compare(mine[:1], [_row("mil", 0, 3, trials=12, per_colour=[1, 1, 1])]) == [expected]


@pytest.fixture
def figures(monkeypatch):
    """The matplotlib Figures `figure.plot` draws (in order), each kept after it is saved."""
    return keep_figures(monkeypatch, figure)


def _lines(fig):
    """{legend label: (points [(x, y)], error bars [(x, low, high)])} of the figure's one Axes."""
    (ax,) = fig.axes
    out = {}
    for bars in ax.containers:
        line, _, (segments,) = bars.lines
        out[bars.get_label()] = ([tuple(p) for p in line.get_xydata().tolist()],
                                 [(a[0], a[1], b[1]) for a, b in segments.get_segments()])
    return out


def test_the_figure_draws_each_lines_means_and_intervals_in_percent(tmp_path, figures):
    """Two lines at 9 and 16 demonstrations, by hand (dyadic rates: exact): each point at 100 x its mean
    rate, its bar from 100 x ci_low to 100 x ci_high, but never above the point's own mean at its low end
    (a percentile interval can miss the mean: MIL's 25% with [37.5%, 50%] draws 25% to 50%); the legend in
    the labels' order, the lines without a label or a point left out; log x with a tick at each size (in
    size order: a set of 16 and 9 iterates 16 first); y 0-100% of the scored colours; the footnote names
    the interval."""
    s = {"methods": {"lstm": [{"size": 9, "mean_rate": 0.25, "ci_low": 0.125, "ci_high": 0.5},
                              {"size": 16, "mean_rate": 0.5, "ci_low": 0.375, "ci_high": 0.75}],
                     "mil-conv0": [{"size": 9, "mean_rate": 0.25, "ci_low": 0.375, "ci_high": 0.5},
                                   {"size": 16, "mean_rate": 0.875, "ci_low": 0.75, "ci_high": 1.0}],
                     "unlabelled": [{"size": 9, "mean_rate": 0.5, "ci_low": 0.5, "ci_high": 0.5}]},
         "interval": "an interval by hand", "config": {"score": "validation"}}
    figure.plot(s, tmp_path / "fig2.png", {"mil-conv0": "MIL", "random": "random policy", "lstm": "LSTM"},
                 title="Figure 2 by hand")
    (fig,) = figures
    (ax,) = fig.axes
    drawn = _lines(fig)
    assert list(drawn) == ["MIL", "LSTM"] and [t.get_text() for t in fig.legends[0].get_texts()] == ["MIL", "LSTM"]
    assert drawn["MIL"] == ([(9, 25), (16, 87.5)], [(9, 25, 50), (16, 75, 100)])
    assert drawn["LSTM"] == ([(9, 25), (16, 50)], [(9, 12.5, 50), (16, 37.5, 75)])
    assert ax.get_xscale() == "log" and list(ax.get_xticks()) == [9, 16]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["9", "16"]
    assert ax.get_ylim() == (0, 100) and ax.get_ylabel() == "one-shot success, validation colours (%)"
    assert ax.get_xlabel() == "meta-training demonstrations (colours x demos per colour)"
    assert ax.get_title() == "Figure 2 by hand"
    assert [t.get_text() for t in fig.texts] == ["error bars: an interval by hand"]
    figure.plot({"methods": {"lstm": s["methods"]["lstm"]}}, tmp_path / "none.png", {"lstm": "LSTM"})
    assert figures[1].axes[0].get_ylabel() == "one-shot success, held-out colours (%)"   # no config: no split named
    figure.plot({"methods": {"lstm": s["methods"]["lstm"]}, "config": None}, tmp_path / "null.png", {"lstm": "LSTM"})
    assert figures[2].axes[0].get_ylabel() == "one-shot success, held-out colours (%)"   # a null one: the same


def test_a_figure_of_one_size_draws_a_row_per_line(tmp_path, figures):
    """A search or an ablation (every drawn line at one size; at one x they would hide each other): a row
    per line, the labels' order top to bottom, each row's mean as a point at 100 x its mean rate with its
    interval as a horizontal bar (never past the mean at either end, as above), and the lowest and highest
    seed as open circles only where two or more seeds ran (the footnote names them only then); x 0-100% of
    the scored colours at that size; 0.3 inch a row; each label followed by its line's name unless it is
    the name, a long one wrapped at a space, not cut or split at a hyphen; a line without a label left
    out, whatever its size."""
    long = "MIL, every parameter adapts (the released code's loop, feature points)"
    s = {"methods": {"mil-conv0": [{"size": 9, "runs": 2, "mean_rate": 0.625, "ci_low": 0.5, "ci_high": 0.75,
                                    "min_rate": 0.5, "max_rate": 0.75}],
                     "lstm": [{"size": 9, "runs": 1, "mean_rate": 0.25, "ci_low": 0.375, "ci_high": 0.5,
                               "min_rate": 0.25, "max_rate": 0.25}],
                     "random": [{"size": 9, "runs": 1, "mean_rate": 0.5, "ci_low": 0.25, "ci_high": 0.375,
                                 "min_rate": 0.5, "max_rate": 0.5}],
                     "unlabelled": [{"size": 16, "runs": 1, "mean_rate": 0.5, "ci_low": 0.5, "ci_high": 0.5}]},
         "interval": "an interval by hand", "config": {"score": "test"}}
    figure.plot(s, tmp_path / "fig2.png", {"mil-conv0": long, "random": "random policy", "lstm": "lstm"},
                 title="one size by hand")
    (fig,) = figures
    (ax,) = fig.axes
    assert [t.get_text() for t in ax.get_yticklabels()] == [          # bottom to top
        "lstm", "random policy (random)", "MIL, every parameter adapts (the\nreleased code's loop, feature points)\n(mil-conv0)"]
    assert list(ax.get_yticks()) == [0, 1, 2] and ax.get_ylim() == (-0.6, 2.6)
    bars = {}
    for bar in ax.containers:
        point, _, (segments,) = bar.lines
        bars[bar.get_label()] = (point.get_xydata().tolist(), [[tuple(end) for end in seg] for seg in segments.get_segments()])
    assert bars == {long: ([[62.5, 2]], [[(50, 2), (75, 2)]]), "random policy": ([[50, 1]], [[(25, 1), (50, 1)]]),
                    "lstm": ([[25, 0]], [[(25, 0), (50, 0)]])}
    circles = [line.get_xydata().tolist() for line in ax.lines if line.get_markerfacecolor() == "none"]
    assert circles == [[[50, 2], [75, 2]]]                         # seeds: mil-conv0's two, none for one run
    assert ax.get_xlim() == (0, 100) and ax.get_title() == "one size by hand"
    assert ax.get_xlabel() == "one-shot success, test colours (%)\nat 9 meta-training demonstrations"
    assert [t.get_text() for t in fig.texts] == ["error bars: an interval by hand; open circles: the lowest and highest seed"]
    assert fig.get_figheight() == pytest.approx(1.4 + 0.3 * 3)
    assert (tmp_path / "fig2.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    one_seed = {"methods": {"lstm": [{**s["methods"]["lstm"][0], "size": 2304}]}, "interval": "by hand"}
    figure.plot(one_seed, tmp_path / "one.png", {"lstm": "LSTM"})
    assert [t.get_text() for t in figures[1].texts] == ["error bars: by hand"]     # no circle drawn, none named
    assert figures[1].axes[0].get_xlabel() == "one-shot success, held-out colours (%)\nat 2,304 meta-training demonstrations"
    twice = {"methods": {"lstm": s["methods"]["lstm"] * 2}}
    with pytest.raises(ValueError, match="2 points of lstm at size 9: one per line and size"):
        figure.plot(twice, tmp_path / "twice.png", {"lstm": "LSTM"})
    assert not (tmp_path / "twice.png").exists()
    figure.plot({"methods": {"unlabelled": s["methods"]["unlabelled"]}}, tmp_path / "none.png", {"lstm": "LSTM"})
    assert (tmp_path / "none.png").exists() and not figures[-1].axes[0].lines    # no line to draw: empty axes


def _results(folder, rows, config):
    """A finished sweep's results folder by hand: runs.csv and a summary.json recording `config`."""
    os.makedirs(folder)
    sweep_rows.write_rows(rows, os.path.join(folder, "runs.csv"))
    with open(os.path.join(folder, "summary.json"), "w") as f:
        json.dump({"config": config, "command": "python -m oneshot.experiments fig2 --profile tiny"}, f)


def test_summarise_pairs_and_labels_the_lines_in_the_summarys_order(tmp_path, figures):
    """`summarise` of a folder whose summary names its lines random, lstm, mil-all, mil-conv0 and no scored
    split (a sweep from before the test split): the differences each line that adapts minus each that does
    not, in that order; the split is the validation colours; the figure's rows are those lines' labels in that
    order, the title counts 2 seeds (8 rows). By hand: mil-conv0 8/8 and 6/8, lstm 2/8 and 0/8, one colour
    each: 0.875 - 0.125 = 0.75."""
    order = ["random", "lstm", "mil-all", "mil-conv0"]
    scores = {"random": (0, 1), "lstm": (2, 0), "mil-all": (4, 4), "mil-conv0": (8, 6)}
    rows = [_row(m, seed, scores[m][seed]) for m in order for seed in (0, 1)]
    _results(tmp_path / "r", rows, {"name": "tiny", "methods": order})
    assert command.main(["summarise", str(tmp_path / "r")]) == 0
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert [(d["a"], d["b"]) for d in s["differences"]] == [("mil-all", "random"), ("mil-all", "lstm"),
                                                           ("mil-conv0", "random"), ("mil-conv0", "lstm")]
    assert s["differences"][3]["difference"] == 0.75 and s["config"]["score"] == "validation"
    (fig,) = figures                                   # one size: a row per line, the first at the top
    assert [t.get_text() for t in fig.axes[0].get_yticklabels()][::-1] == [
        "random policy (random)", "LSTM (lstm)", "MIL, every parameter adapts (step 0.25)\n(mil-all)",
        "MIL, first convolution adapts\n(mil-conv0)"]
    assert fig.axes[0].get_title() == "Figure 2 (tiny profile, 2 seeds)"
    assert fig.axes[0].get_xlabel().startswith("one-shot success, validation colours (%)")


def test_summarise_reads_a_summary_whose_config_is_null_as_one_without(tmp_path):
    """`"config": null`, which `load_results` takes for no config recorded: summarised as one without it
    (every line, in LINES' order; the validation colours), not an AttributeError."""
    rows = [_row("lstm", 0, 2), _row("mil-conv0", 0, 6)]
    _results(tmp_path / "r", rows, None)
    assert command.main(["summarise", str(tmp_path / "r")]) == 0
    s = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert [(d["a"], d["b"], d["difference"]) for d in s["differences"]] == [("mil-conv0", "lstm", 0.5)]
    assert s["config"] == {"score": "validation"} and (tmp_path / "r" / "fig2.png").exists() == command.PLOTS


@pytest.mark.parametrize("config", [None, {}, {"name": ""}])
def test_summarises_figure_names_no_profile_when_none_is_recorded(tmp_path, figures, config):
    """A summary that records no profile name: its figure's title counts the seeds and names no profile
    ("Figure 2 (1 seed)", not "Figure 2 ( profile, 1 seed)")."""
    _results(tmp_path / "r", [_row("lstm", 0, 2), _row("mil-conv0", 0, 6)], config)
    assert command.main(["summarise", str(tmp_path / "r")]) == 0
    (fig,) = figures
    assert fig.axes[0].get_title() == "Figure 2 (1 seed)"


def test_summarise_refuses_a_folder_without_rows_and_keeps_its_summary(tmp_path, capsys):
    """A results folder whose runs.csv holds no row: exit 2 with one line, its summary.json left as it was
    (not replaced by a summary of nothing)."""
    _results(tmp_path / "r", [], {"name": "tiny"})
    before = (tmp_path / "r" / "summary.json").read_text()
    assert command.main(["summarise", str(tmp_path / "r")]) == 2
    assert capsys.readouterr().err == f"error: {tmp_path / 'r'} holds no runs.csv rows to summarise\n"
    assert (tmp_path / "r" / "summary.json").read_text() == before


def test_the_sweeps_summary_and_figure_report_its_lines_differences_and_part(tmp_path, monkeypatch, figures,
                                                                             tiny_argv):
    """`fig2 --profile tiny --seeds 1` (runs by `fake_run`, in threads): summary_seeds1.json's differences
    are each adapting line minus each other one, in the profile's order, at both sizes; the figure's title
    names the part."""
    monkeypatch.setattr(command, "ensure_data", lambda *args, **kwargs: None)      # fake runs read no data
    assert command.main(tiny_argv + ["--seeds", "1"]) == 0
    s = json.loads((tmp_path / "out" / "summary_seeds1.json").read_text())
    adapting, other = ["mil-conv0", "mil-all"], ["contextual", "lstm", "random"]
    pairs = [(a, b, n) for a in adapting for b in other for n in (9, 12)]
    assert [(d["a"], d["b"], d["size"]) for d in s["differences"]] == pairs
    assert figures[0].axes[0].get_title() == "Figure 2 (tiny profile, seed 1 of 2)"


def test_seeds_prints_the_interval_low_end_first(tmp_path, capsys):
    """Seed 0 scores every trial, seed 1 none: a replicate draws seed 0 twice (1 in 4: 100%), seed 1 twice
    (1 in 4: 0%) or one of each (50%), so the mean is 50% and the interval [0%, 100%], printed low end first."""
    a = _write(tmp_path / "a.json", seed=0, per_colour={0: 4, 1: 4})
    b = _write(tmp_path / "b.json", seed=1, per_colour={0: 0, 1: 0})
    assert command.main(["seeds", a, b]) == 0
    assert "mean over 2 seeds: 50.0% [0.0%, 100.0%] (8/16; seeds from 0.0% to 100.0%" in capsys.readouterr().out


def test_compare_prints_each_point_and_fails_when_one_differs(tmp_path, capsys):
    """The table row is here's rate, there's, and the difference with its interval (the compare test's
    numbers: 75% here, 25% there, +50 [50, 50]); exit 1 if a point differs, 0 if all agree."""
    os.makedirs(tmp_path / "there")
    sweep_rows.write_rows([_row("mil-conv0", 0, 2, per_colour=[2, 0])], tmp_path / "there" / "runs.csv")
    assert command._compare([_row("mil-conv0", 0, 6, per_colour=[4, 2])], tmp_path / "there") == 1
    out = capsys.readouterr().out.splitlines()
    assert out[-2].split() == ["mil-conv0", "9", "75.0", "25.0", "50.0", "[", "50.0,", "50.0]", "DIFFERS"]
    assert out[-1] == "0 of 1 points agree; 1 differ"
    assert command._compare([_row("mil-conv0", 0, 2, per_colour=[2, 0])], tmp_path / "there") == 0
    assert capsys.readouterr().out.splitlines()[-1] == "1 of 1 points agree"


def test_a_parts_file_names_and_words_follow_the_profiles_order():
    """--seeds 2 0 --lines lstm mil-conv0 --sizes 5184 192 of the paper profile: seeds 0, 2; its lines in
    the profile's order (mil-conv0 first); sizes 192 (24 x 8) and 5184 (324 x 16): the same file names
    whichever order the flags were given in."""
    cfg, part, words = parts.narrow(PROFILES["paper"], [2, 0], ["lstm", "mil-conv0"], [5184, 192])
    assert part == "_seeds0-2_mil-conv0_lstm_sizes192-5184"
    assert words == "seeds 0, 2 of 3, mil-conv0, lstm, 192, 5184 demonstrations"
    assert (cfg.seeds, cfg.methods, cfg.sizes) == ((0, 2), ("mil-conv0", "lstm"), ((24, 8), (324, 16)))


def test_a_results_folder_without_a_recorded_profile_or_split_is_read_as_its_age_says(tmp_path):
    """A summary that records no config (from before configs were recorded) is no other profile's: the tiny
    sweep may write there. One that records no scored split is from before the test split: it scored the
    validation colours, and the tiny sweep (test colours) does not compare with it."""
    cfg = PROFILES["tiny"]
    os.makedirs(tmp_path / "old")
    (tmp_path / "old" / "summary.json").write_text(json.dumps({"methods": {}, "runs": 0}))
    folders.check_results_folder(cfg, tmp_path / "old")
    rows = [_row("mil-conv0", 0, 1)]
    _results(tmp_path / "before-test", rows, {"name": "tiny"})
    with pytest.raises(ValueError, match="was scored on the validation colours and this sweep scores the test"):
        folders.check_comparable(cfg, tmp_path / "before-test", rows)


def test_a_row_of_negative_successes_or_no_trials_is_refused():
    """A run's result needs 0 <= successes <= trials and trials >= 1: -1 of 3, or 0 of 0, is no rate (a
    runs.csv line is checked the same way: test_sweep_faults)."""
    spec = RunSpec("lstm", 3, 3, 0, 2)
    for successes, trials in ((-1, 3), (0, 0)):
        with pytest.raises(ValueError, match=f"run_fn returned {successes} successes in {trials} trials"):
            sweep_rows.row_of(spec, {"successes": successes, "trials": trials}, 1.0)
