"""Checkpoints against damage and hand edits (`checkpoint.load` raises CheckpointError, naming the file,
or gives back exactly what was saved), and against data they were not trained on (`checkpoint.check_data`)."""
import dataclasses
import json
import os
import pathlib
import struct
import zipfile

import numpy as np
import pytest

from oneshot.data import datasets
from oneshot.maml import optim
from oneshot import methods
from oneshot.policy import network
from oneshot.training import checkpoint, checkpoint_meta, config, fit_check, run_folder
from oneshot.world.arm import ArmConfig
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import WorldConfig
from test_npz import write_lying

# A tiny MIL run with everything a checkpoint can hold: feature points, a bias transformation, learnt
# step sizes (Meta-SGD), a moving average, and Adam's state after two steps.
CFG = dataclasses.replace(config.TrainConfig(), ema=0.5, learn_alpha=True, inner_params="conv0", inner_steps=1,
                          alpha=0.1, bias_transform=2, feature_points=True)
NET = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5,), feature_points=True, bias_transform=2)
WORLD = WorldConfig(image_size=8)


def save_tiny(path, cfg=CFG, net_cfg=NET, world=WORLD, seconds=None):
    """Save a tiny checkpoint at path; returns what was saved, as `load` returns it (rng: its state)."""
    rng = np.random.default_rng(0)
    params = methods.of(cfg).init_params(net_cfg, rng)
    adam = optim.adam_init(params)
    for _ in range(2):
        grads = {k: rng.standard_normal(v.shape).astype(v.dtype) for k, v in params.items()}
        params, adam = optim.adam_step(params, grads, adam)
    ema = {k: (0.5 * v).astype(v.dtype) for k, v in params.items()} if cfg.ema and methods.of(cfg).learns else None
    checkpoint.save(path, params, adam, 2, rng, cfg, net_cfg, ema, world=world, seconds=seconds)
    return {"params": params, "ema": ema, "adam": adam, "iteration": 2, "rng": rng.bit_generator.state,
            "config": cfg, "network": net_cfg, "world": None if world is None else
            json.loads(json.dumps(world if isinstance(world, dict) else dataclasses.asdict(world))),
            "state_layout": list(datasets.STATE_LAYOUT), "seconds": seconds}


def assert_equal(ckpt, saved):
    """Every array (values and dtype), the iteration, configs, random state and world are the saved ones."""
    def same(p, q):
        assert (p is None) == (q is None)
        if p is not None:
            assert p.keys() == q.keys()
            for k in p:
                assert p[k].dtype == q[k].dtype and np.array_equal(p[k], q[k]), k
    same(ckpt["params"], saved["params"])
    same(ckpt["ema"], saved["ema"])
    same(ckpt["adam"]["m"], saved["adam"]["m"])
    same(ckpt["adam"]["v"], saved["adam"]["v"])
    assert ckpt["adam"]["step"] == saved["adam"]["step"] and ckpt["iteration"] == saved["iteration"]
    assert ckpt["config"] == saved["config"] and ckpt["network"] == saved["network"]
    assert ckpt["rng"].bit_generator.state == saved["rng"]
    assert ckpt["world"] == saved["world"] and ckpt["state_layout"] == saved["state_layout"]
    assert ckpt["seconds"] == saved["seconds"]


def rewrite(path, edit_meta=None, edit_arrays=None):
    """Rewrite a checkpoint by hand, as someone with np.load and a text editor would."""
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    meta = json.loads(str(arrays.pop("meta")))
    if edit_meta:
        edit_meta(meta)
    if edit_arrays:
        edit_arrays(arrays)
    np.savez(path, meta=np.array(json.dumps(meta)), **arrays)


def old_style(meta):
    """The metadata as the first checkpoints recorded it (the shipped policy's): no world, state layout,
    seconds or checksum, the network's stride, and no config fields added since."""
    for key in ("world", "state_layout", "seconds", "checksum"):
        del meta[key]
    for key in ("config", "network"):
        for field in checkpoint_meta.ADDED_LATER[key]:
            del meta[key][field]
    meta["network"]["stride"] = 2


def metadata(**changes):
    """A dataset's metadata as `datasets.load` returns it (read from JSON), its world WORLD with `changes`."""
    return json.loads(json.dumps({"world": dataclasses.asdict(dataclasses.replace(WORLD, **changes))}))


