"""The palette (oneshot.world.palette): "hues" mode pinned bit for bit, the "grid" mode's counts, split margins
and scene sampling, and a grid palette end to end through the world, the expert, collection and a saved
dataset."""
import colorsys
import dataclasses
import hashlib
import json
import re

import numpy as np
import pytest

from oneshot.data import collection, datasets
from oneshot.expert import controller
from oneshot.training import checkpoint_meta
from oneshot.world import palette
from oneshot.world.palette import PaletteConfig
from oneshot.world.render import world_to_pixels
from oneshot.world.reach import ReachWorld, WorldConfig
from oneshot.world.scene import Scene

GRID = PaletteConfig(mode="grid")


def hsv_to_rgb255(hue_deg, s, v):
    """Independent of colorsys (the closed form f(n) = v - v s max(0, min(k, 4 - k, 1)), k = (n + H/60)
    mod 6, n = 5, 3, 1): (..., 3) float in 0-255."""
    hue_deg, s, v = np.broadcast_arrays(*(np.asarray(x, float) for x in (hue_deg, s, v)))
    k = (np.array([5, 3, 1]) + hue_deg[..., None] / 60) % 6
    return 255 * (v[..., None] - v[..., None] * s[..., None] * np.clip(np.minimum(k, 4 - k), 0, 1))


def rgb_distances(a, b):
    """(len(a), len(b)) Euclidean distances between uint8 RGB rows, in 0-255 units."""
    return np.linalg.norm(a[:, None].astype(float) - b[None].astype(float), axis=-1)


# --- "hues" mode: today's palette, bit for bit (the shipped policy and its datasets depend on it) ----

def test_hues_mode_is_the_original_palette_bit_for_bit():
    rgb = palette.palette_rgb()[:palette.n_grid()]                  # the test colours come after
    assert rgb.shape == (48, 3) and rgb.dtype == np.uint8
    assert hashlib.sha256(rgb.tobytes()).hexdigest() == \
        "71d471778ba6095d68ad898241a25446f4575d3cca0d16c7693a86a7a9543f59"
    assert rgb[[0, 1, 5, 16, 47]].tolist() == [[255, 0, 0], [255, 32, 0], [255, 159, 0], [0, 255, 0], [255, 0, 32]]
    assert palette.split_colours("validation").tolist() == list(range(0, 48, 4))
    assert palette.split_colours("train").tolist() == [i for i in range(48) if i % 4]
    assert (palette.n_grid(), palette.n_colours()) == (48, 72)
    assert palette.hue_distance_deg(np.arange(48)[:, None], np.arange(48)[None]).sum() == 207360.0
    assert palette.colour_name(4) == "hue 30 deg" and palette.colour_name(5) == "hue 37.5 deg"


def test_hues_mode_scene_colours_are_the_original_draws():
    """50 seeds x both splits, drawn as the world draws them; pinned from the code before grid mode."""
    draws = []
    for seed in range(50):
        rng = np.random.default_rng(seed)
        for split in ("train", "validation"):                      # the two splits of that code
            target = int(rng.choice(palette.split_colours(split)))
            draws.append(palette.sample_scene_colours(target, 3, split, rng))
    draws = np.stack(draws).astype(np.int64)
    assert draws[:4].tolist() == [[41, 21, 10], [12, 20, 0], [23, 31, 42], [44, 4, 16]]
    assert hashlib.sha256(draws.tobytes()).hexdigest() == \
        "d8e144d7766680672cc7681d5fd9186aab9650a31b74d0e594644dd9c23ba6e5"


def test_old_configs_and_metadata_without_mode_load_as_hues_mode():
    assert PaletteConfig(48, 4, 60.0) == PaletteConfig()                  # positional construction
    old = {"size": 48, "heldout_every": 4, "min_separation_deg": 60.0}    # a dataset saved before "mode"
    assert PaletteConfig(**old) == PaletteConfig() and PaletteConfig(**old).mode == "hues"
    world = json.loads(json.dumps(dataclasses.asdict(WorldConfig())))    # as a dataset's metadata holds it
    world["palette"] = old
    assert datasets.world_config({"world": world}) == WorldConfig()


