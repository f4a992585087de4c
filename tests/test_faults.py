"""Round 3 of hostile inputs and faults (issue 30, classes 4-6; issue 31, researchers): processes end
with one line however they are stopped, paths are checked before any work, a torn or foreign log line is
named (and a torn last line forgiven), a run resumes with its own config from a bare `--resume`, and the
long commands run without their progress bars when their output goes to a log."""
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from oneshot import collect, evaluate, train
from oneshot.training import checkpoint, config, run_folder
from test_hostile import refused

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture
def smoke(tiny_split_datasets):
    paths = tiny_split_datasets
    return dataclasses.replace(config.PROFILES["smoke"], train_data=paths["train"], validation_data=paths["validation"],
                               test_data=paths["test"], iterations=2, checkpoint_every=1)


def test_a_plain_kill_of_collect_is_one_line_and_ends_its_workers(tmp_path):
    command = [sys.executable, "-m", "oneshot.collect", "--out", str(tmp_path / "d.npz"), "--tasks", "36",
               "--demos", "24", "--workers", "2"]
    parent = subprocess.Popen(command, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=tmp_path,
                              env=dict(os.environ, PYTHONPATH=ROOT))      # this checkout, not the installed oneshot
    try:
        time.sleep(2.5)
        children = subprocess.run(["pgrep", "-P", str(parent.pid)], capture_output=True, text=True).stdout.split()
        assert children, "the collect never started its workers"
        parent.send_signal(signal.SIGTERM)
        _, err = parent.communicate(timeout=30)
    finally:
        parent.kill()
    assert parent.returncode == 130 and "Traceback" not in err
    assert err.rstrip().split("\n")[-1].split("\r")[-1].startswith("error: interrupted while collecting train demos (")
    deadline = time.time() + 5
    while time.time() < deadline and any(os.path.exists(f"/proc/{c}") for c in children):
        time.sleep(0.1)
    assert not any(os.path.exists(f"/proc/{c}") for c in children), "a worker outlived the collect"
    assert not (tmp_path / "d.npz").exists()                       # nothing half-written


def test_a_run_folder_with_too_long_a_name_is_refused_before_any_folder_is_made(capsys, tmp_path):
    run = tmp_path / "/".join(["a"] * 20) / ("b" * 300)
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(run)])       # one line, status 2
    assert "argument --run" in line and "more than the 255 a name may have" in line
    assert not (tmp_path / "a").exists()


def test_a_dataset_that_cannot_be_written_is_refused_before_collecting(capsys, tmp_path):
    (tmp_path / "file").write_text("")
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"),
                                           "--train-data", str(tmp_path / "file" / "t.npz")])
    assert "argument --train-data: cannot write" in line and "is a file" in line
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("damage, says", [
    (b'{"iteration": 2, "meta_l', None),                                          # torn last line: forgiven
    (b'{"iteration": 1, "meta_loss": 1.0}\n{"iteration": 2, "meta_l\n', "log.jsonl:2 is not a log record"),
    (b'{"meta_loss": 1.0}\n', "log.jsonl:1 is not a log record"),                  # no "iteration"
    (b'{"iteration": "4"}\n', "log.jsonl:1 is not a log record"),
])
def test_a_damaged_log_is_named_with_its_line_and_a_torn_last_line_forgiven(smoke, tmp_path, damage, says):
    run = tmp_path / "run"
    run_folder.train(smoke, run, progress=False, stop_after=1)
    log = run / "log.jsonl"
    kept = log.read_bytes()
    log.write_bytes((b"" if says else kept) + damage)
    if says is None:
        run_folder.train(smoke, run, resume=True, progress=False)
        lines = log.read_text().splitlines()
        assert [json.loads(line)["iteration"] for line in lines] == [1, 2]           # the torn line dropped
    else:
        with pytest.raises(ValueError, match=f"{says}.*the checkpoint is fine: move .*log.jsonl away"):
            run_folder.train(smoke, run, resume=True, progress=False)


def test_resuming_past_the_asked_iterations_says_so_instead_of_claiming_work(capsys, smoke, tmp_path):
    run_folder.train(smoke, tmp_path / "run", progress=False)                   # at iteration 2
    with pytest.raises(ValueError, match=r"is at iteration 2, past --iterations 1: nothing to train"):
        run_folder.train(dataclasses.replace(smoke, iterations=1), tmp_path / "run", resume=True, progress=False)


