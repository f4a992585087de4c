"""`python -m oneshot.experiments difference` (oneshot/experiments/difference.py): the paired difference
between two lines of one or two results folders, against numbers worked out by hand from a few
hand-written rows, and its refusals, each a one-line error (exit 2)."""
import json

import pytest

from oneshot.experiments import __main__ as command
from oneshot.experiments import rows as sweep_rows
from test_summary import _row


def _folder(path, rows):
    path.mkdir()
    sweep_rows.write_rows(rows, path / "runs.csv")
    return str(path)


def test_the_difference_is_a_minus_b_with_its_interval_over_seeds_and_colours(tmp_path, capsys):
    """a (mil-conv0): seed 0 scores 2 of 2 on colour 0 and 0 of 2 on colour 1, seed 1 every trial: mean
    (50% + 100%) / 2 = 75%. b (lstm): nothing, 0%. So a - b = +75 points. A replicate draws seed 0 twice (1
    in 4) and colour 1 twice (1 in 4): a rate of 0, 1 in 16 = 6.25% > 2.5%, so the low end is 0; a rate
    of 100% has 7 in 16, so the high end is 100. b - a is the same negated."""
    folder = _folder(tmp_path / "r", [_row("mil-conv0", 0, 2, 4, per_colour=[2, 0]),
                                      _row("mil-conv0", 1, 4, 4, per_colour=[2, 2]),
                                      _row("lstm", 0, 0, 4, per_colour=[0, 0]),
                                      _row("lstm", 0, 0, 4, size=(3, 4), per_colour=[0, 0])])   # a size a lacks
    assert command.main(["difference", folder, "mil-conv0", "lstm"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("mil-conv0 - lstm, in points, on the same 2 colours")
    assert out[1:] == ["      9 demos: +75.0 [+0.0, +100.0]  (seeds 0, 1 against 0)"]   # 12 demos: only lstm
    assert command.main(["difference", folder, "lstm", "mil-conv0"]) == 0
    assert capsys.readouterr().out.splitlines()[1].split()[:5] == ["9", "demos:", "-75.0", "[-100.0,", "+0.0]"]


def test_lines_of_two_folders_and_some_seeds(tmp_path, capsys):
    """--b-results reads b from another sweep's folder; --seeds 1 keeps seed 1 of each: 4 of 4 against
    1 of 4 (0 of 2 on colour 0, 1 of 2 on colour 1), +75 points; with one seed each, only the colours vary:
    a - b is 100 when a replicate draws colour 0 twice (1 in 4), 50 when colour 1 twice (1 in 4), else 75.
    Every seed: a (0% + 100%) / 2 = 50%, b (100% + 25%) / 2 = 62.5%, so -12.5 points."""
    a = _folder(tmp_path / "a", [_row("mil-conv0", 0, 0, 4, per_colour=[0, 0]),
                                 _row("mil-conv0", 1, 4, 4, per_colour=[2, 2])])
    b = _folder(tmp_path / "b", [_row("lstm", 0, 4, 4, per_colour=[2, 2]),
                                 _row("lstm", 1, 1, 4, per_colour=[0, 1])])
    assert command.main(["difference", a, "mil-conv0", "lstm", "--b-results", b, "--seeds", "1"]) == 0
    line = capsys.readouterr().out.splitlines()[1]
    assert line.split()[:3] == ["9", "demos:", "+75.0"] and line.endswith("(seeds 1 against 1)")
    assert line.split()[3:5] == ["[+50.0,", "+100.0]"]
    assert command.main(["difference", a, "mil-conv0", "lstm", "--b-results", b]) == 0
    assert capsys.readouterr().out.splitlines()[1].split()[2] == "-12.5"


def _rekeyed(row, colours):
    """`row` with its per-colour counts moved to the colours `colours` (as another split's are)."""
    notes = json.loads(row["notes"])
    notes["per_colour"] = dict(zip(map(str, colours), notes["per_colour"].values()))
    return dict(row, notes=json.dumps(notes))


def test_one_line_of_two_folders_and_lines_of_two_budgets_are_named_as_such(tmp_path, capsys):
    """The same line in two sweeps' folders pairs (each named with its folder); runs of other iteration
    counts pair too, and each side's budget is printed; a size only one line has is skipped, whatever its runs."""
    a = _folder(tmp_path / "a", [_row("lstm", 0, 4, 4, per_colour=[2, 2]),
                                 _row("lstm", 0, 1, 4, size=(3, 4), per_colour=[1, 0]),
                                 _row("lstm", 1, 1, 4, size=(3, 4), iterations=4, per_colour=[1, 0])])   # mixed: 12 only
    b = _folder(tmp_path / "b", [_row("lstm", 0, 2, 4, iterations=4, per_colour=[1, 1])])
    assert command.main(["difference", a, "lstm", "lstm", "--b-results", b]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"lstm ({a}) - lstm ({b}), in points, on the same 2 colours")
    assert out[1:] == ["      9 demos: +50.0 [+50.0, +50.0]  (seeds 0 at 2 iterations against 0 at 4 iterations)"]


@pytest.mark.parametrize("case, message", [
    ("no folder", "holds no runs.csv: name a sweep's results folder"),
    ("no line", "holds no runs of line 'contextual' (its lines: lstm, mil-conv0); name a line it holds"),
    ("no runs", "holds no runs of line 'mil-conv0' (no runs yet)"),
    ("no seed", "mil-conv0 has no run of seed(s) 7 at 9 demonstrations (its seeds there: 0); name seeds both"),
    ("a seed one line lacks", "lstm has no run of seed(s) 1 at 9 demonstrations (its seeds there: 0)"),
    ("one line twice", "a and b are both lstm of "),
    ("other colours", "mil-conv0 and lstm were scored on other colours (2 and 3): name results scored on one split"),
    ("the same number of other colours", "mil-conv0 and lstm were scored on other colours (2 and 2, not the same ones)"),
    ("no colours", "lstm's runs at 9 demonstrations hold no per-colour counts"),
    ("no colours either", "mil-conv0's runs at 9 demonstrations hold no per-colour counts"),
    ("two budgets at a size", "lstm at size 9 mixes runs of (colours, demos, iterations) [(3, 3, 2), (3, 3, 4)]; name results of one"),
    ("a seed twice", "lstm at size 9 has seed(s) repeated: [0, 0]; name results of one configuration, each seed once"),
    ("no shared size", "mil-conv0 and lstm share no size: mil-conv0 at [9], lstm at [12] demonstrations"),
])
def test_what_cannot_be_paired_is_a_one_line_error(tmp_path, capsys, case, message):
    a = {"no colours either": [_row("mil-conv0", 0, 1, 4)], "a seed one line lacks": [
        _row("mil-conv0", 0, 1, 4, per_colour=[1, 0]), _row("mil-conv0", 1, 1, 4, per_colour=[1, 0])],
         "no runs": []}.get(case, [_row("mil-conv0", 0, 1, 4, per_colour=[1, 0])])
    lstm = _row("lstm", 0, 1, 4, per_colour=[0, 1])
    b = {"other colours": [_row("lstm", 0, 1, 6, per_colour=[1, 0, 0])],
         "the same number of other colours": [_rekeyed(lstm, [2, 3])],
         "no colours": [_row("lstm", 0, 1, 4)], "no colours either": [_row("lstm", 0, 1, 4)],
         "two budgets at a size": [lstm, _row("lstm", 1, 1, 4, iterations=4, per_colour=[0, 1])],
         "a seed twice": [lstm, lstm],
         "no shared size": [_row("lstm", 0, 1, 4, size=(3, 4), per_colour=[1, 0])],
         "no runs": []}.get(case, [lstm])
    folder = str(tmp_path / "nowhere") if case == "no folder" else _folder(tmp_path / "r", a + b)
    args = {"no line": ["mil-conv0", "contextual"], "no seed": ["mil-conv0", "lstm", "--seeds", "7"],
            "a seed one line lacks": ["mil-conv0", "lstm", "--seeds", "0", "1"],
            "one line twice": ["lstm", "lstm"]}.get(case, ["mil-conv0", "lstm"])
    with pytest.raises(SystemExit) as exit_:
        command.main(["difference", folder, *args])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and err.startswith("error: ") and message in err