def test_grid_config_round_trips_through_json_metadata():
    back = PaletteConfig(**json.loads(json.dumps(dataclasses.asdict(GRID))))   # tuples come back as lists
    assert back == GRID and hash(back) == hash(GRID)                           # hashable: collect keys on it
    assert (GRID.size, GRID.heldout_every, GRID.guard) == (72, 6, 1)
    assert GRID.saturations == (1.0, 0.75, 0.5) and GRID.values == (1.0, 0.8, 0.6)


def test_bad_palette_configs_are_refused_with_their_value():
    with pytest.raises(ValueError, match="'rgb'"):
        PaletteConfig(mode="rgb")
    with pytest.raises(ValueError, match=r"saturations.*\(0, 1\]"):
        PaletteConfig(mode="grid", saturations=(1.0, 0.0))
    with pytest.raises(ValueError, match="guard 3 leaves no training hue"):
        PaletteConfig(mode="grid", guard=3)


# --- "grid" mode ----------------------------------------------------------------------------------

def test_grid_counts_and_split_layout():
    n = palette.n_grid(GRID)
    train, held = palette.split_colours("train", GRID), palette.split_colours("validation", GRID)
    assert (n, palette.n_colours(GRID), len(train), len(held)) == (648, 696, 324, 108)
    for idx in (train, held):
        assert np.issubdtype(idx.dtype, np.integer) and np.all(np.diff(idx) > 0)
        assert idx.min() >= 0 and idx.max() < n
    assert not set(train.tolist()) & set(held.tolist())
    hue_deg = lambda idx: set((palette.colour_hue(idx, GRID) * 5).tolist())
    assert hue_deg(held) == set(range(0, 360, 30))                   # the hues mode's held-out hues
    assert hue_deg(train) == {h for h in range(0, 360, 5) if h % 30 in (10, 15, 20)}
    guard = set(range(n)) - set(train.tolist()) - set(held.tolist())
    assert len(guard) == 216
    assert hue_deg(np.array(sorted(guard))) == {h for h in range(0, 360, 5) if h % 30 in (5, 25)}


def test_grid_rows_are_the_named_hue_saturation_value():
    """Every row of palette_rgb against an independent HSV formula, at the HSV its name states."""
    rgb = palette.palette_rgb(GRID)
    assert rgb.shape == (696, 3) and rgb.dtype == np.uint8
    names = [palette.colour_name(i, GRID) for i in range(696)]
    assert len(set(names)) == 696 and names[58] == "hue 30 deg, sat 0.75, val 0.8"
    assert names[648:650] == ["hue 0 deg, sat 0.875, val 0.9", "hue 0 deg, sat 0.875, val 0.7"]   # test colours
    hsv = np.array([re.fullmatch(r"hue (\S+) deg, sat (\S+), val (\S+)", s).groups() for s in names], float)
    assert np.abs(rgb - hsv_to_rgb255(*hsv.T)).max() <= 0.5 + 1e-9
    assert palette.hue_distance_deg(0, 8, GRID) == 0 and palette.hue_distance_deg(0, 9, GRID) == 5
    assert palette.hue_distance_deg(0, 647, GRID) == 5                 # around the wheel


def test_grid_validation_colours_keep_their_margin_from_training_colours():
    """The documented margins: >= 10 degrees of hue, and in RGB >= 12 (held-out to training) and >= 6
    (any two training colours), the minima over every pair (module docstring)."""
    rgb = palette.palette_rgb(GRID)
    train, held = palette.split_colours("train", GRID), palette.split_colours("validation", GRID)
    assert palette.hue_distance_deg(held[:, None], train[None], GRID).min() == 10
    assert rgb_distances(rgb[held], rgb[train]).min() == pytest.approx(12.0)
    d = rgb_distances(rgb[train], rgb[train])
    assert d[np.triu_indices(len(train), 1)].min() == pytest.approx(6.0)