# --- what is saved is what is loaded -----------------------------------------------------------------

def test_round_trip_with_the_world_and_a_checksum(tmp_path):
    path = tmp_path / "checkpoint.npz"
    saved = save_tiny(path)
    ckpt = checkpoint.load(path)
    assert_equal(ckpt, saved)
    assert ckpt["world"]["image_size"] == 8 and ckpt["world"]["arm"]["max_torque"] == 0.5
    with np.load(path) as f:
        meta = json.loads(str(f["meta"]))
        assert meta["checksum"] == checkpoint.checksum({k: f[k] for k in f.files if k != "meta"})
    # the world as a dict (a dataset's metadata["world"]) or as a WorldConfig: the same record
    save_tiny(tmp_path / "dict.npz", world=metadata()["world"])
    assert checkpoint.load(tmp_path / "dict.npz")["world"] == ckpt["world"]
    # the meta-training time so far (`train` records it at every checkpoint)
    save_tiny(tmp_path / "timed.npz", seconds=12.5)
    assert checkpoint.load(tmp_path / "timed.npz")["seconds"] == 12.5 and ckpt["seconds"] is None


@pytest.mark.parametrize("method", list(methods.REGISTRY))
def test_every_method_round_trips(tmp_path, method):
    cfg = dataclasses.replace(config.TrainConfig(), method=method, lstm_units=3, ema=0.5)
    saved = save_tiny(tmp_path / "c.npz", cfg, methods.of(cfg).network_config(8))
    assert_equal(checkpoint.load(tmp_path / "c.npz"), saved)


def test_a_layer_norm_run_saved_before_its_offsets_started_at_zero_scores_but_does_not_resume(tmp_path):
    """Before NetworkConfig recorded `init`, layer-norm offsets began as random draws: such a checkpoint
    loads (flagged), and resuming it is refused in one message; one saved now resumes."""
    cfg = dataclasses.replace(CFG, layer_norm=True, never_adapt=("ln",))
    net = dataclasses.replace(NET, layer_norm=True)
    for name, edit, drawn in (("now.npz", None, False), ("before.npz", lambda m: m["network"].pop("init"), True)):
        save_tiny(tmp_path / name, cfg=cfg, net_cfg=net)
        if edit:
            rewrite(tmp_path / name, edit)
        assert checkpoint.load(tmp_path / name)["ln_offsets_drawn"] is drawn
    assert checkpoint.load(tmp_path / "now.npz")["network"].init == "he"
    (tmp_path / "run").mkdir()
    os.replace(tmp_path / "before.npz", tmp_path / "run" / "checkpoint.npz")
    with pytest.raises(ValueError, match="began with random layer-norm offsets .* start a new run folder"):
        run_folder._resumable(cfg, str(tmp_path / "run" / "checkpoint.npz"))


def test_an_old_style_checkpoint_loads_and_is_checked_by_its_network_image_size_and_palette_mode(tmp_path):
    """A checkpoint that records no world is checked by what it does record: the network's image size
    and its config's palette mode ("hues" when the config predates the field: the only palette then)."""
    path = tmp_path / "old.npz"
    saved = save_tiny(path, seconds=3.0)
    rewrite(path, old_style)
    ckpt = checkpoint.load(path)
    assert_equal(ckpt, dict(saved, world=None, state_layout=None, seconds=None))
    assert ckpt["config"].palette == "hues"
    fit_check.check_data(ckpt, metadata(horizon=50, palette=PaletteConfig(size=12)), "old.npz", "d.npz")
    with pytest.raises(checkpoint.CheckpointError) as e:
        fit_check.check_data(ckpt, metadata(image_size=32), "old.npz", "d32.npz")
    assert str(e.value) == ("old.npz was trained on 8x8 images but d32.npz holds 32x32 images; "
                            "use data collected with --image-size 8")
    grid = metadata(palette=PaletteConfig(mode="grid"))
    with pytest.raises(checkpoint.CheckpointError) as e:
        fit_check.check_data(ckpt, grid, "old.npz", "grid.npz")
    assert str(e.value) == ("old.npz was trained on the 'hues' palette but grid.npz holds the 'grid' palette; "
                            "use data collected with --palette hues (or, to test the policy on other colours, "
                            "python -m oneshot.evaluate --any-palette)")
    fit_check.check_data(ckpt, grid, "old.npz", "grid.npz", palette=False)
    assert fit_check.world_config(ckpt).palette == PaletteConfig(mode="hues")
    rewrite(path, lambda meta: meta["config"].update(palette="grid"))      # recorded: its own mode
    fit_check.check_data(checkpoint.load(path), grid, "old.npz", "grid.npz")
    assert fit_check.world_config(checkpoint.load(path)).palette == PaletteConfig(mode="grid")
    rewrite(path, lambda meta: meta["config"].update(palette="Grid"))      # edited by hand: named, not a crash
    with pytest.raises(checkpoint.CheckpointError, match=r"old\.npz'?: meta 'config': unknown palette 'Grid'; "
                                                         r"use one of \('hues', 'grid'\)"):
        checkpoint.load(path)


