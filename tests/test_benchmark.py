"""`python -m oneshot.benchmark maml`: what its figures are made of (the timings themselves are for the
benchmark, not the tests). Each runs the benchmark in its own process: it sets BLAS's threads."""
import dataclasses
import json
import subprocess
import sys

import pytest

from oneshot import methods
from oneshot.benchmark import expert, privileged
from oneshot.data import datasets
from oneshot.experiments.lines import LINES


def benchmark(*argv):
    out = subprocess.run([sys.executable, "-m", "oneshot.benchmark", "maml", *argv], capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout)


def test_maml_breakdown_finds_every_part_of_a_meta_gradient():
    """`--breakdown` times the network's functions by name under cProfile: if one were renamed or moved,
    its group would silently read 0 ms. The groups and autograd's Python add up to the part's time."""
    result = benchmark("--breakdown", "--profile", "smoke", "--iterations", "1", "--inner-steps", "1")
    assert (result["profile"], result["tasks"], result["frames"], result["inner_steps"]) == ("smoke", 2, 20, 1)
    parts = ["conv_products_ms", "transposed_products_ms", "im2col_col2im_ms", "other_layer_primitives_ms"]
    assert all(result[k] > 0 for k in parts + ["part_ms", "rollout_step_ms", "adapt_one_demo_ms"])
    assert sum(result[k] for k in parts) + result["autograd_python_ms"] == pytest.approx(result["part_ms"], abs=0.5)
    assert "exchange_ms" not in result                     # one process: nothing is exchanged


def test_maml_reads_its_rate_against_the_ceiling_measured_in_the_same_run():
    result = benchmark("--profile", "smoke", "--iterations", "1", "--blas-threads", "1")
    assert (result["shards"], result["blas_threads"], result["ceiling_cores"]) == (1, 1, 1)
    assert ("warning" in result) == (result["percent_of_ceiling"] > 100)     # a busy machine's figure says so
    rate = result["gflop_per_iteration"] / result["seconds_per_iteration"]
    assert result["gflop_per_second"] == pytest.approx(rate, rel=0.02)
    assert result["percent_of_ceiling"] == pytest.approx(100 * rate / result["ceiling_gflop_per_second"], rel=0.02)


@pytest.mark.parametrize("command", ["expert", "collect", "maml", "privileged"])
def test_every_benchmark_option_says_what_it_does(capsys, command):
    from oneshot.benchmark import __main__ as benchmark
    with pytest.raises(SystemExit):
        benchmark.main([command, "--help"])
    lines = capsys.readouterr().out.split("options:")[1].splitlines()
    bare = []
    for i, line in enumerate(lines):
        if line.startswith("  -"):
            inline = [part for part in line.strip().split("  ") if part.strip()]
            below = i + 1 < len(lines) and lines[i + 1].startswith(" " * 10) and not lines[i + 1].lstrip().startswith("-")
            if len(inline) < 2 and not below:
                bare.append(inline[0])
    assert not bare, f"options of `benchmark {command}` without help: {bare}"


def test_maml_times_a_figure_2_line_as_its_sweep_trains_it():
    """`--line L`: the meta-iteration of a line of the sweeps (oneshot.experiments.lines), e.g. Figure 2's
    every-parameter line (layer norm, every parameter adapts, the released widths), not a training profile's,
    as a sweep trains it (one process, one BLAS thread). Not with --profile; not a line that does not learn."""
    line = "mil-released+widths-flat"
    result = benchmark("--line", line, "--iterations", "1", "--meta-batch", "2")
    method = methods.of(dataclasses.replace(LINES[line], meta_batch=2, shards=1))
    assert (result["line"], result["inner_params"], result["meta_batch"]) == (line, "all", 2)
    assert (result["shards"], result["blas_threads"]) == (1, 1) and "profile" not in result
    assert result["gflop_per_iteration"] == round(method.meta_gradient_flops(method.network_config(32), 20, 2) / 1e9, 2)
    assert result["gflop_per_iteration"] != benchmark("--profile", "released", "--iterations", "1", "--meta-batch", "2",
                                                      "--shards", "1", "--blas-threads", "1")["gflop_per_iteration"]
    for argv, message in ((["--profile", "released", "--line", line], "not allowed with argument --profile"),
                          (["--line", "random"], "argument --line: invalid choice: 'random'"),
                          (["--line", line, "--method", "lstm"], f"the line {line} names its method; drop --method"),
                          (["--line", "lstm", "--breakdown"], "not the lstm baseline's: time a profile or a line of MIL"),
                          # a flag its method never reads: it was timed as if it did something
                          (["--method", "lstm", "--first-order"], "--first-order does not apply to the lstm method"),
                          (["--lstm-units", "8"], "--lstm-units does not apply to the mil method"),
                          (["--method", "contextual", "--inner-steps", "3", "--inner-params", "all"],
                           "--inner-steps, --inner-params do not apply to the contextual method"),
                          (["--blas-threads", "99999"], "argument --blas-threads: expected 1 to")):      # was recorded
        out = subprocess.run([sys.executable, "-m", "oneshot.benchmark", "maml", *argv], capture_output=True, text=True)
        assert out.returncode == 2 and message in out.stderr


def test_a_baselines_iteration_reports_no_inner_loop():
    result = benchmark("--profile", "smoke", "--method", "lstm", "--iterations", "1", "--blas-threads", "1")
    assert result["method"] == "lstm" and not {"inner_steps", "inner_params", "first_order"} & set(result)


def test_collect_benchmark_takes_at_least_two_demos_per_colour(monkeypatch):
    """--demos below two per training colour collects two per colour (a dataset needs two), not an error."""
    asked = {}

    def collect(tasks, per_task, split, seed, workers, progress):
        asked.update(tasks=tasks, per_task=per_task)
        raise KeyboardInterrupt                       # stop there: only what is asked for is under test
    monkeypatch.setattr(expert.collection, "collect", collect)
    with pytest.raises(KeyboardInterrupt):
        expert.bench_collect(4, workers=1)
    assert asked == {"tasks": 36, "per_task": 2}


def test_privileged_benchmark_refuses_data_of_another_split(tiny_split_datasets):
    with pytest.raises(datasets.DatasetError, match="holds validation colours, not meta-training colours"):
        privileged.bench_privileged("colour", 1, trials=1, train_data=tiny_split_datasets["validation"])


def test_the_expert_benchmark_counts_its_successes():
    """`benchmark expert` reports the count of scenes the expert reached (500/500 reads better than 1.0),
    and the rate it makes."""
    result = expert.bench_expert(scenes=3)
    assert result["scenes"] == 3 and isinstance(result["expert_successes"], int)
    assert result["expert_success_rate"] == result["expert_successes"] / 3
