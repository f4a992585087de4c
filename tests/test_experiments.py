"""The Figure 2 sweep machinery, with a fake run: plan, resume, failures, executors, summary, plot, CLI."""
import concurrent.futures
import csv
import dataclasses
import fcntl
import glob
import json
import os
import shlex
import shutil

import numpy as np
import pytest

from oneshot import collect, evaluate
from oneshot.data import collection, datasets
from oneshot.experiments import __main__ as command, fig2, folders, lines, parts
from oneshot.experiments import sweep as sweeping
from oneshot.training.scoring import wilson_interval
from oneshot.experiments.fig2 import PROFILES, plan, run_context
from oneshot.experiments.lines import LINES
from oneshot.training import checkpoint, run_data, run_folder
from oneshot.experiments import stats, summary
from oneshot.experiments.figure import plot
from oneshot.experiments.summary import summarise
from oneshot.experiments import rows as sweep_rows
from oneshot.experiments.rows import COLUMNS, RunSpec
from oneshot.experiments.sweep import sweep
from oneshot.tools import cli, host
from oneshot.expert.controller import ExpertConfig
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import WorldConfig
from test_checkpoint import _set, rewrite

TINY = PROFILES["tiny"]
HELDOUT_COLOURS = 12


def fake_run(spec, run_dir, context):
    """A run that trains nothing: deterministic numbers from the spec; one file per call in run_dir;
    fails while run_dir holds a file named "fail"."""
    with open(os.path.join(run_dir, f"call-{len(os.listdir(run_dir))}"), "w"):
        pass
    if os.path.exists(os.path.join(run_dir, "fail")):
        raise RuntimeError("told to fail")
    trials = HELDOUT_COLOURS * context["trials"]
    return {"successes": (spec.colours * spec.demos + spec.seed) % trials, "trials": trials,
            "final_loss": 0.5 + spec.seed, "profile": context["profile"]}


def calls(work_dir):
    return len(glob.glob(os.path.join(work_dir, "*", "call-*")))


def run_sweep(tmp_path, executor=None, **kwargs):
    with (concurrent.futures.ThreadPoolExecutor(2) if executor is None else executor) as ex:
        return sweep(plan(TINY), tmp_path / "results", tmp_path / "work", run_context(TINY, tmp_path / "data"),
                     executor=ex, run_fn=fake_run, progress=False, **kwargs)


def without_time(rows):
    return [{k: v for k, v in row.items() if k != "wall_seconds"} for row in rows]


def test_plan_is_every_method_size_and_seed_smallest_first():
    for cfg in PROFILES.values():
        runs = plan(cfg)
        assert sorted((r.method, (r.colours, r.demos), r.seed) for r in runs) == sorted(
            (m, s, seed) for m in cfg.methods for s in cfg.sizes for seed in cfg.seeds)
        assert len({r.run_id for r in runs}) == len(runs)
        assert all(r.iterations == fig2.iterations(cfg, r.method) for r in runs)
        assert all(fig2.iterations(cfg, m) == cfg.iterations for m in cfg.methods if m not in lines.LONGER)
        # seed by seed, small datasets first: the first len(sizes) x len(methods) runs draw the whole figure
        first = runs[:len(cfg.sizes) * len(cfg.methods)]
        assert {r.seed for r in first} == {cfg.seeds[0]} and [r.size for r in first] == sorted(r.size for r in first)
        # within a size, the lines in the profile's order (no measured costs in the code)
        for size in cfg.sizes:
            assert [r.method for r in first if (r.colours, r.demos) == size] == list(cfg.methods)
    assert plan(PROFILES["quick"])[0].method == PROFILES["quick"].methods[0]
    assert len(plan(PROFILES["paper"])) == 5 * 5 * 3
    for line in ("mil-released+widths+30k", "mil-released+widths+3steps+30k"):
        longer = [r for r in plan(PROFILES["ablation"]) if r.method == line]
        assert [(r.seed, r.iterations) for r in longer] == [(0, 30000), (1, 30000)]
    assert lines.LINES["mil-released+widths+3steps+30k"].inner_steps == 3
    with pytest.raises(ValueError, match=r"mil-released\+widths\+30k continues mil-released\+widths to 30000 iterations"):
        dataclasses.replace(PROFILES["ablation"], iterations=30000)


def test_the_2304_point_with_five_seeds_trains_and_scores_the_paper_profiles_runs():
    """`--profile paper-2304`'s seeds 0-2 are Figure 2's own runs at 2,304 (the same run ids, training
    configurations and scoring), so its rows extend the figure's point and a paper sweep's folders serve."""
    five, paper = PROFILES["paper-2304"], PROFILES["paper"]
    context = {k: v for k, v in run_context(five).items() if k != "profile"}
    assert context == {k: v for k, v in run_context(paper).items() if k != "profile"}
    ours = {r.run_id: r for r in plan(five)}
    theirs = [r for r in plan(paper) if r.size == 2304 and r.method.startswith("mil-")]
    assert sorted(r.run_id for r in theirs) == sorted(i for i, r in ours.items() if r.seed in paper.seeds)
    assert {r.seed for r in ours.values()} == {0, 1, 2, 3, 4} and five.score == "test"
    for run in theirs:
        assert fig2.run_config(ours[run.run_id], run_context(five)) == fig2.run_config(run, run_context(paper))


def test_the_ablation_lines_are_the_released_details_added_and_removed_one_at_a_time():
    all_, released, full = (lines.LINES[n] for n in ("mil-all", "mil-released", "mil-released+widths"))
    differ = lambda a, b: {f.name for f in dataclasses.fields(a) if getattr(a, f.name) != getattr(b, f.name)}
    for detail, change in lines.RELEASED.items():
        assert differ(lines.LINES[f"mil-all+{detail}"], all_) == set(change)
        assert differ(lines.LINES[f"mil-released-{detail}"], released) == set(change)
        assert differ(lines.LINES[f"mil-released+widths-{detail}"], full) == set(change)
        assert f"mil-all+{detail}" in lines.ABLATION and f"mil-released+widths-{detail}" in lines.ABLATION
    assert differ(full, released) == {"channels", "hidden"} and differ(released, all_) == set(lines._ALL)
    assert differ(lines.LINES["mil-released+widths+3steps"], full) == {"inner_steps"}
    assert differ(lines.LINES["mil-released+widths-flat+3steps"], lines.LINES["mil-released+widths-flat"]) == {"inner_steps"}
    # every committed row's line is still in the ablation (the notebook orders them by it)
    committed = os.path.join(os.path.dirname(__file__), "..", "results", "fig2_ablation", "runs.csv")
    assert {r["method"] for r in sweep_rows.read_rows(committed)} <= set(lines.ABLATION)
    net = fig2.methods.of(lines.LINES["mil-released+widths"]).network_config(32)
    assert (net.channels, net.hidden, net.init, net.layer_norm) == ((30, 30, 30), (200, 200), "released", True)
    assert released.init == "released" and fig2.PROFILES_TRAIN["released"].init == "released"


COMMITTED = sorted(glob.glob(os.path.join(os.path.dirname(__file__), "..", "results", "fig2_*", "summary.json")))


@pytest.mark.parametrize("summary_path", COMMITTED, ids=lambda p: os.path.basename(os.path.dirname(p)))
def test_each_profile_with_committed_results_still_plans_their_lines(summary_path):
    """The committed results/fig2_<profile> are reproduced by their command: the profile still names the
    lines, sizes and seeds they were run with (lines added for other sweeps do not leak into them)."""
    _, committed = fig2.load_results(os.path.dirname(summary_path))
    cfg = PROFILES[committed["config"]["name"]]
    assert list(cfg.methods) == committed["config"]["methods"]
    assert [list(s) for s in cfg.sizes] == committed["config"]["sizes"]
    assert list(cfg.seeds) == committed["config"]["seeds"]
    folders.check_results_folder(cfg, os.path.dirname(summary_path))     # its own command may write there


