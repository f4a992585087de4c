"""Pictures (oneshot.tools.viz) and the demo's choice of what to show (oneshot.demo): sizes, the target ring
where the scene puts the target, the base and hand where the arm has them, labels, the GIF's frames, a
failure shown when there is one, and captions that say what the arm did."""
import colorsys

import numpy as np
import pytest
from PIL import Image

from oneshot import demo, methods
from oneshot.expert import controller
from oneshot.maml import imitation
from oneshot.tools import viz
from oneshot.training import checkpoint
from oneshot.world import palette, render
from oneshot.world.reach import ReachWorld, WorldConfig
from oneshot.world.scene import Scene

H = W = 32
SCALE = 4
RED = (255, 0, 0)


def _episode(n_steps=20, seed=0):
    """A synthetic episode (n_steps, H, W, 3) uint8: dark noise, no pure white (the ring's colour)."""
    return np.random.default_rng(seed).integers(0, 200, (n_steps, H, W, 3)).astype(np.uint8)


def _white(image):
    """(H, W) bool: pixels of exactly the ring's colour."""
    return (np.asarray(image.convert("RGB")) == viz.MARK).all(axis=-1)


def test_filmstrip_grows_by_one_tile_per_kept_frame_and_per_row():
    tile_w, tile_h = W * SCALE + 6, H * SCALE + 6          # a frame enlarged, plus the gap
    base = viz.filmstrip([_episode(20)] * 2, every=2, scale=SCALE, gap=6)
    # every=2 keeps t = 0, 2, ..., 18 and the last, 19: 11 columns; 10 steps keep 0, 2, ..., 8, 9: 6
    assert viz.filmstrip([_episode(10)] * 2, every=2, scale=SCALE, gap=6).size == (base.width - 5 * tile_w, base.height)
    assert viz.filmstrip([_episode(20)] * 2, every=4, scale=SCALE, gap=6).size == (base.width - 5 * tile_w, base.height)
    # one more row, in its own group (group=1): a tile's height and the 2-gap space between groups
    assert viz.filmstrip([_episode(20)] * 3, every=2, scale=SCALE, gap=6).size == \
        (base.width, base.height + tile_h + 12)
    # four rows in two groups of two: two more rows, still one space between groups
    assert viz.filmstrip([_episode(20)] * 4, every=2, scale=SCALE, gap=6, group=2).size == \
        (base.width, base.height + 2 * tile_h)


def test_the_ring_is_centred_on_the_disc_the_scene_places():
    """Rendered disc at a world position; the ring drawn at world_to_pixels of that position surrounds it."""
    cfg = WorldConfig()
    target = np.array([0.08, -0.05])                      # metres
    far_arm = np.array([[-0.2, 0.2]] * 3)                  # the arm folded into a far corner
    frame = render.render(far_arm, target[None], np.array([RED], np.uint8), arena_half_width=cfg.arena_half_width)
    marks = viz.episode_marks([{"scene": Scene(np.array([0]), target[None]), "end_effector": far_arm[1:]}], cfg)
    centre, radius = marks["targets"][0], marks["radius"]
    plain, ringed = viz.marked_frame(frame, SCALE), viz.marked_frame(frame, SCALE, centre, radius)
    plain, ringed = np.asarray(plain), np.asarray(ringed)
    assert plain.shape == (H * SCALE, W * SCALE, 3)
    ring = (plain != ringed).any(axis=-1)
    ys, xs = np.nonzero(ring)
    distance = np.hypot(xs + 0.5 - centre[0] * SCALE, ys + 0.5 - centre[1] * SCALE)
    r = radius * SCALE
    assert len(xs) > 2 * np.pi * r * 0.4                  # dashes cover about half the circle
    assert distance.min() >= r - SCALE // 2 - 1.5 and distance.max() <= r + 1.5
    assert (ringed[ring] == viz.MARK).all()
    # ... and centred on the disc, whose pixels keep their colour
    disc = np.abs(plain.astype(int) - RED).max(axis=-1) < 60
    dy, dx = np.nonzero(disc)
    assert np.hypot(xs.mean() - dx.mean(), ys.mean() - dy.mean()) < 1.5
    assert not (disc & ring).any()
    assert tuple(ringed[int(centre[1] * SCALE), int(centre[0] * SCALE)]) == RED


