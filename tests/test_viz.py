"""Pictures (oneshot.tools.viz) and the demo's choice of what to show (oneshot.demo): sizes, the target ring
where the scene puts the target, labels, the GIF's frames, and a failure shown when there is one."""
import numpy as np
from PIL import Image

from oneshot import demo
from oneshot.tools import viz
from oneshot.world import render
from oneshot.world.reach import Scene, WorldConfig

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
    centre, radius = demo.target_pixels(Scene(np.array([0]), target[None]), cfg)
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


def test_outcomes_tell_a_near_miss_from_a_distractor():
    scene = Scene(np.array([0, 16, 32]), np.array([[0.1, 0.0], [-0.1, 0.0], [0.0, 0.15]]), target=0)
    def trial(end, success=False):
        return {"success": success, "scene": scene, "end_effector": np.tile(end, (20, 1))}
    assert demo.outcome(trial([0.1, 0.0], success=True)) == "reached"
    assert demo.outcome(trial([0.1, 0.07])) == "missed: near miss"
    assert demo.outcome(trial([-0.09, 0.0])) == "missed: went to a distractor"