def test_grid_colours_that_can_share_a_scene_differ_clearly():
    """Training colours >= 60 degrees apart in hue (which may share a scene) are >= 56 RGB units
    apart (measured 56.8), and every colour stands out from the black background and the white arm."""
    rgb = palette.palette_rgb(GRID)
    train = palette.split_colours("train", GRID)
    can_share = palette.hue_distance_deg(train[:, None], train[None], GRID) >= GRID.min_separation_deg
    assert rgb_distances(rgb[train], rgb[train])[can_share].min() > 56
    assert rgb_distances(rgb, np.array([[0, 0, 0]])).min() >= 153
    assert rgb_distances(rgb, np.array([[255, 255, 255]])).min() >= 127       # pale yellow (255, 255, 128)


def test_grid_scene_colours_are_of_the_split_and_60_degrees_apart():
    for split in palette.SPLITS:
        allowed = set(palette.split_colours(split, GRID).tolist())
        seen = set()
        for seed in range(300):
            rng = np.random.default_rng(seed)
            target = int(rng.choice(sorted(allowed)))
            n_objects = 3 + seed % 2
            colours = palette.sample_scene_colours(target, n_objects, split, rng, GRID)
            assert colours.shape == (n_objects,) and colours[0] == target
            assert set(colours.tolist()) <= allowed
            hue = palette.hue_distance_deg(colours[:, None], colours[None], GRID)
            assert hue[np.triu_indices(n_objects, 1)].min() >= 60
            seen |= set(colours.tolist())
        assert len(seen) > len(allowed) / 2                # distractors vary in saturation and value too


def test_grid_colours_outside_the_split_are_refused():
    guard = 9                                               # hue 5 degrees: the guard band, in neither split
    for split in palette.SPLITS:
        with pytest.raises(ValueError, match=f"colour 9 is not a '{split}' colour"):
            palette.check_colour(guard, split, GRID)
    with pytest.raises(ValueError, match=r"\[0, 696\)"):
        palette.colour_name(696, GRID)



CUSTOM = PaletteConfig(size=24, heldout_every=3, saturations=(0.9, 0.4), values=(0.7,), test_colours=((5.0, 0.5, 0.5),))


def reference_rgb(cfg):
    """palette_rgb written colour by colour from the module docstring's index layout, with colorsys."""
    rows, held = [], palette.heldout_hues(cfg).tolist()
    for i in range(palette.n_colours(cfg)):
        if i < palette.n_grid(cfg):
            hue, offset = i // palette.per_hue(cfg), 0.0
            s, v = divmod(i % palette.per_hue(cfg), len(cfg.values))
            s, v = cfg.saturations[s], cfg.values[v]
        else:
            k, j = divmod(i - palette.n_grid(cfg), len(cfg.test_colours))
            hue, (offset, s, v) = held[k], cfg.test_colours[j]
        rows.append(colorsys.hsv_to_rgb((hue * 360.0 / cfg.size + offset) % 360.0 / 360.0, s, v))
    return np.round(np.array(rows) * 255).astype(np.uint8)


@pytest.mark.parametrize("cfg, digest", [
    (PaletteConfig(), "08d793c2f274e373d5cd9c85ab5b75edfb3ab313a73ae82adc2eb335a9e9e02c"),
    (GRID, "822ca879abac236410c943bb4d11655cdc6f0fac37a4b9b4d37da990703c4547"),
    (CUSTOM, "dc36bd48158808f3b41aede3661b48581b42c849ffbaf42603faf6869a53e27b")], ids=["hues", "grid", "custom"])
