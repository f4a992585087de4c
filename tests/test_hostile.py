"""The command-line tools against hostile arguments: each refused value fails before any work, with
exit status 2 (bad input) or 1 (a failure), ONE line on stderr naming the flag or the cause and the fix,
no traceback, and nothing written. Commands run in-process through `cli.run`, as `python -m` runs them;
`test_python_m_exits_with_the_status_and_one_line` checks each module's `__main__` is wired to it."""
import argparse
import concurrent.futures
import dataclasses
import json
import os
import pathlib
import shlex
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

from oneshot import __main__ as top, demo
from oneshot.benchmark import __main__ as benchmark
from oneshot.exercises import __main__ as exercises
from oneshot.experiments import __main__ as experiments
from oneshot.data import collection, datasets
from oneshot.expert.controller import ExpertConfig
from oneshot.maml import inner, optim, shards
from oneshot.policy import network
from oneshot import methods
from oneshot.methods.mil import MIL
from oneshot.tools import cli
from oneshot.training import checkpoint, config, fit_check, run_data, run_folder
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import WorldConfig
from oneshot import collect, evaluate, train

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
    shown = shown_on_a_terminal(err)
    assert len(shown.splitlines()) == 1 and shown.startswith("error: ") and "Traceback" not in err, err
    return shown.strip(), out


def shown_on_a_terminal(text):
    """What a terminal shows of `text`: of each line, what follows its last carriage return (a progress
    bar wiped with "\r   \r" leaves nothing)."""
    return "\n".join(line.split("\r")[-1] for line in text.split("\n"))


def nothing_written(folder):
    assert list(pathlib.Path(folder).iterdir()) == []


@pytest.fixture(scope="module")
def tiny_checkpoint(tmp_path_factory):
    """An untrained checkpoint of the tiny profile (no training: the commands must refuse before using it)."""
    path = tmp_path_factory.mktemp("ckpt") / "checkpoint.npz"
    cfg, rng = config.PROFILES["smoke"], np.random.default_rng(0)
    net_cfg = methods.of(cfg).network_config(8)
    params = methods.of(cfg).init_params(net_cfg, rng)
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
    used = min(os.cpu_count(), 2 * 2)                               # the cores, or the 4 demos if fewer
    assert f"with {used} process{'es' if used > 1 else ''} in" in capsys.readouterr().out


@pytest.mark.parametrize("cores, workers, used", [(64, None, 4), (64, "3", 3), (2, "8", 2), (1, None, 1)])
def test_collect_takes_the_fewest_of_workers_cores_and_demos(tmp_path, monkeypatch, cores, workers, used):
    """The rule above on machines of any size (the test above cannot tell cores from demos on <= 4 cores)."""
    class Stop(Exception):
        pass

    def spy(*args, **kwargs):
        raise Stop(args[4])                                         # collect(tasks, demos, split, seed, workers, ...)
    monkeypatch.setattr(collect.os, "cpu_count", lambda: cores)
    monkeypatch.setattr(collect, "collect", spy)
    with pytest.raises(Stop) as stopped:
        collect.main(["--out", str(tmp_path / "d.npz"), *TINY[:-2], *(["--workers", workers] if workers else [])])
    assert stopped.value.args == (used,)


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
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), flag, "0"])
    assert f"argument {flag}: expected a whole number >= 1; got '0'" in line
    nothing_written(tmp_path)


@pytest.mark.parametrize("flag, value, says", [
    ("--hidden", "200,0", "argument --hidden: expected comma-separated whole numbers >= 1, e.g. 200,200; got '200,0'"),
    ("--channels", "30,x", "argument --channels: expected comma-separated whole numbers >= 1"),
    ("--init", "xavier", "argument --init: invalid choice: 'xavier'"),
    ("--random-stds", "0.1,-1", "argument --random-stds: expected comma-separated finite numbers >= 0, e.g. "
                                "0.1,0.5,1; got '0.1,-1'")])
def test_train_refuses_bad_widths_and_inits_naming_the_flag(capsys, tmp_path, flag, value, says):
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), flag, value])
    assert says in line
    nothing_written(tmp_path)


def test_widths_are_comma_separated_whole_numbers():
    assert cli.positive_ints("200,200") == (200, 200) and cli.positive_ints("30") == (30,)


def test_number_types_take_their_bounds_and_refuse_fractions():
    """0 is a seed, a --noise and an --eval-every; 2.5 or 1e3 workers is a mistake to name, not 2 or 1000."""
    assert cli.non_negative_int("0") == 0 and cli.positive_int("1") == 1 and cli.finite_non_negative_float("0") == 0.0
    for text in ("2.5", "1e3", "2.0"):
        with pytest.raises(argparse.ArgumentTypeError, match=f"^expected a whole number >= 1; got '{text}'$"):
            cli.positive_int(text)


def test_the_memory_check_of_a_dataset_counts_what_the_dataset_holds(tiny_datasets):
    """`collect` refuses a dataset larger than memory by this count: it is every array's bytes, exactly."""
    data = datasets.load(tiny_datasets[1])
    tasks, demos, horizon, size = data["images"].shape[:4]
    held = sum(v.nbytes for v in data.values() if isinstance(v, np.ndarray))
    assert cli.dataset_bytes(tasks, demos, horizon, size, data["colours"].shape[2]) == held


def test_train_refuses_a_meta_batch_larger_than_memory(capsys, tmp_path):
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), "--meta-batch", HUGE,
                                           "--train-data", str(tmp_path / "train.npz"),
                                           "--validation-data", str(tmp_path / "heldout.npz")])
    assert f"a meta-batch of {HUGE} tasks" in line and "PB of memory" in line and "smaller --meta-batch" in line
    nothing_written(tmp_path)                                     # no dataset collected either


def test_the_random_policy_is_not_refused_for_a_meta_batch_it_never_draws(tmp_path, monkeypatch):
    """It is fitted, not trained on meta-batches: its meta-batch of 1,000 was refused as 11 GB of
    activations of a network it does not have."""
    monkeypatch.setattr(cli, "available_memory_bytes", lambda: 10 ** 9)
    started = []
    monkeypatch.setattr(train, "train", lambda cfg, *a, **k: started.append(cfg.meta_batch))
    train.main(["--profile", "smoke", "--run", str(tmp_path / "run"), "--method", "random", "--meta-batch", "1000",
                "--train-data", str(tmp_path / "train.npz"), "--validation-data", str(tmp_path / "heldout.npz")])
    assert started == [1000]


def test_a_baselines_meta_batch_refusal_offers_no_flag_of_eq_1(capsys, tmp_path, monkeypatch):
    """The LSTM's meta-batch that does not fit: the fix is the meta-batch or the network, not --inner-steps
    or --inner-params, which the LSTM refuses (`Method.ignores`)."""
    monkeypatch.setattr(cli, "available_memory_bytes", lambda: 10 ** 8)
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), "--method", "lstm",
                                           "--meta-batch", "1000", "--train-data", str(tmp_path / "train.npz"),
                                           "--validation-data", str(tmp_path / "heldout.npz")])
    assert "a meta-batch of 1000 tasks (their images and the activations the meta-gradient keeps; 20 frames" in line
    assert line.endswith("use a smaller --meta-batch (the profile's: 2), or a smaller network (see python -m "
                         "oneshot.train --help)") and "inner" not in line
    nothing_written(tmp_path)