def test_a_bare_resume_continues_a_smoke_run_with_its_own_config(capsys, smoke, tmp_path):
    """`train --run R --resume` of a run not trained with the default profile: the checkpoint's own
    config (its datasets too), not the default profile's, and no data collected first."""
    run = tmp_path / "run"
    train.main(["--profile", "smoke", "--run", str(run), "--train-data", smoke.train_data, "--validation-data",
                smoke.validation_data, "--iterations", "1"])
    assert capsys.readouterr().out.startswith(f"training 1 meta-iteration: profile smoke, seed 0, into "
                                              f"{run / 'checkpoint.npz'} (Ctrl-C saves it; --resume continues)\n")
    train.main(["--run", str(run), "--resume", "--iterations", "2"])
    out, err = capsys.readouterr()
    assert out.startswith("training 1 meta-iteration (from 1): the run's own settings, seed 0, into ")
    assert "trained 1 meta-iteration (from 1 to 2)" in out and "collecting" not in err
    ckpt = checkpoint.load(run / "checkpoint.npz")
    assert ckpt["iteration"] == 2 and ckpt["config"] == dataclasses.replace(
        config.PROFILES["smoke"], train_data=smoke.train_data, validation_data=smoke.validation_data, iterations=2)
    # finished: a bare resume says there is nothing to train (it said "trained 0 meta-iterations (from 2 to 2)"),
    # and below its count the advice is only to ask for more (without --iterations it trains to its own 2)
    os.rename(smoke.validation_data, smoke.validation_data + ".aside")                # nothing is read or collected
    try:
        assert train.main(["--run", str(run), "--resume"]) is None
    finally:
        os.rename(smoke.validation_data + ".aside", smoke.validation_data)
    out, err = capsys.readouterr()
    assert out == (f"{str(run / 'checkpoint.npz')!r} is at iteration 2, which --iterations 2 asks for: nothing to "
                   f"train; resume with --iterations above 2\n") and err == ""
    line, _ = refused(capsys, train.main, ["--run", str(run), "--resume", "--iterations", "1"])
    assert line.endswith("past --iterations 1: nothing to train; resume with --iterations above 2")
    checkpoint.save(run / "checkpoint.npz", ckpt["params"], ckpt["adam"], 2, ckpt["rng"],   # as if stopped at 2 of 5
                    dataclasses.replace(ckpt["config"], iterations=5), ckpt["network"], ckpt["ema"], ckpt["world"],
                    ckpt["seconds"])
    line, _ = refused(capsys, train.main, ["--run", str(run), "--resume", "--iterations", "1"])
    assert line.endswith("nothing to train; resume with --iterations above 2, or without --iterations (to its 5)")
    train.main(["--run", str(run), "--resume", "--iterations", "2"])
    assert capsys.readouterr().out.endswith("which --iterations 2 asks for: nothing to train; resume with "
                                            "--iterations above 2, or without --iterations (to its 5)\n")


def test_collect_train_and_evaluate_draw_their_progress_bar_unless_told_not_to(capsys, smoke, tmp_path):
    """`--no-progress`, as `fig2` has it: a log of these commands held every redraw of the bar (one
    `evaluate` of 720 trials wrote 180 of them into one line)."""
    tiny = ["--tasks", "2", "--demos", "2", "--horizon", "10", "--image-size", "8", "--workers", "1"]
    data = ["--train-data", smoke.train_data, "--validation-data", smoke.validation_data, "--iterations", "1"]
    commands = [(collect.main, lambda name: ["--out", str(tmp_path / f"{name}.npz"), *tiny], "collecting train demos"),
                (train.main, lambda name: ["--profile", "smoke", "--run", str(tmp_path / name), *data], "meta-training"),
                (evaluate.main, lambda name: [str(tmp_path / "quiet" / "checkpoint.npz"), "--trials", "1", "--train", "",
                                              "--unadapted"],
                 "one-shot trials (validation)")]
    for main, argv, bar in commands:
        main(argv("quiet") + ["--no-progress"])
        out, err = capsys.readouterr()
        assert out and bar not in err and "it/s" not in err, err
        main(argv("shown"))
        assert bar in capsys.readouterr().err


def test_a_clone_named_oneshot_works_from_its_parent_folder(tmp_path):
    """With an editable install, Python finds a clone named `oneshot` in the current folder before the
    installed package and took it (its data/ folder too) for the package: commands crashed run from the
    clone's parent folder. The repository root hands over to the real package (its __init__.py)."""
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    (tmp_path / "oneshot").symlink_to(repo, target_is_directory=True)      # the clone, as its parent sees it
    done = subprocess.run([sys.executable, "-c", "import oneshot, oneshot.data.datasets as d, oneshot.train; "
                           "print(oneshot.__version__, d.__name__)"], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout.split() == ["0.1.0", "oneshot.data.datasets"], done.stderr