def test_palette_rgb_is_the_colour_by_colour_reference_bit_for_bit(cfg, digest):
    """Every colour of every mode (test colours included) equals the per-colour reference exactly, and the
    whole palette its pinned digest (the values before palette_rgb was vectorised)."""
    rgb = palette.palette_rgb(cfg)
    assert rgb.dtype == np.uint8 and np.array_equal(rgb, reference_rgb(cfg))
    assert hashlib.sha256(rgb.tobytes()).hexdigest() == digest
    i = np.arange(palette.n_colours(cfg))
    levels = np.stack(palette.colour_levels(i, cfg), -1)              # broadcasts, as colour_hue_deg does
    assert levels.tolist() == [list(palette.colour_levels(int(k), cfg)) for k in i]

# --- a grid palette end to end ----------------------------------------------------------------------

def test_a_grid_world_draws_each_disc_in_its_palette_colour():
    rgb = palette.palette_rgb(GRID)
    for split in palette.SPLITS:
        world = ReachWorld(WorldConfig(palette=GRID, split=split))
        colours = palette.split_colours(split, GRID)
        for seed, target in enumerate(colours[::13]):        # includes the dull (sat 0.5, val 0.6) corner
            obs, info = world.reset(seed=seed, options={"target_colour": int(target)})
            scene = info["scene"]
            assert scene.target_colour == target
            for pos, colour in zip(scene.positions, scene.colours):
                px, py = world_to_pixels(pos, world.config.arena_half_width, 32)
                pixel = obs["image"][int(py), int(px)].astype(int)
                assert np.abs(pixel - rgb[colour]).max() <= 3, (colour, pixel, rgb[colour])


def test_the_expert_demonstrates_and_collect_records_grid_colours(tmp_path):
    world = ReachWorld(WorldConfig(palette=GRID, split="train"))
    train = palette.split_colours("train", GRID)
    for colour in (train[0], train[-1]):
        assert controller.demonstrate(world, seed=0, options={"target_colour": int(colour)})["success"]
    dataset = collection.collect(2, 2, "train", seed=0, workers=1, world_cfg=WorldConfig(palette=GRID),
                              progress=False)
    datasets.save(dataset, tmp_path / "grid.npz")
    back = datasets.load(tmp_path / "grid.npz")
    assert datasets.world_config(back["metadata"]).palette == GRID
    assert np.array_equal(back["colours"], dataset["colours"])
    assert set(back["colours"].ravel().tolist()) <= set(train.tolist())
    assert back["colours"].max() > 72              # indices past the hue count survive the int16 arrays


def test_a_grid_world_replays_a_scene_with_colours_past_the_hue_count():
    world = ReachWorld(WorldConfig(palette=GRID))
    scene = Scene(colours=np.array([301, 474, 630]), positions=np.array([[0.1, 0.0], [0.0, 0.1], [-0.1, 0.0]]),
                  target=0)
    obs, _ = world.reset(options={"scene": scene})
    px, py = world_to_pixels(scene.positions[0], world.config.arena_half_width, 32)
    assert np.array_equal(obs["image"][int(py), int(px)], palette.palette_rgb(GRID)[301])


# --- the test split ---------------------------------------------------------------------------------