SHIPPED_HELDOUT = pathlib.Path(__file__).parent.parent / "data" / "heldout.npz"


def test_the_shipped_policy_loads_and_fits_the_held_out_data_but_not_64x64_images():
    from oneshot.demo import PRETRAINED
    ckpt = checkpoint.load(PRETRAINED)
    assert ckpt["world"] is None and ckpt["network"].image_size == 32
    if SHIPPED_HELDOUT.exists():
        fit_check.check_data(ckpt, datasets.load(SHIPPED_HELDOUT)["metadata"], PRETRAINED, str(SHIPPED_HELDOUT))
    with pytest.raises(checkpoint.CheckpointError, match=r"32x32 images but h64\.npz holds 64x64 images; "
                                                         r"use data collected with --image-size 32"):
        fit_check.check_data(ckpt, metadata(image_size=64), PRETRAINED, "h64.npz")
    with pytest.raises(checkpoint.CheckpointError, match=r"the 'hues' palette but grid\.npz holds the 'grid'"):
        fit_check.check_data(ckpt, metadata(image_size=32, palette=PaletteConfig(mode="grid")), PRETRAINED, "grid.npz")


# --- check_data -------------------------------------------------------------------------------------

@pytest.mark.parametrize("changes, trained, holds, fix", [
    (dict(image_size=64), "8x8 images", "64x64 images", "--image-size 8"),
    (dict(horizon=50), "20-step demos", "50-step demos", "--horizon 20"),
    (dict(arm=ArmConfig(max_torque=1.0)), "torques of at most 0.5 N m", "torques of at most 1.0 N m",
     "max_torque 0.5"),
    (dict(palette=PaletteConfig(mode="grid")), "the 'hues' palette", "the 'grid' palette",
     "--palette hues (or, to test the policy on other colours, python -m oneshot.evaluate --any-palette)"),
    (dict(palette=PaletteConfig(size=24)), "the 'hues' palette with size 48", "the 'hues' palette with size 24",
     "--palette hues"),
])
def test_check_data_names_both_values_and_the_fix(tmp_path, changes, trained, holds, fix):
    save_tiny(tmp_path / "c.npz")
    ckpt = checkpoint.load(tmp_path / "c.npz")
    with pytest.raises(checkpoint.CheckpointError) as e:
        fit_check.check_data(ckpt, metadata(**changes), "runs/x/checkpoint.npz", "data/other.npz")
    message = str(e.value)
    assert message.startswith(f"runs/x/checkpoint.npz was trained on {trained}")
    assert f"but data/other.npz holds {holds}" in message and fix in message and "\n" not in message
    if "palette" in changes:
        fit_check.check_data(ckpt, metadata(**changes), "c.npz", "d.npz", palette=False)


