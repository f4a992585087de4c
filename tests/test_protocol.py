"""The protocol (docs/experiments.md): every choice reads the validation split, never the test split.

Each path of the package that makes a choice is run here while every dataset it loads and every trial
scene it plays is recorded: training (its validation checks, which early stopping and the iteration
count read), the random policy's choice of its torque std, a hyperparameter search's runs, and evaluate
without `--split test`. None of them may load a test dataset or play a test scene; the test split's own
path (`evaluate --split test`) does, which shows the recording can see it.
"""
import dataclasses

import pytest

from oneshot import evaluate, methods
from oneshot.data import datasets
from oneshot.experiments import fig2
from oneshot.experiments.rows import RunSpec
from oneshot.maml import imitation
from oneshot.training import config, run_folder


@pytest.fixture
def seen(monkeypatch):
    """{"datasets": [split of every dataset loaded], "scenes": [split of every trial scene played]}."""
    record = {"datasets": [], "scenes": []}
    load, trial_seed = datasets.load, imitation.trial_seed

    def loading(path):
        dataset = load(path)
        record["datasets"].append(dataset["metadata"]["split"])
        return dataset

    def seeding(seed, task, trial, split="validation"):
        record["scenes"].append(split)
        return trial_seed(seed, task, trial, split)
    monkeypatch.setattr(datasets, "load", loading)
    monkeypatch.setattr(imitation, "trial_seed", seeding)
    return record


@pytest.fixture
def smoke(tiny_split_datasets):
    paths = tiny_split_datasets
    return dataclasses.replace(config.PROFILES["smoke"], train_data=paths["train"], validation_data=paths["validation"],
                               test_data=paths["test"], iterations=4, eval_every=2, eval_trials=1)


@pytest.mark.parametrize("method", list(methods.REGISTRY))
def test_training_and_its_choices_never_read_the_test_split(seen, smoke, tmp_path, method):
    run_folder.train(dataclasses.replace(smoke, method=method, lstm_units=4, random_stds=(0.25, 1.0)),
                     tmp_path / "run", progress=False)
    assert "test" not in seen["datasets"] and "test" not in seen["scenes"]
    assert "validation" in seen["scenes"]                 # the checks (or the std's choice) did play scenes


def test_a_search_scores_on_validation_and_never_reads_the_test_split(seen, tmp_path):
    search = dataclasses.replace(fig2.PROFILES["tiny"], score="validation", name="search-tiny")
    fig2.ensure_data(search, tmp_path / "data", workers=1, progress=False)
    seen["datasets"].clear()
    context = fig2.run_context(search, tmp_path / "data")
    for line in ("mil-conv0", "random"):
        row = fig2.run_one(RunSpec(line, 3, 3, 0, 2), str(tmp_path / line), context)
        assert row["trials"] == search.validation[0] * search.trials
    assert "test" not in seen["datasets"] and "test" not in seen["scenes"]


def test_evaluate_reads_the_test_split_only_when_asked(seen, smoke, tmp_path):
    run_folder.train(smoke, tmp_path / "run", progress=False)
    seen["datasets"].clear(), seen["scenes"].clear()
    evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--trials", "1"])
    assert "test" not in seen["datasets"] and "test" not in seen["scenes"]
    evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--trials", "1", "--split", "test", "--train", ""])
    assert seen["datasets"][-1] == "test" and seen["scenes"][-1] == "test"      # the recording sees the test split