@pytest.mark.parametrize("flag, value", [("--meta-batch", "1000"), ("--inner-steps", "100000")])
def test_train_counts_the_activations_of_a_meta_batch_not_only_its_images(capsys, tmp_path, monkeypatch, flag, value):
    """The smoke profile's meta-batch of 1,000 holds 491 MB of images and about 21 GB of activations: it
    passed the images-only check and grew until the kernel killed it (or a training process beside it)."""
    monkeypatch.setattr(cli, "available_memory_bytes", lambda: 8 * 10 ** 9)

    def not_refused(*args, **kwargs):            # never train it here: it would take the machine's memory
        raise AssertionError("train.main did not refuse the meta-batch before training")
    monkeypatch.setattr(train, "train", not_refused)
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), flag, value,
                                           "--train-data", str(tmp_path / "train.npz"),
                                           "--validation-data", str(tmp_path / "heldout.npz")])
    assert "the activations the meta-gradient keeps" in line and "8.0 GB is available" in line
    assert "use a smaller --meta-batch (the profile's: 2) or fewer --inner-steps" in line
    nothing_written(tmp_path)


def test_train_counts_each_tasks_copies_of_the_parameters_it_adapts(capsys, tmp_path, monkeypatch):
    """One dense layer of 200,000 on the smoke profile (every parameter adapts, 3 steps): its parameters
    (2.1 GB with Adam's moments) and the activations fit in 8 GB, but each task's copies of the adapted
    parameters do not (a layer of 1,000,000 passed both checks and the kernel killed it at 20.8 GB)."""
    monkeypatch.setattr(cli, "available_memory_bytes", lambda: 8 * 10 ** 9)
    monkeypatch.setattr(train, "train", lambda *a, **k: pytest.fail("train.main did not refuse before training"))
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), "--hidden", "200000",
                                           "--train-data", str(tmp_path / "train.npz"),
                                           "--validation-data", str(tmp_path / "heldout.npz")])
    assert "a meta-batch of 2 tasks" in line and "each task's copies of the 129,830,002 numbers eq. (1) adapts" in line
    assert "adapt fewer parameters (--inner-params), or a smaller network" in line
    nothing_written(tmp_path)


@pytest.mark.parametrize("argv, says", [
    (["--method", "lstm", "--inner-params", "conv0", "--inner-steps", "5"],
     "--inner-steps, --inner-params do not apply to the lstm method (it never reads them); drop them"),
    (["--method", "random", "--inner-steps", "3", "--first-order", "true"], "do not apply to the random method"),
    (["--method", "contextual", "--alpha", "0.1"], "--alpha does not apply to the contextual method"),
    (["--lstm-units", "8"], "--lstm-units does not apply to the mil method (it never reads it); drop it"),
    (["--method", "lstm", "--random-stds", "0.5"], "--random-stds does not apply to the lstm method")])
def test_train_refuses_a_flag_its_method_never_reads(capsys, tmp_path, argv, says):
    """`--method lstm --inner-steps 5` trained an LSTM and recorded 5 inner steps it never took."""
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), *argv,
                                           "--train-data", str(tmp_path / "train.npz"),
                                           "--validation-data", str(tmp_path / "heldout.npz")])
    assert says in line
    nothing_written(tmp_path)
    for method, reads in (("lstm", "lstm_units"), ("random", "random_stds"), ("mil", "inner_steps")):
        assert methods.of(dataclasses.replace(config.PROFILES["smoke"], method=method)).refuse_ignored([reads]) is None


def test_train_names_the_flag_of_a_bad_inner_loop_value(capsys, tmp_path):
    """It said "loss_scale must be finite and > 0", the field's name, not the flag a person typed."""
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"),
                                           "--inner-loss-scale", "0"])
    assert "loss_scale must be finite and > 0" in line and "--inner-loss-scale > 0" in line
    nothing_written(tmp_path)


@pytest.mark.parametrize("extra", [[], ["--breakdown"]])
def test_the_benchmark_counts_the_activations_of_a_meta_batch_before_timing(capsys, monkeypatch, extra):
    monkeypatch.setattr(cli, "available_memory_bytes", lambda: 8 * 10 ** 9)
    line, _ = refused(capsys, benchmark.main, ["maml", "--profile", "smoke", "--meta-batch", "1000", *extra])
    assert "a meta-batch of 1000 tasks (3 inner steps: their images, the activations the meta-gradient keeps and each " \
        "task's copies" in line
    assert "8.0 GB is available; use a smaller --meta-batch or fewer --inner-steps" in line


@pytest.mark.parametrize("argv, says", [
    (["--hidden", "100000000,100000000"], "the mil policy's 10,000,065,000,030,002 parameters"),
    (["--bias-transform", "100000000"], "the mil policy's"),
    (["--method", "lstm", "--lstm-units", "1000000000"], "the lstm policy's")])
def test_train_refuses_a_network_larger_than_memory(capsys, tmp_path, argv, says):
    """Widths that cannot fit are refused in one line before any work (they were a MemoryError traceback,
    or, for --channels, the OOM killer)."""
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), *argv,
                                           "--train-data", str(tmp_path / "train.npz"),
                                           "--validation-data", str(tmp_path / "heldout.npz")])
    assert says in line and "B of memory, and" in line and "use smaller --channels, --hidden" in line
    assert ("--lstm-units" in line) == ("lstm" in argv)              # a flag MIL would refuse is not offered
    nothing_written(tmp_path)


def test_train_refuses_a_never_adapt_prefix_that_names_no_parameter(capsys, tmp_path):
    """A typo on the command line (conv_0 for conv0) would silently adapt every parameter: refused, naming
    the parameters. A profile's own prefix that names nothing here (the released profile's "ln" without
    layer norm) changes nothing and is not refused, nor is a checkpoint saved with one."""
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), "--never-adapt",
                                           "conv_0", "--train-data", str(tmp_path / "train.npz"),
                                           "--validation-data", str(tmp_path / "heldout.npz")])
    assert "argument --never-adapt: 'conv_0' starts no parameter's name" in line and "conv0_w, conv0_b" in line
    nothing_written(tmp_path)
    assert inner.unmatched(["conv0_w", "ln0_offset"], ("ln", "conv_0", "conv0_")) == ["conv_0"]
    cfg, rng = dataclasses.replace(config.PROFILES["smoke"], never_adapt=("ln",)), np.random.default_rng(0)
    net_cfg = methods.of(cfg).network_config(8)
    params = methods.of(cfg).init_params(net_cfg, rng)
    checkpoint.save(tmp_path / "c.npz", params, optim.adam_init(params), 0, rng, cfg, net_cfg)
    assert checkpoint.load(tmp_path / "c.npz")["config"].never_adapt == ("ln",)


