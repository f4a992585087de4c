"""The teaching notebooks, run in a real Jupyter kernel and checked on what they compute.

Each notebook runs from top to bottom in a fresh IPython kernel (nbclient and ipykernel), as a
student's Jupyter runs it, with the working directory a temporary folder (nothing is written into
the repository), matplotlib on its non-interactive backend (MPLBACKEND=Agg), and `oneshot` imported
from where this test imports it. A cell with an error output fails the test, naming the notebook, the
cell and the error. The test sets nothing else in the kernel: notebook 3 sets its own BLAS threads,
visibly. Then one code cell that the test appends prints, as JSON, the values the notebook computed,
and the test checks them: the expert's demo succeeded, the meta-gradient passed its finite-difference
check, the meta-loss fell, and so on. Notebook 4 reads the committed results of the Figure 2
experiment (results/ in the repository); while none are committed, it reads a tiny sweep the test makes (seconds)
with the experiment's own command, in the same format. The exercise notebooks (notebooks/exercises/)
run with each cell tagged `exercise-N` replaced by the reference solution of exercise N.
"""
import importlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import numpy as np
import pytest
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError

import oneshot
from oneshot import demo, methods
from oneshot.experiments import fig2, lines
from oneshot.experiments.difference import differences, line_rows
from oneshot.experiments.rows import read_rows
from oneshot.world import palette

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
RESULTS = Path(__file__).resolve().parent.parent / "results"             # the committed experiment results
EXERCISE_NOTEBOOKS = sorted((NOTEBOOKS / "exercises").glob("*.ipynb"))
CELL_TIMEOUT = 600        # seconds for one cell; all the notebooks together take well under a minute
ADDED = "added_by_test"   # metadata flag of the cells the test adds


def kernel_env():
    """The kernel's environment: this process's, with matplotlib's Agg backend, and `oneshot` found
    where this test found it (the same checkout, whether installed or not)."""
    package_parent = str(Path(oneshot.__file__).resolve().parent.parent)
    path = os.pathsep.join(p for p in (package_parent, os.environ.get("PYTHONPATH")) if p)
    return dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=path)


def added_cell(source):
    return nbformat.v4.new_code_cell(source, metadata={ADDED: True})


def execute(nb, name, folder, first=None, values=None):
    """Run notebook `nb` (nbformat) in a fresh kernel, working directory `folder`.

    first: code the test runs in a cell before the notebook's first one. values: the source of a
    dict expression over the notebook's variables; a cell appended after the last one prints it as
    JSON (its last line of output). Returns (the notebook with its outputs, that dict or None).
    """
    cells = list(nb.cells)
    nb.cells = ([added_cell(first)] if first else []) + cells
    if values:
        nb.cells.append(added_cell(f"import json\nprint(json.dumps({values}))"))
    client = NotebookClient(nb, timeout=CELL_TIMEOUT, kernel_name="python3",
                            resources={"metadata": {"path": str(folder)}})
    try:
        client.execute(env=kernel_env())
    except CellExecutionError as e:
        failed = next((c for c in nb.cells if any(o.output_type == "error" for o in c.get("outputs", []))), None)
        if failed is None or failed.metadata.get(ADDED):
            where = "a cell the test added"
        else:
            where = f"cell {cells.index(failed)} (id {failed.get('id')!r}, counting markdown cells)"
        traceback = re.sub(r"\x1b\[[0-9;]*m", "", str(e))             # without the terminal colours
        raise AssertionError(f"{name}: {where} raised {e.ename}: {e.evalue}\n\n{traceback}") from None
    errors = [c.get("id") for c in nb.cells if any(o.output_type == "error" for o in c.get("outputs", []))]
    assert not errors, f"{name}: error output in cells {errors} (tagged raises-exception?)"
    return nb, (json.loads(stdout(nb.cells[-1]).strip().splitlines()[-1]) if values else None)


def stdout(*cells):
    """Everything the cells printed to stdout."""
    return "".join(o.text for c in cells for o in c.get("outputs", [])
                   if o.output_type == "stream" and o.name == "stdout")


def run_notebook(name, folder, first=None, values=None):
    return execute(nbformat.read(NOTEBOOKS / name, as_version=4), name, folder, first, values)


