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


RECIPE = {"method": "mil", "alpha": 0.3, "raw": False}


def _write(path, split="test", seed=0, per_colour=None, trials_per_colour=4, order=None, result=None, **policy):
    """An evaluate --json result by hand: per_colour {colour: successes}, written in `order` of colours
    (default sorted); `result` and `policy` override fields of the split's result and of the policy."""
    per_colour = {0: 1, 1: 1} if per_colour is None else per_colour
    successes, trials = sum(per_colour.values()), trials_per_colour * len(per_colour)
    rates = {str(c): per_colour[c] / trials_per_colour for c in (order or sorted(per_colour))}
    path.write_text(json.dumps({split: {"successes": successes, "trials": trials, "rate": successes / trials,
                                        "per_colour": rates, **(result or {})},
                                "policy": {"checkpoint": f"runs/seed{seed}/checkpoint.npz", "training_seed": seed,
                                           "method": "mil", "recipe": RECIPE, "dataset": f"data/{split}.npz",
                                           "trials_per_colour": trials_per_colour, "eval_seed": 0, **policy}}))
    return str(path)


def test_seeds_pools_evaluates_own_results(two_seeds, tmp_path, capsys):
    out = tmp_path / "summary.json"
    assert command.main(["seeds", *(path for path, _ in two_seeds), "--out", str(out)]) == 0
    pooled = json.loads(out.read_text())
    tests = [results["test"] for _, results in two_seeds]
    assert [p["training_seed"] for p in pooled["policies"]] == [0, 1]
    assert pooled["split"] == "test" and pooled["trials_per_colour"] == 3 and pooled["colours"] == 2
    assert pooled["successes"] == sum(r["successes"] for r in tests) and pooled["trials"] == sum(r["trials"] for r in tests)
    assert pooled["mean_rate"] == pytest.approx(np.mean([r["rate"] for r in tests]))
    assert "mean over 2 seeds" in capsys.readouterr().out
    assert pooled["command"].startswith("python -m oneshot.experiments seeds ")


def test_seeds_interval_is_the_seed_and_colour_bootstrap_of_the_counts(tmp_path, capsys):
    # seed 0: 4, 0 and 2 of 4 on colours 0, 1, 2 (50%); seed 1: 3, 1 and 0 (33.3%), its colours listed in
    # another order: the bootstrap must pair colour c of one seed with colour c of the other
    a = _write(tmp_path / "a.json", seed=0, per_colour={0: 4, 1: 0, 2: 2})
    b = _write(tmp_path / "b.json", seed=1, per_colour={0: 3, 1: 1, 2: 0}, order=[2, 0, 1])
    out = tmp_path / "s.json"
    assert command.main(["seeds", b, a, "--out", str(out)]) == 0
    pooled = json.loads(out.read_text())
    mean, lo, hi = stats.interval(np.array([[4, 0, 2], [3, 1, 0]]), np.full((2, 3), 4))
    assert (pooled["mean_rate"], pooled["ci_low"], pooled["ci_high"]) == pytest.approx((mean, lo, hi))
    assert mean == pytest.approx((6 / 12 + 4 / 12) / 2)
    misread = stats.interval(np.array([[4, 0, 2], [0, 3, 1]]), np.full((2, 3), 4))   # b's colours in file order
    assert misread[1:] != pytest.approx((lo, hi))
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("training seed 0: 50.0% (6/12)") and printed[1].startswith("training seed 1: 33.3% (4/12)")
    assert "mean over 2 seeds: 41.7% [" in printed[2] and "seeds from 33.3% to 50.0%" in printed[2]


@pytest.mark.parametrize("second, why", [
    (dict(split="validation"), "differ in split"),
    (dict(seed=0), "training seed(s) repeated"),
    (dict(trials_per_colour=2), "differ in trials_per_colour"),
    (dict(per_colour={0: 1, 2: 1}), "differ in colours"),
    (dict(eval_seed=1), "differ in eval_seed"),
    (dict(method="lstm"), "differ in method"),
    (dict(recipe=dict(RECIPE, alpha=0.1)), "differ in recipe"),
    (dict(recipe=dict(RECIPE, other_colour_demo=True)), "b.json: other_colour_demo=True"),   # names what differs
    (dict(dataset="data/other.npz"), "differ in dataset"),
])
def test_seeds_refuses_results_that_do_not_pool(tmp_path, capsys, second, why):
    a = _write(tmp_path / "a.json", seed=0)
    b = _write(tmp_path / "b.json", **{"seed": 1, **second})
    line, _ = refused(capsys, command.main, ["seeds", a, b])
    assert why in line