def test_check_data_accepts_matching_data_and_compares_recorded_state_layouts(tmp_path):
    save_tiny(tmp_path / "c.npz")
    ckpt = checkpoint.load(tmp_path / "c.npz")
    assert ckpt["state_layout"] == list(datasets.STATE_LAYOUT)
    assert fit_check.check_data(ckpt, metadata(split="validation"), "c.npz", "d.npz") is None
    older = metadata()
    older["world"]["palette"] = {"heldout_every": 4, "min_separation_deg": 60.0, "size": 48}   # older data's record
    fit_check.check_data(ckpt, older, "c.npz", "d.npz")
    fit_check.check_data(ckpt, dict(metadata(), state_layout=list(datasets.STATE_LAYOUT)), "c.npz", "d.npz")
    swapped = list(datasets.STATE_LAYOUT[2:4] + datasets.STATE_LAYOUT[:2] + datasets.STATE_LAYOUT[4:])
    save_tiny(tmp_path / "no_world.npz", world=None)                # the layout is checked without a world too
    for path in ("c.npz", "no_world.npz"):
        with pytest.raises(checkpoint.CheckpointError, match=r"states laid out as \['shoulder angle', .* but d\.npz "
                                                             r"holds states laid out as \['shoulder velocity'"):
            fit_check.check_data(checkpoint.load(tmp_path / path), dict(metadata(), state_layout=swapped),
                                  path, "d.npz")


# --- damaged and hand-edited files ------------------------------------------------------------------

def test_an_npy_header_claiming_a_giant_shape_is_refused_before_reading(tmp_path):
    """A valid zip (CRCs and all) whose member's header claims 10^12 floats: refused from the header."""
    path = tmp_path / "giant.npz"
    save_tiny(path)
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    write_lying(path, arrays, "params/fc0_w", "<f4", (10 ** 12,))
    with pytest.raises(checkpoint.CheckpointError, match=r"giant\.npz' is not a readable oneshot checkpoint "
                                                         r"\(params/fc0_w\.npy's header claims a \(1000000000000,\) "
                                                         r"float32 array, which is not the 320 bytes the member "
                                                         r"holds\); move it aside and train it again"):
        checkpoint.load(path)


@pytest.mark.parametrize("edit, message", [
    (lambda a: a.pop("params/out_b"), "has no array 'params/out_b' (expected shape (2,))"),
    (lambda a: a.pop("adam/v/inner_lr/conv0_w"), "has no array 'adam/v/inner_lr/conv0_w'"),
    (lambda a: a.update({"ema/fc0_w": a["ema/fc0_w"][:-1]}), "'ema/fc0_w' has shape (15, 5) but its network "
                                                            "and method need (16, 5)"),
    (lambda a: a.update({"params/fc0_b": a["params/fc0_b"].astype(np.float64)}), "'params/fc0_b' has dtype float64"),
    (lambda a: a.update({"params/extra": np.zeros(3, np.float32)}), "unexpected array 'params/extra'"),
])
def test_arrays_are_checked_against_the_stored_configs(tmp_path, edit, message):
    """Without a checksum (older checkpoints), every name, shape and dtype is still checked."""
    path = tmp_path / "c.npz"
    save_tiny(path)
    rewrite(path, old_style, edit)
    with pytest.raises(checkpoint.CheckpointError) as e:
        checkpoint.load(path)
    assert str(path) in str(e.value) and message in str(e.value)
    assert str(e.value).endswith("; move it aside and train it again (with the train or fig2 command that made "
                                 "it), or use another checkpoint")


def test_changed_arrays_fail_the_checksum(tmp_path):
    path = tmp_path / "c.npz"
    save_tiny(path)
    rewrite(path, edit_arrays=lambda a: a["params/out_b"].__setitem__(0, 1.0))
    with pytest.raises(checkpoint.CheckpointError, match=r"c\.npz' fails its checksum"):
        checkpoint.load(path)


def _set(section, key, value):
    def edit(meta):
        (meta[section] if section else meta)[key] = value
    return edit


def _delete(section, key):
    def edit(meta):
        del (meta[section] if section else meta)[key]
    return edit