def test_the_filmstrip_rings_the_target_in_every_frame_of_its_row_only():
    rows, target = [_episode(20, 0), _episode(20, 1)], (12.0, 20.0)
    one_tile = _white(viz.marked_frame(rows[1][0], SCALE, target, 3.0)).sum()
    strip = viz.filmstrip(rows, every=2, scale=SCALE, targets=[None, target], radius=3.0)
    assert one_tile > 0 and _white(strip).sum() == 11 * one_tile      # 11 kept frames, all ringed
    assert _white(viz.filmstrip(rows, every=2, scale=SCALE)).sum() == 0


def test_labels_and_swatches_fill_the_left_margin_and_time_steps_the_top():
    rows = [_episode(20)] * 2
    bare = viz.filmstrip(rows, every=2, scale=SCALE, gap=6)
    labelled = viz.filmstrip(rows, every=2, scale=SCALE, gap=6, labels=["hue 0 deg\ndemonstration",
                             "hue 0 deg\nmissed: went to a distractor"], swatches=[RED, RED])
    margin = labelled.width - bare.width
    assert margin > 100 and labelled.height == bare.height
    left = np.asarray(labelled)[:, :margin]
    assert (left != viz.BACKGROUND).any(axis=-1).sum() > 500                  # text
    assert (left == RED).all(axis=-1).sum() > 50                             # the swatches
    # above the first row (two rows of tiles, one space between groups): the numbers of the time steps
    above = np.asarray(bare)[:bare.height - 2 * (H * SCALE + 6) - 12]
    assert above.shape[0] > 15 and (above != viz.BACKGROUND).any(axis=-1).sum() > 11 * 50


def test_the_gif_has_a_frame_per_step_each_three_panels_wide(tmp_path):
    solid = [np.broadcast_to(np.array(c, np.uint8), (20, H, W, 3)) for c in (RED, (0, 255, 0), (0, 0, 255))]
    images = viz.side_by_side(solid, ["demonstration", "before adapting", "after adapting\nreached"],
                              targets=[(8, 8), (16, 16), (16, 16)], scale=6, gap=6)
    assert len(images) == 20
    for t, image in enumerate(images):
        assert image.width == 6 + 3 * (W * 6 + 6)
        pixels = np.asarray(image)
        for colour in solid:                              # each panel once, a few pixels under its ring
            n = (pixels == colour[0, 0, 0]).all(axis=-1).sum()
            assert 0.9 * (W * 6) * (H * 6) < n <= (W * 6) * (H * 6)
        assert t == 0 or not np.array_equal(pixels, np.asarray(images[t - 1]))   # the step number changes
    viz.save_gif(images, tmp_path / "trial.gif")
    gif = Image.open(tmp_path / "trial.gif")
    assert gif.n_frames == 20 and gif.size == images[0].size
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tmp")]    # written atomically


def test_the_film_strip_shows_a_failure_when_one_occurred():
    ok = np.ones((12, 3), bool)
    assert demo.shown_trials(ok, 4) == [(0, 0), (1, 0), (2, 0), (3, 0)]
    failed_later = ok.copy()
    failed_later[7, 2] = False
    assert demo.shown_trials(failed_later, 4) == [(0, 0), (1, 0), (2, 0), (7, 2)]
    failed_shown_colour = ok.copy()
    failed_shown_colour[1, 2] = failed_shown_colour[9, 0] = False
    assert demo.shown_trials(failed_shown_colour, 4) == [(0, 0), (1, 2), (2, 0), (3, 0)]
    already_shown = ok.copy()
    already_shown[2, 0] = already_shown[5, 1] = False
    assert demo.shown_trials(already_shown, 4) == [(0, 0), (1, 0), (2, 0), (3, 0)]


def test_the_animation_prefers_a_scene_where_adapting_made_the_difference():
    reached, near, wrong = "reached", demo.NEAR_MISS, demo.DISTRACTOR
    adapted = np.array([[reached, reached], [reached, near], [reached, reached]])
    assert demo.contrast_trial(adapted, np.array([[reached, near], [wrong, reached], [reached, wrong]])) == (1, 0)
    assert demo.contrast_trial(adapted, np.array([[reached, near], [reached, wrong], [reached, reached]])) == (0, 1)
    assert demo.contrast_trial(adapted, np.full((3, 2), reached)) == (0, 0)
    assert demo.contrast_trial(np.full((3, 2), wrong), np.full((3, 2), wrong)) == (0, 0)
    # an unadapted arm that passed the target and left it counts as going elsewhere, as a distractor does
    assert demo.contrast_trial(adapted, np.array([[reached, near], [demo.LEFT, reached], [reached, wrong]])) == (1, 0)


