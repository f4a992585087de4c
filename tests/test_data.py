"""The demonstration dataset: collection, round trip, determinism, and rejection of bad files."""
import collections
import dataclasses
import io
import json
import os
import re
import struct
import tracemalloc
import zipfile

import numpy as np
import pytest

from oneshot.data import collection, datasets, npz
from oneshot.expert import controller
from oneshot.world import palette
from oneshot.world.arm import ArmConfig
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import ReachWorld, WorldConfig, observation_state
from oneshot import collect
from test_npz import write_lying


@pytest.fixture(scope="module")
def small():
    return collection.collect(n_tasks=3, demos_per_task=2, split="train", seed=5, workers=1, progress=False)


@pytest.fixture(scope="module")
def tiny_file(tmp_path_factory):
    """A saved dataset of 4 KB: 2 tasks x 2 demos of 8 steps of 8x8 images."""
    path = tmp_path_factory.mktemp("tiny") / "tiny.npz"
    datasets.save(collection.collect(2, 2, "train", seed=7, workers=1, world_cfg=WorldConfig(image_size=8, horizon=8),
                              progress=False), path)
    return path


def test_collected_demos_are_expert_successes_of_their_task(small):
    datasets.validate(small)
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
    datasets.save(small, path)
    back = datasets.load(path)
    for key in datasets.ARRAYS:
        assert back[key].dtype == small[key].dtype and np.array_equal(back[key], small[key]), key
    assert back["metadata"]["format_version"] == datasets.FORMAT_VERSION
    assert back["metadata"]["seed"] == 5
    assert [p.name for p in tmp_path.iterdir()] == ["d.npz"]     # no temporary file left behind


def test_collection_is_seeded_and_independent_of_worker_count(small):
    again = collection.collect(n_tasks=3, demos_per_task=2, split="train", seed=5, workers=2, progress=False)
    for key in datasets.ARRAYS:
        assert np.array_equal(again[key], small[key]), key
    other = collection.collect(n_tasks=3, demos_per_task=2, split="train", seed=6, workers=1, progress=False)
    assert not np.array_equal(other["positions"], small["positions"])


def test_truncated_file_is_rejected(small, tmp_path):
    path = tmp_path / "d.npz"
    datasets.save(small, path)
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(datasets.DatasetError, match="truncated or corrupt"):
        datasets.load(path)


def _rewrite(path, **changes):
    """Rewrite a saved dataset with some members replaced (the checksum is left as it was)."""
    with np.load(path) as f:
        members = {k: f[k] for k in f.files}
    members.update(changes)
    with open(path, "wb") as f:
        np.savez_compressed(f, **members)


def test_changed_arrays_fail_the_checksum(small, tmp_path):
    path = tmp_path / "d.npz"
    datasets.save(small, path)
    actions = small["actions"].copy()
    actions[1, 1, 3, 0] += 0.01
    _rewrite(path, actions=actions)
    with pytest.raises(datasets.DatasetError, match="checksum"):
        datasets.load(path)


def test_wrong_version_missing_key_bad_dtype_and_nan_are_named(small, tmp_path):
    path = tmp_path / "d.npz"
    datasets.save(small, path)
    meta = json.loads(str(np.load(path)["metadata"]))
    _rewrite(path, metadata=np.array(json.dumps(dict(meta, format_version=99))))
    with pytest.raises(datasets.DatasetError, match="format version 99"):
        datasets.load(path)

    datasets.save(small, path)
    with np.load(path) as f:
        members = {k: f[k] for k in f.files if k != "seeds"}
    with open(path, "wb") as f:
        np.savez_compressed(f, **members)
    with pytest.raises(datasets.DatasetError, match="no array 'seeds'"):
        datasets.load(path)

    bad = dict(small, states=small["states"].astype(np.float64))
    with pytest.raises(datasets.DatasetError, match="states must be 4-d float32"):
        datasets.validate(bad)
    bad = dict(small, actions=small["actions"][:, :, :-1])
    with pytest.raises(datasets.DatasetError, match=r"actions has shape .* expected"):
        datasets.validate(bad)
    nan = small["actions"].copy()
    nan[0, 0, 0, 0] = np.nan
    with pytest.raises(datasets.DatasetError, match="NaN"):
        datasets.validate(dict(small, actions=nan))
    with pytest.raises(FileNotFoundError, match="oneshot.collect"):
        datasets.load(tmp_path / "missing.npz")
    (tmp_path / "text.npz").write_text("not a zip")
    with pytest.raises(datasets.DatasetError, match="not a readable"):
        datasets.load(tmp_path / "text.npz")