@pytest.mark.parametrize("edit, names", [
    (_delete(None, "rng"), "no 'rng'"),
    (_set(None, "rng", {"bit_generator": "MT19937", "state": {}}), "meta 'rng' is not a random state"),
    (_set(None, "iteration", "2"), "meta 'iteration' is '2', not int"),
    (_set(None, "iteration", -1), "meta 'iteration' is -1"),
    (_set(None, "checksum", None), "meta 'checksum' is None, not str"),
    (_set(None, "seconds", "5"), "meta 'seconds' is '5', not float or int or NoneType"),
    (_set(None, "seconds", -1.0), "meta 'seconds' is -1.0, not a time >= 0"),
    (_set(None, "seconds", float("inf")), "meta 'seconds' is inf, not a time >= 0"),
    (_set(None, "notes", "mine"), "unknown key 'notes'"),
    (_set("config", "learning_rate", 0.1), "meta 'config' has an unknown field 'learning_rate'"),
    (_delete("config", "alpha"), "meta 'config' has no field 'alpha'"),
    (_set("config", "meta_batch", "5"), "meta 'config' field 'meta_batch' is '5', not a whole number"),
    (_set("config", "lr", float("nan")), "meta 'config' field 'lr' is nan, not a finite number"),
    (_set("config", "first_order", 1), "meta 'config' field 'first_order' is 1, not a bool"),
    (_set("config", "method", "maml"), "meta 'config': method must be one of"),
    (_delete("network", "hidden"), "meta 'network' has no field 'hidden'"),
    (_set("network", "hidden", [5, "5"]), "meta 'network' field 'hidden' is (5, '5'), not a list of whole numbers"),
    (_set("network", "kernel", 2), "meta 'network': kernel must be odd"),
    (_set("network", "hidden", [6]), "'params/fc0_w' has shape (16, 5) but its network and method need (16, 6)"),
    (_set("network", "feature_points", False), "'params/fc0_w' has shape (16, 5) but its network and method "
                                               "need (24, 5)"),                         # flattened: a wider fc0_w
    (_set("network", "image_size", 64), "meta 'world' has image_size 8 but its network 64"),
    (_set("world", "arm", {}), "meta 'world' is not a world config"),
])
def test_hand_edited_metadata_is_refused_naming_the_file_and_the_key(tmp_path, edit, names):
    path = tmp_path / "c.npz"
    save_tiny(path)
    rewrite(path, edit)
    with pytest.raises(checkpoint.CheckpointError) as e:
        checkpoint.load(path)
    assert str(path) in str(e.value) and names in str(e.value) and "\n" not in str(e.value)


def test_a_config_claiming_a_giant_network_is_refused_without_building_it(tmp_path):
    path = tmp_path / "c.npz"
    save_tiny(path, dataclasses.replace(CFG, feature_points=False), dataclasses.replace(NET, feature_points=False),
              world=None)
    rewrite(path, _set("network", "image_size", 10 ** 7))        # fc0_w would be 2.5 10^13 x 5 floats
    with pytest.raises(checkpoint.CheckpointError, match=r"'params/fc0_w' has shape \(24, 5\) but its network "
                                                         r"and method need \(25000000000008, 5\)"):
        checkpoint.load(path)
    cfg = dataclasses.replace(config.TrainConfig(), method="lstm", lstm_units=3)
    save_tiny(path, cfg, methods.of(cfg).network_config(8))
    rewrite(path, _set("config", "lstm_units", 10 ** 9))
    with pytest.raises(checkpoint.CheckpointError, match=r"lstm_units is 1000000000 but the network's state_dim is "
                                                         r"only 9"):
        checkpoint.load(path)


def test_not_a_checkpoint(tmp_path):
    for name, content in (("empty.npz", b""), ("text.npz", b"PK\x03\x04 not really")):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(checkpoint.CheckpointError, match=f"{name}' is not a readable oneshot checkpoint"):
            checkpoint.load(tmp_path / name)
    np.savez(tmp_path / "data.npz", x=np.zeros(3))
    with pytest.raises(checkpoint.CheckpointError, match=r"data\.npz' has no metadata"):
        checkpoint.load(tmp_path / "data.npz")


# --- bit flips ----------------------------------------------------------------------------------------

def header_spans(path):
    """(start, end) byte ranges of every member's zip local header and npy header."""
    raw = pathlib.Path(path).read_bytes()
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            start = info.header_offset
            name_len, extra_len = struct.unpack("<HH", raw[start + 26:start + 30])
            npy = start + 30 + name_len + extra_len                   # the member's data, its npy header first
            header_len, = struct.unpack("<H", raw[npy + 8:npy + 10])
            yield start, npy + 10 + header_len