def test_notebooks_are_committed_without_outputs():
    names = sorted(p.name for p in NOTEBOOKS.glob("*.ipynb"))
    assert names == ["01_world_and_expert.ipynb", "02_maml.ipynb", "03_one_shot_imitation.ipynb",
                     "04_experiments.ipynb"]
    for name in names:
        nb = json.loads((NOTEBOOKS / name).read_text())
        assert nb["nbformat"] == 4 and nb["cells"][0]["cell_type"] == "markdown"
        assert "Section" in "".join(nb["cells"][0]["source"]), f"{name}: the title cell names no paper section"
    for path in [NOTEBOOKS / name for name in names] + EXERCISE_NOTEBOOKS:
        nb = json.loads(path.read_text())
        assert nb["nbformat"] == 4, f"{path.name}: nbformat {nb['nbformat']}, not 4"
        for i, cell in enumerate(nb["cells"]):
            if cell["cell_type"] == "code":
                assert cell["outputs"] == [] and cell["execution_count"] is None, \
                    f"{path.name}: clear the outputs before committing (cell {cell.get('id', i)})"


WORLD_VALUES = """{
    "demo_success": bool(demo["success"]), "final_mm": float(final_mm), "plan_converged": bool(plan.converged),
    "cost_history": [float(c) for c in plan.cost_history], "gap": [float(g) for g in gap],
    "gap_fine": [float(g) for g in gap_fine], "open_loop_mm": float(open_loop_mm),
    "dataset_images_shape": list(dataset["images"].shape), "round_trip_ok": bool(round_trip_ok),
    "plt_is_none": plt is None}"""


def test_world_and_expert(tmp_path):
    _, v = run_notebook("01_world_and_expert.ipynb", tmp_path, values=WORLD_VALUES)
    assert v["demo_success"] and v["final_mm"] < 50                    # the expert reached the disc
    history = np.array(v["cost_history"])
    assert v["plan_converged"] and np.all(np.diff(history) <= 0) and history[-1] < 0.5 * history[0]
    gap, gap_fine = np.array(v["gap"]), np.array(v["gap_fine"])
    assert gap.max() < 0.03                                             # model tracks Pymunk ...
    assert gap_fine.max() < 0.7 * gap.max()                             # ... closer with finer substeps
    assert v["final_mm"] < v["open_loop_mm"]                            # the feedback gains help
    assert tuple(v["dataset_images_shape"]) == (2, 2, 20, 32, 32, 3) and v["round_trip_ok"]


# Run first in the kernel: as if neither matplotlib nor IPython were installed (a kernel is IPython,
# so its own modules stay loaded; the notebook's `import`s of them raise ImportError).
WITHOUT_PLOTS = """import sys
for module in ("matplotlib", "matplotlib.pyplot", "IPython", "IPython.display"):
    sys.modules[module] = None"""


def test_world_notebook_runs_without_matplotlib_or_ipython(tmp_path):
    nb, v = run_notebook("01_world_and_expert.ipynb", tmp_path, first=WITHOUT_PLOTS, values=WORLD_VALUES)
    assert v["plt_is_none"] and v["demo_success"]
    assert "install matplotlib to see it" in stdout(*nb.cells)


def test_maml(tmp_path):
    _, v = run_notebook("02_maml.ipynb", tmp_path, values="""{
        "loss_before_step": float(loss_before_step), "loss_after_one_step": float(loss_after_one_step),
        "fd_relative_error": float(fd_relative_error), "first_order_relative_error": float(first_order_relative_error),
        "batched_matches_loop": bool(batched_matches_loop),
        "meta_loss_before": float(meta_loss_before), "meta_loss_after": float(meta_loss_after),
        "n_params": n_params, "flops_per_frame": float(flops_per_frame), "actions_shape": list(actions.shape)}""")
    assert v["loss_after_one_step"] < v["loss_before_step"]            # eq. (1) lowers the task's loss
    assert v["fd_relative_error"] < 1e-6                                # second order = finite differences
    assert v["first_order_relative_error"] > 100 * v["fd_relative_error"]
    assert v["batched_matches_loop"]
    assert v["meta_loss_after"] < 0.6 * v["meta_loss_before"]          # meta-training works on new sines
    assert v["n_params"] == 125_202 and v["flops_per_frame"] == pytest.approx(3.05e6, rel=0.01)
    assert tuple(v["actions_shape"]) == (20, 2)


