import numpy as np
import pytest

from oneshot.data import collection, datasets
from oneshot.expert.controller import ExpertConfig
from oneshot.tools import host
from oneshot.training.config import PROFILES

SMOKE = PROFILES["smoke"]


def pytest_configure(config):
    """The suite's own process uses one BLAS thread, as every command of the package does
    (`oneshot.tools.host`): its products are small, and beside other work on the cores (a kernel, a
    worker, another program) OpenBLAS's spinning second thread made tests up to 4 times slower. Tests
    of a command's own thread count set another count first (test_experiments.py)."""
    host.blas_threads(1)


@pytest.fixture(scope="session")
def tiny_split_datasets(tmp_path_factory):
    """Small real datasets, collected as the smoke profile collects (its seeds and DART noise): 3
    meta-training colours x 3 demos, 2 validation colours x 2 demos, 2 test colours x 2 demos.
    Returns {split: path}."""
    folder = tmp_path_factory.mktemp("data")
    expert_cfg = ExpertConfig(action_noise=SMOKE.demo_noise)
    paths = {}
    for split, tasks, demos, seed in (("train", 3, 3, 0), ("validation", 2, 2, 1), ("test", 2, 2, 2)):
        paths[split] = str(folder / f"tiny_{split}.npz")
        datasets.save(collection.collect(tasks, demos, split, seed=seed, workers=1, expert_cfg=expert_cfg,
                                         progress=False), paths[split])
    return paths


@pytest.fixture(scope="session")
def tiny_datasets(tiny_split_datasets):
    """(meta-training, validation) paths of `tiny_split_datasets`."""
    return tiny_split_datasets["train"], tiny_split_datasets["validation"]


@pytest.fixture
def rng():
    return np.random.default_rng(0)