@pytest.mark.parametrize("summary_path", COMMITTED, ids=lambda p: os.path.basename(os.path.dirname(p)))
def test_each_committed_summary_is_its_runs_csv_summarised_again(summary_path):
    """Every published rate, interval and paired difference is what `summarise` computes from the committed
    rows today: the bootstrap's seeded stream (stats.METHOD), its percentiles, the mean over seeds and
    the pairs' order are all pinned by the numbers the README and docs quote."""
    rows, committed = fig2.load_results(os.path.dirname(summary_path))
    lines = [m for m in committed["config"]["methods"] if m in LINES]
    again = json.loads(json.dumps(summarise(rows, None, None, command._pairs(lines))))
    assert again["methods"] == committed["methods"]
    assert again["differences"] == committed["differences"]


def test_committed_results_are_found():
    assert len(COMMITTED) >= 3


def test_run_spec_names_and_checks():
    spec = RunSpec("lstm", 72, 12, 1, 6000)
    assert (spec.size, spec.run_id) == (864, "lstm_c72_d12_s1_i6000")
    assert RunSpec("mil-paper", 3, 4, 0, 2).run_id == "mil-paper_c3_d4_s0_i2"
    with pytest.raises(ValueError, match="methods must be distinct names from"):
        fig2.SweepConfig(methods=("mil-conv0", "maml"))
    with pytest.raises(ValueError, match="colours must be an int >= 1"):
        RunSpec("mil", 0, 3, 0, 2)
    with pytest.raises(ValueError, match="distinct products"):
        fig2.SweepConfig(sizes=((24, 6), (12, 12)))
    with pytest.raises(ValueError, match="larger than the collected data"):
        fig2.SweepConfig(sizes=((400, 8),))


def test_sweep_writes_one_row_per_run_with_the_columns(tmp_path):
    rows = run_sweep(tmp_path)
    with open(tmp_path / "results" / "runs.csv", newline="") as f:
        reader = csv.DictReader(f)
        written = list(reader)
    assert tuple(reader.fieldnames) == COLUMNS
    assert len(written) == len(rows) == len(plan(TINY))
    keys = [(r["method"], int(r["size"]), int(r["seed"])) for r in written]
    assert keys == sorted(keys)                                  # sorted by (method, size, seed)
    for row in written:
        spec = RunSpec(row["method"], int(row["colours"]), int(row["demos_per_colour"]), int(row["seed"]),
                       int(row["iterations"]))
        expected = fake_run(spec, tmp_path, run_context(TINY))
        assert int(row["size"]) == spec.size
        assert (int(row["successes"]), int(row["trials"])) == (expected["successes"], expected["trials"])
        assert float(row["rate"]) == round(expected["successes"] / expected["trials"], 4)
        lo, hi = wilson_interval(expected["successes"], expected["trials"])
        assert (float(row["ci_low"]), float(row["ci_high"])) == (round(lo, 4), round(hi, 4))
        assert json.loads(row["notes"]) == {"final_loss": 0.5 + spec.seed, "profile": "tiny"}
    assert without_time(sweep_rows.read_rows(tmp_path / "results" / "runs.csv")) == without_time(rows)


def test_second_sweep_redoes_nothing(tmp_path):
    first = run_sweep(tmp_path)
    assert calls(tmp_path / "work") == len(plan(TINY))
    second = run_sweep(tmp_path)
    assert calls(tmp_path / "work") == len(plan(TINY))
    assert second == first


def test_failed_run_is_left_out_and_retried_alone(tmp_path, capsys):
    bad = plan(TINY)[3]
    os.makedirs(tmp_path / "work" / bad.run_id)
    (tmp_path / "work" / bad.run_id / "fail").touch()
    rows = run_sweep(tmp_path)
    assert len(rows) == len(plan(TINY)) - 1
    assert bad.run_id not in {sweep_rows.row_id(r) for r in sweep_rows.read_rows(tmp_path / "results" / "runs.csv")}
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and bad.run_id in err[0] and "RuntimeError: told to fail" in err[0]
    assert "told to fail" in (tmp_path / "work" / bad.run_id / "error.txt").read_text()
    (tmp_path / "work" / bad.run_id / "fail").unlink()
    before = calls(tmp_path / "work")
    rows = run_sweep(tmp_path)
    assert calls(tmp_path / "work") == before + 1 and len(rows) == len(plan(TINY))
    assert not (tmp_path / "work" / bad.run_id / "error.txt").exists()


def test_bad_results_are_run_failures():
    spec = RunSpec("mil", 3, 3, 0, 2)
    for result, message in (({"successes": 5, "trials": 3}, "5 successes in 3 trials"),
                             ({"trials": 3}, "'successes' and 'trials'"),
                             ({"successes": 1, "trials": 3, "rate": 0.3}, "fills those columns itself")):
        with pytest.raises(ValueError, match=message):
            sweep_rows.row_of(spec, result, 1.0)
    row = sweep_rows.row_of(spec, {"successes": 1, "trials": 3, "wall_seconds": 99.0, "loss": np.float32(0.5),
                                    "steps": np.int64(7)}, 1.0)
    assert row["wall_seconds"] == 99.0 and json.loads(row["notes"]) == {"loss": 0.5, "steps": 7}


