"""`python -m oneshot.experiments scenes` (oneshot/experiments/scenes.py): scene checks paired by name,
their training-colour scores read back against hand-written evaluate results, the picture read back from
its matplotlib Axes, and the refusals, each a one-line error (exit 2)."""
import json

import pytest

from oneshot.experiments import __main__ as command
from oneshot.experiments import scenes
from helpers import keep_figures


def _check(successes, trials=10, demo_scenes=False, checkpoint="runs/a/checkpoint.npz", raw=False, **recipe):
    """An evaluate --json result by hand: its training colours' score and the policy it records."""
    recipe = {"raw": raw, "inner_steps": 1, **recipe, **({"demo_scenes": True} if demo_scenes else {})}
    return {"validation": {"successes": 1, "trials": 10}, "train": {"successes": successes, "trials": trials},
            "policy": {"checkpoint": checkpoint, "training_seed": 0, "trials_per_colour": 5, "recipe": recipe}}


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


def _counted(successes, trials):
    """A demo-scene check whose training-colour counts are `successes` and `trials`, as written."""
    result = _check(0, demo_scenes=True)
    result["train"] = {"successes": successes, "trials": trials}
    return result


NO_SCORE = "x_demo_scenes.json holds no training-colour score of a checkpoint"
TWO = "x_demo_scenes.json and x_new_scenes.json differ in"