@pytest.mark.parametrize("mode", palette.MODES)
def test_the_three_splits_are_disjoint_and_the_test_colours_at_their_documented_distances(mode):
    """Train, validation and test colours share no index and no RGB colour. In the grid the test colours
    are of the held-out hues, as far in hue from every training colour as the validation colours (10
    deg); the hues palette's are the fully saturated hues half-way between (3.75 deg from both). RGB
    distances as the module docstring states them."""
    cfg = PaletteConfig(mode=mode)
    rgb = palette.palette_rgb(cfg)
    train, val, test = (palette.split_colours(s, cfg) for s in palette.SPLITS)
    assert len(test) == (24 if mode == "hues" else 48) and (mode == "hues" or len(test) >= 36)
    assert not (set(train) & set(val) or set(train) & set(test) or set(val) & set(test))
    assert not ({tuple(c) for c in rgb[test]} & {tuple(c) for c in rgb[np.concatenate([train, val])]})
    hue = lambda a, b: palette.hue_distance_deg(a[:, None], b[None], cfg).min()
    assert (hue(test, train), hue(val, train)) == ((3.75, 7.5) if mode == "hues" else (10, 10))
    assert set(palette.colour_hue(test, cfg).tolist()) == set(palette.colour_hue(val, cfg).tolist())
    if mode == "hues":                                   # of the palette's kind: fully saturated and bright
        assert np.all(rgb[test].max(axis=1) == 255) and np.all(rgb[test].min(axis=1) == 0)
    documented = {"hues": (16.0, 15.0), "grid": (26.9, 27.7)}[mode]
    assert rgb_distances(rgb[test], rgb[train]).min() == pytest.approx(documented[0], abs=0.05)
    assert rgb_distances(rgb[test], rgb[val]).min() == pytest.approx(documented[1], abs=0.05)
    # a wrong split would fail: validation and test are as documented, not the other way round
    assert rgb_distances(rgb[val], rgb[train]).min() == pytest.approx(31.0 if mode == "hues" else 12.0, abs=0.05)


def test_a_test_scene_draws_its_distractors_from_the_test_colours():
    rng = np.random.default_rng(0)
    test = set(palette.split_colours("test", GRID).tolist())
    for target in sorted(test)[::5]:
        colours = palette.sample_scene_colours(target, 3, "test", rng, GRID)
        assert set(colours.tolist()) <= test
        assert palette.hue_distance_deg(colours[:, None], colours[None], GRID)[np.triu_indices(3, 1)].min() >= 60
    with pytest.raises(ValueError, match="is not a 'test' colour"):
        palette.sample_scene_colours(0, 3, "test", rng, GRID)
    with pytest.raises(ValueError, match="test_colours"):
        PaletteConfig(mode="grid", test_colours=((0.0, 1.0, 1.0),))     # a validation colour itself
    with pytest.raises(ValueError, match="test_colours"):
        PaletteConfig(test_colours=((7.5, 1.0, 1.0),))                  # a training hue


def test_files_of_the_test_levels_versions_read_as_the_same_test_colours():
    """Checkpoints and datasets written between 87055e1 and 18fc823 saved `test_levels`, (saturation,
    value) at each held-out hue: they load, with those colours, in that order."""
    levels = [[0.8, 1.0], [1.0, 0.8], [0.8, 0.8]]                      # that version's hues palette
    saved = {"size": 48, "heldout_every": 4, "min_separation_deg": 60.0, "mode": "hues", "saturations": [1.0],
             "values": [1.0], "guard": 0, "test_levels": levels}
    cfg = palette.saved_config(saved)
    test = palette.split_colours("test", cfg)
    rgb = np.asarray(palette.palette_rgb(cfg))[test].astype(float)
    expected = [255 * np.array(colorsys.hsv_to_rgb(h / 48, s, v)) for h in palette.heldout_hues(cfg) for s, v in levels]
    np.testing.assert_allclose(rgb, expected, atol=1)                  # hue by hue, level by level
    grid = dataclasses.asdict(palette.PaletteConfig(mode="grid"))      # the grid's: the same colours as now
    grid["test_levels"] = [list(t[1:]) for t in grid.pop("test_colours")]
    assert palette.saved_config(grid) == palette.PaletteConfig(mode="grid")
    world = {"image_size": 32, "horizon": 20, "arm": {"max_torque": 1.0}, "palette": grid}
    assert checkpoint_meta.world_fields(world, "here")["palette"] == palette.PaletteConfig(mode="grid")
    with pytest.raises(TypeError):                                     # what an old file met before
        palette.PaletteConfig(**grid)
