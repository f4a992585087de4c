"""The demonstration dataset: collection, round trip, determinism, and rejection of bad files."""
import dataclasses
import json
import os
import zipfile

import numpy as np
import pytest

from oneshot import collect, data, palette
from oneshot.arm import ArmConfig
from oneshot.palette import PaletteConfig
from oneshot.world import ReachWorld, WorldConfig


@pytest.fixture(scope="module")
def small():
    return collect.collect(n_tasks=3, demos_per_task=2, split="train", seed=5, workers=1, progress=False)


def test_collected_demos_are_expert_successes_of_their_task(small):
    data.validate(small)
    meta = small["metadata"]
    assert meta["n_tasks"] == 3 and meta["demos_per_task"] == 2 and meta["dropped"] == 0
    assert set(small["task_colours"].tolist()) <= set(palette.split_colours("train").tolist())
    assert len(set(small["task_colours"].tolist())) == 3          # tasks are distinct colours
    for i in range(3):
        for k in range(2):
            target = small["positions"][i, k, small["target_index"][i, k]]
            # the state after the last frame is not stored; the last frames' end effectors are
            assert np.linalg.norm(small["states"][i, k, -1, 4:] - target) < 0.05
    assert not np.array_equal(small["positions"][0, 0], small["positions"][0, 1])  # new scene per demo


def test_round_trip_is_exact(small, tmp_path):
    path = tmp_path / "d.npz"
    data.save(small, path)
    back = data.load(path)
    for key in data.ARRAYS:
        assert back[key].dtype == small[key].dtype and np.array_equal(back[key], small[key]), key
    assert back["metadata"]["format_version"] == data.FORMAT_VERSION
    assert back["metadata"]["seed"] == 5
    assert [p.name for p in tmp_path.iterdir()] == ["d.npz"]     # no temporary file left behind


def test_collection_is_seeded_and_independent_of_worker_count(small):
    again = collect.collect(n_tasks=3, demos_per_task=2, split="train", seed=5, workers=2, progress=False)
    for key in data.ARRAYS:
        assert np.array_equal(again[key], small[key]), key
    other = collect.collect(n_tasks=3, demos_per_task=2, split="train", seed=6, workers=1, progress=False)
    assert not np.array_equal(other["positions"], small["positions"])


def test_truncated_file_is_rejected(small, tmp_path):
    path = tmp_path / "d.npz"
    data.save(small, path)
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(data.DatasetError, match="truncated or corrupt"):
        data.load(path)


def _rewrite(path, **changes):
    """Rewrite a saved dataset with some members replaced (the checksum is left as it was)."""
    with np.load(path) as f:
        members = {k: f[k] for k in f.files}
    members.update(changes)
    with open(path, "wb") as f:
        np.savez_compressed(f, **members)


def test_changed_arrays_fail_the_checksum(small, tmp_path):
    path = tmp_path / "d.npz"
    data.save(small, path)
    actions = small["actions"].copy()
    actions[1, 1, 3, 0] += 0.01
    _rewrite(path, actions=actions)
    with pytest.raises(data.DatasetError, match="checksum"):
        data.load(path)


def test_wrong_version_missing_key_bad_dtype_and_nan_are_named(small, tmp_path):
    path = tmp_path / "d.npz"
    data.save(small, path)
    meta = json.loads(str(np.load(path)["metadata"]))
    _rewrite(path, metadata=np.array(json.dumps(dict(meta, format_version=99))))
    with pytest.raises(data.DatasetError, match="format version 99"):
        data.load(path)

    data.save(small, path)
    with np.load(path) as f:
        members = {k: f[k] for k in f.files if k != "seeds"}
    with open(path, "wb") as f:
        np.savez_compressed(f, **members)
    with pytest.raises(data.DatasetError, match="no array 'seeds'"):
        data.load(path)

    bad = dict(small, states=small["states"].astype(np.float64))
    with pytest.raises(data.DatasetError, match="states must be 4-d float32"):
        data.validate(bad)
    bad = dict(small, actions=small["actions"][:, :, :-1])
    with pytest.raises(data.DatasetError, match=r"actions has shape .* expected"):
        data.validate(bad)
    nan = small["actions"].copy()
    nan[0, 0, 0, 0] = np.nan
    with pytest.raises(data.DatasetError, match="NaN"):
        data.validate(dict(small, actions=nan))
    with pytest.raises(FileNotFoundError, match="oneshot.collect"):
        data.load(tmp_path / "missing.npz")
    (tmp_path / "text.npz").write_text("not a zip")
    with pytest.raises(data.DatasetError, match="not a readable"):
        data.load(tmp_path / "text.npz")