def flip_positions(path, n, rng):
    """n byte positions: a third anywhere, a third in the central directory and end record, a third
    in the members' local and npy headers."""
    size = os.path.getsize(path)
    with zipfile.ZipFile(path) as z:
        directory = z.start_dir
    spans = list(header_spans(path))
    anywhere = rng.integers(0, size, n // 3)
    central = rng.integers(directory, size, n // 3)
    starts, ends = np.array(spans).T
    pick = rng.integers(0, len(spans), n - 2 * (n // 3))
    headers = starts[pick] + (rng.random(len(pick)) * (ends - starts)[pick]).astype(int)
    return np.concatenate([anywhere, central, headers])


@pytest.mark.parametrize("style, flips", [("current", 400), ("old", 200)])
def test_single_bit_flips_load_the_original_or_raise_checkpoint_error(tmp_path, style, flips):
    """Every flipped file gives back exactly the original, or CheckpointError naming the file; nothing
    else escapes, and nothing loads changed. "old": without a checksum, so the zip's CRCs and the
    name, shape and dtype checks do all the work."""
    original = tmp_path / "original.npz"
    saved = save_tiny(original)
    if style == "old":
        rewrite(original, old_style)
        saved = dict(saved, world=None, state_layout=None)
    raw = original.read_bytes()
    flipped = tmp_path / "flipped.npz"
    rng = np.random.default_rng(20)
    outcomes = {"equal": 0, "raised": 0}
    for pos in flip_positions(original, flips, rng):
        damaged = bytearray(raw)
        damaged[pos] ^= 1 << int(rng.integers(8))
        flipped.write_bytes(bytes(damaged))
        try:
            ckpt = checkpoint.load(flipped)
        except checkpoint.CheckpointError as e:
            assert str(flipped) in str(e), str(e)
            outcomes["raised"] += 1
            continue
        assert_equal(ckpt, saved)
        outcomes["equal"] += 1
    assert outcomes["equal"] + outcomes["raised"] == flips
    assert outcomes["raised"] > flips // 2 and outcomes["equal"] > 0    # both happen: the sample covers both


@pytest.mark.parametrize("change, says", [
    (lambda a: dict(a, params={k: v.astype(np.float64) for k, v in a["params"].items()}), "has dtype float64"),
    (lambda a: dict(a, ema=None), "has no array 'ema/"),
    (lambda a: dict(a, iteration=-1), "meta 'iteration' is -1, not >= 0"),
    (lambda a: dict(a, world="bad"), "meta 'world' is 'bad', not dict"),
    (lambda a: dict(a, net_cfg=dataclasses.replace(NET, hidden=(7,))), "has shape"),
])
def test_save_refuses_what_load_would_refuse_and_writes_nothing(tmp_path, change, says):
    rng = np.random.default_rng(0)
    params = methods.of(CFG).init_params(NET, rng)
    a = change(dict(params=params, ema=params if CFG.ema else None, iteration=2, world=WORLD, net_cfg=NET))
    with pytest.raises(ValueError, match=f"checkpoint.save would write a file that checkpoint.load refuses: .*{says}"):
        checkpoint.save(tmp_path / "c.npz", a["params"], optim.adam_init(params), a["iteration"], rng, CFG,
                        a["net_cfg"], a["ema"], world=a["world"])
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="needs the run's np.random.Generator as rng; got RandomState"):
        checkpoint.save(tmp_path / "c.npz", params, optim.adam_init(params), 2, np.random.RandomState(0), CFG, NET)


def test_a_dataset_and_a_checkpoint_taken_for_each_other_are_named_for_what_they_are(tmp_path, tiny_split_datasets):
    save_tiny(tmp_path / "c.npz")
    with pytest.raises(datasets.DatasetError, match="is a checkpoint .*, not a dataset; load it with oneshot.training"):
        datasets.load(tmp_path / "c.npz")
    with pytest.raises(checkpoint.CheckpointError, match="is a dataset of demonstrations, not a checkpoint"):
        checkpoint.load(tiny_split_datasets["validation"])


def test_a_missing_checkpoint_names_the_command_that_makes_it(tmp_path):
    """A run folder's checkpoint: the command names that run folder (not the default one)."""
    with pytest.raises(FileNotFoundError, match=f"train one with `python -m oneshot.train --run {tmp_path / 'seed0'}`"):
        checkpoint.load(tmp_path / "seed0" / "checkpoint.npz")
    with pytest.raises(FileNotFoundError, match="train one with `python -m oneshot.train`$"):
        checkpoint.load(tmp_path / "policy.npz")
