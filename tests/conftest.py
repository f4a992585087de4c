import numpy as np
import pytest

from oneshot.data import collection, datasets


@pytest.fixture(scope="session")
def tiny_datasets(tmp_path_factory):
    """Small real datasets: 3 training colours x 3 demos, 2 held-out colours x 2 demos."""
    folder = tmp_path_factory.mktemp("data")
    train = folder / "tiny_train.npz"
    heldout = folder / "tiny_heldout.npz"
    datasets.save(collection.collect(3, 3, "train", seed=0, workers=1, progress=False), train)
    datasets.save(collection.collect(2, 2, "heldout", seed=1, workers=1, progress=False), heldout)
    return str(train), str(heldout)


@pytest.fixture
def rng():
    return np.random.default_rng(0)