@pytest.mark.parametrize("where", ["the validation data", "the run's log", "the test data", "the test data too"])
def test_train_refuses_a_dataset_path_it_would_overwrite_or_reuse(capsys, tmp_path, where):
    """The same file for meta-training and validation (or test), or a dataset at one of the run's own
    files: refused before any demonstration is collected."""
    run = tmp_path / "run"
    train_data = run / "log.jsonl" if where == "the run's log" else tmp_path / "same.npz"
    validation_data = tmp_path / ("same.npz" if where == "the validation data" else "heldout.npz")
    test_data = {"the test data": train_data, "the test data too": validation_data}.get(where, tmp_path / "test.npz")
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(run), "--train-data", str(train_data),
                                           "--validation-data", str(validation_data), "--test-data", str(test_data)])
    assert {"the validation data": "is also the meta-training data",
            "the run's log": f"the train data {train_data} is one of the run's own files",
            "the test data": f"the test data {test_data} is also the train data; the test colours need a file of "
                             f"their own (--test-data)",
            "the test data too": f"the test data {test_data} is also the validation data"}[where] in line
    nothing_written(tmp_path)


# --- 6. evaluate ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("trials", ["0", "-3"])
def test_evaluate_refuses_trials_below_one(capsys, tiny_checkpoint, trials):
    line, _ = refused(capsys, evaluate.main, [tiny_checkpoint, "--trials", trials])
    assert "--trials" in line and ">= 1" in line


@pytest.mark.parametrize("method", ["lstm", "contextual", "random"])
def test_evaluate_refuses_an_inner_step_for_a_policy_that_does_not_adapt(capsys, tmp_path, method):
    """--alpha or --inner-steps on a baseline's checkpoint scored it as if they changed something."""
    cfg, rng = dataclasses.replace(config.PROFILES["smoke"], method=method), np.random.default_rng(0)
    net_cfg = methods.of(cfg).network_config(32)
    params = methods.of(cfg).init_params(net_cfg, rng)
    checkpoint.save(tmp_path / "c.npz", params, optim.adam_init(params), 0, rng, cfg, net_cfg)
    line, _ = refused(capsys, evaluate.main, [str(tmp_path / "c.npz"), "--alpha", "0.1", "--inner-steps", "2"])
    assert f"--alpha, --inner-steps do not apply to the {method} method (it never reads them); drop them" in line


def test_evaluate_with_no_dataset_to_score_says_so(capsys, tiny_checkpoint):
    line, _ = refused(capsys, evaluate.main, [tiny_checkpoint, "--validation", "", "--train", ""])
    assert "--validation '' names no dataset, but the validation colours are what this scores" in line
    line, _ = refused(capsys, evaluate.main, [tiny_checkpoint, "--split", "test", "--test", ""])
    assert "--test '' names no dataset" in line


def test_evaluate_names_a_missing_dataset_and_the_command_that_makes_it(capsys, tmp_path, tiny_checkpoint):
    missing = str(tmp_path / "heldout.npz")
    line, out = refused(capsys, evaluate.main, [tiny_checkpoint, "--validation", missing, "--train", ""])
    cfg = config.PROFILES["smoke"]
    assert (f"no dataset at {missing!r} (validation, --validation)" in line and
            f"python -m oneshot.collect --out {missing} --split validation --tasks 12 --demos {cfg.validation_demos}"
            f" --seed 1 --noise 0.1" in line)
    assert out == ""


def test_evaluate_finds_a_missing_training_set_before_the_held_out_trials(capsys, tmp_path, tiny_checkpoint):
    heldout = tmp_path / "heldout.npz"
    datasets.save(collection.collect(2, 2, "validation", 1, 1, WorldConfig(image_size=8, horizon=10), progress=False), heldout)
    line, out = refused(capsys, evaluate.main, [tiny_checkpoint, "--validation", str(heldout),
                                                "--train", str(tmp_path / "train.npz")])
    assert "no dataset at" in line and "(train, --train)" in line and "--split train" in line and "--train ''" in line
    assert out == ""                                              # no held-out trial was run


def test_evaluate_offers_to_skip_the_training_contrast_only_when_its_dataset_is_missing(capsys, tmp_path, tiny_checkpoint):
    train_path = tmp_path / "train.npz"
    datasets.save(collection.collect(2, 2, "train", 1, 1, WorldConfig(image_size=8, horizon=10), progress=False),
                  train_path)
    line, _ = refused(capsys, evaluate.main, [tiny_checkpoint, "--validation", str(tmp_path / "v.npz"),
                                              "--train", str(train_path)])
    assert "(validation, --validation)" in line and "--train ''" not in line and "(train" not in line


def test_evaluate_names_every_missing_dataset_in_one_message_with_the_commands(capsys, tmp_path, tiny_checkpoint):
    """One round trip: the scored split's dataset and the training contrast's, both missing, both named,
    and the commands that make them (a checkpoint's own paths and demo counts, not the default profile's)."""
    line, out = refused(capsys, evaluate.main, [tiny_checkpoint, "--split", "test", "--test", str(tmp_path / "t.npz"),
                                                "--train", str(tmp_path / "tr.npz")])
    assert line.count("python -m oneshot.collect") == 2 and " && " in line
    assert f"--out {tmp_path / 't.npz'} --split test --tasks 24 --demos 2 --seed 2" in line
    assert f"--out {tmp_path / 'tr.npz'} --split train --tasks 36 --demos 3 --seed 0" in line and out == ""


@pytest.mark.parametrize("where", ["folder", "under a file"])
def test_evaluate_checks_the_json_path_before_any_work(capsys, tmp_path, where):
    (tmp_path / "file").write_text("")
    path = tmp_path if where == "folder" else tmp_path / "file" / "r.json"
    # the checkpoint does not exist either: the --json path is checked first, before anything is read
    line, _ = refused(capsys, evaluate.main, [str(tmp_path / "missing.npz"), "--json", str(path)])
    assert "argument --json" in line and ("is a folder" in line or "is a file, not a folder" in line)
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


def test_evaluate_refuses_a_json_path_that_is_one_of_its_inputs(capsys, tmp_path, tiny_checkpoint):
    """--json onto the checkpoint, or onto a dataset it reads (also through a link), would destroy it: refused
    in one line before anything is read, the file untouched."""
    ckpt = tmp_path / "c.npz"
    ckpt.write_bytes(pathlib.Path(tiny_checkpoint).read_bytes())
    (tmp_path / "v.npz").write_bytes(b"a dataset")
    (tmp_path / "link.json").symlink_to(tmp_path / "v.npz")
    for json_path, named in ((ckpt, ckpt), (tmp_path / "v.npz", tmp_path / "v.npz"),
                             (tmp_path / "link.json", tmp_path / "v.npz")):
        before = named.read_bytes()
        line, out = refused(capsys, evaluate.main, [str(ckpt), "--validation", str(tmp_path / "v.npz"),
                                                    "--json", str(json_path)])
        assert f"argument --json {json_path} would overwrite" in line and "a file this command reads" in line
        assert out == "" and named.read_bytes() == before
    cli.not_an_input(str(tmp_path / "r.json"), [str(ckpt), None, ""], "--json")          # another file: fine
    with pytest.raises(ValueError, match="would write into"):                             # inside an input folder
        cli.not_an_input(str(tmp_path / "run" / "r.json"), [str(tmp_path / "run")], "--out")