@pytest.mark.parametrize("case, files, message", [
    ("two checkpoints", {"x_demo_scenes.json": _check(9, demo_scenes=True, checkpoint="p"),
                         "x_new_scenes.json": _check(2, checkpoint="q")}, f"{TWO} checkpoint: a pair is one policy's"),
    ("raw and not", {"x_demo_scenes.json": _check(9, demo_scenes=True, raw=True), "x_new_scenes.json": _check(2)},
     f"{TWO} recipe:"),
    ("3 inner steps and 1", {"x_demo_scenes.json": _check(9, demo_scenes=True, inner_steps=3),
                             "x_new_scenes.json": _check(2)}, f"{TWO} recipe: a pair is one policy's two checks"),
    ("other trials", {"x_demo_scenes.json": _check(9, demo_scenes=True),
                      "x_new_scenes.json": {**_check(2), "policy": {**_check(2)["policy"], "trials_per_colour": 2}}},
     f"{TWO} trials_per_colour"),
    ("swapped", {"x_demo_scenes.json": _check(2), "x_new_scenes.json": _check(9, demo_scenes=True)},
     "x_demo_scenes.json was scored in new scenes, not as its name says: name it ..._new_scenes.json"),
    ("both in demo scenes", {"x_demo_scenes.json": _check(9, demo_scenes=True),
                             "x_new_scenes.json": _check(2, demo_scenes=True)},
     "x_new_scenes.json was scored in its demonstrations scenes, not as its name says: name it ..._demo_scenes"),
    ("the other-colour control", {"x_demo_scenes.json": _check(2, demo_scenes=True, other_colour_demo=True),
                                  "x_new_scenes.json": _check(2)}, "x_demo_scenes.json is the other-colour control"),
    ("no training colours", {"x_demo_scenes.json": {"policy": {"recipe": {}}}, "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("a null policy", {"x_demo_scenes.json": {**_check(2), "policy": None}, "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("no checkpoint", {"x_demo_scenes.json": _check(9, demo_scenes=True, checkpoint=None),
                       "x_new_scenes.json": _check(2, checkpoint=None)}, NO_SCORE),
    ("more successes than trials", {"x_demo_scenes.json": _counted(11, 10), "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("no trials", {"x_demo_scenes.json": _counted(0, 0), "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("fewer than none", {"x_demo_scenes.json": _counted(-1, 10), "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("fractions", {"x_demo_scenes.json": _counted(2.7, 10.9), "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("text", {"x_demo_scenes.json": _counted("3", "10"), "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("truths", {"x_demo_scenes.json": _counted(True, True), "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("infinity", {"x_demo_scenes.json": _counted(1, float("inf")), "x_new_scenes.json": _check(2)}, NO_SCORE),
    ("named twice", {"x_new_scenes_demo_scenes.json": _check(2, demo_scenes=True), "x_new_scenes_new_scenes.json":
                     _check(2)}, "x_new_scenes_demo_scenes.json names its check twice"),
    ("no pair", {"x_demo_scenes_other_colour.json": _check(2, demo_scenes=True)}, "holds no pair of"),
    ("a twin that is a folder", {"x_demo_scenes.json": _check(2, demo_scenes=True)}, "holds no pair of"),
    ("not JSON", {"x_demo_scenes.json": _check(2, demo_scenes=True)}, "x_new_scenes.json is not JSON"),
])
def test_what_is_not_one_policys_two_checks_is_a_one_line_error(tmp_path, capsys, case, files, message):
    folder = _write(tmp_path / "scenes", files)
    if case == "not JSON":
        (tmp_path / "scenes" / "x_new_scenes.json").write_text("{")
    if case == "a twin that is a folder":
        (tmp_path / "scenes" / "x_new_scenes.json").mkdir()
    with pytest.raises(SystemExit) as exit_:
        command.main(["scenes", folder])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and err.startswith("error: ") and message in err
    assert not (tmp_path / "scenes.png").exists()


@pytest.mark.parametrize("case", ["no folder", "--out an input", "--out a folder", "--out somewhere else's file"])
def test_what_the_command_cannot_read_or_must_not_write_is_a_one_line_error(tmp_path, capsys, case):
    """A missing folder; a picture over one of its checks, or over any file not a PNG; a folder for a
    picture: each one line, exit 2, before anything is drawn or replaced."""
    folder = _two_pairs(tmp_path)
    (tmp_path / "README.md").write_text("mine")
    argv = {"no folder": [str(tmp_path / "nowhere")], "--out an input": [folder, "--out", f"{folder}/a_new_scenes.json"],
            "--out a folder": [folder, "--out", folder],
            "--out somewhere else's file": [folder, "--out", str(tmp_path / "README.md")]}[case]
    with pytest.raises(SystemExit) as exit_:
        command.main(["scenes", *argv])
    err = capsys.readouterr().err
    message = {"no folder": "no folder", "--out an input": "exists and is not a PNG picture",
               "--out a folder": "--out", "--out somewhere else's file": "exists and is not a PNG picture"}[case]
    assert exit_.value.code == 2 and err.count("\n") == 1 and err.startswith("error: ") and message in err
    assert json.loads((tmp_path / "scenes" / "a_new_scenes.json").read_text()) == _check(7)
    assert (tmp_path / "README.md").read_text() == "mine" and not (tmp_path / "scenes.png").exists()


def test_the_picture_goes_beside_the_folder_however_it_is_named(tmp_path, capsys, monkeypatch):
    """FOLDER/ and FOLDER give FOLDER.png; '.' gives ../<its name>.png, not a hidden '..png' inside it; a
    '_raw' pair is labelled with its suffix; an existing PNG is replaced."""
    pytest.importorskip("matplotlib")
    folder = _two_pairs(tmp_path)
    _write(tmp_path / "scenes", {"a_demo_scenes_raw.json": _check(8, demo_scenes=True, raw=True),
                                 "a_new_scenes_raw.json": _check(6, raw=True)})
    assert command.main(["scenes", folder + "/"]) == 0 and (tmp_path / "scenes.png").exists()
    assert "  a_raw " in capsys.readouterr().out
    (tmp_path / "scenes.png").unlink()
    monkeypatch.chdir(folder)
    assert command.main(["scenes", "."]) == 0 and (tmp_path / "scenes.png").exists()
    assert capsys.readouterr().out.splitlines()[-1] == f"picture: {'..'}/scenes.png"
    assert not (tmp_path / "scenes" / "..png").exists()
    assert command.main(["scenes", ".", "--out", "../scenes.png"]) == 0       # a PNG: replaced


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
              and line.get_markerfacecolor() != "none"]
    empty = [line.get_xydata().tolist() for line in ax.lines if line.get_markerfacecolor() == "none"]
    bars = [line.get_xydata().tolist() for line in ax.lines if line.get_marker() in ("None", "", None)]
    assert filled == [[[90, 0]], [[70, 1]]] and empty == [[[20, 0]], [[70, 1]]]
    assert bars == [[[20, 0], [90, 0]], [[70, 1], [70, 1]]]
    assert ax.get_xlim() == (0, 100) and ax.get_ylim() == (-0.6, 1.6)
    assert ax.get_title() == "Learnt the task, or its meta-training scenes?"
    assert [t.get_text() for t in drawn[0].legends[0].get_texts()] == ["in scenes it meta-trained on", "in new scenes"]
    assert (tmp_path / "scenes.png").read_bytes()[:4] == b"\x89PNG"
    assert command.main(["scenes", folder, "--out", str(tmp_path / "elsewhere.png")]) == 0
    assert (tmp_path / "elsewhere.png").exists()