def test_failed_save_leaves_the_old_file_and_no_debris(small, tmp_path, monkeypatch):
    path = tmp_path / "d.npz"
    datasets.save(small, path)
    before = path.read_bytes()

    def explode(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np.lib.format, "write_array", explode)
    with pytest.raises(OSError, match="disk full"):
        datasets.save(small, path)
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["d.npz"]


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="has 12 colours"):
        collection.collect(n_tasks=13, demos_per_task=2, split="validation", progress=False)
    with pytest.raises(ValueError, match="at least 2 demos"):
        collection.collect(n_tasks=2, demos_per_task=1, progress=False)
    with pytest.raises(ValueError, match="unknown colour split"):
        collection.collect(n_tasks=2, demos_per_task=2, split="holdout", progress=False)


def test_command_line_writes_a_loadable_file(tmp_path, capsys):
    out = tmp_path / "cli.npz"
    collect.main(["--out", str(out), "--split", "validation", "--tasks", "2", "--demos", "2",
                  "--workers", "1", "--seed", "1"])
    d = datasets.load(out)
    assert d["metadata"]["split"] == "validation"
    assert set(d["task_colours"].tolist()) <= set(palette.split_colours("validation").tolist())
    assert "expert success" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        collect.main(["--out", str(out), "--tasks", "0"])
    assert zipfile.is_zipfile(out)                                  # the failed call left it intact


def test_world_config_rebuilds_the_world_a_dataset_was_collected_in(tiny_datasets):
    """From a saved dataset's metadata: the WorldConfig it was collected with (nested arm and palette
    configs, tuples as tuples), and a world that, reset with a recorded scene seed, shows the recorded
    first frame."""
    for path, split in zip(tiny_datasets, ("train", "validation")):
        dataset = datasets.load(path)
        cfg = datasets.world_config(dataset["metadata"])
        assert cfg == dataclasses.replace(WorldConfig(), split=split)
        obs, _ = ReachWorld(cfg).reset(seed=int(dataset["seeds"][1, 0]),
                                       options={"target_colour": int(dataset["task_colours"][1])})
        assert np.array_equal(obs["image"], dataset["images"][1, 0, 0])


def test_world_config_round_trips_every_field_through_json():
    """Every field of the world and the arm away from its default (a grid palette with its own levels),
    through the JSON that `datasets.save` writes: tuples come back as tuples, nested configs as configs."""
    cfg = WorldConfig(arm=ArmConfig(l1=0.12, l2=0.09, m1=1.5, m2=0.7, radius=0.02, damping=0.03, max_torque=0.4,
                                    dt=0.04, substeps=7, q0=(0.1, 1.2)),
                      palette=PaletteConfig(mode="grid", size=36, heldout_every=6, min_separation_deg=45.0,
                                            saturations=(1.0, 0.6), values=(0.9, 0.7), guard=1),
                      split="validation", horizon=15, image_size=64, n_objects=2, arena_half_width=0.25,
                      object_radius=0.02, min_object_radius=0.06, max_object_radius=0.2, success_radius=0.04,
                      min_separation=0.1, start_noise=0.01)
    for config, default in ((cfg, WorldConfig()), (cfg.arm, ArmConfig())):
        same = [f.name for f in dataclasses.fields(config) if getattr(config, f.name) == getattr(default, f.name)]
        assert same == [], f"give {same} a non-default value here, so that their round trip is tested"
    assert cfg.palette != PaletteConfig()
    metadata = json.loads(json.dumps({"world": dataclasses.asdict(cfg)}, sort_keys=True))
    assert datasets.world_config(metadata) == cfg