def test_one_shot_imitation(tmp_path):
    # The pre-trained cells run on the shipped policy, as a student's do.
    assert os.path.exists(demo.PRETRAINED), f"the shipped policy {demo.PRETRAINED} is missing"
    _, v = run_notebook("03_one_shot_imitation.ipynb", tmp_path, values="""{
        "loss_before": float(loss_before), "loss_adapted": float(loss_adapted),
        "probe_before": float(probe_before), "probe_after": float(probe_after),
        "trial_success_is_bool": isinstance(trial["success"], bool), "trial_images_shape": list(trial["images"].shape),
        "pretrained_loss_before": pretrained_loss_before, "pretrained_loss_adapted": pretrained_loss_adapted,
        "pretrained_trials": len(pretrained_trials), "N_TRIALS": N_TRIALS,
        "blas_threads": host.blas_threads(1)}""")   # returns the count the notebook left (its `host`)
    assert v["loss_adapted"] < v["loss_before"]                        # eq. (1) on eq. (2) fits the demo
    assert v["probe_after"] < v["probe_before"]                        # a few meta-iterations help
    assert v["trial_success_is_bool"] and tuple(v["trial_images_shape"]) == (20, 32, 32, 3)
    assert v["pretrained_loss_adapted"] < v["pretrained_loss_before"]  # adapting the shipped policy fits the demo
    assert v["pretrained_trials"] == v["N_TRIALS"]
    assert v["blas_threads"] in (1, None)                              # the notebook set one BLAS thread


@pytest.fixture(scope="module")
def fig2_results(tmp_path_factory):
    """The results folder notebook 4 reads: the committed one (fig2.RESULTS) when it holds a
    Figure 2 sweep, else a folder made here with `python -m oneshot.experiments fig2 --profile tiny` (20
    runs of 2 meta-iterations: seconds), in the committed format, as fig2_quick. Its copy as fig2_search
    stands in for the hyperparameter search, so that the notebook's search table runs too."""
    if any((RESULTS / f"fig2_{p}" / "summary.json").exists() for p in ("paper", "paper-validation", "quick")):
        return RESULTS
    folder = tmp_path_factory.mktemp("fig2")
    results = folder / "results"
    command = [sys.executable, "-m", "oneshot.experiments", "fig2", "--profile", "tiny", "--no-progress",
               "--out", str(results / "fig2_quick"), "--work", str(folder / "work"), "--data", str(folder / "data")]
    done = subprocess.run(command, cwd=folder, env=kernel_env(), capture_output=True, text=True)
    assert done.returncode == 0, f"the tiny Figure 2 sweep failed:\n{done.stderr}"
    shutil.copytree(results / "fig2_quick", results / "fig2_search")
    return results


def with_results(results):
    """Notebook 4, its first code cell's `RESULTS = ...` line pointing at `results`."""
    nb = nbformat.read(NOTEBOOKS / "04_experiments.ipynb", as_version=4)
    first = next(c for c in nb.cells if c.cell_type == "code")
    first.source, n = re.subn(r"^RESULTS = .*$", f"RESULTS = {str(results)!r}", first.source, flags=re.M)
    assert n == 1, "notebook 4's first code cell must set RESULTS on one line `RESULTS = ...`"
    return nb


EXPERIMENT_VALUES = """{
    "results": RESULTS, "profile": PROFILE, "methods": ORDER, "sizes": SIZES, "rows": len(rows),
    "adaptation": adaptation, "inner_loops": [[size, a["successes"], b["successes"]] for size, a, b in inner_loops],
    "per_colour": per_colour, "search_table": search_table, "ablation_table": ablation_table, "scenes_table": scenes_table,
    "control_table": control_table, "live": live,
    "inner_loop_differences": {f"{folder} {size}": [d["difference"], d["ci_low"], d["ci_high"]]
                               for (folder, size), d in inner_loop_differences.items()},
    "ITERATIONS": ITERATIONS,
    "plt_is_none": plt is None}"""