@pytest.mark.parametrize("change", [
    dict(result={"per_colour": {"0": "Infinity"}}), dict(result={"successes": 1e400}),
    dict(result={"per_colour": ["0", "1"]}), dict(result={"per_colour": {}}), dict(result={"per_colour": {"x": 0.5}}),
    dict(training_seed=[2]), dict(training_seed=None), dict(training_seed="2"), dict(training_seed=True),
    dict(result={"per_colour": {"0": 0.3, "1": 0.2}}),       # not whole trials of 4
    dict(result={"per_colour": {"0": 1.5, "1": 0.25}}),      # above 1
    dict(result={"per_colour": {"0": float("nan"), "1": 0.25}}),
])
def test_seeds_refuses_what_evaluate_did_not_write_in_one_line(tmp_path, capsys, change):
    a = _write(tmp_path / "a.json", seed=0)
    b = _write(tmp_path / "b.json", **{"seed": 1, **change})
    line, _ = refused(capsys, command.main, ["seeds", a, b])
    assert "b.json is not one split's result" in line


@pytest.mark.parametrize("text", ['[1, 2]', '{"test": {"successes": 1}}', 'not json', '{"policy": {}}', ''])
def test_seeds_refuses_files_that_are_not_evaluate_results(tmp_path, capsys, text):
    a = _write(tmp_path / "a.json", seed=0)
    (tmp_path / "b.json").write_text(text)
    line, _ = refused(capsys, command.main, ["seeds", a, str(tmp_path / "b.json")])
    assert "b.json is not" in line


@pytest.mark.parametrize("result, why", [({"successes": 8}, "disagree with its totals (2/8)"),
                                         ({"trials": 9}, "disagree with its totals (2/9)")])
def test_seeds_refuses_counts_that_disagree_with_their_totals(tmp_path, capsys, result, why):
    a = _write(tmp_path / "a.json", seed=0)
    b = _write(tmp_path / "b.json", seed=1, result=result)
    line, _ = refused(capsys, command.main, ["seeds", a, b])
    assert "b.json: its per-colour rates" in line and why.replace("(2/8)", "(8/8)") in line


def test_seeds_names_a_missing_result_and_what_to_give(tmp_path, capsys):
    a = _write(tmp_path / "a.json", seed=0)
    line, _ = refused(capsys, command.main, ["seeds", a, str(tmp_path / "missing.json")])
    assert f"no file {tmp_path / 'missing.json'}; name the JSON files of `python -m oneshot.evaluate" in line


def test_seeds_needs_two_results_and_keeps_its_inputs(tmp_path, capsys):
    a, b = _write(tmp_path / "a.json", seed=0), _write(tmp_path / "b.json", seed=1)
    line, _ = refused(capsys, command.main, ["seeds", a])
    assert "needs the results of two or more training seeds" in line
    before = (tmp_path / "b.json").read_text()
    line, _ = refused(capsys, command.main, ["seeds", a, b, "--out", b])
    assert "would overwrite" in line and "one of the results to pool" in line and (tmp_path / "b.json").read_text() == before


def test_seeds_out_replaces_only_an_earlier_summary(tmp_path, capsys):
    """--out replaced any file (notes, runs.csv, an evaluate result not among those pooled) with the
    summary: now only an earlier summary, or an empty file, is replaced; anything else is refused and left."""
    a, b = _write(tmp_path / "a.json", seed=0), _write(tmp_path / "b.json", seed=1)
    other = _write(tmp_path / "c.json", seed=2)
    for name, content in (("notes.txt", "mine\n"), ("runs.csv", "method,size\n"), ("c.json", None)):
        path = tmp_path / name
        if content is not None:
            path.write_text(content)
        before = path.read_bytes()
        line, printed = refused(capsys, command.main, ["seeds", a, b, "--out", str(path)])
        assert f"--out {path} exists and is not a summary of seeds --out" in line and printed == ""
        assert path.read_bytes() == before
    out = tmp_path / "summary.json"
    out.write_text("")
    for pair in ((a, b), (a, other)):                   # empty, then an earlier summary: replaced
        assert command.main(["seeds", *pair, "--out", str(out)]) == 0
        assert [p["training_seed"] for p in json.loads(out.read_text())["policies"]] == [0, 1 if pair[1] == b else 2]