def _zip_structure(raw):
    """The byte positions of a zip's own records in `raw`: each member's local header (with its name and
    extra field), and the central directory with the end records."""
    end = raw.rfind(b"PK\x05\x06")
    directory = struct.unpack("<I", raw[end + 16:end + 20])[0]
    positions = list(range(directory, len(raw)))
    with zipfile.ZipFile(io.BytesIO(raw)) as z:
        for info in z.infolist():
            start = info.header_offset
            name, extra = struct.unpack("<HH", raw[start + 26:start + 30])
            positions += range(start, start + 30 + name + extra)
    return positions


def test_every_single_bit_flip_loads_the_same_data_or_is_named(tiny_file, tmp_path):
    """500 single-bit flips (seeded) of a small dataset file, 350 anywhere (mostly in deflated data, and
    so in the .npy headers too) and 150 in the zip's own records: each flipped file loads to the same
    arrays and metadata, or raises DatasetError naming it. Nothing else escapes, and no load allocates
    more than a few MB (a flipped bit in a .npy header can claim a shape of terabytes)."""
    raw = tiny_file.read_bytes()
    original = datasets.load(tiny_file)
    rng = np.random.default_rng(20)
    anywhere = rng.choice(8 * len(raw), 350, replace=False)
    in_records = rng.choice([8 * i + b for i in _zip_structure(raw) for b in range(8)], 150, replace=False)
    path = tmp_path / "flipped.npz"
    outcomes = collections.Counter()
    tracemalloc.start()
    try:
        for bit in [*anywhere, *in_records]:
            damaged = bytearray(raw)
            damaged[bit // 8] ^= 1 << bit % 8
            path.write_bytes(bytes(damaged))
            tracemalloc.reset_peak()
            try:
                back = datasets.load(path)
            except datasets.DatasetError as e:
                assert str(path) in str(e) and "python -m oneshot.collect" in str(e), (bit, str(e))
                outcomes["named"] += 1
            except Exception as e:
                pytest.fail(f"flipping bit {bit} (byte {bit // 8}) let {e!r} escape")
            else:
                for key in datasets.ARRAYS:
                    assert back[key].dtype == original[key].dtype and np.array_equal(back[key], original[key]), bit
                assert back["metadata"] == original["metadata"], bit
                outcomes["same"] += 1
            assert tracemalloc.get_traced_memory()[1] < 10_000_000, f"bit {bit}: a load allocated over 10 MB"
    finally:
        tracemalloc.stop()
    # both outcomes occur: most flips break the deflated data or its CRC-32; flips in dates, unused
    # flags or the local copies of sizes the zip's directory overrides change nothing that is read
    assert outcomes["named"] > 300 and outcomes["same"] > 20, outcomes


HUGE = {"images": ("|u1", (2, 2, 8, 8, 8, 3 * 10**12)), "metadata": ("<U100000000", (10**4,))}   # 24 TB, 4 TB


@pytest.mark.parametrize("key", HUGE)
def test_a_header_claiming_a_huge_array_is_a_dataset_error_before_anything_is_allocated(tiny_file, tmp_path, key):
    """A .npy header in the file claims terabytes (a shape, or the metadata string's length), over the
    member's real bytes: load names the file, the claim and the fix, and allocates nothing (npz.Reader
    compares the claim with the zip's directory first; tests/test_npz.py tests that on its own)."""
    with np.load(tiny_file) as f:
        members = {name: f[name] for name in f.files}
    path = tmp_path / "huge.npz"
    write_lying(path, members, key, *HUGE[key], zipfile.ZIP_DEFLATED)
    descr, shape = HUGE[key]
    claim = f"{key}.npy's header claims a {shape} {np.dtype(descr)} array, which is not the {members[key].nbytes} bytes"
    tracemalloc.start()
    try:
        with pytest.raises(datasets.DatasetError, match=re.escape(claim)) as error:
            datasets.load(path)
        assert tracemalloc.get_traced_memory()[1] < 10_000_000
    finally:
        tracemalloc.stop()
    assert str(error.value).startswith(repr(str(path))) and str(error.value).endswith(datasets.FIX)


def _metadata(path):
    with np.load(path) as f:
        return json.loads(str(f["metadata"]))


@pytest.mark.parametrize("change, message", [
    (lambda m: m.pop("world"), "its metadata has no world; re-create it with `python -m oneshot.collect`"),
    (lambda m: m["world"].pop("image_size"), "its metadata has no world.image_size"),
    (lambda m: m["world"]["arm"].pop("max_torque"), "its metadata has no world.arm.max_torque"),
    (lambda m: m.pop("split"), "its metadata has no split"),
    (lambda m: m["world"].update(image_size=16), "its metadata says world.image_size = 16, but its arrays have 8"),
    (lambda m: m["world"].update(horizon=20), "its metadata says world.horizon = 20, but its arrays have 8"),
    (lambda m: m["world"].update(colour=3), r"its metadata does not describe a world \(TypeError: .*colour"),
    (lambda m: m["world"]["palette"].update(mode="rainbow"), "does not describe a world .*unknown palette mode"),
    (lambda m: m.update(split="validation"), "its metadata says split 'validation', but its world's split is 'train'"),
    (lambda m: m.update(state_layout=list(reversed(datasets.STATE_LAYOUT))), "its states are laid out as"),
])
def test_metadata_the_package_reads_is_checked_on_loading(tiny_file, tmp_path, change, message):
    """A file whose arrays pass their checksum (the checksum covers the arrays only) but whose metadata
    lacks or contradicts what imitation, train and evaluate read is refused when it is loaded, not with
    a KeyError later in `world_config`."""
    meta = _metadata(tiny_file)
    change(meta)
    path = tmp_path / "d.npz"
    path.write_bytes(tiny_file.read_bytes())
    _rewrite(path, metadata=np.array(json.dumps(meta)))
    with pytest.raises(datasets.DatasetError, match=message) as error:
        datasets.load(path)
    assert str(error.value).startswith(repr(str(path)))


def test_metadata_that_is_not_an_object_is_named(tiny_file, tmp_path):
    path = tmp_path / "d.npz"
    path.write_bytes(tiny_file.read_bytes())
    _rewrite(path, metadata=np.array(json.dumps([1, 2])))
    with pytest.raises(datasets.DatasetError, match="its metadata must be a JSON object; got list"):
        datasets.load(path)
    with pytest.raises(datasets.DatasetError, match=r"dataset: its metadata does not describe a world \(KeyError: 'world'"):
        datasets.world_config({})                                    # used on its own, too


def test_save_refuses_metadata_that_load_would_refuse(small, tmp_path):
    metadata = dict(small["metadata"])
    del metadata["world"]
    with pytest.raises(datasets.DatasetError, match="dataset: its metadata has no world"):
        datasets.save(dict(small, metadata=metadata), tmp_path / "d.npz")
    assert list(tmp_path.iterdir()) == []


def test_the_state_layout_is_the_worlds_and_is_saved(small, tmp_path):
    """STATE_LAYOUT names the numbers of `world.observation_state` in its order (checked against the
    world's own joint state (q1, q2, qd1, qd2) and end effector), and save records it."""
    world = ReachWorld(WorldConfig())
    world.reset(seed=0, options={"target_colour": 1})
    for _ in range(3):
        obs, *_ = world.step(np.array([0.3, -0.2]))
    named = dict(zip(datasets.STATE_LAYOUT, observation_state(obs)))
    q1, q2, qd1, qd2 = world.state
    expected = {"shoulder angle": q1, "elbow angle": q2, "shoulder velocity": qd1, "elbow velocity": qd2,
                "end effector x": world.joints()[2, 0], "end effector y": world.joints()[2, 1]}
    assert len(named) == 6 and named.keys() == expected.keys()
    for name in expected:
        assert named[name] == pytest.approx(expected[name], abs=1e-6), name
    assert len({abs(v) for v in named.values()}) == 6                # distinct values: the order is tested
    datasets.save(small, tmp_path / "d.npz")
    assert datasets.load(tmp_path / "d.npz")["metadata"]["state_layout"] == list(datasets.STATE_LAYOUT)


def test_a_file_written_before_the_state_layout_was_recorded_still_loads(small, tmp_path):
    """Files written by earlier versions: np.savez_compressed, "seconds" and "workers" in the metadata,
    no "state_layout". They load as they are (their states have today's layout)."""
    path = tmp_path / "old.npz"
    arrays = {key: small[key] for key in datasets.ARRAYS}
    meta = dict(small["metadata"], seconds=1.5, workers=2, format_version=1, checksum=datasets.checksum(arrays))
    np.savez_compressed(path, metadata=np.array(json.dumps(meta, sort_keys=True)), **arrays)
    back = datasets.load(path)
    assert back["metadata"] == json.loads(json.dumps(meta)) and "state_layout" not in back["metadata"]
    for key in datasets.ARRAYS:
        assert np.array_equal(back[key], small[key]), key


@pytest.mark.parametrize("colour", [999, "validation"])
def test_a_colour_outside_the_datasets_split_is_refused_on_save(small, tmp_path, colour):
    """A task colour outside the palette (999), or of another split, saved and loaded before; it failed
    only at meta-test ("colour 999 is not a 'validation' colour")."""
    bad = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in small.items()}
    new = 999 if colour == 999 else int(palette.split_colours("validation")[0])
    old = bad["task_colours"][0]
    bad["task_colours"][0] = new
    bad["colours"][0][bad["colours"][0] == old] = new            # its demos' targets too: consistent otherwise
    with pytest.raises(datasets.DatasetError, match=rf"task_colours holds \[{new}\], not 'train' colours of its 'hues'"):
        datasets.save(bad, tmp_path / "bad.npz")
    assert not (tmp_path / "bad.npz").exists()
    distractor = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in small.items()}
    others = distractor["colours"][..., :] != distractor["task_colours"][:, None, None]   # not the target
    distractor["colours"][np.nonzero(others)[0][0], np.nonzero(others)[1][0], np.nonzero(others)[2][0]] = new
    with pytest.raises(datasets.DatasetError, match=rf"colours holds \[{new}\], not 'train' colours"):
        datasets.save(distractor, tmp_path / "bad.npz")
    # and on load: a file written without the check (its checksum made to fit), read back
    meta = datasets.save(small, tmp_path / "good.npz")
    arrays = {k: bad[k] for k in datasets.ARRAYS}
    written = dict(meta, checksum=datasets.checksum(arrays))
    with open(tmp_path / "bad.npz", "wb") as f:
        npz.write(f, {"metadata": np.array(json.dumps(written, sort_keys=True)), **arrays})
    with pytest.raises(datasets.DatasetError, match=rf"task_colours holds \[{new}\], not 'train' colours"):
        datasets.load(tmp_path / "bad.npz")


