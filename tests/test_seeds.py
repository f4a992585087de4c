"""`python -m oneshot.experiments seeds`: one recipe's policies (one per training seed), each scored by
`python -m oneshot.evaluate --json`, pooled into a mean with its interval over seeds and colours."""
import dataclasses
import json

import numpy as np
import pytest

from oneshot import evaluate
from oneshot.experiments import __main__ as command, stats
from oneshot.training import config, run_folder
from test_hostile import refused


@pytest.fixture(scope="module")
def two_seeds(tiny_split_datasets, tmp_path_factory):
    """Two smoke policies (training seeds 0 and 1), each scored on the test split by evaluate --json:
    [(json path, evaluate's results)]."""
    paths, folder = tiny_split_datasets, tmp_path_factory.mktemp("seeds")
    cfg = dataclasses.replace(config.PROFILES["smoke"], train_data=paths["train"], validation_data=paths["validation"],
                              test_data=paths["test"], iterations=1)
    scored = []
    for seed in (0, 1):
        run_folder.train(dataclasses.replace(cfg, seed=seed), folder / f"seed{seed}", progress=False)
        out = folder / f"seed{seed}_test.json"
        results = evaluate.main([str(folder / f"seed{seed}" / "checkpoint.npz"), "--split", "test", "--train", "",
                                 "--trials", "3", "--json", str(out)])
        scored.append((str(out), results))
    return scored


def _write(path, split, seed, per_colour, trials_per_colour, **policy):
    """An evaluate --json result by hand: per_colour {colour: successes}."""
    successes = sum(per_colour.values())
    trials = trials_per_colour * len(per_colour)
    path.write_text(json.dumps({split: {"successes": successes, "trials": trials, "rate": successes / trials,
                                        "per_colour": {str(c): s / trials_per_colour for c, s in per_colour.items()}},
                                "policy": {"checkpoint": f"runs/seed{seed}/checkpoint.npz", "training_seed": seed,
                                           "method": "mil", "trials_per_colour": trials_per_colour, "eval_seed": 0,
                                           **policy}}))
    return str(path)


def test_seeds_pools_evaluates_own_results_with_the_seed_and_colour_interval(two_seeds, tmp_path, capsys):
    out = tmp_path / "summary.json"
    assert command.main(["seeds", *(path for path, _ in two_seeds), "--out", str(out)]) == 0
    pooled = json.loads(out.read_text())
    tests = [results["test"] for _, results in two_seeds]
    assert [p["training_seed"] for p in pooled["policies"]] == [0, 1]
    assert pooled["split"] == "test" and pooled["trials_per_colour"] == 3
    assert pooled["successes"] == sum(r["successes"] for r in tests) and pooled["trials"] == sum(r["trials"] for r in tests)
    # the interval is stats.interval of the (seeds, colours) counts evaluate measured
    colours = sorted(tests[0]["per_colour"])
    successes = np.array([[round(3 * r["per_colour"][c]) for c in colours] for r in tests])
    mean, lo, hi = stats.interval(successes, np.full_like(successes, 3))
    assert (pooled["mean_rate"], pooled["ci_low"], pooled["ci_high"]) == pytest.approx((mean, lo, hi))
    assert mean == pytest.approx(np.mean([r["rate"] for r in tests]))
    assert "mean over 2 seeds" in capsys.readouterr().out
    assert pooled["command"].startswith("python -m oneshot.experiments seeds ")


def test_seeds_prints_each_policy_then_the_mean_over_seeds(tmp_path, capsys):
    # seed 0: 4/4 on colour 0 and 0/4 on colour 1 (50%); seed 1: 1/4 and 1/4 (25%): mean 37.5%
    a = _write(tmp_path / "a.json", "test", 0, {0: 4, 1: 0}, 4)
    b = _write(tmp_path / "b.json", "test", 1, {0: 1, 1: 1}, 4)
    assert command.main(["seeds", b, a]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("training seed 0: 50.0% (4/8)") and printed[1].startswith("training seed 1: 25.0% (2/8)")
    assert "mean over 2 seeds: 37.5% [" in printed[2] and "seeds from 25.0% to 50.0%" in printed[2]


@pytest.mark.parametrize("second, why", [
    (dict(split="validation"), "differ in split (test, validation)"),
    (dict(seed=0), "training seed(s) repeated"),
    (dict(trials_per_colour=2), "differ in trials_per_colour"),
    (dict(per_colour={0: 1, 2: 1}), "differ in colours"),
    (dict(eval_seed=1), "differ in eval_seed"),
])
def test_seeds_refuses_results_that_do_not_pool(tmp_path, capsys, second, why):
    a = _write(tmp_path / "a.json", "test", 0, {0: 1, 1: 1}, 4)
    args = dict(split="test", seed=1, per_colour={0: 1, 1: 1}, trials_per_colour=4) | second
    b = _write(tmp_path / "b.json", args.pop("split"), args.pop("seed"), args.pop("per_colour"),
               args.pop("trials_per_colour"), **args)
    line, _ = refused(capsys, command.main, ["seeds", a, b])
    assert why in line


@pytest.mark.parametrize("text", ['[1, 2]', '{"test": {"successes": 1}}', 'not json', '{"policy": {}}'])
def test_seeds_refuses_what_evaluate_did_not_write_in_one_line(tmp_path, capsys, text):
    a = _write(tmp_path / "a.json", "test", 0, {0: 1, 1: 1}, 4)
    (tmp_path / "b.json").write_text(text)
    line, _ = refused(capsys, command.main, ["seeds", a, str(tmp_path / "b.json")])
    assert "b.json is not" in line