def test_experiments(fig2_results, tmp_path):
    nb, v = execute(with_results(fig2_results), "04_experiments.ipynb", tmp_path, values=EXPERIMENT_VALUES)
    printed = stdout(*nb.cells).splitlines()
    profile = next((p for p in ("paper", "paper-validation") if (fig2_results / f"fig2_{p}" / "summary.json").exists()),
                   "quick")
    rows, summary = fig2.load_results(str(fig2_results / f"fig2_{profile}"))
    assert v["results"] == str(fig2_results) and v["profile"] == profile
    assert f"reproduce: python -m oneshot.experiments fig2 --profile {profile}" in printed
    # Section 2: every method and size the summary holds, and every run.
    points = {(m, p["size"]): p for m, ps in summary["methods"].items() for p in ps}
    assert sorted(v["methods"]) == sorted(summary["methods"]) and v["rows"] == len(rows) == summary["runs"]
    assert v["sizes"] == sorted({size for _, size in points})
    # Section 3: adapted vs unadapted, for exactly the MIL methods; the adapted counts, pooled from the
    # rows, are the summary's; the unadapted ones are counts of the same trials.
    mil = {m for m in summary["methods"] if methods.of(lines.LINES[m]).adapts}
    assert set(v["adaptation"]) == mil
    for method, by_size in v["adaptation"].items():
        assert sorted(map(int, by_size)) == sorted(p["size"] for p in summary["methods"][method])
        for size, (adapted, unadapted, trials) in by_size.items():
            p = points[method, int(size)]
            assert (adapted, trials) == (p["successes"], p["trials"]) and 0 <= unadapted <= trials
    # Section 4: one line per size both inner loops were run at, with the summary's counts.
    every = "mil-released+widths-flat" if "mil-released+widths-flat" in summary["methods"] else "mil-all"
    both = sorted({p["size"] for p in summary["methods"].get("mil-conv0", [])} &
                  {p["size"] for p in summary["methods"].get(every, [])})
    assert [line[0] for line in v["inner_loops"]] == both and (both or profile == "quick")
    assert all([a, b] == [points["mil-conv0", s]["successes"], points[every, s]["successes"]]
               for s, a, b in v["inner_loops"])
    # ... and the two inner loops paired on their colours (`difference`), in both folders that hold them;
    # at 2,304 with five seeds each, the numbers docs/results.md 8.5 quotes
    expected = {}
    for folder in ("fig2_paper", "fig2_paper-2304"):
        held = {r["method"] for r in read_rows(fig2_results / folder / "runs.csv")}
        if {every, "mil-conv0"} <= held:
            pairs = differences(line_rows(fig2_results / folder, every), line_rows(fig2_results / folder, "mil-conv0"))
            expected.update({f"{folder} {d['size']}": [d["difference"], d["ci_low"], d["ci_high"]] for d in pairs})
    assert v["inner_loop_differences"] == expected and (expected or profile == "quick")
    if "fig2_paper-2304 2304" in expected:
        assert [round(100 * x, 1) for x in expected["fig2_paper-2304 2304"]] == [-25.5, -55.2, 4.3]
    # Section 5: the per-colour counts add up to the summary's at each method's largest size, and are
    # of held-out colours of the grid palette.
    recorded = {r["method"] for r in rows if "per_colour" in json.loads(r["notes"])}
    assert set(v["per_colour"]) == recorded
    header = next(line.split() for line in printed if line.split()[:2] == ["colour", "name"])
    assert header == ["colour", "name", *v["per_colour"]]           # each method's column apart from the next
    scored = summary.get("config", {}).get("score", "validation")      # the split the sweep scored
    heldout = set(palette.split_colours(scored, palette.PaletteConfig(mode="grid")).tolist())
    for method, counts in v["per_colour"].items():
        largest = max((p for p in summary["methods"][method]), key=lambda p: p["size"])
        assert [sum(c[0] for c in counts.values()), sum(c[1] for c in counts.values())] == \
            [largest["successes"], largest["trials"]]
        assert {int(c) for c in counts} <= heldout
    # Section 6: one line per variant and size of the search, if there is one.
    search = fig2_results / "fig2_search" / "summary.json"
    if search.exists():
        variants = json.loads(search.read_text())["methods"]
        assert len(v["search_table"]) == sum(len(ps) for ps in variants.values())
    else:
        assert v["search_table"] is None
    # Section 4's ablation: every committed row, in the ablation's order, with its own counts.
    ablation = fig2_results / "fig2_ablation" / "runs.csv"
    expected = [[r["method"], r["seed"], r["successes"], r["trials"], json.loads(r["notes"])["unadapted_successes"]]
                for r in (read_rows(ablation) if ablation.exists() else [])]
    assert sorted(map(list, v["ablation_table"])) == sorted(expected)
    order = [lines.ABLATION.index(line) for line, *_ in v["ablation_table"]]
    assert order == sorted(order) and (len(expected) > 0) == ablation.exists()
    # ... and every committed scene check, its counts as its two files hold them.
    scenes = fig2_results / "fig2_ablation" / "scenes"
    expected = []
    for demo_file in sorted(scenes.glob("*_demo_scenes.json")):
        name = demo_file.name[:-len("_demo_scenes.json")]
        demo, new = json.loads(demo_file.read_text()), json.loads((scenes / f"{name}_new_scenes.json").read_text())
        assert demo["policy"]["recipe"].get("demo_scenes") and not new["policy"]["recipe"].get("demo_scenes")
        expected.append([name, demo["train"]["successes"], new["train"]["successes"],
                         demo["validation"]["successes"], new["validation"]["successes"]])
    assert list(map(list, v["scenes_table"])) == sorted(expected)
    picture = next(c for c in nb.cells if c.get("id") == "experiments-scenes-picture")   # ... and as a picture
    shown = [o["data"] for o in picture.outputs if o.get("output_type") == "display_data"]   # Agg: as text
    assert [d.get("text/plain", "")[:13] for d in shown] == ["<Figure size "] * bool(expected and not v["plt_is_none"])
    # ... and the other-colour control: each policy's own-colour and farthest-hue counts, as its files hold them
    # (Figure 2's seeds 1 and 2 in fig2_paper, seeds 3 and 4 in fig2_paper-2304), in the order of their names
    controls = [fig2_results / folder / "scenes" for folder in ("fig2_paper", "fig2_paper-2304")]
    expected, other_files = [], sorted((f for folder in controls for f in folder.glob("*_demo_scenes_other_colour.json")),
                                       key=lambda f: f.name)
    for other_file in other_files:
        name = other_file.name[:-len("_demo_scenes_other_colour.json")]
        own = json.loads((other_file.parent / f"{name}_demo_scenes.json").read_text())
        other = json.loads(other_file.read_text())
        assert other["policy"]["recipe"].get("other_colour_demo") and not own["policy"]["recipe"].get("other_colour_demo")
        expected.append([name, own["train"]["successes"], other["train"]["successes"], own["train"]["trials"]])
    assert list(map(list, v["control_table"])) == expected
    for folder in controls:                      # each scenes folder that exists has its controls in the table
        assert folder.exists() == any(f.parent == folder for f in other_files), folder
    # Section 7: every method of the figure ran; the trained ones' losses are finite and the fixed probe
    # meta-batch's loss fell; one trial per held-out colour (2).
    assert list(v["live"]) == list(lines.FIGURE)
    for method, r in v["live"].items():
        assert r["trials"] == 2 and 0 <= r["successes"] <= r["trials"]
        if "std" in r:
            assert r["std"] in lines.LINES[method].random_stds
        else:
            assert len(r["history"]) == v["ITERATIONS"] and np.all(np.isfinite(r["history"]))
            assert np.isfinite(r["probe_before"]) and r["probe_after"] < r["probe_before"], method