def test_outcomes_say_where_the_arm_stopped_by_distance_not_only_by_the_closest_disc():
    """Within 0.06 m (half the discs' minimum separation) of a disc it went there; farther from every
    disc, it went to none, whichever is closest (the demo's GIF once said "went to a distractor" of an
    arm that stopped 8.7 and 10 cm from two distractors)."""
    scene = Scene(np.array([0, 16, 32]), np.array([[0.1, 0.0], [-0.1, 0.0], [0.0, 0.15]]), target=0)
    def trial(end, success=False):
        return {"success": success, "scene": scene, "end_effector": np.tile(end, (20, 1))}
    assert demo.outcome(trial([0.1, 0.0], success=True)) == "reached"
    assert demo.outcome(trial([0.1, 0.055])) == demo.NEAR_MISS == "missed: near miss"
    assert demo.outcome(trial([-0.1, 0.055])) == demo.DISTRACTOR == "missed: went to a distractor"
    assert demo.outcome(trial([0.1, 0.07])) == demo.outcome(trial([-0.1, 0.065])) == demo.ASTRAY
    assert demo.outcome(trial([0.0, 0.07])) == demo.ASTRAY == "missed: near no disc"   # between all three
    # the radius is the world's: half its min_separation
    assert demo.outcome(trial([0.1, 0.07]), WorldConfig(min_separation=0.16)) == demo.NEAR_MISS
    # within the success radius of the target (0.05 m) before the final fifth, then away: it left
    left = trial([-0.1, 0.055])
    left["end_effector"][:3] = [0.1, 0.049]
    assert demo.outcome(left) == demo.LEFT == "missed: reached, then left"
    left["end_effector"][:3] = [0.1, 0.051]                              # never within the radius
    assert demo.outcome(left) == demo.DISTRACTOR
    assert demo.outcome(left, WorldConfig(success_radius=0.052)) == demo.LEFT


def test_marked_frames_mark_the_base_and_the_hand_where_given():
    frame = _episode(1)[0]
    plain = np.asarray(viz.marked_frame(frame, SCALE))
    for base, hand in (((16.0, 16.0), None), (None, (5.0, 9.0)), ((16.0, 16.0), (5.0, 9.0))):
        marked = np.asarray(viz.marked_frame(frame, SCALE, base=base, hand=hand))
        ys, xs = np.nonzero((marked != plain).any(axis=-1))
        assert (marked[ys, xs] == viz.MARK).all()
        at = np.stack([xs + 0.5, ys + 0.5], -1) / SCALE                    # frame pixels
        on_base = np.abs(at - (base or (-9, -9))).max(axis=1) <= viz.BASE_HALF_WIDTH + 0.2    # a square
        on_hand = np.abs(np.linalg.norm(at - (hand or (-9, -9)), axis=1) - viz.HAND_RADIUS) <= 0.6  # a circle
        assert (on_base | on_hand).all()
        assert (on_base.sum() > 20) == (base is not None) and (on_hand.sum() > 20) == (hand is not None)
    assert np.array_equal(np.asarray(viz.marked_frame(frame, SCALE, hand=(np.nan, np.nan))), plain)


def test_episode_marks_put_the_hand_on_the_arms_end_in_every_frame():
    """A demo's hands come from its states, a rollout's from its end effectors one step late (and the start
    pose's for frame 0): two records of the same episode give the same marks, on the arm's white pixels."""
    world = ReachWorld()
    recorded = controller.demonstrate(world, seed=2)
    rollout = {"scene": recorded["scene"], "end_effector": recorded["end_effector"]}
    marks = viz.episode_marks([recorded, rollout], world.config)
    from_states, from_rollout = marks["hands"]
    assert from_states.shape == (20, 2) and np.abs(from_states - from_rollout).max() < 1e-4
    assert np.allclose(marks["base"], (16, 16)) and np.allclose(marks["radius"], 2 * 0.025 * 32 / 0.44)
    x, y = np.floor(from_states).astype(int).T
    brightest = [recorded["images"][t, y[t] - 1:y[t] + 2, x[t] - 1:x[t] + 2].max() for t in range(20)]
    assert min(brightest) > 100                   # the arm (or a disc over it) at every hand mark, not background
    noisy = viz.episode_marks([rollout], WorldConfig(start_noise=0.1))["hands"][0]
    assert np.isnan(noisy[0]).all() and np.array_equal(noisy[1:], from_rollout[1:])  # start unknown: unmarked


