"""Grading as teachers do it (issue 31): notebooks handed in, executed or never executed, graded
directly (no nbconvert) into a gradebook CSV and JSON; an assignment of a few exercises graded alone;
`check --file` on a notebook; `list` naming each exercise's notebook. The notebooks are the real stubs
of notebooks/exercises/, filled in as students would."""
import copy
import csv
import inspect
import io
import json
import os
import shutil
import stat
from pathlib import Path

import pytest

from oneshot.exercises import EXERCISES, gradebook, solutions, submissions
from oneshot.exercises import __main__ as cli_main
from oneshot.exercises.grading import Graded
from oneshot.exercises.sandbox import Limits
from oneshot.tools import cli

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks" / "exercises"
WRONG_8 = """def contextual_input(images, demo_images):
    return np.concatenate([images, np.broadcast_to(demo_images[..., :1, :, :, :], images.shape)], axis=-1)
"""


def notebook(name, answers=None, executed=False, extra=()):
    """The stub notebook `name` with the exercise cells of `answers` {n: code} filled in, `extra` code
    cells appended, and, if `executed`, execution counts and outputs as Jupyter leaves them."""
    nb = copy.deepcopy(json.loads((NOTEBOOKS / name).read_text()))
    for cell in nb["cells"]:
        tags = [t for t in cell["metadata"].get("tags", []) if t.startswith("exercise-")]
        if tags and int(tags[0].removeprefix("exercise-")) in (answers or {}):
            cell["source"] = (answers[int(tags[0].removeprefix("exercise-"))]).splitlines(keepends=True)
    nb["cells"] += [{"cell_type": "code", "id": f"x{i}", "metadata": {}, "source": source, "outputs": [],
                     "execution_count": None} for i, source in enumerate(extra)]
    for count, cell in enumerate(c for c in nb["cells"] if c["cell_type"] == "code"):
        if executed:
            cell["execution_count"] = count + 1
            cell["outputs"] = [{"output_type": "stream", "name": "stdout", "text": ["exercise 9: correct\n"]}]
    return json.dumps(nb)


def reference_source(number):
    return inspect.getsource(solutions.SOLUTIONS[number])


@pytest.fixture(scope="module")
def handed_in(tmp_path_factory):
    folder = tmp_path_factory.mktemp("handed_in")
    everything = {n: reference_source(n) for n in (8, 9, 10)}
    shell = ["!pip install numpy\n%matplotlib inline\nimport numpy as np", "%%bash\necho not python",
             "%%time\nkept = True"]
    (folder / "alice.ipynb").write_text(notebook("03_baselines.ipynb", everything, extra=shell))
    (folder / "bob.ipynb").write_text(notebook("03_baselines.ipynb", {8: WRONG_8, 9: reference_source(9),
                                                                       10: "def lstm_step(w_h, xw, h, c:\n"},
                                               executed=True, extra=["scratch = undefined_name"]))
    (folder / "carol.ipynb").write_text(notebook("03_baselines.ipynb"))       # the stub, never touched
    (folder / "dave").mkdir()
    (folder / "dave" / "work.ipynb").write_text(notebook("03_baselines.ipynb", {9: reference_source(9)}))
    return folder