def test_validate_names_a_target_index_out_of_range_a_nan_position_and_a_target_of_another_colour(small):
    """Each is refused as a DatasetError saying what: target_index = n (one past the last object), a NaN
    object position, one demo whose target object is a distractor (not its task's colour)."""
    def changed(key, change):
        bad = dict(small, **{key: small[key].copy()})
        change(bad[key])
        return bad
    n_obj = small["colours"].shape[2]
    with pytest.raises(datasets.DatasetError, match=rf"target_index must lie in \[0, {n_obj}\)"):
        datasets.validate(changed("target_index", lambda a: a.__setitem__((0, 1), n_obj)))
    with pytest.raises(datasets.DatasetError, match="positions contains NaN"):
        datasets.validate(changed("positions", lambda a: a.__setitem__((2, 0, 1, 1), np.nan)))
    distractor = int(np.flatnonzero(small["colours"][1, 0] != small["task_colours"][1])[0])
    with pytest.raises(datasets.DatasetError, match="some demo's target object does not have its task's colour"):
        datasets.validate(changed("target_index", lambda a: a.__setitem__((1, 0), distractor)))


def test_a_failed_demo_is_retried_on_a_fresh_scene_counted_and_the_successful_seed_kept(monkeypatch):
    """The expert's first scene for demo 1 of task 0 is made to fail: collection retries it on the scene of
    attempt 1 (another seed), stores that seed (which reproduces the stored demo), and counts the failure:
    1 failed attempt, expert success rate 4 / 5."""
    world = WorldConfig(image_size=8, horizon=8)
    failing, demonstrate = collection.scene_seed(3, 0, 1, 0), controller.demonstrate
    assert len({collection.scene_seed(3, 0, 1, attempt) for attempt in range(collection.MAX_ATTEMPTS)}) == 10

    def first_scene_fails(*args, seed, **kwargs):
        demo = demonstrate(*args, seed=seed, **kwargs)
        return dict(demo, success=False) if seed == failing else demo
    monkeypatch.setattr(controller, "demonstrate", first_scene_fails)
    data = collection.collect(2, 2, "train", seed=3, workers=1, world_cfg=world, progress=False)
    meta = data["metadata"]
    assert meta["failed_attempts"] == 1 and meta["expert_success_rate"] == pytest.approx(4 / 5)
    assert data["seeds"][0, 1] == collection.scene_seed(3, 0, 1, 1) and data["seeds"][0, 0] == collection.scene_seed(3, 0, 0, 0)
    obs, _ = ReachWorld(dataclasses.replace(world, split="train")).reset(
        seed=int(data["seeds"][0, 1]), options={"target_colour": int(data["task_colours"][0])})
    assert np.array_equal(obs["image"], data["images"][0, 1, 0])