def test_an_output_beside_an_input_folder_is_not_inside_it(tmp_path):
    """runs/fig2b is not inside runs/fig2 (a name that only starts with the folder's is another folder)."""
    cli.not_an_input(str(tmp_path / "fig2b" / "policy.npz"), [str(tmp_path / "fig2")], "--out")
    with pytest.raises(ValueError, match="would write into"):
        cli.not_an_input(str(tmp_path / "fig2" / "policy.npz"), [str(tmp_path / "fig2")], "--out")


# --- 8. and 9. train's other arguments -------------------------------------------------------------------

@pytest.mark.parametrize("iterations", ["0", "-1"])
def test_train_refuses_fewer_than_one_iteration(capsys, tmp_path, iterations):
    line, out = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"),
                                             "--iterations", iterations])
    assert "argument --iterations: expected a whole number >= 1" in line and "checkpoint" not in out
    nothing_written(tmp_path)


def test_train_booleans_are_words_it_knows(capsys, tmp_path):
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"),
                                           "--first-order", "maybe"])
    assert "argument --first-order" in line and "true/1/yes" in line and "false/0/no" in line and "'maybe'" in line
    assert [cli.boolean(w) for w in ("true", "YES", "1", "False", "no", "0")] == [True] * 3 + [False] * 3
    nothing_written(tmp_path)


def test_train_refuses_a_negative_evaluation_period(capsys, tmp_path):
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"), "--eval-every", "-1"])
    assert "argument --eval-every: expected a whole number >= 0" in line
    nothing_written(tmp_path)


# --- 2, 7, 8, 13. a training process: its folder, its end ------------------------------------------------
# (2, shard workers dying with the training process: tests/test_shards.py)

@pytest.fixture
def tiny_cfg(tiny_datasets):
    train_path, validation_path = tiny_datasets
    return dataclasses.replace(config.PROFILES["smoke"], train_data=train_path, validation_data=validation_path,
                               iterations=6, checkpoint_every=100)


def _interrupt_at(monkeypatch, call):
    """Make the `call`-th meta-gradient (1-based) raise KeyboardInterrupt, as Ctrl-C in the middle of it."""
    real, calls = MIL.meta_gradient, []

    def meta_gradient(*args):
        calls.append(1)
        if len(calls) == call:
            raise KeyboardInterrupt
        return real(*args)
    monkeypatch.setattr(MIL, "meta_gradient", meta_gradient)


@pytest.mark.parametrize("extras", [{}, {"ema": 0.5, "eval_every": 3, "eval_trials": 1}])
def test_ctrl_c_saves_the_last_finished_iteration_and_resume_continues_exactly(tmp_path, tiny_cfg, monkeypatch, extras):
    tiny_cfg = dataclasses.replace(tiny_cfg, **extras)          # with a moving average and held-out checks too
    whole = run_folder.train(tiny_cfg, tmp_path / "whole", progress=False)
    _interrupt_at(monkeypatch, 4)
    with pytest.raises(run_folder.Interrupted, match=r"interrupted at iteration 3; checkpoint: .*checkpoint.npz "
                                                r"\(continue with --resume\)"):
        run_folder.train(tiny_cfg, tmp_path / "stopped", progress=False)
    assert checkpoint.load(tmp_path / "stopped" / "checkpoint.npz")["iteration"] == 3
    monkeypatch.undo()
    resumed = run_folder.train(tiny_cfg, tmp_path / "stopped", resume=True, progress=False)
    assert all(np.array_equal(resumed[k], whole[k]) for k in whole)
    ends = [checkpoint.load(tmp_path / run / "checkpoint.npz") for run in ("whole", "stopped")]
    assert (ends[0]["ema"] is None) == (not extras)
    assert all(np.array_equal(ends[0]["ema"][k], ends[1]["ema"][k]) for k in ends[0]["ema"] or {})
    logs = [[{k: v for k, v in json.loads(line).items() if k != "seconds"}
             for line in (tmp_path / run / "log.jsonl").read_text().splitlines()] for run in ("whole", "stopped")]
    assert logs[0] == logs[1] and len(logs[0]) == 6 + 2 * bool(extras)   # every line once (and 2 checks)


def test_a_second_ctrl_c_while_the_interrupted_run_saves_does_not_lose_its_checkpoint(tmp_path, tiny_cfg,
                                                                                     monkeypatch):
    real, sent = checkpoint.save, []

    def save(*args, **kwargs):                          # Ctrl-C and a kill, the moment the save begins
        for sig in (signal.SIGINT, signal.SIGTERM):
            os.kill(os.getpid(), sig)
            sent.append(sig)
        return real(*args, **kwargs)

    def term(signum, frame):                            # as the train command has it: a kill is Ctrl-C
        raise KeyboardInterrupt
    _interrupt_at(monkeypatch, 4)
    monkeypatch.setattr(checkpoint, "save", save)
    previous = (signal.signal(signal.SIGINT, signal.default_int_handler),   # as a terminal's Ctrl-C, even
                signal.signal(signal.SIGTERM, term))                         # when pytest runs in the background
    stopped = None
    try:
        run_folder.train(tiny_cfg, tmp_path / "stopped", progress=False)
    except KeyboardInterrupt as e:          # the run's Interrupted, or a second signal getting through
        stopped = e
    finally:
        after = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
        signal.signal(signal.SIGINT, previous[0])
        signal.signal(signal.SIGTERM, previous[1])
    assert isinstance(stopped, run_folder.Interrupted) and "interrupted at iteration 3" in str(stopped)
    assert len(sent) == 2 and after == (signal.default_int_handler, term)   # both stop the next command again
    assert checkpoint.load(tmp_path / "stopped" / "checkpoint.npz")["iteration"] == 3


def test_an_interrupted_run_in_a_thread_saves_its_checkpoint_too(tmp_path, tiny_cfg, monkeypatch):
    """A sweep's thread pool trains in threads, where no signal handler can be set: the save is not guarded
    there (signals reach only the main thread), and not a ValueError either."""
    _interrupt_at(monkeypatch, 4)
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        stopped = pool.submit(run_folder.train, tiny_cfg, tmp_path / "stopped", progress=False).exception()
    assert isinstance(stopped, run_folder.Interrupted), stopped
    assert checkpoint.load(tmp_path / "stopped" / "checkpoint.npz")["iteration"] == 3


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signalled_training_saves_says_where_in_one_line_and_exits_130(tmp_path, tiny_datasets, sig):
    run = tmp_path / "run"
    command = [sys.executable, "-m", "oneshot.train", "--profile", "smoke", "--run", str(run), "--iterations",
               "100000", "--checkpoint-every", "100000", "--train-data", tiny_datasets[0],
               "--validation-data", tiny_datasets[1]]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=dict(os.environ, PYTHONPATH=str(ROOT)),   # SIGINT as a terminal has it (a
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # background shell ignores it)
    try:
        log = run / "log.jsonl"
        deadline = time.monotonic() + 120
        while not (log.exists() and log.read_text().count("\n") >= 2) and time.monotonic() < deadline:
            time.sleep(0.1)                                   # two iterations done: it is training
        process.send_signal(getattr(signal, sig))
        out, err = process.communicate(timeout=60)
    finally:
        process.kill()
    assert process.returncode == 130, err
    last = err.strip().splitlines()[-1]                   # tqdm's bar may precede it
    iteration = checkpoint.load(run / "checkpoint.npz")["iteration"]
    assert iteration >= 2 and last == (f"error: interrupted at iteration {iteration}; checkpoint: "
                                       f"{run / 'checkpoint.npz'} (continue with --resume)")
    assert "Traceback" not in err and not [p for p in run.iterdir() if p.name.startswith(".tmp")]