def test_failed_save_leaves_the_old_file_and_no_debris(small, tmp_path, monkeypatch):
    path = tmp_path / "d.npz"
    data.save(small, path)
    before = path.read_bytes()

    def explode(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", explode)
    with pytest.raises(OSError, match="disk full"):
        data.save(small, path)
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["d.npz"]


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="has 12 colours"):
        collect.collect(n_tasks=13, demos_per_task=2, split="heldout", progress=False)
    with pytest.raises(ValueError, match="at least 2 demos"):
        collect.collect(n_tasks=2, demos_per_task=1, progress=False)
    with pytest.raises(ValueError, match="unknown colour split"):
        collect.collect(n_tasks=2, demos_per_task=2, split="validation", progress=False)


def test_command_line_writes_a_loadable_file(tmp_path, capsys):
    out = tmp_path / "cli.npz"
    collect.main(["--out", str(out), "--split", "heldout", "--tasks", "2", "--demos", "2",
                  "--workers", "1", "--seed", "1"])
    d = data.load(out)
    assert d["metadata"]["split"] == "heldout"
    assert set(d["task_colours"].tolist()) <= set(palette.split_colours("heldout").tolist())
    assert "expert success" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        collect.main(["--out", str(out), "--tasks", "0"])
    assert zipfile.is_zipfile(out)                                  # the failed call left it intact


def test_world_config_rebuilds_the_world_a_dataset_was_collected_in(tiny_datasets):
    """From a saved dataset's metadata: the WorldConfig it was collected with (nested arm and palette
    configs, tuples as tuples), and a world that, reset with a recorded scene seed, shows the recorded
    first frame."""
    for path, split in zip(tiny_datasets, ("train", "heldout")):
        dataset = data.load(path)
        cfg = data.world_config(dataset["metadata"])
        assert cfg == dataclasses.replace(WorldConfig(), split=split)
        obs, _ = ReachWorld(cfg).reset(seed=int(dataset["seeds"][1, 0]),
                                       options={"target_colour": int(dataset["task_colours"][1])})
        assert np.array_equal(obs["image"], dataset["images"][1, 0, 0])


def test_world_config_round_trips_every_field_through_json():
    """Every field of the world and the arm away from its default (a grid palette with its own levels),
    through the JSON that `data.save` writes: tuples come back as tuples, nested configs as configs."""
    cfg = WorldConfig(arm=ArmConfig(l1=0.12, l2=0.09, m1=1.5, m2=0.7, radius=0.02, damping=0.03, max_torque=0.4,
                                    dt=0.04, substeps=7, q0=(0.1, 1.2)),
                      palette=PaletteConfig(mode="grid", size=36, heldout_every=6, min_separation_deg=45.0,
                                            saturations=(1.0, 0.6), values=(0.9, 0.7), guard=1),
                      split="heldout", horizon=15, image_size=64, n_objects=2, arena_half_width=0.25,
                      object_radius=0.02, min_object_radius=0.06, max_object_radius=0.2, success_radius=0.04,
                      min_separation=0.1, start_noise=0.01)
    for config, default in ((cfg, WorldConfig()), (cfg.arm, ArmConfig())):
        same = [f.name for f in dataclasses.fields(config) if getattr(config, f.name) == getattr(default, f.name)]
        assert same == [], f"give {same} a non-default value here, so that their round trip is tested"
    assert cfg.palette != PaletteConfig()
    metadata = json.loads(json.dumps({"world": dataclasses.asdict(cfg)}, sort_keys=True))
    assert data.world_config(metadata) == cfg
