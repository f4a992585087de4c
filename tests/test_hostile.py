"""The command-line tools against hostile arguments: each refused value fails before any work, with
exit status 2 (bad input) or 1 (a failure), ONE line on stderr naming the flag or the cause and the fix,
no traceback, and nothing written. Commands run in-process through `cli.run`, as `python -m` runs them;
`test_python_m_exits_with_the_status_and_one_line` checks each module's `__main__` is wired to it."""
import argparse
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from oneshot import benchmark, checkpoint, cli, collect, config, data, demo, evaluate, methods, optim, shards, train
from oneshot.world import WorldConfig

ROOT = pathlib.Path(__file__).resolve().parents[1]
HUGE = "1000000000000"
TINY = ["--tasks", "2", "--demos", "2", "--horizon", "10", "--image-size", "8", "--workers", "1"]


def refused(capsys, main, argv, status=2, failures=()):
    """Run `main(argv)` as `python -m` does; check the exit status and that stderr is one `error:` line
    and no traceback. Returns (that line, stdout)."""
    with pytest.raises(SystemExit) as exit_:
        cli.run(main, argv, failures)
    out, err = capsys.readouterr()
    assert exit_.value.code == status, err
    assert len(err.splitlines()) == 1 and err.startswith("error: ") and "Traceback" not in err, err
    return err.strip(), out


def nothing_written(folder):
    assert list(pathlib.Path(folder).iterdir()) == []


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    """An untrained checkpoint of the tiny profile (no training: the commands must refuse before using it)."""
    path = tmp_path_factory.mktemp("ckpt") / "checkpoint.npz"
    cfg, rng = config.PROFILES["tiny"], np.random.default_rng(0)
    net_cfg = methods.network_config(cfg, 8)
    params = methods.init_params(cfg, net_cfg, rng)
    checkpoint.save(path, params, optim.adam_init(params), 0, rng, cfg, net_cfg)
    return str(path)


# --- 1. collect --workers ----------------------------------------------------------------------------

@pytest.mark.parametrize("workers", ["0", "-1"])
def test_collect_refuses_fewer_than_one_worker(capsys, tmp_path, workers):
    line, _ = refused(capsys, collect.main, ["--out", str(tmp_path / "new" / "d.npz"), "--workers", workers])
    assert "--workers" in line and ">= 1" in line and repr(workers) in line
    nothing_written(tmp_path)                                     # not even the folder of --out


def test_collect_uses_no_more_processes_than_cores_and_demos(capsys, tmp_path):
    out = tmp_path / "new" / "d.npz"                               # its folder is created at the end
    collect.main(["--out", str(out), *TINY[:-1], HUGE])
    used = data.load(out)["metadata"]["workers"]
    assert used == min(os.cpu_count(), 2 * 2) and f"with {used} process" in capsys.readouterr().out


# --- 4. sizes: counts of zero, and what cannot fit in memory -----------------------------------------

@pytest.mark.parametrize("flag", ["--demos", "--horizon"])
def test_collect_refuses_a_dataset_larger_than_memory_before_allocating(capsys, tmp_path, flag):
    line, _ = refused(capsys, collect.main, ["--out", str(tmp_path / "d.npz"), flag, HUGE])
    assert "PB of memory" in line and "available" in line and "fewer --tasks or --demos" in line
    nothing_written(tmp_path)


