"""`python -m oneshot.experiments scenes` (oneshot/experiments/scenes.py): scene checks paired by name,
their training-colour scores read back against hand-written evaluate results, the picture read back from
its matplotlib Axes, and the refusals, each a one-line error (exit 2)."""
import json

import pytest

from oneshot.experiments import __main__ as command
from oneshot.experiments import scenes
from helpers import keep_figures


def _check(successes, trials=10, demo_scenes=False, checkpoint="runs/a/checkpoint.npz", raw=False):
    """An evaluate --json result by hand: its training colours' score and the policy it records."""
    recipe = {"raw": raw, **({"demo_scenes": True} if demo_scenes else {})}
    return {"validation": {"successes": 1, "trials": 10}, "train": {"successes": successes, "trials": trials},
            "policy": {"checkpoint": checkpoint, "recipe": recipe}}


def _write(folder, files):
    folder.mkdir(exist_ok=True)
    for name, result in files.items():
        (folder / name).write_text(json.dumps(result))
    return str(folder)


def _two_pairs(tmp_path):
    """b memorised (9 of 10 in its scenes, 2 in new ones); a learnt (7 and 7); an other-colour control."""
    return _write(tmp_path / "scenes", {
        "b_s1_demo_scenes.json": _check(9, demo_scenes=True, checkpoint="b"),
        "b_s1_new_scenes.json": _check(2, checkpoint="b"),
        "a_demo_scenes.json": _check(7, demo_scenes=True), "a_new_scenes.json": _check(7),
        "a_demo_scenes_other_colour.json": _check(1, demo_scenes=True), "notes.txt": {}})


def test_pairs_by_name_in_name_order_and_names_the_unpaired(tmp_path):
    pairs, unpaired = scenes.read_pairs(_two_pairs(tmp_path))
    assert pairs == [{"label": "a", "demo": (7, 10), "new": (7, 10)},
                     {"label": "b_s1", "demo": (9, 10), "new": (2, 10)}]
    assert unpaired == ["a_demo_scenes_other_colour.json"]


@pytest.mark.parametrize("case, files, message", [
    ("two checkpoints", {"x_demo_scenes.json": _check(9, demo_scenes=True, checkpoint="p"),
                         "x_new_scenes.json": _check(2, checkpoint="q")}, "x_demo_scenes.json and x_new_scenes.json "
                                                                           "score two policies"),
    ("raw and not", {"x_demo_scenes.json": _check(9, demo_scenes=True, raw=True), "x_new_scenes.json": _check(2)},
     "score two policies (other checkpoints, or one with --raw)"),
    ("swapped", {"x_demo_scenes.json": _check(2), "x_new_scenes.json": _check(9, demo_scenes=True)},
     "x_demo_scenes.json was scored in new scenes, not as its name says"),
    ("no training colours", {"x_demo_scenes.json": {"policy": {"recipe": {}}}, "x_new_scenes.json": _check(2)},
     "x_demo_scenes.json holds no training-colour score"),
    ("more successes than trials", {"x_demo_scenes.json": _check(11, demo_scenes=True), "x_new_scenes.json": _check(2)},
     "x_demo_scenes.json holds no training-colour score"),
    ("no pair", {"x_demo_scenes_other_colour.json": _check(2, demo_scenes=True)}, "holds no pair of"),
    ("not JSON", {"x_demo_scenes.json": _check(2, demo_scenes=True)}, "x_new_scenes.json is not JSON"),
])
def test_what_is_not_one_policys_two_checks_is_a_one_line_error(tmp_path, capsys, case, files, message):
    folder = _write(tmp_path / "scenes", files)
    if case == "not JSON":
        (tmp_path / "scenes" / "x_new_scenes.json").write_text("{")
    with pytest.raises(SystemExit) as exit_:
        command.main(["scenes", folder])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and err.startswith("error: ") and message in err
    assert not (tmp_path / "scenes.png").exists()


def test_no_folder_is_a_one_line_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        command.main(["scenes", str(tmp_path / "nowhere")])
    assert exit_.value.code == 2 and "no folder" in capsys.readouterr().err


def test_the_command_prints_each_pair_and_draws_a_row_each_beside_the_folder(tmp_path, capsys, monkeypatch):
    """Rows top to bottom in name order; in each, the score in its demonstrations' scenes filled and in new
    scenes open, at 100 x its rate, joined by a bar; x 0-100%; the picture is the folder's name + .png."""
    drawn = keep_figures(monkeypatch, scenes)
    folder = _two_pairs(tmp_path)
    assert command.main(["scenes", folder]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].split() == ["a", "70.0%", "(7/10)", "70.0%", "(7/10)"]
    assert out[2].split() == ["b_s1", "90.0%", "(9/10)", "20.0%", "(2/10)"]
    assert out[3] == "not paired: a_demo_scenes_other_colour.json" and out[4] == f"picture: {folder}.png"
    (ax,) = drawn[0].axes
    assert [t.get_text() for t in ax.get_yticklabels()] == ["b_s1", "a"]            # bottom to top
    filled = [line.get_xydata().tolist() for line in ax.lines if line.get_marker() == "o"
              and line.get_markerfacecolor() != "white"]
    empty = [line.get_xydata().tolist() for line in ax.lines if line.get_markerfacecolor() == "white"]
    bars = [line.get_xydata().tolist() for line in ax.lines if line.get_marker() in ("None", "", None)]
    assert filled == [[[90, 0]], [[70, 1]]] and empty == [[[20, 0]], [[70, 1]]]
    assert bars == [[[20, 0], [90, 0]], [[70, 1], [70, 1]]]
    assert ax.get_xlim() == (0, 100)
    assert (tmp_path / "scenes.png").read_bytes()[:4] == b"\x89PNG"
    assert command.main(["scenes", folder, "--out", str(tmp_path / "elsewhere.png")]) == 0
    assert (tmp_path / "elsewhere.png").exists()