def test_a_folder_of_executed_and_unexecuted_notebooks_is_graded_into_a_gradebook(handed_in, tmp_path, capsys):
    gradebook, grades = tmp_path / "grades.csv", tmp_path / "grades.json"
    assert cli_main.main(["grade", str(handed_in), "--exercises", "8,9,10", "--timeout", "5",
                          "--csv", str(gradebook), "--json", str(grades)]) == 0
    out = capsys.readouterr().out
    assert "alice.ipynb  total  3/3 correct, 3 attempted" in out
    assert f"wrote {gradebook}" in out and f"wrote {grades}" in out
    rows = {row["student"]: row for row in csv.DictReader(gradebook.open())}
    assert list(rows["alice"]) == ["student", "submission", "exercise_8", "exercise_9", "exercise_10", "total",
                                   "max_score", "flagged", "notes"]
    assert [rows[s]["total"] for s in ("alice", "bob", "carol", "dave")] == ["3", "1", "0", "1"]
    assert rows["bob"]["exercise_9"] == "1" and rows["bob"]["exercise_8"] == "0"
    assert rows["bob"]["notes"] == "8 not yet; 10 missing" and rows["dave"]["submission"] == "dave/"
    assert rows["carol"]["notes"] == "8 not written; 9 not written; 10 not written" and rows["alice"]["max_score"] == "3"
    assert "carol.ipynb  total  0/3 correct, 0 attempted" in out           # stubs handed in as they were given out
    students = {s["student"]: s for s in json.loads(grades.read_text())["students"]}
    assert students["bob"]["verdicts"]["8"].startswith("not yet: you stacked the demo's FIRST image")
    assert students["bob"]["verdicts"]["10"].startswith("missing (cell ") and "SyntaxError" in students["bob"]["verdicts"]["10"]
    assert students["carol"]["verdicts"]["9"] == "not written: wilson_interval raises NotImplementedError, as the stub does"


def test_an_assignment_grades_only_its_exercises(tmp_path, capsys):
    header = "import autograd.numpy as anp\nimport numpy as np\nfrom autograd import grad\n" \
             "from oneshot.policy.network import forward\n\n"
    (tmp_path / "erin.py").write_text(header + reference_source(5) + "\n" + reference_source(6))
    (tmp_path / "frank.py").write_text(header + reference_source(5).replace("anp.sum(residual ** 2)",
                                                                           "anp.mean(residual ** 2)"))
    assert cli_main.main(["grade", str(tmp_path), "--exercises", "6,5", "--json", str(tmp_path / "g.json")]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if not line.startswith("wrote")]
    assert [line.split()[1] for line in lines] == ["5", "6", "total", "5", "6", "total"]
    assert lines[2].endswith("total  2/2 correct, 2 attempted") and lines[5].endswith("total  0/2 correct, 1 attempted")
    assert lines[4].endswith("6  missing")
    grades = json.loads((tmp_path / "g.json").read_text())
    assert grades["exercises"] == [5, 6] and [s["total"] for s in grades["students"]] == [2, 0]
    assert cli_main.parser().parse_args(["grade", "x"]).timeout == 10.0        # an endless loop costs 10 s


def test_a_submission_the_grader_will_not_follow_or_read_is_named_not_dropped(tmp_path, capsys):
    """A link to a file, or a FIFO, named like a submission: not graded (a link could point anywhere),
    and the teacher is told which and why, on stderr; the real file beside them is graded."""
    folder, elsewhere = tmp_path / "class", tmp_path / "elsewhere.py"
    folder.mkdir()
    elsewhere.write_text(reference_source(1))
    (folder / "gina.py").write_text(reference_source(1))
    (folder / "henry.py").symlink_to(elsewhere)
    os.mkfifo(folder / "ivan.py")
    (folder / "notes.txt").write_text("not a submission, and not named like one")
    (folder / "roster.csv").symlink_to(folder / "notes.txt")                 # a link, not named like one
    (folder / "empty.py").mkdir()                                           # a folder with no code: not one
    assert cli_main.main(["grade", str(folder), "--exercises", "1"]) == 0
    out, err = capsys.readouterr()
    assert [line.split()[0] for line in out.splitlines()] == ["gina.py", "gina.py"]
    assert [line.split()[1] for line in err.splitlines() if line.startswith("warning: ")][-2:] == ["henry.py", "ivan.py"]
    assert "henry.py is not graded: it is a symbolic link" in err and "ivan.py is not graded: it is a FIFO" in err
    assert not any(name in err for name in ("notes.txt", "roster.csv", "empty.py"))