def test_collect_checks_memory_against_what_is_available(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(cli, "available_memory_bytes", lambda: 1_000)        # a 1 kB machine
    line, _ = refused(capsys, collect.main, ["--out", str(tmp_path / "d.npz"), *TINY])
    need = cli.dataset_bytes(2, 2, 10, 8, WorldConfig().n_objects)
    assert need > 1_000 and cli.human_bytes(need) in line and "1.0 kB is available" in line
    nothing_written(tmp_path)


@pytest.mark.parametrize("flag", ["--meta-batch", "--log-every", "--checkpoint-every", "--eval-trials"])
def test_train_refuses_counts_of_zero(capsys, tmp_path, flag):
    line, _ = refused(capsys, train.main, ["--profile", "tiny", "--run", str(tmp_path / "run"), flag, "0"])
    assert f"argument {flag}: expected a whole number >= 1; got '0'" in line
    nothing_written(tmp_path)


def test_train_refuses_a_meta_batch_larger_than_memory(capsys, tmp_path):
    line, _ = refused(capsys, train.main, ["--profile", "tiny", "--run", str(tmp_path / "run"), "--meta-batch", HUGE,
                                           "--train-data", str(tmp_path / "train.npz"),
                                           "--heldout-data", str(tmp_path / "heldout.npz")])
    assert f"a meta-batch of {HUGE} tasks" in line and "PB of memory" in line and "smaller --meta-batch" in line
    nothing_written(tmp_path)                                     # no dataset collected either


# --- 6. evaluate ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("trials", ["0", "-3"])
def test_evaluate_refuses_trials_below_one(capsys, tiny_checkpoint, trials):
    line, _ = refused(capsys, evaluate.main, [tiny_checkpoint, "--trials", trials])
    assert "--trials" in line and ">= 1" in line


def test_evaluate_with_no_datasets_says_so(capsys, tiny_checkpoint):
    line, _ = refused(capsys, evaluate.main, [tiny_checkpoint, "--heldout", "", "--train", ""])
    assert "nothing to evaluate" in line


def test_evaluate_names_a_missing_dataset_and_the_command_that_makes_it(capsys, tmp_path, tiny_checkpoint):
    missing = str(tmp_path / "heldout.npz")
    line, out = refused(capsys, evaluate.main, [tiny_checkpoint, "--heldout", missing, "--train", ""])
    cfg = config.PROFILES["tiny"]
    assert (f"no heldout dataset at {missing!r} (--heldout)" in line and
            f"python -m oneshot.collect --out {missing} --split heldout --tasks 12 --demos {cfg.heldout_demos}" in line)
    assert out == ""


def test_evaluate_finds_a_missing_training_set_before_the_held_out_trials(capsys, tmp_path, tiny_checkpoint):
    heldout = tmp_path / "heldout.npz"
    data.save(collect.collect(2, 2, "heldout", 1, 1, WorldConfig(image_size=8, horizon=10), progress=False), heldout)
    line, out = refused(capsys, evaluate.main, [tiny_checkpoint, "--heldout", str(heldout),
                                                "--train", str(tmp_path / "train.npz")])
    assert "no train dataset" in line and "--split train" in line and "--train ''" in line
    assert out == ""                                              # no held-out trial was run


@pytest.mark.parametrize("where", ["folder", "under a file"])
def test_evaluate_checks_the_json_path_before_any_work(capsys, tmp_path, where):
    (tmp_path / "file").write_text("")
    path = tmp_path if where == "folder" else tmp_path / "file" / "r.json"
    # the checkpoint does not exist either: the --json path is checked first, before anything is read
    line, _ = refused(capsys, evaluate.main, [str(tmp_path / "missing.npz"), "--json", str(path)])
    assert "argument --json" in line and ("is a folder" in line or "is a file, not a folder" in line)
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


# --- 8. and 9. train's other arguments -------------------------------------------------------------------

@pytest.mark.parametrize("iterations", ["0", "-1"])
def test_train_refuses_fewer_than_one_iteration(capsys, tmp_path, iterations):
    line, out = refused(capsys, train.main, ["--profile", "tiny", "--run", str(tmp_path / "run"),
                                             "--iterations", iterations])
    assert "argument --iterations: expected a whole number >= 1" in line and "checkpoint" not in out
    nothing_written(tmp_path)


def test_train_booleans_are_words_it_knows(capsys, tmp_path):
    line, _ = refused(capsys, train.main, ["--profile", "tiny", "--run", str(tmp_path / "run"),
                                           "--first-order", "maybe"])
    assert "argument --first-order" in line and "true/1/yes" in line and "false/0/no" in line and "'maybe'" in line
    assert [cli.boolean(w) for w in ("true", "YES", "1", "False", "no", "0")] == [True] * 3 + [False] * 3
    nothing_written(tmp_path)


def test_train_refuses_a_negative_evaluation_period(capsys, tmp_path):
    line, _ = refused(capsys, train.main, ["--profile", "tiny", "--run", str(tmp_path / "run"), "--eval-every", "-1"])
    assert "argument --eval-every: expected a whole number >= 0" in line
    nothing_written(tmp_path)


# --- 10. demo --------------------------------------------------------------------------------------------

def test_demo_refuses_a_missing_checkpoint_it_was_given(capsys, tmp_path):
    missing = str(tmp_path / "missing.npz")
    line, out = refused(capsys, demo.main, ["--checkpoint", missing, "--out", str(tmp_path / "out")])
    assert f"no checkpoint at {missing!r}" in line and "python -m oneshot.train" in line
    assert out == ""                                              # no expert demos, no pictures
    nothing_written(tmp_path)


@pytest.mark.parametrize("argv, flag", [(["--trials", "0"], "--trials"), (["--out", "FILE"], "--out")])
def test_demo_refuses_bad_trials_and_an_unwritable_folder(capsys, tmp_path, argv, flag):
    (tmp_path / "file").write_text("")
    argv = [str(tmp_path / "file") if a == "FILE" else a for a in argv]
    line, out = refused(capsys, demo.main, argv)
    assert f"argument {flag}" in line and out == ""


# --- 11. collect --out, --noise, --seed ------------------------------------------------------------------

@pytest.mark.parametrize("where", ["folder", "under a file"])
def test_collect_checks_out_before_collecting(capsys, tmp_path, where):
    (tmp_path / "file").write_text("")
    out = tmp_path if where == "folder" else tmp_path / "file" / "d.npz"
    line, printed = refused(capsys, collect.main, ["--out", str(out), *TINY])
    assert "argument --out" in line and printed == ""
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


def test_writable_file_tries_the_folder_rather_than_trusting_permissions(tmp_path, monkeypatch):
    """os.access says yes to root even on a read-only file system: the check makes (and drops) a file."""
    def read_only(*args, **kwargs):
        raise PermissionError(13, "Read-only file system")
    monkeypatch.setattr(cli.tempfile, "TemporaryFile", read_only)
    with pytest.raises(argparse.ArgumentTypeError, match="no new files can be made .*Read-only file system"):
        cli.writable_file(str(tmp_path / "a" / "b.npz"))
    nothing_written(tmp_path)


@pytest.mark.parametrize("argv, expected", [(["--noise", "nan"], "argument --noise: expected a finite number >= 0"),
                                            (["--noise", "inf"], "argument --noise: expected a finite number >= 0"),
                                            (["--noise", "-0.1"], "argument --noise: expected a finite number >= 0"),
                                            (["--seed", "-1"], "argument --seed: expected a whole number >= 0")])
def test_collect_names_the_flag_of_a_bad_number(capsys, tmp_path, argv, expected):
    line, _ = refused(capsys, collect.main, ["--out", str(tmp_path / "d.npz"), *argv])
    assert expected in line
    nothing_written(tmp_path)


# --- 12. benchmark ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv, expected", [
    (["expert", "--scenes", "0"], "argument --scenes: expected a whole number >= 1"),
    (["maml", "--iterations", "0"], "argument --iterations: expected a whole number >= 1"),
    (["maml", "--profile", "bogus"], "argument --profile: invalid choice: 'bogus'")])