def test_a_second_training_in_the_same_folder_is_refused(tmp_path, tiny_cfg):
    run = tmp_path / "run"
    with run_folder.lock_run(str(run)):                        # as a training process holds it
        done = subprocess.run([sys.executable, "-m", "oneshot.train", "--profile", "smoke", "--run", str(run),
                               "--train-data", tiny_cfg.train_data, "--validation-data", tiny_cfg.validation_data],
                              capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert done.returncode == 1 and done.stderr == (f"error: another process (pid {os.getpid()}) is training in "
                                                    f"{str(run)!r}; wait for it to end, or use another --run folder\n")
    assert done.stdout == ""                                  # no "training ... into" banner before the refusal
    assert [p.name for p in run.iterdir()] == [".lock"]   # nothing else was written, and the folder kept
    run_folder.train(tiny_cfg, run, progress=False)            # free again once the owner is gone


def test_a_run_folder_that_is_a_file_is_refused(capsys, tmp_path, tiny_cfg):
    (tmp_path / "run").write_text("")
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(tmp_path / "run"),
                                           "--train-data", tiny_cfg.train_data, "--validation-data", tiny_cfg.validation_data])
    assert "is a file, not a folder; choose another path" in line and line.startswith("error: argument --run")


@pytest.mark.parametrize("link", ["nowhere", "loop"])
def test_a_run_folder_that_is_a_link_to_nothing_is_refused(capsys, tmp_path, tiny_cfg, link):
    """A dangling symbolic link, or a loop of links, as --run: it said `[Errno 17] File exists`."""
    run = tmp_path / "run"
    run.symlink_to(tmp_path / "missing" if link == "nowhere" else run)
    line, _ = refused(capsys, train.main, ["--profile", "smoke", "--run", str(run / "inner"),
                                           "--train-data", tiny_cfg.train_data, "--validation-data", tiny_cfg.validation_data])
    assert line.startswith("error: argument --run") and f"{str(run)!r} is a symbolic link to nothing (or a loop of " \
                                                           f"links); remove it, or choose another path" in line
    assert run.is_symlink() and not (tmp_path / "missing").exists()


def test_resume_removes_what_a_killed_checkpoint_write_left(tmp_path, tiny_cfg):
    run = tmp_path / "run"
    run_folder.train(dataclasses.replace(tiny_cfg, iterations=2), run, progress=False)
    (run / ".tmp-kill9.npz").write_bytes(b"half a checkpoint")
    run_folder.train(tiny_cfg, run, resume=True, progress=False)
    assert not (run / ".tmp-kill9.npz").exists()


def test_a_run_that_fails_before_starting_leaves_no_folder(tmp_path, tiny_cfg):
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"not a dataset")
    with pytest.raises(datasets.DatasetError):
        run_folder.train(dataclasses.replace(tiny_cfg, train_data=str(broken)), tmp_path / "run", progress=False)
    assert [p.name for p in tmp_path.iterdir()] == ["broken.npz"]


def test_divergence_names_the_checkpoint_only_if_there_is_one(tmp_path, tiny_cfg, monkeypatch):
    real = MIL.meta_gradient
    monkeypatch.setattr(MIL, "meta_gradient", lambda *a: (np.nan, real(*a)[1]))
    with pytest.raises(run_folder.TrainingDiverged, match="at iteration 1; no checkpoint was saved before it"):
        run_folder.train(tiny_cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "checkpoint.npz").exists()
    monkeypatch.undo()
    run_folder.train(dataclasses.replace(tiny_cfg, iterations=2), tmp_path / "run2", progress=False)
    monkeypatch.setattr(MIL, "meta_gradient", lambda *a: (np.nan, real(*a)[1]))
    path = tmp_path / "run2" / "checkpoint.npz"
    with pytest.raises(run_folder.TrainingDiverged, match=f"the last good checkpoint \\({path}, iteration 2\\) is "
                                                     f"kept: --resume with a smaller --lr"):
        run_folder.train(tiny_cfg, tmp_path / "run2", resume=True, progress=False)


@pytest.mark.parametrize("shards", [1, 2])
def test_a_diverging_run_says_so_without_numpy_warnings(capfd, tmp_path, tiny_cfg, shards):
    """The meta-loss overflows at a step size of 1e30: the error says so; numpy's overflow warnings, from
    this process or a shard's, would only add noise before it."""
    cfg = dataclasses.replace(tiny_cfg, lr=1e30, shards=shards)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(run_folder.TrainingDiverged, match="the meta-loss became nan"):
            run_folder.train(cfg, tmp_path / "run", progress=False)
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)]
    assert "Warning" not in capfd.readouterr().err


def test_a_bare_resume_keeps_the_runs_own_length_and_step(capsys, tmp_path, tiny_cfg):
    """`--resume` alone (what the Ctrl-C message says to type) continues with the run's --lr and
    --iterations, not the profile's."""
    run = str(tmp_path / "run")
    given = ["--profile", "smoke", "--run", run, "--train-data", tiny_cfg.train_data, "--validation-data",
             tiny_cfg.validation_data]
    run_folder.train(dataclasses.replace(tiny_cfg, lr=1e-4, iterations=2, checkpoint_every=1), run, progress=False,
                stop_after=1)
    train.main(given + ["--resume"])
    kept = checkpoint.load(os.path.join(run, "checkpoint.npz"))
    assert (kept["config"].lr, kept["iteration"]) == (1e-4, 2) != (config.PROFILES["smoke"].lr, config.PROFILES["smoke"].iterations)
    capsys.readouterr()