def test_a_second_sweep_on_the_same_work_folder_is_refused(tmp_path):
    os.makedirs(tmp_path / "work")
    with open(tmp_path / "work" / ".sweep.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)       # a sweep holds the folder
        with pytest.raises(sweeping.SweepLocked, match="another sweep is running"):
            run_sweep(tmp_path)
    assert calls(tmp_path / "work") == 0
    assert len(run_sweep(tmp_path)) == len(plan(TINY))          # released: the sweep runs


def test_a_finished_sweep_reads_its_rows_while_another_sweep_holds_the_folder(tmp_path):
    rows = run_sweep(tmp_path)
    with open(tmp_path / "work" / ".sweep.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert run_sweep(tmp_path) == rows                     # nothing to run: no lock needed
        (tmp_path / "results" / "runs.csv").write_text(
            "".join((tmp_path / "results" / "runs.csv").read_text().splitlines(True)[:-1]))
        with pytest.raises(sweeping.SweepLocked):              # one run to do again: the lock is needed
            run_sweep(tmp_path)
    assert calls(tmp_path / "work") == len(plan(TINY))


def test_thread_and_process_pools_give_the_same_rows(tmp_path):
    threads = run_sweep(tmp_path / "threads")
    processes = sweep(plan(TINY)[:4], tmp_path / "processes" / "results", tmp_path / "processes" / "work",
                      run_context(TINY, tmp_path / "threads" / "data"), run_fn=fake_run, progress=False)
    by_id = {sweep_rows.row_id(r): r for r in without_time(threads)}
    assert without_time(processes) == sorted((by_id[r.run_id] for r in plan(TINY)[:4]), key=sweep_rows.row_order)


def test_dask_executor_gives_the_same_rows(tmp_path):
    distributed = pytest.importorskip("distributed")
    runs = plan(TINY)[:2]
    threads = run_sweep(tmp_path / "threads")
    by_id = {sweep_rows.row_id(r): r for r in without_time(threads)}
    # In-process workers: a cluster of processes takes ~5 s to start (the process pool test above
    # covers pickling); what this checks is that Dask's executor plugs in unchanged.
    with distributed.Client(processes=False, n_workers=2, threads_per_worker=1, dashboard_address=None) as client:
        rows = sweep(runs, tmp_path / "dask" / "results", tmp_path / "dask" / "work",
                     run_context(TINY, tmp_path / "threads" / "data"), executor=client.get_executor(pure=False),
                     run_fn=fake_run, progress=False)
    assert without_time(rows) == sorted((by_id[r.run_id] for r in runs), key=sweep_rows.row_order)


def test_summarise_pools_seeds():
    def row(seed, successes, trials, size=(24, 8)):
        return {"method": "mil", "size": size[0] * size[1], "colours": size[0], "demos_per_colour": size[1],
                "seed": seed, "iterations": 10, "successes": successes, "trials": trials}
    rows = [row(0, 90, 120), row(1, 60, 120), row(2, 105, 120), row(0, 10, 40, size=(3, 3))]
    s = summarise(rows, PROFILES["tiny"], "python -m oneshot.experiments fig2 --profile tiny")
    small, big = s["methods"]["mil"]
    assert (small["size"], small["runs"], small["mean_rate"]) == (9, 1, 0.25)
    assert big["size"] == 192 and big["seeds"] == [0, 1, 2]
    assert (big["successes"], big["trials"]) == (255, 360)
    assert big["mean_rate"] == pytest.approx((0.75 + 0.5 + 0.875) / 3)
    assert (big["min_rate"], big["max_rate"]) == (0.5, 0.875)
    # The interval includes the seeds' spread (these rows have no per-colour counts: seeds alone are
    # resampled). By hand: the 27 equally likely draws of 3 of the rates {0.75, 0.5, 0.875}; each extreme
    # (all three 0.5, all three 0.875) has probability 1/27 > 2.5%, so the interval is [0.5, 0.875]: far
    # wider than the pooled binomial one (Wilson on 255/360: [0.659, 0.753]) that ignored the seeds.
    assert (big["ci_low"], big["ci_high"]) == (0.5, 0.875)
    assert "seeds and scored colours resampled" in s["interval"]
    assert s["config"]["name"] == "tiny" and s["runs"] == 4
    assert s["command"].endswith("--profile tiny")
    json.dumps(s)
    with pytest.raises(ValueError, match="mixes runs"):
        summarise([row(0, 1, 2, size=(24, 8)), row(1, 1, 2, size=(12, 16))])


def test_plot_writes_a_png(tmp_path):
    pytest.importorskip("matplotlib")
    rows = run_sweep(tmp_path)
    plot(summarise(rows), tmp_path / "fig2.png", lines.LABELS)
    assert (tmp_path / "fig2.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not glob.glob(str(tmp_path / ".tmp-*"))               # atomic: no temporary file left


@pytest.fixture
def tiny_argv(tmp_path, monkeypatch):
    """The fig2 command line of the tiny profile in tmp_path, its runs done by `fake_run` in threads."""
    monkeypatch.setattr(command, "run_one", fake_run)
    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor",
                        lambda workers, mp_context, **_: concurrent.futures.ThreadPoolExecutor(workers))
    return ["fig2", "--profile", "tiny", "--out", str(tmp_path / "out"), "--work", str(tmp_path / "w"),
            "--data", str(tmp_path / "data"), "--no-progress"]


def test_cli_writes_summary_and_says_when_the_plot_needs_matplotlib(tmp_path, monkeypatch, capsys, tiny_argv):
    monkeypatch.setattr(command, "PLOTS", False)
    argv = tiny_argv
    assert command.main(argv) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["runs"] == len(plan(TINY))
    assert summary["command"] == "python -m oneshot.experiments " + " ".join(argv)
    assert summary["config"] == json.loads(json.dumps(dataclasses.asdict(TINY)))
    assert 'pip install ".[plots]"' in capsys.readouterr().out
    assert not (tmp_path / "out" / "fig2.png").exists()


@pytest.mark.parametrize("held", ["runs", "summary"])
def test_cli_refuses_a_results_folder_of_another_profile(tmp_path, capsys, tiny_argv, held):
    """The committed quick profile's folder as --out of the tiny profile: refused before any work, every
    file as it was (its summary and figure would be replaced, and `summarise` would pool both)."""
    out = tmp_path / "out"
    shutil.copytree(os.path.join(os.path.dirname(__file__), "..", "results", "fig2_quick"), out)
    (out / ("summary.json" if held == "runs" else "runs.csv")).unlink()
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(SystemExit) as e:
        command.main(tiny_argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and f"{out} holds another sweep's results" in err, err
    assert ("runs that are not the tiny profile's" if held == "runs" else "a summary of the quick profile") in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before and not (tmp_path / "w").exists()


def test_cli_writes_no_summary_until_every_run_finished(tmp_path, monkeypatch, capsys, tiny_argv):
    """Notebook 04 shows a profile's summary.json as its figure: it is written only for the whole sweep."""
    monkeypatch.setattr(command, "PLOTS", False)
    argv = tiny_argv
    bad = plan(TINY)[0]
    (tmp_path / "w" / bad.run_id).mkdir(parents=True)
    (tmp_path / "w" / bad.run_id / "fail").touch()
    assert command.main(argv) == 1
    assert f"{len(plan(TINY)) - 1} of {len(plan(TINY))} runs finished" in capsys.readouterr().out
    assert not (tmp_path / "out" / "summary.json").exists()
    (tmp_path / "w" / bad.run_id / "fail").unlink()
    assert command.main(argv) == 0
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["runs"] == len(plan(TINY))


def test_cli_seeds_sweeps_part_of_the_profile_into_files_of_its_own(tmp_path, capsys, tiny_argv):
    """--seeds 0: seed 0's runs only; its summary and figure are named for the seed, and the profile's
    summary.json (which notebook 04 reads as the whole figure) is not written."""
    argv = tiny_argv + ["--seeds", "1"]
    assert command.main(argv) == 0
    seed1 = [r for r in plan(TINY) if r.seed == 1]
    assert 0 < len(seed1) < len(plan(TINY)) and calls(tmp_path / "w") == len(seed1)
    summary = json.loads((tmp_path / "out" / "summary_seeds1.json").read_text())
    assert summary["runs"] == len(seed1) and summary["config"]["seeds"] == [1]
    assert all(point["seeds"] == [1] for points in summary["methods"].values() for point in points)
    assert not (tmp_path / "out" / "summary.json").exists()
    assert (tmp_path / "out" / "fig2_seeds1.png").exists() == command.PLOTS
    assert command.main(argv[:-2] + ["--seeds", "0", "1"]) == 0              # every seed: the whole figure
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["runs"] == len(plan(TINY))
    assert calls(tmp_path / "w") == len(plan(TINY))                           # seed 1's runs not redone


def test_cli_lines_sweeps_some_lines_into_files_of_their_own(tmp_path, capsys, tiny_argv):
    """--lines L --seeds S: one line's runs of one seed (reproducing one run), in files named for them."""
    line = TINY.methods[1]
    assert command.main(tiny_argv + ["--lines", line, "--seeds", "0"]) == 0
    chosen = [r for r in plan(TINY) if r.seed == 0 and r.method == line]
    assert len(chosen) == len(TINY.sizes) and calls(tmp_path / "w") == len(chosen)
    assert sorted(d for d in os.listdir(tmp_path / "w") if not d.startswith(".")) == sorted(r.run_id for r in chosen)
    summary = json.loads((tmp_path / "out" / f"summary_seeds0_{line}.json").read_text())
    assert list(summary["methods"]) == [line] and summary["runs"] == len(chosen)
    assert not (tmp_path / "out" / "summary.json").exists()
    assert command.main(tiny_argv) == 0                                     # the rest, not these again
    assert calls(tmp_path / "w") == len(plan(TINY))


def test_many_lines_make_a_short_file_name():
    many = PROFILES["ablation"].methods[:-1]
    assert parts.lines_part(["lstm", "random"]) == "lstm_random"
    short = parts.lines_part(many)
    assert short.startswith(f"{len(many)}lines-") and len(short) < 30 and short == parts.lines_part(many)
    assert short != parts.lines_part(many[:-1])


def test_cli_summarise_redoes_a_finished_sweeps_summary_and_refuses_an_unfinished_one(tmp_path, monkeypatch, capsys,
                                                                                       tiny_argv):
    monkeypatch.setattr(command, "PLOTS", False)
    assert command.main(tiny_argv) == 0
    out = tmp_path / "out"
    before = json.loads((out / "summary.json").read_text())
    assert command.main(["summarise", str(out)]) == 0
    after = json.loads((out / "summary.json").read_text())
    assert after["summarised_by"] == f"python -m oneshot.experiments summarise {out}"
    assert capsys.readouterr().out.endswith(f"runs: {out / 'summary.json'}\n")         # no figure: none said
    drawn = []
    monkeypatch.setattr(command, "PLOTS", True)
    monkeypatch.setattr(command, "plot", lambda summary, path, *args, **kwargs: drawn.append(path))
    assert command.main(["summarise", str(out)]) == 0
    assert capsys.readouterr().out.endswith(f"runs: {out / 'summary.json'}\nfigure: {out / 'fig2.png'}\n")
    assert drawn == [str(out / "fig2.png")]
    assert (after["command"], after["config"], after["methods"]) == (before["command"], before["config"], before["methods"])
    rows = sweep_rows.read_rows(out / "runs.csv")           # a run's row gone: the sweep is not finished
    gone = next(r for r in rows if (r["method"], r["seed"]) == ("mil-conv0", 0) and r["size"] == min(r["size"] for r in rows))
    sweep_rows.write_rows([r for r in rows if r is not gone], out / "runs.csv")
    written = (out / "summary.json").read_text()
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        cli.run(command.main, ["summarise", str(out)])
    assert stop.value.code == 2 and (out / "summary.json").read_text() == written
    assert capsys.readouterr().err == (f"error: {out / 'runs.csv'} lacks 1 of its sweep's {len(rows)} runs (mil-conv0 "
                                       f"at {gone['size']} demos, seed 0): summarise redoes a finished sweep's summary; "
                                       f"finish the sweep first ({before['command']})\n")
    (out / "summary.json").unlink()                         # a sweep still running has only its runs.csv
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        cli.run(command.main, ["summarise", str(out)])
    assert stop.value.code == 2
    assert capsys.readouterr().err == (f"error: {out} holds no summary.json: summarise redoes a finished sweep's "
                                       f"summary; finish the sweep first (run its fig2 command again)\n")


@pytest.mark.parametrize("text, says", [("[]", "is not a Figure 2 summary"), ('{"config": "x"}', "is not a Figure 2 summary"),
                                         ('{"config": {"methods": 5}}', "is not a Figure 2 summary"),
                                         ('{"config": {"sizes": null}}', "is not a Figure 2 summary"),
                                         ('{"config": {"sizes": [9]}}', "is not a Figure 2 summary"),
                                         ('{"config": {"sizes": [[3, "3"]]}}', "is not a Figure 2 summary"),
                                         ('{"config": {"seeds": 0}}', "is not a Figure 2 summary"),
                                         ('{"config": {"seeds": [true]}}', "is not a Figure 2 summary"),
                                         ('{"config": {', "is not JSON")])
def test_summarise_refuses_a_damaged_summary_in_one_line(tmp_path, capsys, text, says):
    (tmp_path / "summary.json").write_text(text)
    (tmp_path / "runs.csv").write_text(",".join(COLUMNS) + "\n")
    with pytest.raises(SystemExit) as stop:
        cli.run(command.main, ["summarise", str(tmp_path)])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert f"{tmp_path / 'summary.json'} {says}" in err and "restore it (git checkout)" in err
    assert (tmp_path / "summary.json").read_text() == text


def test_cli_sizes_sweeps_one_point_first_into_files_of_its_own(tmp_path, capsys, tiny_argv):
    """--sizes N: only the runs of that size (e.g. the headline point before the rest), in files named for
    it; the whole sweep afterwards does the others and not these again."""
    size = 12
    assert command.main(tiny_argv + ["--sizes", str(size), "--seeds", "1"]) == 0
    chosen = [r for r in plan(TINY) if r.size == size and r.seed == 1]
    assert 0 < len(chosen) < len(plan(TINY)) and calls(tmp_path / "w") == len(chosen)
    assert sorted(d for d in os.listdir(tmp_path / "w") if not d.startswith(".")) == sorted(r.run_id for r in chosen)
    summary = json.loads((tmp_path / "out" / f"summary_seeds1_sizes{size}.json").read_text())
    assert summary["runs"] == len(chosen) and summary["config"]["sizes"] == [[3, 4]]
    assert all(point["size"] == size for points in summary["methods"].values() for point in points)
    assert not (tmp_path / "out" / "summary.json").exists()
    assert (tmp_path / "out" / f"fig2_seeds1_sizes{size}.png").exists() == command.PLOTS
    assert command.main(tiny_argv + ["--sizes", "12", "9"]) == 0              # every size: the whole figure
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["runs"] == len(plan(TINY))
    assert calls(tmp_path / "w") == len(plan(TINY))                           # the first runs not redone


@pytest.mark.parametrize("argv, message", [
    (["fig2", "--profile", "tiny", "--seeds", "7"], "--seeds must be distinct seeds of the tiny profile, [0, 1]"),
    (["fig2", "--profile", "tiny", "--seeds", "0", "0"], "--seeds must be distinct"),
    (["fig2", "--profile", "tiny", "--lines", "mil-conv0", "nope"], "--lines must be distinct lines of the tiny profile"),
    (["fig2", "--profile", "tiny", "--lines", "lstm", "lstm"], "--lines must be distinct lines"),
    (["fig2", "--profile", "tiny", "--sizes", "10"], "--sizes must be distinct sizes of the tiny profile, in "
                                                     "demonstrations (9, 12); got 10"),
    (["fig2", "--profile", "tiny", "--sizes", "9", "9"], "--sizes must be distinct sizes"),
    (["fig2", "--profile", "huge"], "invalid choice: 'huge'"),
    (["fig2", "--workers", "0"], "argument --workers: expected a whole number >= 1"),
    (["fig2", "--workers", "2", "--local-cluster", "2"], "not allowed with argument"),
    (["fig2", "--local-cluster", "0"], "argument --local-cluster: this machine has"),
    (["fig2", "--local-cluster", "100000"], "1 to that many workers (a cluster of more machines: --scheduler); "
                                            "got 100000"),
    (["fig2", "--profile", "tiny", "--work", "w", "--out", "w"], "argument --out: w is in the sweep's work folder w"),
    (["fig2", "--profile", "tiny", "--work", "w", "--out", "w/results"], "is in the sweep's work folder"),
    (["fig3"], "invalid choice: 'fig3'"),
])
def test_cli_argument_errors_are_one_line_and_status_2(argv, message, capsys):
    with pytest.raises(SystemExit) as e:
        command.main(argv)
    err = capsys.readouterr().err
    assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and message in err


def test_cli_names_the_cluster_extra_when_dask_is_missing(monkeypatch, capsys):
    monkeypatch.setattr(command, "distributed", None)
    with pytest.raises(SystemExit) as e:
        command.main(["fig2", "--scheduler", "tcp://localhost:8786"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and 'pip install ".[cluster]"' in err


def test_a_wrong_or_damaged_dataset_in_data_is_named_once_before_any_run(tmp_path, capsys, tiny_argv):
    """A file in --data that is not what the sweep collects (truncated; another seed; another image
    size) is named in one line with the sweep's fix, exit 2, before any run starts, and before a missing
    file is collected. It was one failed run per line, exit 1, and a 16-pixel meta-training set was
    blamed on the right validation file."""
    data = tmp_path / "data"
    fig2.ensure_data(TINY, data, workers=1, progress=False)
    paths = fig2.data_paths(TINY, data)
    good = {split: open(path, "rb").read() for split, path in paths.items()}
    noise = ExpertConfig(action_noise=LINES["mil-conv0"].demo_noise)

    def collected(split, seed, **world):
        datasets.save(collection.collect(*TINY.splits()[split], split, seed, 1, WorldConfig(
            palette=PaletteConfig(mode=TINY.palette_mode), **world), noise, False), tmp_path / "other.npz")
        return (tmp_path / "other.npz").read_bytes()
    wrong = [("train", good["train"][:len(good["train"]) // 2], "is not a readable .npz dataset (truncated or "
                                                                "corrupt: File is not a zip file); move it away"),
             ("validation", collected("validation", 7), "was collected with other settings than this sweep's "
                                                       "validation data: seed 7, not 1"),
             ("train", collected("train", run_data.SEEDS["train"], image_size=16),
              "was collected in another world than this sweep's: image_size 16, not 32")]
    capsys.readouterr()
    for (split, text, says), gone in zip(wrong, ("test", "train", "validation")):
        open(paths[split], "wb").write(text)
        os.remove(paths[gone])                           # another split's file, not yet collected
        with pytest.raises(SystemExit) as e:
            cli.run(command.main, tiny_argv)
        err = capsys.readouterr().err
        assert e.value.code == 2 and len(err.strip().splitlines()) == 1 and paths[split] in err and says in err, err
        assert "name another --data" in err and "collecting" not in err and not os.path.exists(paths[gone])
        assert not (tmp_path / "out" / "runs.csv").exists() and not (tmp_path / "w").exists()   # no run started
        for name in (split, gone):
            open(paths[name], "wb").write(good[name])
    assert command.main(tiny_argv) == 0 and len(sweep_rows.read_rows(tmp_path / "out" / "runs.csv")) == len(plan(TINY))


def test_real_runs_resume_and_give_the_same_rows_in_threads_and_processes(tmp_path):
    """Two real tiny runs (`fig2.run_one`: train, checkpoint, score on the held-out trials) in a
    thread pool and in the default process pool: the same rows; a second sweep trains nothing again."""
    runs = [r for r in plan(TINY) if r.seed == 0 and r.method in ("mil-conv0", "lstm") and r.size == 9]
    fig2.ensure_data(TINY, tmp_path / "data", workers=1, progress=False)
    context = run_context(TINY, tmp_path / "data")
    with concurrent.futures.ThreadPoolExecutor(2) as ex:
        threads = sweep(runs, tmp_path / "t" / "results", tmp_path / "t" / "work", context, fig2.run_one,
                        executor=ex, progress=False)
    processes = sweep(runs, tmp_path / "p" / "results", tmp_path / "p" / "work", context, fig2.run_one,
                      progress=False)
    assert len(threads) == 2 and without_time(threads) == without_time(processes)
    assert all(r["trials"] == 2 * TINY.trials for r in threads)              # 2 held-out colours
    checkpoints = sorted(glob.glob(str(tmp_path / "p" / "work" / "*" / "checkpoint.npz")))
    stamps = [os.path.getmtime(c) for c in checkpoints]
    assert len(checkpoints) == 2
    again = sweep(runs, tmp_path / "p" / "results", tmp_path / "p" / "work", context, fig2.run_one,
                  progress=False)
    assert again == processes and [os.path.getmtime(c) for c in checkpoints] == stamps


def test_a_run_with_a_moving_average_also_scores_its_raw_parameters_as_evaluate_does(tmp_path):
    """notes["raw"]: the parameters Adam trained, scored on the same trials as the row (what a run without
    the moving average would score); the same counts and eq. (2) as `python -m oneshot.evaluate --raw`."""
    spec = next(r for r in plan(TINY) if r.seed == 0 and r.method == "mil-conv0" and r.size == 9)
    assert lines.LINES[spec.method].ema > 0
    fig2.ensure_data(TINY, tmp_path / "data", workers=1, progress=False)
    context = run_context(TINY, tmp_path / "data")
    notes = fig2.run_one(spec, str(tmp_path / "run"), context)
    raw = notes["raw"]
    evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--raw", "--split", TINY.score, "--trials", str(TINY.trials),
                   "--train", "", "--unadapted", "--json", str(tmp_path / "raw.json")])
    scored = json.loads((tmp_path / "raw.json").read_text())
    assert (raw["successes"], raw["unadapted_successes"]) == (scored[TINY.score]["successes"],
                                                              scored[f"{TINY.score}_unadapted"]["successes"])
    assert [raw["eq2_before"], raw["eq2_after"]] == [round(scored["adaptation_gain"][k], 4) for k in ("before", "after")]
    assert raw["eq2_before"] != notes["eq2_before"]                         # not the moving average's
    assert set(raw) == {"successes", "unadapted_successes", "eq2_before", "eq2_after"}


def test_evaluate_scores_with_one_blas_thread(tmp_path, monkeypatch):
    """`python -m oneshot.evaluate` runs its trials with one BLAS thread, as train, fig2 and the demo do:
    its products are small and OpenBLAS's spinning threads made it 5-10x slower beside other work."""
    before = host.blas_threads(2)
    if before is None:
        pytest.skip("NumPy's BLAS is not an OpenBLAS that oneshot.tools.host can reach")
    spec = next(r for r in plan(TINY) if r.seed == 0 and r.method == "mil-conv0" and r.size == 9)
    fig2.ensure_data(TINY, tmp_path / "data", workers=1, progress=False)
    fig2.run_one(spec, str(tmp_path / "run"), run_context(TINY, tmp_path / "data"))
    seen, score = [], evaluate.imitation.one_shot_success

    def scoring(*args, **kwargs):                 # the count at scoring time (read by setting it, then put back)
        seen.append(host.blas_threads(1))
        host.blas_threads(seen[-1])
        return score(*args, **kwargs)
    monkeypatch.setattr(evaluate.imitation, "one_shot_success", scoring)
    try:
        host.blas_threads(2)
        evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--split", TINY.score, "--trials", "1", "--train", ""])
    finally:
        host.blas_threads(before)
    assert seen == [1]


def test_a_resumed_run_counts_the_training_time_of_its_killed_sittings(tmp_path):
    """run_one's wall_seconds: the checkpoint's meta-training seconds (every sitting) plus the scoring;
    a checkpoint from before that record gives this sitting's time and says so in the notes."""
    spec = next(r for r in plan(TINY) if r.seed == 0 and r.method == "mil-conv0" and r.size == 9)
    fig2.ensure_data(TINY, tmp_path / "data", workers=1, progress=False)
    context = run_context(TINY, tmp_path / "data")
    whole = fig2.run_one(spec, str(tmp_path / "whole"), context)
    for name, seconds in (("killed", 1000.0), ("older", None)):
        run = tmp_path / name
        run_folder.train(fig2.run_config(spec, context), run, progress=False, stop_after=spec.iterations // 2)
        rewrite(run / "checkpoint.npz", _set(None, "seconds", seconds))    # "killed" after 1000 s of training
        resumed = fig2.run_one(spec, str(run), context)
        assert {k: v for k, v in resumed.items() if k not in ("wall_seconds", "wall")} == \
            {k: v for k, v in whole.items() if k != "wall_seconds"}
        if seconds is None:
            assert resumed["wall"] == "this sitting" and resumed["wall_seconds"] < 1000
        else:
            assert "wall" not in resumed and 1000 < resumed["wall_seconds"] < 1000 + 10 * whole["wall_seconds"]



def test_a_longer_line_continues_its_shorter_runs_checkpoint_and_equals_a_run_from_scratch(tmp_path, monkeypatch):
    """A LONGER line's run starts from the shorter line's finished run (same size and seed) when it
    exists: the same numbers, log and notes as training it from scratch, and it says what it continued;
    a shorter run killed half way, or trained with another config, is not continued."""
    monkeypatch.setitem(lines.LONGER, "long", ("mil-conv0", 4))
    monkeypatch.setitem(lines.LINES, "long", lines.LINES["mil-conv0"])
    every = fig2.run_config
    monkeypatch.setattr(fig2, "run_config", lambda spec, context: dataclasses.replace(
        every(spec, context), log_every=1, eval_every=1, eval_trials=1))        # a log line per iteration
    short = next(r for r in plan(TINY) if r.seed == 0 and r.method == "mil-conv0" and r.size == 9)
    long = dataclasses.replace(short, method="long", iterations=4)
    fig2.ensure_data(TINY, tmp_path / "data", workers=1, progress=False)
    context = run_context(TINY, tmp_path / "data")
    scratch = fig2.run_one(long, str(tmp_path / "scratch" / long.run_id), context)
    fig2.run_one(short, str(tmp_path / "w" / short.run_id), context)
    continuing, before = [], fig2._continue_shorter
    monkeypatch.setattr(fig2, "_continue_shorter", lambda *a: continuing.append(before(*a)) or continuing[-1])
    continued = fig2.run_one(long, str(tmp_path / "w" / long.run_id), context)
    assert continuing == [True] and continued.pop("continued_from") == short.run_id
    assert "continued_from" not in scratch and without_time([scratch]) == without_time([continued])
    assert "meta_loss_end" in scratch
    logs = [[{k: v for k, v in json.loads(line).items() if k != "seconds"}
             for line in open(tmp_path / w / long.run_id / "log.jsonl")] for w in ("scratch", "w")]
    assert logs[0] == logs[1] and [r["iteration"] for r in logs[0] if "meta_loss" in r] == [1, 2, 3, 4]
    assert any("validation_success" in r for r in logs[0])
    ckpts = [checkpoint.load(tmp_path / w / long.run_id / "checkpoint.npz") for w in ("scratch", "w")]
    assert [c["iteration"] for c in ckpts] == [4, 4]
    assert all(np.array_equal(ckpts[0]["params"][k], ckpts[1]["params"][k]) for k in ckpts[0]["params"])
    monkeypatch.setattr(fig2, "_continue_shorter", before)
    # the shorter run killed half way, or trained on other data: the longer one trains from its own start
    run_folder.train(fig2.run_config(short, context), tmp_path / "k" / short.run_id, progress=False, stop_after=1)
    assert not fig2._continue_shorter(long, str(tmp_path / "k" / long.run_id), context)
    shutil.copytree(tmp_path / "w" / short.run_id, tmp_path / "w3" / short.run_id)
    other = dict(context, train_data=context["validation_data"])
    assert not fig2._continue_shorter(long, str(tmp_path / "w3" / long.run_id), other)
    assert fig2._continue_shorter(long, str(tmp_path / "w3" / long.run_id), context)        # the same, as trained
    assert not os.path.exists(tmp_path / "k" / long.run_id)
    assert fig2._continue_shorter(long, str(tmp_path / "w2" / long.run_id), context) is False   # no shorter run there
    monkeypatch.setitem(lines.LINES, "long", dataclasses.replace(lines.LINES["mil-conv0"], lr_schedule="cosine"))
    monkeypatch.setitem(lines.LINES, "mil-conv0", lines.LINES["long"])
    with pytest.raises(ValueError, match="long continues mil-conv0 to 4 iterations: .* a constant step size"):
        dataclasses.replace(TINY, methods=("mil-conv0", "long"))


def test_final_meta_loss_is_the_median_of_the_last_iterations_logged(tmp_path):
    log = tmp_path / "log.jsonl"
    records = [{"iteration": i, "meta_loss": float(i), "seconds": 1.0} for i in range(50, 1001, 50)]
    records.insert(5, {"iteration": 300, "validation_success": 0.5, "trials": 4})
    log.write_text("".join(json.dumps(r) + "\n" for r in records))
    assert fig2.final_meta_loss(log) == 775.0                 # iterations 550..1000
    assert fig2.final_meta_loss(log, last=100) == 975.0       # 950 and 1000
    log.write_text(json.dumps({"iteration": 0, "fit_on_validation_colours": {}}) + "\n")
    assert fig2.final_meta_loss(log) is None


def test_the_two_level_interval_on_a_case_computed_by_hand():
    """Two seeds x two colours, 2 trials each. Seed A: 1/2 and 2/2; seed B: 0/2 and 1/2. A replicate draws
    2 seeds and 2 colours with replacement (16 equally likely draws); its rate is the mean over the drawn
    seeds of their success on the drawn colours. The lowest, 0 (seeds B B, colours 1 1), and the highest,
    1 (A A, 2 2), each have probability 1/16 > 2.5%: the interval is [0, 1] around the mean 0.5. The same
    counts as a single pooled colour per seed give seed rates 0.75 and 0.25, the interval [0.25, 0.75]."""
    successes, trials = np.array([[1, 2], [0, 1]]), np.full((2, 2), 2)
    assert stats.interval(successes, trials) == (0.5, 0.0, 1.0)
    assert stats.interval(successes.sum(1, keepdims=True), trials.sum(1, keepdims=True)) == (0.5, 0.25, 0.75)
    # Differences are paired over colours, each point's seeds drawn on their own. One seed each: a point
    # against itself is 0 in every replicate, against a copy one success better on every colour exactly
    # +0.5 (2 trials a colour): the colours' spread cancels. With both seeds, the seeds' spread does not:
    # A A against B B is 0.75 - 0.25, B B against A A the opposite, each with probability 1/16.
    one = (successes[:1], trials[:1])
    assert stats.difference_interval(one, one) == (0.0, 0.0, 0.0)
    assert stats.difference_interval((one[0] + 1, one[1]), one) == (0.5, 0.5, 0.5)
    assert stats.difference_interval((successes, trials), (successes, trials)) == (0.0, -0.5, 0.5)
    with pytest.raises(ValueError, match="successes within trials"):
        stats.interval(np.array([[3]]), np.array([[2]]))


@pytest.mark.parametrize("folder, says", [
    ("missing", "holds no runs.csv; name a sweep's results folder"),
    ("damaged", "not a runs.csv row (it has 2 fields, not 13); name another results folder to compare with"),
    ("unrelated", "holds no point of this sweep (no runs.csv rows of its lines and sizes); name the results of "
                  "the same profile, e.g. results/fig2_tiny"),
    ("validation", "was scored on the validation colours and this sweep scores the test colours: their points "
                   "do not compare")])
def test_a_compare_folder_is_checked_before_the_sweep(tmp_path, monkeypatch, capsys, folder, says):
    """Before any data or run: a compare folder that is missing, damaged, shares no point with the sweep,
    or was scored on other colours (the committed quick results predate the test split) is refused."""
    committed = os.path.join(os.path.dirname(__file__), "..", "results", "fig2_quick")
    monkeypatch.chdir(tmp_path)
    os.makedirs("damaged")
    with open(os.path.join("damaged", "runs.csv"), "w") as f:
        f.write(",".join(COLUMNS) + "\nhello,world\n")
    shutil.copytree(committed, "unrelated")                       # the quick profile's: no point of tiny's
    os.makedirs("validation")                                     # tiny's points, scored on validation
    sweep_rows.write_rows([sweep_rows.row_of(plan(TINY)[0], {"successes": 1, "trials": 4}, 1.0)],
                          os.path.join("validation", "runs.csv"))
    with open(os.path.join("validation", "summary.json"), "w") as f:
        json.dump({"config": {"name": "tiny", "score": "validation"}}, f)
    with pytest.raises(SystemExit) as e:
        command.main(["fig2", "--profile", "tiny", "--no-progress", "--compare", folder])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "argument --compare: " in err and says in err, err
    assert sorted(os.listdir(".")) == ["damaged", "unrelated", "validation"]   # no data collected, no run, no results


def test_compare_says_which_points_agree_within_their_interval():
    def rows(successes_by_seed):
        return [{"method": "mil-conv0", "size": 9, "colours": 3, "demos_per_colour": 3, "seed": seed, "iterations": 2,
                 "successes": sum(per), "trials": 4 * len(per),
                 "notes": json.dumps({"per_colour": {str(c): n for c, n in enumerate(per)}})}
                for seed, per in enumerate(successes_by_seed)]
    committed = rows([[2, 3, 1], [3, 2, 2], [2, 2, 1]])
    assert [p["agree"] for p in summary.compare(rows([[2, 2, 2], [3, 3, 1], [1, 2, 2]]), committed)] == [True]
    assert [p["agree"] for p in summary.compare(rows([[4, 4, 4], [4, 4, 4], [4, 4, 4]]), committed)] == [False]


def test_an_interrupted_sweep_counts_the_runs_it_has_finished(tmp_path, monkeypatch, capsys):
    """Ctrl-C: `N of M runs finished`, counting the rows this work folder produced (all, with --keep-rows),
    not every row of runs.csv (committed rows are run again)."""
    monkeypatch.chdir(tmp_path)
    assert command.main(["fig2", "--profile", "tiny", "--data-only", "--data", "d", "--no-progress"]) == 0
    spec = next(r for r in plan(TINY) if r.method == "mil-conv0" and r.seed == 0)
    row = sweeping.execute(fig2.run_one, spec, os.path.abspath(os.path.join("w", spec.run_id)), run_context(TINY, "d"))
    committed = dict(row, seed=1)                                       # a row no run of w produced
    os.makedirs("o")
    sweep_rows.write_rows([row, committed], os.path.join("o", "runs.csv"))

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(command, "sweep", interrupted)
    for keep, finished in (([], 1), (["--keep-rows"], 2)):
        assert command.main(["fig2", "--profile", "tiny", "--data", "d", "--work", "w", "--out", "o", "--no-progress",
                             *keep]) == 130
        assert (f"error: interrupted; {finished} of {len(plan(TINY))} runs finished (o/runs.csv), the others continue "
                f"from their checkpoints" in capsys.readouterr().err)


def test_ctrl_c_while_a_sweep_collects_its_data_names_the_collection_not_runs(tmp_path, monkeypatch, capsys):
    """Ctrl-C during `fig2`'s data collection (`--data-only` or before the runs): one line saying how far
    the collection got and that its dataset was not written, not "0 of N runs finished, the others
    continue from their checkpoints" (there are none); status 130, no file in --data."""
    monkeypatch.chdir(tmp_path)
    recorded, real = [], collection._demo_job

    def job(args):                           # the second demo is interrupted
        if recorded:
            raise KeyboardInterrupt
        recorded.append(args)
        return real(args)
    monkeypatch.setattr(collection, "_demo_job", job)
    monkeypatch.setattr(command, "ensure_data", lambda cfg, data, progress: fig2.ensure_data(cfg, data, 1, progress))
    for only in (["--data-only"], []):
        recorded.clear()
        with pytest.raises(SystemExit) as e:
            cli.run(command.main, ["fig2", "--profile", "tiny", "--data", "d", "--no-progress", *only])
        train = TINY.splits()["train"]
        path = fig2.data_paths(TINY, "d")["train"]
        assert e.value.code == 130 and capsys.readouterr().err.splitlines()[-1] == (
            f"error: interrupted while collecting train demos (1 of {train[0] * train[1]} recorded); {path} was not "
            f"written: run the same command again")
        assert [files for _, _, files in os.walk("d") if files] == []          # no dataset, no .tmp-* file
    # Ctrl-C before the runs but not while collecting (saving a dataset, starting a Dask cluster): no run
    # had started, so none is counted or said to continue from a checkpoint.
    monkeypatch.setattr(command, "ensure_data", lambda *args, **kwargs: _raise(KeyboardInterrupt()))
    with pytest.raises(SystemExit) as e:
        cli.run(command.main, ["fig2", "--profile", "tiny", "--data", "d", "--no-progress"])
    assert e.value.code == 130 and capsys.readouterr().err.splitlines()[-1] == (
        "error: interrupted before any run started: run the same command again")


def _raise(error):
    raise error


def test_a_work_folder_resumed_with_other_data_is_refused_once_before_collecting(tmp_path, monkeypatch, capsys):
    """A sweep's work folder with a checkpoint trained on --data d, resumed with --data e: one line, exit
    2, before collecting e's datasets (its runs would each fail to resume). With --data d, or a damaged
    checkpoint (left to its run), or once the run's row is done, it goes on."""
    monkeypatch.chdir(tmp_path)
    assert command.main(["fig2", "--profile", "tiny", "--data-only", "--data", "d", "--no-progress"]) == 0
    spec = next(r for r in plan(TINY) if r.method == "mil-conv0" and r.seed == 0)
    sweeping.execute(fig2.run_one, spec, os.path.abspath(os.path.join("w", spec.run_id)), run_context(TINY, "d"))
    argv = ["fig2", "--profile", "tiny", "--work", "w", "--out", "o", "--no-progress", "--data-only"]
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        command.main([*argv, "--data", "e"])
    err = capsys.readouterr().err
    ckpt = os.path.join("w", spec.run_id, "checkpoint.npz")
    assert e.value.code == 2 and err.count("\n") == 1, err                   # one line
    assert (f"argument --data: {ckpt} was trained on {os.path.abspath('d')}{os.sep}grid_train_c3_d4_s0.npz, not on "
            f"{os.path.abspath('e')}'s: pass --data {os.path.abspath('d')}, as its sweep did, or another --work" in err), err
    assert not os.path.exists("e")
    context = dict(run_context(TINY, "d"), train_data=os.path.abspath(os.path.join("d", "other.npz")))
    with pytest.raises(ValueError, match=r"not .*other\.npz: it is another sweep's run; name another --work$"):
        folders.check_work_data(plan(TINY), "w", context)     # the same folder, another dataset
    assert command.main([*argv, "--data", "d"]) == 0
    row = json.loads(open(os.path.join("w", spec.run_id, sweep_rows.ROW_FILE)).read())
    sweep_rows.write_rows([row], os.path.join("o", "runs.csv"))            # the run is done: not checked
    assert command.main([*argv, "--data", "e"]) == 0 and os.path.isdir("e")
    os.remove(os.path.join("o", "runs.csv"))
    with open(ckpt, "wb") as f:
        f.write(b"not a checkpoint")
    assert command.main([*argv, "--data", "e"]) == 0


def test_a_finished_run_ships_as_a_policy_that_scores_what_its_row_says(tmp_path, monkeypatch, capsys):
    """`ship`: the run's checkpoint, its datasets looked for where `fig2 --data-only` collects them; the
    shipped file, evaluated there, scores its row's numbers. An unfinished run or another line: exit 2."""
    monkeypatch.chdir(tmp_path)
    assert command.main(["fig2", "--profile", "tiny", "--data-only", "--data", "d", "--no-progress"]) == 0
    assert sorted(os.listdir("d")) == sorted(os.path.basename(p) for p in fig2.data_paths(TINY, "d").values())
    assert not os.path.exists("runs")                                   # no run was started
    ship = ["ship", "--profile", "tiny", "--line", "mil-conv0", "--seed", "0", "--work", "w", "--data", "d",
            "--out", "policy.npz"]
    for argv, message in ((ship, "holds no finished run; make it with: python -m oneshot.experiments fig2 --profile "
                                 "tiny --lines mil-conv0 --seeds 0 --work w (that command trains the line at each of "
                                 "the profile's 2 sizes; ship takes the largest)"),
                          ([*ship[:4], "lstm-9", *ship[5:]], "has no run of line 'lstm-9'")):
        with pytest.raises(SystemExit) as e:
            command.main(argv)
        assert e.value.code == 2 and message in capsys.readouterr().err
    assert not os.path.exists("policy.npz")
    spec = max((r for r in plan(TINY) if r.method == "mil-conv0" and r.seed == 0), key=lambda r: r.size)
    row = sweeping.execute(fig2.run_one, spec, os.path.abspath(os.path.join("w", spec.run_id)), run_context(TINY, "d"))
    own = os.path.join("w", spec.run_id, "checkpoint.npz")
    os.rename(own, "aside.npz")                 # its row without its checkpoint: not `train --run` (another profile)
    with pytest.raises(SystemExit) as e:
        cli.run(command.main, ship)
    assert e.value.code == 2 and "holds a finished run without its checkpoint.npz; move that folder aside and make " \
        "it again with: python -m oneshot.experiments fig2 --profile tiny --lines mil-conv0 --seeds 0 --work w" in \
        capsys.readouterr().err
    os.rename("aside.npz", own)
    other = os.path.join("w", "mil-all_c3_d4_s0_i2", "checkpoint.npz")      # another run's, as trained
    os.makedirs(os.path.dirname(other))
    shutil.copyfile(own, other)
    dataset = fig2.data_paths(TINY, "d")["train"]
    # --out onto any run's checkpoint in --work, or onto a dataset: refused, each file left as it was
    for path, message in ((own, "would write into w, the sweep's work folder"), (other, "would write into w"),
                          (dataset, "exists and is not a policy (this command would replace it)")):
        before = open(path, "rb").read()
        with pytest.raises(SystemExit) as e:
            cli.run(command.main, [*ship[:-1], path])
        assert e.value.code == 2 and message in capsys.readouterr().err and open(path, "rb").read() == before
    assert command.main(ship) == 0
    run, shipped = checkpoint.load(os.path.join("w", spec.run_id, "checkpoint.npz")), checkpoint.load("policy.npz")
    assert all(np.array_equal(run["params"][k], shipped["params"][k]) for k in run["params"])
    assert shipped["config"].train_data == os.path.join("d", os.path.basename(run["config"].train_data))
    assert os.path.isabs(run["config"].train_data)
    assert dataclasses.replace(shipped["config"], train_data="", validation_data="", test_data="") == \
        dataclasses.replace(run["config"], train_data="", validation_data="", test_data="")
    scored = evaluate.main(["policy.npz", "--split", TINY.score, "--trials", str(TINY.trials), "--train", ""])
    assert scored[TINY.score]["successes"] == row["successes"] and scored[TINY.score]["trials"] == row["trials"]
    notes = json.loads(row["notes"])              # successes are 0 after 2 iterations; eq. (2) is not
    assert scored["adaptation_gain"]["after"] == pytest.approx(notes["eq2_after"], abs=1e-3)
    assert scored["adaptation_gain"]["before"] == pytest.approx(notes["eq2_before"], abs=1e-3)
    # a checkpoint trained otherwise (another step size; stopped early) is refused, naming what differs
    trained = os.path.join("w", spec.run_id, "checkpoint.npz")
    lr = run["config"].lr
    for change, message in (({"config": dataclasses.replace(run["config"], lr=lr / 2)}, f"(lr {lr / 2!r}, not {lr!r})"),
                            ({"iteration": 1}, f"iteration 1 of {spec.iterations}")):
        c = dict(run, **change)
        checkpoint.save(trained, c["params"], c["adam"], c["iteration"], c["rng"], c["config"], c["network"],
                        ema=c["ema"], world=c["world"], seconds=c["seconds"])
        with pytest.raises(SystemExit) as e:
            command.main([*ship[:-1], "refused.npz"])
        assert e.value.code == 2 and message in capsys.readouterr().err and not os.path.exists("refused.npz")


def test_a_shipped_policys_missing_data_hint_collects_the_sweeps_own_file(tmp_path, monkeypatch):
    """Evaluating a policy of a Figure 2 run whose datasets are missing: the collect command in the message,
    run as printed, makes the same file `fig2 --data-only` makes (its colours and demos, not every colour of
    the split at the profile's demos)."""
    monkeypatch.chdir(tmp_path)
    assert command.main(["fig2", "--profile", "tiny", "--data-only", "--data", "d", "--no-progress"]) == 0
    spec = next(r for r in plan(TINY) if r.method == "mil-conv0")
    cfg = fig2.run_config(spec, run_context(TINY, "e"))               # its datasets are looked for in e/
    for split in ("validation", "test", "train"):
        message = run_data.missing(cfg, [split])
        words = shlex.split(message.split("make it with: ")[1])
        assert words[:3] == ["python", "-m", "oneshot.collect"]
        if split == "test":                      # what training's `ensure` collects is the same file
            run_data.ensure(cfg, [split], progress=False)
        else:
            collect.main([*words[3:], "--workers", "1"])
        made, sweeps = (datasets.load(os.path.join(f, os.path.basename(getattr(cfg, f"{split}_data"))))
                        for f in ("e", "d"))
        assert made["images"].shape == sweeps["images"].shape and np.array_equal(made["actions"], sweeps["actions"])
    named = dataclasses.replace(cfg, validation_data="e/mine.npz")   # a name of the user's: every colour
    assert run_data.collected_size(named, "validation") == (run_data.tasks(cfg, "validation"), cfg.validation_demos)
    # a name that promises too few demos, or another size than the file holds: refused, naming the file
    short = os.path.join("e", run_data.file_name(cfg.palette, "validation", 3, cfg.validation_demos - 1))
    with pytest.raises(run_data.DataMismatch, match=f"{short} is named for 3 validation colours x"):
        run_data.missing(dataclasses.replace(cfg, validation_data=short), ["validation"])
    test_file = os.path.basename(cfg.test_data)
    renamed = os.path.join("e", test_file.replace("_c", "_c1"))     # c2 -> c12: the file holds 2 colours
    shutil.copy(os.path.join("e", test_file), renamed)
    colours = datasets.load(renamed)["metadata"]["n_tasks"]
    with pytest.raises(run_data.DataMismatch, match=f"{colours} colours x .* demos, not the 1{colours} x"):
        run_data.load(dataclasses.replace(cfg, test_data=renamed), "test")


def test_the_every_parameter_policy_is_the_ablations_run_of_its_chosen_line():
    """The README's claim: oneshot/pretrained/mil_every_parameter.npz is `fig2 --profile ablation --lines
    mil-released+widths-flat --seeds 0`'s run, shipped (`ship`): its configuration, iterations, moving
    average, and datasets where `fig2 --profile ablation --data-only` puts them."""
    path = os.path.join(os.path.dirname(__file__), "..", "oneshot", "pretrained", "mil_every_parameter.npz")
    ckpt, cfg = checkpoint.load(path), PROFILES["ablation"]
    spec = next(r for r in plan(cfg) if r.method == "mil-released+widths-flat" and r.seed == 0)
    expected = fig2.run_config(spec, run_context(cfg, "data/fig2"))
    paths = {f: os.path.join("data/fig2", os.path.basename(getattr(expected, f))) for f in ("train_data",
                                                                                          "validation_data", "test_data")}
    assert ckpt["config"] == dataclasses.replace(expected, **paths)
    assert ckpt["config"].inner_params == "all" and ckpt["iteration"] == spec.iterations
    assert ckpt["ema"] is not None and not ckpt["ln_offsets_drawn"]
    assert os.path.getsize(path) < 2_000_000


def test_a_points_rate_is_the_mean_of_its_seeds_rates_not_the_pooled_rate():
    """Seed A 1 of 2, seed B 30 of 40: the mean over seeds is (0.5 + 0.75) / 2 = 0.625; pooling the
    trials (mutant S04) gives 31 / 42 = 0.738."""
    mean, _, _ = stats.interval(np.array([[1], [30]]), np.array([[2], [40]]))
    assert mean == pytest.approx(0.625, abs=1e-15)
    d, _, _ = stats.difference_interval((np.array([[1], [30]]), np.array([[2], [40]])), (np.array([[0]]), np.array([[1]])))
    assert d == pytest.approx(0.625, abs=1e-15)


def test_the_difference_interval_is_the_2_5_and_97_5_percentiles():
    """a: 3 seeds scoring 0, 1, 1 (one colour, one trial); b: one seed scoring 1. A replicate's difference is
    the mean of 3 seed draws of a, minus 1: -1 with probability (1/3)^3 = 3.7%, -2/3 with 22%, ...,
    0 with (2/3)^3 = 30%. 3.7% > 2.5%, so the low end is -1; the 5th percentile (mutant S05) would be -2/3."""
    a = (np.array([[0], [1], [1]]), np.ones((3, 1), int))
    b = (np.array([[1]]), np.ones((1, 1), int))
    d, lo, hi = stats.difference_interval(a, b)
    assert (d, lo, hi) == (pytest.approx(-1 / 3), -1.0, 0.0)