def test_benchmark_refuses_empty_runs_and_unknown_profiles(capsys, argv, expected):
    line, out = refused(capsys, benchmark.main, argv)
    assert expected in line and out == ""


# --- how errors end ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("error, status", [(ValueError("bad value; do this"), 2),
                                           (data.DatasetError("damaged; re-create it"), 2),
                                           (FileExistsError("already holds a run; use --resume"), 2),
                                           (train.TrainingDiverged("the meta-loss became nan"), 1),
                                           (OSError(28, "No space left on device"), 1),
                                           (KeyboardInterrupt(), 130)])
def test_run_turns_each_kind_of_error_into_one_line_and_its_status(capsys, error, status):
    def main(argv):
        raise error
    line, _ = refused(capsys, main, [], status, failures=(train.TrainingDiverged, shards.ShardError))
    assert line == "error: " + (str(error) or "interrupted")


def test_run_keeps_the_traceback_of_a_bug():
    def main(argv):
        return {}["missing"]
    with pytest.raises(KeyError):
        cli.run(main, [])


@pytest.mark.parametrize("module, argv", [("collect", ["--out", "x.npz", "--workers", "0"]),
                                          ("train", ["--iterations", "0"]),
                                          ("evaluate", ["missing-checkpoint.npz"]),
                                          ("demo", ["--checkpoint", "missing-checkpoint.npz"]),
                                          ("benchmark", ["expert", "--scenes", "0"])])
def test_python_m_exits_with_the_status_and_one_line(tmp_path, module, argv):
    done = subprocess.run([sys.executable, "-m", f"oneshot.{module}", *argv], capture_output=True, text=True,
                          cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
    assert done.stderr.startswith("error: ") and done.stdout == ""
    nothing_written(tmp_path)


def test_run_keeps_a_failed_workers_report_after_the_one_line(capsys):
    def main(argv):
        raise shards.ShardError("shard process 0 died (exit code -9)\nworker 0: MemoryError")
    with pytest.raises(SystemExit) as exit_:
        cli.run(main, [], failures=(shards.ShardError,))
    assert exit_.value.code == 1
    assert capsys.readouterr().err.splitlines() == ["error: shard process 0 died (exit code -9)",
                                                    "worker 0: MemoryError"]