def test_the_demo_pictures_mark_target_base_and_hand_in_every_frame():
    """The demo's film strip and GIF against the same pictures unmarked: they differ only by white marks,
    a ring, a square and a circle's worth (over 60 pixels) in every tile."""
    cfg = WorldConfig(split="validation")
    recorded = controller.demonstrate(ReachWorld(cfg), seed=0, options={"target_colour": 4})   # hue 30 deg
    strip = np.asarray(demo.film_strip(cfg, [(recorded, None)]))
    bare = np.asarray(viz.filmstrip([recorded["images"]], labels=["hue 30 deg\ndemonstration"],
                                    swatches=[palette.palette_rgb()[4]]))
    changed = (strip != bare).any(axis=-1)
    assert (strip[changed] == viz.MARK).all() and changed.sum() > 11 * 60        # 11 kept frames
    titles = ["demonstration\nhue 30 deg"] + [f"{when} adapting\n{demo.outcome(recorded, cfg)}"
                                              for when in ("before", "after")]
    for marked, plain in zip(demo.animation(cfg, recorded, recorded, recorded),
                             viz.side_by_side([recorded["images"]] * 3, titles)):
        marked, plain = np.asarray(marked), np.asarray(plain)
        changed = (marked != plain).any(axis=-1)
        assert (marked[changed] == viz.MARK).all() and changed.sum() > 3 * 60    # 3 panels


def test_the_hue_wheel_puts_each_colour_on_its_splits_ring_at_its_hue():
    """Independent of the drawing code: each colour's pixel, computed from its hue in degrees with
    colorsys, sits at its angle on its split's ring; where a held-out hue would be on the outer ring,
    there is background. The grid palette (several colours per hue) is refused in words."""
    size = 360
    image = np.asarray(viz.hue_wheel(size=size))
    outer, centre = 0.44 * size, size / 2
    radius = {split: fraction for split, fraction, _ in viz.RINGS}

    def pixel(degrees, fraction):
        a = np.deg2rad(degrees)
        return image[int(round(centre - fraction * outer * np.sin(a))), int(round(centre + fraction * outer * np.cos(a)))]
    for split in palette.SPLITS:
        for i in palette.split_colours(split):
            degrees = palette.colour_hue_deg(i)
            want = np.round(np.array(colorsys.hsv_to_rgb(degrees / 360.0, 1.0, 1.0)) * 255)
            assert np.array_equal(pixel(degrees, radius[split]), want), (split, i)
    for i in palette.split_colours("validation"):
        assert tuple(pixel(palette.colour_hue_deg(i), radius["train"])) == viz.BACKGROUND
    with pytest.raises(ValueError, match="hue_wheel draws the hues palette.*PaletteConfig\\(mode='hues'\\)"):
        viz.hue_wheel(palette.PaletteConfig(mode="grid"))