def test_the_task_colours_are_a_seeded_draw_of_distinct_colours_of_the_split():
    """The same seed, the same colours in the same order; another seed, another draw."""
    draws = {seed: collection.task_colours(5, "train", seed).tolist() for seed in (0, 1)}
    assert collection.task_colours(5, "train", 0).tolist() == draws[0] and draws[0] != draws[1]
    for colours in draws.values():
        assert len(set(colours)) == 5 and set(colours) <= set(palette.split_colours("train").tolist())


def test_command_line_collects_the_tasks_demos_palette_split_and_noise_it_was_given(tmp_path, capsys):
    """Every demo `python -m oneshot.collect` stores is the one the expert records, with the asked DART noise,
    on the stored seed in the asked palette's split (rebuilt here from the flags, not the file); the noise
    changes the demos, and --tasks x --demos is the dataset's shape."""
    out = tmp_path / "grid.npz"
    collect.main(["--out", str(out), "--split", "test", "--tasks", "2", "--demos", "3", "--palette", "grid",
                  "--noise", "0.2", "--image-size", "8", "--horizon", "8", "--workers", "1", "--seed", "2"])
    d = datasets.load(out)
    assert d["images"].shape[:2] == d["seeds"].shape == (2, 3) and d["metadata"]["expert"]["action_noise"] == 0.2
    grid = PaletteConfig(mode="grid")
    assert set(d["task_colours"].tolist()) <= set(palette.split_colours("test", grid).tolist())
    world = ReachWorld(WorldConfig(image_size=8, horizon=8, palette=grid, split="test"))
    for i, k in ((0, 0), (1, 2)):
        options = {"target_colour": int(d["task_colours"][i])}
        noisy = controller.demonstrate(world, seed=int(d["seeds"][i, k]), options=options,
                                       cfg=controller.ExpertConfig(action_noise=0.2))
        for name in ("images", "states", "actions"):
            assert np.array_equal(noisy[name], d[name][i, k]), (name, i, k)
        plain = controller.demonstrate(world, seed=int(d["seeds"][i, k]), options=options)
        assert not np.array_equal(plain["states"], d["states"][i, k])


@pytest.mark.parametrize("n_failing", [2, collection.MAX_ATTEMPTS - 1])
def test_every_failed_attempt_is_counted_up_to_the_last_one(monkeypatch, n_failing):
    """Demo 1 of task 0 fails on its first n scenes: n failed attempts (not 1 failed demo), success 4 / (4 + n),
    and the seed of attempt n kept; the expert gets all MAX_ATTEMPTS tries, the last one too."""
    world = WorldConfig(image_size=8, horizon=8)
    failing = {collection.scene_seed(3, 0, 1, attempt) for attempt in range(n_failing)}
    demonstrate = controller.demonstrate

    def scenes_fail(*args, seed, **kwargs):
        demo = demonstrate(*args, seed=seed, **kwargs)
        return dict(demo, success=False) if seed in failing else demo
    monkeypatch.setattr(controller, "demonstrate", scenes_fail)
    data = collection.collect(2, 2, "train", seed=3, workers=1, world_cfg=world, progress=False)
    assert data["metadata"]["failed_attempts"] == n_failing
    assert data["metadata"]["expert_success_rate"] == pytest.approx(4 / (4 + n_failing))
    assert data["seeds"][0, 1] == collection.scene_seed(3, 0, 1, n_failing)