def test_check_file_on_a_notebook(handed_in, capsys):
    assert cli_main.main(["check", "9", "--file", str(handed_in / "alice.ipynb")]) == 0
    assert capsys.readouterr().out == "exercise 9 (Sec. IV, the Wilson interval): correct\n"
    assert cli_main.main(["check", "8", "--file", str(handed_in / "bob.ipynb")]) == 1
    assert capsys.readouterr().out.startswith("exercise 8: not yet: you stacked the demo's FIRST image")
    assert cli_main.main(["check", "10", "--file", str(handed_in / "bob.ipynb")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "defines no function lstm_step" in err and "SyntaxError" in err, err


def test_a_notebook_is_graded_as_its_python():
    python_of = submissions.python_of
    assert python_of("!pip install x\nimport os\n%matplotlib inline\nif True:\n    !ls\n") == \
        "pass\nimport os\npass\nif True:\n    pass\n"
    assert python_of("%%bash\necho hi\n") is None and python_of("\n%%html\n<b>") is None
    assert python_of("%%time\nx = 1\n") == "x = 1\n"


def test_list_names_the_notebook_of_each_exercise(capsys):
    assert cli_main.main(["list"]) == 0
    out = capsys.readouterr().out
    for number, exercise in EXERCISES.items():
        line = next(line for line in out.splitlines() if line.split()[:1] == [str(number)])
        assert exercise.notebook in line and f"def {exercise.name}(" in line
    for path in NOTEBOOKS.glob("*.ipynb"):                  # the catalogue agrees with the notebooks' tags
        tags = {int(t.removeprefix("exercise-")) for c in json.loads(path.read_text())["cells"]
                for t in c["metadata"].get("tags", []) if t.startswith("exercise-")}
        assert tags == {n for n, e in EXERCISES.items() if e.notebook == path.name}


def test_the_gradebook_is_written_through_links_and_never_to_a_device(tmp_path):
    graded = [Graded("=HYPERLINK(1).py", [9], {9: "correct"}), Graded("bo,b.py", [9], {9: "timed out after 2 s"})]
    target = tmp_path / "real.csv"
    target.write_text("old")
    (tmp_path / "link.csv").symlink_to(target)
    gradebook.write(str(tmp_path / "link.csv"), gradebook.csv_text(graded, [9]))
    assert (tmp_path / "link.csv").is_symlink()                 # the link is kept; its target is updated
    rows = list(csv.DictReader(target.open()))
    assert rows[0]["student"] == "'=HYPERLINK(1)" and rows[0]["exercise_9"] == "1"       # not a formula
    assert rows[1]["submission"] == "bo,b.py" and rows[1]["notes"] == "9 timed out"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []          # no temporary left
    for bad in ("/dev/null", str(tmp_path)):
        with pytest.raises(SystemExit):
            cli_main.main(["grade", str(tmp_path), "--csv", bad])
    (tmp_path / "alice.py").write_text("x = 1\n")                 # a gradebook onto a submission: refused
    for flag in ("--csv", "--json"):
        with pytest.raises(SystemExit) as e:
            cli.run(cli_main.main, ["grade", str(tmp_path), flag, str(tmp_path / "alice.py")])
        assert e.value.code == 2 and (tmp_path / "alice.py").read_text() == "x = 1\n"
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)                 # still the device


def test_a_gradebook_replaces_only_a_gradebook(tmp_path, capsys):
    """--csv and --json may replace what `grade` wrote before (or an empty file, or one a spreadsheet
    saved with a byte-order mark), never another file (a README, a dataset), never each other, and never
    under a submission's name (the next `grade` of its folder would grade it); each refused in one line
    saying why, exit 2, before any grading, the file untouched."""
    graded = [Graded("alice.py", [9], {9: "correct"})]
    for kind, text in (("csv", gradebook.csv_text), ("json", gradebook.json_text)):
        path = tmp_path / f"old.{kind}"
        gradebook.write(str(path), text(graded, [9]))
        other = {"csv": "json", "json": "csv"}[kind]
        assert gradebook.is_gradebook(str(path), kind) and not gradebook.is_gradebook(str(path), other)
        (tmp_path / "bom").write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
        assert gradebook.is_gradebook(str(tmp_path / "bom"), kind)
    (tmp_path / "empty").write_bytes(b"")
    assert all(gradebook.is_gradebook(str(tmp_path / "empty"), kind) for kind in ("csv", "json"))
    (tmp_path / "README.md").write_text("# read me\n")
    (tmp_path / "notes.json").write_text('{"exercises": [9]}')         # JSON, but not what grade writes
    (tmp_path / "class").mkdir()
    (tmp_path / "class" / "alice.py").write_text("x = 1\n")
    not_ours = "exists and is not a gradebook ({}) that grade wrote (this command would replace it)"
    refused = [(["--json", str(tmp_path / "README.md")], not_ours.format("JSON")),
               (["--csv", str(tmp_path / "README.md")], not_ours.format("CSV")),
               (["--json", str(tmp_path / "notes.json")], not_ours.format("JSON")),
               (["--csv", str(tmp_path / "old.json")], not_ours.format("CSV")),
               (["--csv", str(tmp_path / "both"), "--json", str(tmp_path / "both")], "--csv and --json both name"),
               (["--csv", str(tmp_path / "class" / "out.py")], "is named like a submission (.py/.ipynb); name it .csv"),
               (["--json", str(tmp_path / "grades.ipynb")], "is named like a submission (.py/.ipynb); name it .json")]
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    for flags, says in refused:
        with pytest.raises(SystemExit) as e:
            cli.run(cli_main.main, ["grade", str(tmp_path / "class"), *flags])
        said = capsys.readouterr()
        assert e.value.code == 2 and len(said.err.strip().splitlines()) == 1 and said.out == "", (flags, said)
        assert says in said.err, (flags, said.err)
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before
    # what grade wrote, grade replaces
    for _ in range(2):
        assert cli_main.main(["grade", str(tmp_path / "class"), "--exercises", "9", "--timeout", "5",
                              "--csv", str(tmp_path / "empty"), "--json", str(tmp_path / "old.json")]) == 0
    assert (tmp_path / "empty").read_text().startswith("student,submission,exercise_9,")
    assert json.loads((tmp_path / "old.json").read_text())["exercises"] == [9]


def test_the_gradebooks_columns_for_hand_made_grades():
    """Three students, graded by hand: each column as the module's docstring defines it. A student's name
    keeps its inner dots ("jean.luc.py" is jean.luc; a folder "carol.v2/" keeps its dot); a load error is
    the notes, with 0 points and the assignment's max_score; text a spreadsheet would run as a formula
    (=, +, -, @, a tab or a carriage return first) is quoted with a leading '."""
    graded = [Graded("jean.luc.py", [5, 9], {5: "correct", 9: "flagged: your wilson_interval calls x"}),
              Graded("carol.v2/", [5, 9], load_error="could not load a.py: SyntaxError: invalid syntax"),
              Graded("+1.ipynb", [5, 9], {5: "not yet: ...", 9: "correct"})]
    rows = list(csv.DictReader(io.StringIO(gradebook.csv_text(graded, [5, 9]))))
    assert [(r["student"], r["submission"]) for r in rows] == [("jean.luc", "jean.luc.py"), ("carol.v2", "carol.v2/"),
                                                                ("'+1", "'+1.ipynb")]
    assert [(r["exercise_5"], r["exercise_9"], r["total"], r["max_score"], r["flagged"]) for r in rows] == \
        [("1", "0", "1", "2", "9"), ("0", "0", "0", "2", ""), ("0", "1", "1", "2", "")]
    assert [r["notes"] for r in rows] == ["9 flagged", "could not load a.py: SyntaxError: invalid syntax", "5 not yet"]
    for text in ("=1+1", "+1", "-1", "@SUM(A1)", "\tx", "\rx"):
        assert gradebook._safe(text) == "'" + text
    assert gradebook._safe("alice") == "alice" and gradebook._safe(3) == 3
    students = json.loads(gradebook.json_text(graded, [5, 9]))["students"]
    assert [(s["student"], s["total"], s["max_score"], s["points"]) for s in students] == \
        [("jean.luc", 1, 2, {"5": 1, "9": 0}), ("carol.v2", 0, 2, {"5": 0, "9": 0}), ("+1", 1, 2, {"5": 0, "9": 1})]


def test_what_is_and_is_not_a_submission(tmp_path, monkeypatch):
    """Names starting with "_" or "." are the teacher's (a template, a hidden file), not submissions; a
    folder past MAX_BYTES, or a notebook past it, is refused in words."""
    for name in ("alice.py", "_template.py", ".hidden.py", "bob.ipynb"):
        (tmp_path / name).write_text("x = 1\n" if name.endswith(".py") else notebook("03_baselines.ipynb"))
    assert [p.name for p in submissions.submissions(tmp_path)] == ["alice.py", "bob.ipynb"]
    (tmp_path / "carol").mkdir()
    (tmp_path / "carol" / "a.py").write_text("x = 1\n")
    (tmp_path / "carol" / "data.bin").write_bytes(bytes(3000))
    monkeypatch.setattr(submissions, "MAX_BYTES", 2000)
    for path, words in ((tmp_path / "carol", "carol holds more than"),
                        (tmp_path / "bob.ipynb", "bob.ipynb is larger than")):
        (tmp_path / "copy").mkdir()
        with pytest.raises(submissions.SubmissionError, match=words):
            submissions.working_copy(path, tmp_path / "copy")
        shutil.rmtree(tmp_path / "copy")


def test_a_notebook_runs_as_run_all_does(tmp_path):
    """Its code cells in order, numbered among all its cells from 1 (as Jupyter shows them), going on after
    a cell that raises, even SystemExit (a scratch `exit()`); an nbformat 3 notebook too (worksheets,
    "input")."""
    cells = [{"cell_type": "markdown", "source": "# title"},
             {"cell_type": "code", "source": "def f():\n    return 1\n"},
             {"cell_type": "code", "source": ["raise SystemExit(0)"]},
             {"cell_type": "code", "source": "def g():\n    return 2\n"}]
    v3 = [{"cell_type": "code", "input": c["source"]} if c["cell_type"] == "code" else c for c in cells]
    for nb in ({"nbformat": 4, "cells": cells}, {"nbformat": 3, "worksheets": [{"cells": v3}]}):
        (tmp_path / "n.ipynb").write_text(json.dumps(nb))
        assert [number for number, _ in submissions.notebook_cells(tmp_path / "n.ipynb")] == [2, 3, 4]
        namespace = {}
        exec(submissions.notebook_code(tmp_path / "n.ipynb"), namespace)
        assert namespace["f"]() == 1 and namespace["g"]() == 2
        assert [(n, type(e).__name__) for n, e in namespace["__notebook_errors__"]] == [(3, "SystemExit")]


def test_the_limits_given_on_the_command_line_reach_the_grader(tmp_path, monkeypatch, capsys):
    """--timeout and --memory are the sandbox's limits for grade and check; an exercise that does not exist
    is a one-line error, not a traceback from the grader."""
    (tmp_path / "alice.py").write_text("x = 1\n")
    seen = []
    monkeypatch.setattr(cli_main, "grade", lambda folder, numbers, limits, jobs, found: seen.append(limits) or [])
    monkeypatch.setattr(cli_main, "grade_submission", lambda path, numbers, limits, hidden: seen.append(limits) or
                        Graded("alice.py", numbers, {numbers[0]: "correct"}))
    assert cli_main.main(["grade", str(tmp_path), "--timeout", "3", "--memory", "600"]) == 0
    assert cli_main.main(["check", "9", "--file", str(tmp_path / "alice.py"), "--timeout", "4", "--memory", "700"]) == 0
    assert seen == [Limits(timeout=3.0, memory_mb=600), Limits(timeout=4.0, memory_mb=700)]
    capsys.readouterr()
    for bad in ("11", "0,5", ""):
        with pytest.raises(SystemExit) as stop:
            cli_main.main(["grade", str(tmp_path), "--exercises", bad])
        assert stop.value.code == 2
        assert capsys.readouterr().err == (f"error: argument --exercises: expected comma-separated exercise numbers "
                                           f"1-10, e.g. 5,6; got {bad!r} (see python -m oneshot.exercises grade --help)\n")