def test_resume_may_lower_the_learning_rate_and_logs_it(tmp_path, tiny_cfg):
    run = tmp_path / "run"
    run_folder.train(dataclasses.replace(tiny_cfg, iterations=2), run, progress=False)
    run_folder.train(dataclasses.replace(tiny_cfg, lr=tiny_cfg.lr / 10), run, resume=True, progress=False)
    assert checkpoint.load(run / "checkpoint.npz")["config"].lr == tiny_cfg.lr / 10
    assert {"iteration": 2, "lr": tiny_cfg.lr / 10, "lr_before": tiny_cfg.lr, "step_now": tiny_cfg.lr / 10} in [
        json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    with pytest.raises(ValueError, match="seed: checkpoint 0, now 1"):
        run_folder.train(dataclasses.replace(tiny_cfg, seed=1), run, resume=True, progress=False)


# --- 3, 5, 6. files that do not fit, are damaged, or hold a diverged policy -------------------------------

@pytest.fixture(scope="module")
def trained(tmp_path_factory, tiny_datasets):
    """A tiny profile's checkpoint after one iteration (it records the 32x32, 20-step world of its data)."""
    run = tmp_path_factory.mktemp("trained")
    cfg = dataclasses.replace(config.PROFILES["smoke"], train_data=tiny_datasets[0], validation_data=tiny_datasets[1],
                              iterations=1)
    run_folder.train(cfg, run, progress=False)
    return str(run / "checkpoint.npz")


@pytest.fixture(scope="module")
def heldout_16(tmp_path_factory):
    """Held-out demos of 16x16 images: not what any checkpoint here was trained on."""
    path = tmp_path_factory.mktemp("h16") / "heldout16.npz"
    datasets.save(collection.collect(2, 2, "validation", 1, 1, WorldConfig(image_size=16, horizon=8), progress=False), path)
    return str(path)


def test_evaluate_refuses_data_of_another_image_size_naming_both(capsys, trained, heldout_16):
    line, out = refused(capsys, evaluate.main, [trained, "--validation", heldout_16, "--train", ""])
    assert line == (f"error: {trained} was trained on 32x32 images but {heldout_16} holds 16x16 images; "
                    f"use data collected with --image-size 32")
    assert out == ""                                              # refused before the first trial


def test_the_shipped_policy_refuses_64x64_data(capsys, tmp_path):
    """The issue's case: the shipped 32x32 policy on 64x64 held-out data reported 4/12 instead of 9/12."""
    shipped = str(ROOT / "oneshot" / "pretrained" / "mil_default.npz")
    heldout = str(tmp_path / "heldout64.npz")
    datasets.save(collection.collect(2, 2, "validation", 1, 1, WorldConfig(image_size=64, horizon=8), progress=False), heldout)
    line, _ = refused(capsys, evaluate.main, [shipped, "--validation", heldout, "--train", ""])
    assert "trained on 32x32 images" in line and "holds 64x64 images" in line


def test_resume_refuses_a_training_set_replaced_by_another_image_size(tmp_path, tiny_cfg):
    run, data = tmp_path / "run", tmp_path / "train16.npz"
    data.write_bytes(pathlib.Path(tiny_cfg.train_data).read_bytes())
    cfg = dataclasses.replace(tiny_cfg, train_data=str(data))
    run_folder.train(dataclasses.replace(cfg, iterations=1), run, progress=False)
    datasets.save(collection.collect(3, 3, "train", 0, 1, WorldConfig(image_size=16, horizon=8),   # replaced
                                     ExpertConfig(action_noise=0.1), progress=False), data)
    with pytest.raises(checkpoint.CheckpointError, match="trained on 32x32 images but .*train16.npz holds 16x16"):
        run_folder.train(cfg, run, resume=True, progress=False)


@pytest.mark.parametrize("change, says, fix", [
    ({"expert_cfg": ExpertConfig(action_noise=0.0)}, "noise 0.0, not 0.1", "collect"),   # notebook 1's old command
    ({"seed": 5}, "seed 5, not 0", "collect"),
    ({"demos_per_task": 2}, "2 demos per colour, not 3", "collect"),                   # 2-demo data at the path
    # another split's file: collecting this split's data into it, or moving it away, is no fix (each was the advice)
    ({"split": "validation"}, "split 'validation', not 'train'", "name"),
])
def test_training_refuses_data_collected_with_other_settings_than_its_profile(tmp_path, tiny_cfg, change, says, fix):
    settings = dict(n_tasks=3, demos_per_task=3, split="train", seed=0, workers=1,
                    expert_cfg=ExpertConfig(action_noise=0.1), progress=False)
    other = tmp_path / "train.npz"
    datasets.save(collection.collect(**{**settings, **change}), other)
    with pytest.raises(run_data.DataMismatch) as refused:
        run_folder.train(dataclasses.replace(tiny_cfg, train_data=str(other)), tmp_path / "run", progress=False)
    message = str(refused.value)
    assert message.startswith(f"{other} was collected with other settings than this run's train data: {says}; ")
    collect = "python -m oneshot.collect --out {} --split train --tasks "
    fixes = {"collect": f"; move it away (this command then collects the right one: {collect.format(other)}",
             "name": f"; name a train dataset instead (to make one: {collect.format('FILE')}"}
    assert fixes[fix] in message and not any(f in message for name, f in fixes.items() if name != fix), message
    assert fix == "collect" or "move it away" not in message                  # the test set is not to be moved
    assert not (tmp_path / "run").exists()                          # refused before anything was written


def test_the_demo_acts_in_the_world_the_policy_was_trained_in(trained):
    assert fit_check.world_config(checkpoint.load(trained)).image_size == 32
    small = checkpoint.load(trained)
    small["world"] = None                                         # an older checkpoint: its network's size
    small["network"] = dataclasses.replace(small["network"], image_size=8)
    assert fit_check.world_config(small) == WorldConfig(image_size=8)


def test_evaluate_on_another_palette_only_when_asked(capsys, tmp_path, trained):
    grid = str(tmp_path / "grid_validation.npz")
    datasets.save(collection.collect(2, 2, "validation", 1, 1, WorldConfig(palette=PaletteConfig(mode="grid")),
                              progress=False), grid)
    line, _ = refused(capsys, evaluate.main, [trained, "--validation", grid, "--train", ""])
    assert "trained on the 'hues' palette but" in line and "--any-palette" in line
    results = cli.run(evaluate.main, [trained, "--validation", grid, "--train", "", "--trials", "1", "--any-palette"])
    assert results["validation"]["trials"] == 2                     # a transfer test: it runs
    # its note counts the grid's colours, and its collect command makes grid colours (not hues over the file)
    assert f"holds 2 of the 108 validation colours this profile collects; this scored those 2 (the whole set: move " \
           f"it away, or python -m oneshot.collect --out {grid} --split validation --tasks 108 " in capsys.readouterr().out
    named = str(tmp_path / "grid_validation_c2_d1_s1.npz")      # named for 1 demo, fewer than the profile's 2: the
    os.rename(grid, named)                                      # note's count raised DataMismatch after the trials
    results = cli.run(evaluate.main, [trained, "--validation", named, "--train", "", "--trials", "1", "--any-palette",
                                      "--json", str(tmp_path / "r.json")])
    assert results["validation"]["trials"] == 2 and (tmp_path / "r.json").exists()
    assert "this scored" not in capsys.readouterr().out


def test_evaluate_raw_on_a_run_without_a_moving_average_says_it_changes_nothing(capsys, trained):
    """The smoke profile keeps no moving average: --raw scores what it always does, and says so."""
    plain = evaluate.main([trained, "--train", "", "--trials", "1"])
    assert "moving average" not in capsys.readouterr().err
    raw = evaluate.main([trained, "--train", "", "--trials", "1", "--raw"])
    assert f"note: {trained} kept no moving average: its parameters are the raw ones" in capsys.readouterr().err
    assert raw["validation"]["successes"] == plain["validation"]["successes"]


@pytest.mark.parametrize("damaged", ["checkpoint", "dataset"])
def test_evaluate_names_a_damaged_file(capsys, tmp_path, trained, tiny_datasets, damaged):
    source = trained if damaged == "checkpoint" else tiny_datasets[1]
    broken = tmp_path / f"broken-{damaged}.npz"
    raw = bytearray(pathlib.Path(source).read_bytes())
    raw[len(raw) // 2] ^= 0x10                                    # one bit, in the middle of the arrays
    broken.write_bytes(bytes(raw))
    argv = [str(broken), "--validation", tiny_datasets[1]] if damaged == "checkpoint" else [trained, "--validation", str(broken)]
    line, out = refused(capsys, evaluate.main, argv + ["--train", ""])
    assert repr(str(broken)) in line and ("train it again" in line or "re-create it" in line) and out == ""


def test_evaluate_says_a_diverged_policy_diverged(capsys, tmp_path, trained, tiny_datasets):
    """A finite checkpoint whose torques overflow: a named error, not "action contains NaN" from the world."""
    ckpt = checkpoint.load(trained)
    huge = {k: np.full_like(v, 1e30) for k, v in ckpt["params"].items()}
    path = tmp_path / "diverged.npz"
    checkpoint.save(path, huge, optim.adam_init(huge), 1, ckpt["rng"], ckpt["config"], ckpt["network"],
                    world=ckpt["world"])
    line, _ = refused(capsys, evaluate.main, [str(path), "--validation", tiny_datasets[1], "--train", ""])
    assert "the policy's torques are" in line and "use an earlier checkpoint" in line


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


def test_demo_checks_its_pictures_paths_before_the_work(capsys, tmp_path):
    """A picture's path taken by a folder is refused before any demonstration is recorded (stdout empty)."""
    (tmp_path / "one_shot_trial.gif").mkdir()
    line, out = refused(capsys, demo.main, ["--out", str(tmp_path)])
    assert "argument --out" in line and "one_shot_trial.gif" in line and "folder" in line
    assert out == "" and [p.name for p in tmp_path.iterdir()] == ["one_shot_trial.gif"]   # no one_shot.png


def test_demo_interrupted_wipes_its_progress_bar_and_says_so_in_one_line(capsys, tmp_path, monkeypatch):
    """Ctrl-C during the trials: the half-drawn bar is wiped, the terminal shows `error: interrupted` alone."""
    real, calls = demo.imitation.rollout, []

    def rollout(*args, **kwargs):
        calls.append(1)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return real(*args, **kwargs)
    monkeypatch.setattr(demo.imitation, "rollout", rollout)
    line, _ = refused(capsys, demo.main, ["--out", str(tmp_path), "--trials", "2"], status=130)
    assert line == "error: interrupted"
    nothing_written(tmp_path)


def test_demo_refuses_a_policy_that_does_not_adapt_before_the_demonstrations(capsys, tmp_path):
    path = tmp_path / "random.npz"
    cfg, rng = dataclasses.replace(config.PROFILES["smoke"], method="random"), np.random.default_rng(0)
    net_cfg = methods.of(cfg).network_config(8)
    params = methods.of(cfg).init_params(net_cfg, rng)
    checkpoint.save(path, params, optim.adam_init(params), 0, rng, cfg, net_cfg)
    line, out = refused(capsys, demo.main, ["--checkpoint", str(path), "--out", str(tmp_path / "out")])
    assert "'random' policy, which does not adapt" in line and "oneshot.evaluate" in line
    assert out == ""                                              # no expert demos recorded first


# --- 11. collect --out, --noise, --seed ------------------------------------------------------------------

@pytest.mark.parametrize("where", ["folder", "under a file"])
def test_collect_checks_out_before_collecting(capsys, tmp_path, where):
    (tmp_path / "file").write_text("")
    out = tmp_path if where == "folder" else tmp_path / "file" / "d.npz"
    line, printed = refused(capsys, collect.main, ["--out", str(out), *TINY])
    assert "argument --out" in line and printed == ""
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


def test_collect_replaces_a_dataset_but_never_another_kind_of_file(capsys, tmp_path, tiny_checkpoint):
    """A policy or any other file at --out is refused and left as it was; a dataset is replaced, and so
    is a file too damaged to tell (a truncated .npz, an empty file: what loading it says to re-create)."""
    policy, notes = tmp_path / "policy.npz", tmp_path / "notes.txt"
    policy.write_bytes(pathlib.Path(tiny_checkpoint).read_bytes())
    notes.write_text("mine")
    for path in (policy, notes):
        before = path.read_bytes()
        line, printed = refused(capsys, collect.main, ["--out", str(path), "--split", "validation", *TINY])
        assert f"--out {path} exists and is not a dataset of demonstrations" in line and "move that one aside" in line
        assert path.read_bytes() == before and printed == ""
    data = tmp_path / "d.npz"
    for seed in ("0", "1"):                                   # the second replaces the first
        collect.main(["--out", str(data), "--split", "validation", "--seed", seed, *TINY])
        assert datasets.load(data)["metadata"]["seed"] == int(seed)
    for damaged in (data.read_bytes()[:-100], b""):
        data.write_bytes(damaged)
        collect.main(["--out", str(data), "--split", "validation", *TINY])
        assert datasets.load(data)["metadata"]["seed"] == 0


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
    (["maml", "--profile", "bogus"], "argument --profile: invalid choice: 'bogus'"),
    (["maml", "--method", "lstm", "--lstm-units", "1000000000"], "the lstm policy's 4,000,000,456,000,069,203 "
                                                                  "parameters and what a meta-iteration keeps")])