def test_the_demo_adapts_each_colour_on_its_own_demo_and_counts_and_shows_what_it_ran(tmp_path, monkeypatch, capsys):
    """`python -m oneshot.demo` checked against what it did, seen through spies on the expert, the adaptation,
    the rollouts and the pictures: demos with the checkpoint's DART noise, seeded by --seed; each colour's
    policy adapted on that colour's demo; every trial a new scene (evaluate's trial seeds), played by the
    adapted and the unadapted policy; the counts those rollouts' own successes (re-judged from the hand's
    path); the film strip's trials the adapted ones and the GIF's panels demo, before, after."""
    ckpt = checkpoint.load(demo.PRETRAINED)
    base, cfg = checkpoint.policy_params(ckpt), WorldConfig()
    is_base = lambda policy: all(np.array_equal(policy[k], base[k]) for k in base)
    real = dict(demonstrate=controller.demonstrate, prepare=imitation.prepare_demos, rollout=imitation.rollout,
                filmstrip=viz.filmstrip, side_by_side=viz.side_by_side)
    demos, events, shown = [], [], {}

    class Stop(Exception):
        pass

    def first_demo_only(*args, **kwargs):
        demos.append(kwargs["seed"])
        raise Stop
    monkeypatch.setattr(controller, "demonstrate", first_demo_only)
    for seed in ("0", "1"):
        with pytest.raises(Stop):
            demo.main(["--out", str(tmp_path), "--seed", seed])
    assert demos[0] != demos[1], "the demos' scenes ignore --seed"
    demos.clear()

    def demonstrate(*args, **kwargs):
        d = real["demonstrate"](*args, **kwargs)
        demos.append((kwargs["seed"], kwargs["cfg"], d))
        return d

    def prepare(images, *args):
        events.append(("adapt", images))
        return real["prepare"](images, *args)

    def rollout(policy, world, seed, colour):
        r = real["rollout"](policy, world, seed, colour)
        events.append(("rollout", policy, seed, colour, r))
        return r
    monkeypatch.setattr(controller, "demonstrate", demonstrate)
    monkeypatch.setattr(imitation, "prepare_demos", prepare)
    monkeypatch.setattr(imitation, "rollout", rollout)
    monkeypatch.setattr(viz, "filmstrip", lambda images, **kw: shown.setdefault("strip", images) and
                        real["filmstrip"](images, **kw))
    monkeypatch.setattr(viz, "side_by_side", lambda images, titles, **kw: shown.setdefault("gif", (images, titles)) and
                        real["side_by_side"](images, titles, **kw))
    result = demo.main(["--out", str(tmp_path), "--trials", "2", "--seed", "1"])

    test_colours = palette.split_colours("test", cfg.palette)
    assert [int(d["scene"].target_colour) for _, _, d in demos] == [int(c) for c in test_colours]
    assert ckpt["config"].demo_noise > 0 and all(c.action_noise == ckpt["config"].demo_noise for _, c, _ in demos)
    assert len({s for s, _, _ in demos}) == len(demos)
    by_colour = {int(d["scene"].target_colour): d for _, _, d in demos}
    adapted, unadapted = [], []
    for i, (colour, d) in enumerate(by_colour.items()):       # per colour: adapt on its demo, then 2 x 2 rollouts
        step = events[5 * i: 5 * i + 5]
        assert step[0][0] == "adapt" and step[0][1] is d["images"], f"colour {i} adapted on another colour's demo"
        for j, (a, u) in enumerate(zip(step[1::2], step[2::2])):
            assert a[0] == u[0] == "rollout" and a[3] == u[3] == colour
            assert a[2] == u[2] == imitation.trial_seed(1, i, j, "test")        # a new scene per trial, shared by both
            assert not is_base(a[1]) and is_base(u[1])
            adapted.append(a[4])
            unadapted.append(u[4])
    assert len(events) == 5 * len(by_colour)

    def reached(r):                                           # the success criterion, on the final fifth
        ee, target = r["end_effector"], r["scene"].positions[r["scene"].target]
        return bool(np.linalg.norm(ee[-len(ee) // 5:] - target, axis=1).min() <= cfg.success_radius)
    assert [r["success"] for r in adapted + unadapted] == [reached(r) for r in adapted + unadapted]
    assert result == {"successes": sum(map(reached, adapted)), "trials": 2 * len(test_colours),
                      "unadapted_successes": sum(map(reached, unadapted))}
    printed = capsys.readouterr().out
    assert f"{result['successes']}/{result['trials']} = " in printed
    assert f"to each demo: {methods.of(ckpt['config']).describe()}\n3. Run it in 2 new scenes per colour" in printed
    strip = shown["strip"]                                    # rows: a demo, then an adapted trial of its colour
    picked = demo.shown_trials(np.reshape([reached(r) for r in adapted], (len(by_colour), 2)))   # chosen by them
    assert [id(x) for x in strip] == [id(x) for i, j in picked
                                      for x in (list(by_colour.values())[i]["images"], adapted[2 * i + j]["images"])]
    images, titles = shown["gif"]
    before = next(r for r in unadapted if r["images"] is images[1])
    after = next(r for r in adapted if r["images"] is images[2])
    assert before["scene"].positions.tolist() == after["scene"].positions.tolist()
    assert titles[1].endswith(demo.outcome(before)) and titles[2].endswith(demo.outcome(after))


@pytest.mark.parametrize("stage", ["animation", "gif_encoded"])
def test_a_demo_interrupted_while_drawing_leaves_both_pictures_as_they_were(tmp_path, monkeypatch, stage):
    """one_shot.png and one_shot_trial.gif are drawn and encoded before either is written: a Ctrl-C while
    the animation was drawn (or encoded) left a new film strip beside the last run's animation."""
    old = {name: f"an earlier run's {name}".encode() for name in ("one_shot.png", "one_shot_trial.gif")}
    for name, data in old.items():
        (tmp_path / name).write_bytes(data)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt
    monkeypatch.setattr(demo if stage == "animation" else viz, stage, interrupted)
    with pytest.raises(KeyboardInterrupt):
        demo.main(["--out", str(tmp_path), "--trials", "1", "--seed", "1"])
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == old