def test_experiments_notebook_runs_without_matplotlib(fig2_results, tmp_path):
    nb, v = execute(with_results(fig2_results), "04_experiments.ipynb", tmp_path, first=WITHOUT_PLOTS,
                    values=EXPERIMENT_VALUES)
    assert v["plt_is_none"] and len(v["live"]) == len(lines.FIGURE)
    assert "install matplotlib to see the figure" in stdout(*nb.cells)


def exercise_number(cell):
    """N if the code cell is tagged `exercise-N`, else None."""
    numbers = [int(tag[len("exercise-"):]) for tag in cell.metadata.get("tags", [])
               if re.fullmatch(r"exercise-\d+", tag)]
    assert len(numbers) <= 1, f"cell {cell.get('id')!r} is tagged with several exercises: {numbers}"
    return numbers[0] if numbers else None


@pytest.mark.parametrize("path", [pytest.param(p, id=p.name) for p in EXERCISE_NOTEBOOKS] or
                         [pytest.param(None, marks=pytest.mark.skip(reason="no notebooks in notebooks/exercises/"))])
def test_exercise_notebook_with_the_reference_solutions(path, tmp_path):
    try:
        exercises = importlib.import_module("oneshot.exercises")
    except ModuleNotFoundError as e:
        if e.name != "oneshot.exercises":
            raise
        pytest.skip("oneshot.exercises (the reference solutions) cannot be imported: it does not exist")
    from helpers import solution_source                  # it imports oneshot.exercises
    nb = nbformat.read(path, as_version=4)
    solved = {}                                          # exercise number -> the function's name
    for cell in nb.cells:
        n = exercise_number(cell) if cell.cell_type == "code" else None
        if n is not None:
            solved[n] = exercises.EXERCISES[n].name
            cell.source = solution_source(n)             # typed in, as a student would: reference(n) is flagged
    assert solved, f"{path.name}: no code cell is tagged exercise-N"
    # The notebook's own check cells run on the solutions; then the test asks the checker itself.
    nb.cells.append(added_cell("from oneshot.exercises import check"))
    verdicts = "{" + ", ".join(f'"{n}": check({n}, {name}).passed' for n, name in solved.items()) + "}"
    _, passed = execute(nb, f"exercises/{path.name}", tmp_path, values=verdicts)
    assert all(passed.values()), \
        f"{path.name}: the reference solutions fail the checks of exercises {[n for n, ok in passed.items() if not ok]}"