def test_benchmark_refuses_empty_runs_and_unknown_profiles(capsys, argv, expected):
    line, out = refused(capsys, benchmark.main, argv)
    assert expected in line and out == ""


# --- how errors end ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("error, status", [(ValueError("bad value; do this"), 2),
                                           (datasets.DatasetError("damaged; re-create it"), 2),
                                           (FileExistsError("already holds a run; use --resume"), 2),
                                           (run_folder.TrainingDiverged("the meta-loss became nan"), 1),
                                           (OSError(5, "Input/output error"), 1),
                                           (KeyboardInterrupt(), 130)])
def test_run_turns_each_kind_of_error_into_one_line_and_its_status(capsys, error, status):
    def main(argv):
        raise error
    line, _ = refused(capsys, main, [], status, failures=(run_folder.TrainingDiverged, shards.ShardError))
    assert line == "error: " + (str(error) or "interrupted")


@pytest.mark.parametrize("filename", [None, "runs/x/checkpoint.npz"])
def test_a_full_disk_is_named_with_what_to_do(capsys, filename):
    def main(argv):
        raise OSError(28, "No space left on device", filename)
    line, _ = refused(capsys, main, [], 1)
    assert line.startswith("error: the disk is full (no space left on device") and "free some space" in line
    assert line.endswith("free some space, or write to another disk")
    assert (f"for {filename!r}" in line) == (filename is not None)


def test_out_of_memory_says_to_ask_for_less(capsys):
    def main(argv):
        raise MemoryError("Unable to allocate 21.3 GiB for an array")
    line, _ = refused(capsys, main, [], 1)
    assert line.startswith("error: out of memory") and "a smaller --meta-batch" in line


def test_a_reader_that_goes_away_ends_the_command_quietly(tmp_path):
    """`python -m oneshot.exercises list | head -1`: exit 141 as `cat` would, no traceback or error line
    (it said `error: [Errno 32] Broken pipe`)."""
    script = ("import sys\nfrom oneshot.tools import cli\n"
              "def main(argv):\n    for _ in range(100000):\n        print('line of output ' * 4)\n"
              "sys.exit(cli.run(main))\n")
    command = f"{shlex.quote(sys.executable)} -c {shlex.quote(script)} | head -1; exit ${{PIPESTATUS[0]}}"
    done = subprocess.run(command, shell=True,
                          capture_output=True, text=True, cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                          timeout=60, executable="/bin/bash")
    assert done.stdout.startswith("line of output") and done.stderr == "", done.stderr
    assert done.returncode == 141                                   # the command's own status, not head's


def test_a_plain_kill_ends_a_command_as_ctrl_c_does_and_run_gives_the_signal_back(capsys):
    """SIGTERM (`kill`, a scheduler's stop) while the command works: `error: interrupted`, status 130; after
    `run`, the caller's own handler is back (a notebook or a test calling `run` is not left with run's)."""
    caught = []

    def callers_own(signum, frame):
        caught.append(signum)

    def main(argv):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(1)                                # the handler runs before this line ends

    previous = signal.signal(signal.SIGTERM, callers_own)
    try:
        line, _ = refused(capsys, main, [], 130)
        assert line == "error: interrupted" and caught == []
        assert signal.getsignal(signal.SIGTERM) is callers_own
    finally:
        signal.signal(signal.SIGTERM, previous)


CTRL_C_AT_NUMPY = """
import importlib.abc, os, signal, sys
class CtrlCAtNumpy(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "numpy":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)       # Ctrl-C as the command starts importing NumPy
        return None
sys.meta_path.insert(0, CtrlCAtNumpy())
"""


def default_ctrl_c():
    """In the child: Ctrl-C as a terminal gives it, even when pytest runs as a background job (SIGINT ignored,
    which a child inherits, and which `oneshot` rightly leaves alone)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("module, argv", [("train", ["--help"]), ("experiments", ["fig2", "--help"])])
def test_ctrl_c_while_a_command_imports_is_one_line_and_130(tmp_path, module, argv):
    """`python -m oneshot.train`, Ctrl-C in the first half second, while it imports NumPy: `error:
    interrupted`, status 130, as later (it was a traceback through the imports, status 1). And cli.run
    puts Python's own handler back, so that a Ctrl-C during the command is a KeyboardInterrupt again
    (training saves its checkpoint on it)."""
    (tmp_path / "sitecustomize.py").write_text(CTRL_C_AT_NUMPY)      # run by Python at start-up
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(ROOT)]))
    done = subprocess.run([sys.executable, "-m", f"oneshot.{module}", *argv], capture_output=True, text=True,
                          cwd=tmp_path, env=env, timeout=60, preexec_fn=default_ctrl_c)
    assert (done.returncode, done.stderr, done.stdout) == (130, "error: interrupted\n", "")
    check = ("import signal, sys\nfrom oneshot.tools import cli\n"
             "cli.run(lambda argv: print(signal.getsignal(signal.SIGINT) is signal.default_int_handler))")
    done = subprocess.run([sys.executable, "-c", "import sys; sys.argv[:1] = ['-m']\n" + check], capture_output=True,
                          text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60, preexec_fn=default_ctrl_c)
    assert (done.returncode, done.stdout) == (0, "True\n"), done.stderr


def test_run_keeps_the_traceback_of_a_bug():
    def main(argv):
        return {}["missing"]
    with pytest.raises(KeyError):
        cli.run(main, [])


@pytest.mark.parametrize("module, argv", [("collect", ["--out", "x.npz", "--workers", "0"]),
                                          ("train", ["--iterations", "0"]),
                                          ("evaluate", ["missing-checkpoint.npz"]),
                                          ("demo", ["--checkpoint", "missing-checkpoint.npz"]),
                                          ("benchmark", ["expert", "--scenes", "0"]),
                                          ("benchmark", []), ("experiments", []), ("exercises", [])])
def test_python_m_exits_with_the_status_and_one_line(tmp_path, module, argv):
    done = subprocess.run([sys.executable, "-m", f"oneshot.{module}", *argv], capture_output=True, text=True,
                          cwd=tmp_path, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60)
    assert done.returncode == 2 and len(done.stderr.splitlines()) == 1, done.stderr
    assert done.stderr.startswith("error: ") and done.stdout == ""
    nothing_written(tmp_path)


def test_python_m_oneshot_names_every_command_in_one_line(tmp_path):
    """`python -m oneshot` was Python's own "No module named oneshot.__main__" (exit 1). Every module of the
    package that runs with -m (a module with a __main__ block, or a package with __main__.py) is named."""
    package = pathlib.Path(ROOT) / "oneshot"
    runnable = {p.stem if p.name != "__main__.py" else p.parent.name for p in package.rglob("*.py")
                if 'if __name__ == "__main__"' in p.read_text()} - {"oneshot"}
    assert set(top.COMMANDS) == runnable
    done = subprocess.run([sys.executable, "-m", "oneshot"], capture_output=True, text=True, cwd=tmp_path,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=60)
    assert done.returncode == 2 and done.stdout == "" and len(done.stderr.splitlines()) == 1, done.stderr
    assert done.stderr.startswith("error: ") and all(name in done.stderr for name in top.COMMANDS)
    nothing_written(tmp_path)


def test_run_keeps_a_failed_workers_report_after_the_one_line(capsys):
    def main(argv):
        raise shards.ShardError("shard process 0 died (exit code -9)\nworker 0: MemoryError")
    with pytest.raises(SystemExit) as exit_:
        cli.run(main, [], failures=(shards.ShardError,))
    assert exit_.value.code == 1
    assert capsys.readouterr().err.splitlines() == ["error: shard process 0 died (exit code -9)",
                                                    "worker 0: MemoryError"]


# --- a newcomer's first mistakes: each refused in one line that names the fix ---------------------------

def test_a_newcomers_first_mistakes_are_named_with_their_fix(capsys, tmp_path):
    grader = lambda argv: sys.exit(exercises.main(argv))            # as its __main__ runs it
    (tmp_path / "alice.py").write_text("def is_success(e, t, r=0.05):\n    return True\n")
    for main, argv, words in (
            (experiments.main, [], "error: name a command: fig2, summarise, seeds, ship, difference or scenes "),
            (benchmark.main, [], "error: name a command: expert, collect, maml or privileged "),
            (grader, ["grade", str(tmp_path / "alice.py")],
             f"is a file, not a folder of submissions: grade the folder that holds it, or check one exercise in it "
             f"with `python -m oneshot.exercises check N --file {tmp_path / 'alice.py'}`"),
            (grader, ["check", "five", "--file", str(tmp_path / "alice.py")],
             "argument number: expected a whole number >= 1; got 'five'"),
            (experiments.main, ["summarise", str(tmp_path / "nope")], f"no such folder: {tmp_path / 'nope'} "
                                                                      f"(summarise takes a finished sweep's")):
        line, _ = refused(capsys, main, argv)
        assert words in line, line
    with pytest.raises(SystemExit):                  # a parser with one subcommand names it
        cli.Parser(prog="p").error("the following arguments are required: {only}")
    assert capsys.readouterr().err == "error: name the command only (see p --help)\n"
