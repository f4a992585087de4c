"""The reaching world: scenes, rendering, determinism, success, and errors (oneshot.world.reach)."""
import dataclasses

import numpy as np
import pytest

from helpers import check_hostile_scenes, one_line_error
from oneshot.data.datasets import STATE_LAYOUT
from oneshot.world import arm, palette
from oneshot.world.render import render, world_to_pixels
from oneshot.world.reach import ReachWorld, WorldConfig, closest_object, is_success, observation_state
from oneshot.world.scene import Scene, sample_scene


def test_a_disc_of_colour_c_appears_where_the_scene_says_in_colour_c():
    for size in (32, 64):
        world = ReachWorld(WorldConfig(image_size=size))
        rgb = palette.palette_rgb()
        for seed in range(5):
            obs, info = world.reset(seed=seed)
            scene = info["scene"]
            for pos, colour in zip(scene.positions, scene.colours):
                px, py = world_to_pixels(pos, world.config.arena_half_width, size)
                pixel = obs["image"][int(py), int(px)].astype(int)
                assert np.abs(pixel - rgb[colour]).max() <= 40, (size, pos, pixel, rgb[colour])
            # and nowhere else: a pixel far from every object and the arm is background
            assert obs["image"][0, 0].tolist() == [0, 0, 0]


def test_image_pixels_of_each_colour_sit_at_its_disc():
    """Independent check through the image: the centroid of pixels near colour c is the disc centre."""
    world = ReachWorld()
    obs, info = world.reset(seed=3)
    image = obs["image"].astype(int)
    for pos, colour in zip(info["scene"].positions, info["scene"].colours):
        mask = np.abs(image - palette.palette_rgb()[colour]).max(-1) < 60
        ys, xs = np.nonzero(mask)
        centre = world_to_pixels(pos, world.config.arena_half_width, 32)
        assert np.hypot(xs.mean() + 0.5 - centre[0], ys.mean() + 0.5 - centre[1]) < 1.0


def test_same_seed_same_trajectory_bit_for_bit():
    actions = np.random.default_rng(0).uniform(-0.5, 0.5, (20, 2))

    def run():
        world = ReachWorld()
        obs, _ = world.reset(seed=42, options={"target_colour": 5})
        frames = [obs["image"]]
        states = [observation_state(obs)]
        for a in actions:
            obs, *_ = world.step(a)
            frames.append(obs["image"])
            states.append(observation_state(obs))
        return np.stack(frames), np.stack(states)

    (f1, s1), (f2, s2) = run(), run()
    assert np.array_equal(f1, f2) and np.array_equal(s1, s2)
    world = ReachWorld()
    _, i1 = world.reset(seed=42, options={"target_colour": 5})
    _, i2 = world.reset(seed=43, options={"target_colour": 5})
    assert not np.array_equal(i1["scene"].positions, i2["scene"].positions)


def test_scenes_are_reachable_separated_and_distinguishable():
    cfg = WorldConfig()
    rng = np.random.default_rng(0)
    train = set(palette.split_colours("train").tolist())
    for _ in range(200):
        colour = int(rng.choice(sorted(train)))
        scene = sample_scene(colour, rng, cfg)
        assert scene.target_colour == colour
        r = np.linalg.norm(scene.positions, axis=1)
        assert np.all((r >= cfg.min_object_radius) & (r <= cfg.max_object_radius))
        d = np.linalg.norm(scene.positions[:, None] - scene.positions[None], axis=-1)
        assert d[np.triu_indices(3, 1)].min() > 2 * cfg.success_radius
        hue = palette.hue_distance_deg(scene.colours[:, None], scene.colours[None])
        assert hue[np.triu_indices(3, 1)].min() >= cfg.palette.min_separation_deg
        assert set(scene.colours.tolist()) <= train          # no held-out colour, not even a distractor


def test_palette_splits_never_overlap():
    train, held, test = (palette.split_colours(s) for s in ("train", "validation", "test"))
    assert not set(train) & set(held) and not set(test) & (set(train) | set(held))
    assert len(train) + len(held) + len(test) == palette.n_colours() == 72
    assert len(np.unique(palette.palette_rgb(), axis=0)) == palette.n_colours()


def test_success_criterion_uses_the_final_fifth():
    target = np.array([0.1, 0.0])
    far = np.tile([0.0, 0.15], (20, 1))
    near_late = far.copy()
    near_late[-2] = [0.1, 0.049]                   # within 0.05 during the last 4 of 20 steps
    near_early = far.copy()
    near_early[-5] = [0.1, 0.0]                    # only before the final fifth
    assert is_success(near_late, target)
    assert not is_success(near_early, target)
    assert not is_success(far, target)
    boundary = far.copy()
    boundary[-1] = [0.1, 0.05]
    assert is_success(boundary, target)            # "within 0.05": the boundary counts


def test_closest_object_looks_at_the_final_fifth_only():
    positions = np.array([[0.1, 0.0], [0.0, 0.15], [-0.1, 0.0]])
    path = np.tile([0.0, 0.0], (20, 1))
    path[:16] = [-0.1, 0.01]                       # sits on object 2, but only before the final fifth
    path[16:] = [0.0, 0.12]                        # then ends 0.03 m from object 1
    index, distance = closest_object(path, positions)
    assert index == 1 and distance == pytest.approx(0.03)


def test_step_api_reward_truncation_and_success_flag():
    world = ReachWorld()
    obs, info = world.reset(seed=0)
    assert set(obs) == {"image", "joint_angles", "joint_velocities", "end_effector"}
    assert obs["image"].shape == (32, 32, 3) and obs["image"].dtype == np.uint8
    for t in range(20):
        obs, reward, terminated, truncated, info = world.step(np.zeros(2))
        assert reward == pytest.approx(-np.linalg.norm(obs["end_effector"] - info["target_position"]))
        assert not terminated and truncated == (t == 19)
    assert info["success"] is False                  # a motionless arm does not reach
    with pytest.raises(RuntimeError, match="call reset"):
        world.step(np.zeros(2))


def test_bad_input_is_rejected_with_a_message_naming_the_fix():
    world = ReachWorld()
    with pytest.raises(RuntimeError, match="reset"):
        world.step(np.zeros(2))
    world.reset(seed=0)
    with pytest.raises(ValueError, match=r"\(2,\) joint torques"):
        world.step(np.zeros(3))
    with pytest.raises(ValueError, match="NaN"):
        world.step(np.array([np.nan, 0.0]))
    held = int(palette.split_colours("validation")[0])
    with pytest.raises(ValueError, match="not a 'train' colour"):
        world.reset(seed=0, options={"target_colour": held})
    with pytest.raises(ValueError, match="unknown colour split"):
        WorldConfig(split="heldout")                 # what the validation split was called; now unknown
    with pytest.raises(ValueError, match="out of range"):
        world.reset(options={"scene": Scene(colours=np.array([1, 2]), positions=np.zeros((2, 2)), target=2)})
    with pytest.raises(ValueError, match="min_separation"):
        WorldConfig(min_separation=0.09)



def test_bool_and_float_colours_and_sizes_are_refused_where_they_enter():
    """True was colour 1 and 5.0 "not a 'train' colour" though 5 is one; image_size=32.0 was taken. The
    world refuses them itself, not only behind the Gymnasium env."""
    for colour in (True, np.True_, False, 5.0, np.float64(5.0), "5"):
        one_line_error(lambda: palette.check_colour(colour, "train"), r"colour must be an int; .* "
                       r"choose one of oneshot.world.palette.split_colours\('train'\)")
        one_line_error(lambda: ReachWorld().reset(seed=0, options={"target_colour": colour}),
                       r"target_colour must be an int")
    palette.check_colour(np.int64(5), "train")                 # NumPy ints are palette indices
    for name, value in (("image_size", 32.0), ("horizon", True), ("n_objects", 3.0)):
        one_line_error(lambda: WorldConfig(**{name: value}), rf"{name} must be an int; got {value!r}")
    assert type(WorldConfig(image_size=np.int64(16)).image_size) is int     # a plain int, as JSON saves it


def test_hostile_scenes_are_refused_by_the_world_and_a_good_one_is_copied():
    """A NaN position made every reward NaN; float colours were a raw IndexError when drawn."""
    world = ReachWorld()
    check_hostile_scenes(world.reset, world.step)


def test_complex_or_non_numeric_actions_are_refused_not_truncated():
    """np.asarray(action, dtype=float) dropped a complex torque's imaginary part (with only a warning),
    read the string "0.1" as 0.1 and True as 1 N m."""
    world = ReachWorld()
    world.reset(seed=0)
    for action in (np.array([0.1 + 0.4j, 0.0]), [0.1j, 0], np.array(["0.1", "0.2"]), np.array([True, False])):
        one_line_error(lambda: world.step(action), r"action must be \(2,\) real joint torques in N m; got .* float array")
    assert world.t == 0                                        # nothing was applied
    for action in (np.array([0.1, -0.2], np.float32), np.array([0, 1]), [0.1, -0.2]):
        world.step(action)                                     # real torques of any real dtype still work
    assert world.t == 3

def test_heldout_world_uses_only_validation_colours():
    world = ReachWorld(dataclasses.replace(WorldConfig(), split="validation"))
    held = set(palette.split_colours("validation").tolist())
    for seed in range(20):
        _, info = world.reset(seed=seed)
        assert set(info["scene"].colours.tolist()) <= held


def test_writing_into_what_the_world_returns_changes_nothing_in_the_world():
    """info holds copies of the scene and target; obs's end effector is not the array success is judged on."""
    def run(vandal):
        world = ReachWorld()
        _, info = world.reset(seed=0)
        if vandal:
            info["target_position"][:] = 0.0
            info["scene"].positions[:] = 0.0
        for _ in range(world.config.horizon):
            obs, reward, _, _, info = world.step(np.array([0.3, -0.2]))
            if vandal:
                obs["end_effector"][:] = info["target_position"]      # would fake a success if aliased
        return world.scene.target_position.copy(), reward, info["success"]

    assert run(False)[1:] == run(True)[1:] and np.array_equal(run(False)[0], run(True)[0])
    assert run(True)[2] is False


def test_render_before_reset_says_what_to_do():
    with pytest.raises(RuntimeError, match=r"call reset\(\) before render\(\)"):
        ReachWorld().render()



@pytest.mark.parametrize("field, value, says", [
    ("success_radius", -0.05, "success_radius must be > 0 metres; got -0.05"),
    ("success_radius", float("nan"), "success_radius must be a finite number"),
    ("start_noise", -0.1, "start_noise must be >= 0 radians; got -0.1"),
    ("arena_half_width", -1, "arena_half_width must be"),
    ("object_radius", -0.1, "object_radius must be"),
    ("max_object_radius", 0.5, r"need 0.07 < 0.5 <= arena_half_width - object_radius = 0.195"),
    ("min_object_radius", 0.3, r"need 0.3 < 0.19"),
    ("n_objects", 0, "n_objects must be at least 1"),
    ("image_size", 10 ** 5, "image_size must be at most 1024"),
])
def test_a_world_config_that_cannot_make_a_sensible_world_is_refused(field, value, says):
    """Each was accepted (success made impossible, noise ignored, discs outside the arena) or failed
    later with a library's message (Pillow's, NumPy's), or hung (a 100000-pixel image)."""
    one_line_error(lambda: WorldConfig(**{field: value}), says)


def test_reset_options_are_a_dict_naming_one_target():
    world = ReachWorld(WorldConfig(split="validation"))
    scene = world.reset(seed=0)[1]["scene"]
    one_line_error(lambda: world.reset(seed=0, options="target_colour"), "reset options must be a dict")
    one_line_error(lambda: world.reset(seed=0, options={"target_color": 9}),     # was a random colour, unseen
                   r"unknown reset options \['target_color'\]; use \('target_colour', 'scene'\)")
    one_line_error(lambda: world.reset(seed=0, options={"scene": scene, "target_colour": 9}),
                   "'scene' and 'target_colour' both name the target: pass one of them")


@pytest.mark.parametrize("bad", [1.5, True, "3", -1])
def test_palette_names_only_palette_indices(bad):
    one_line_error(lambda: palette.colour_name(bad), r"colour must be an int; got .*; name a palette index in "
                                                     r"\[0, 72\)|colour -1 is not a palette index \(an int in \[0, 72\)\)")


@pytest.mark.parametrize("size", [0, 2.5])
def test_a_palette_of_no_hues_is_refused(size):
    one_line_error(lambda: palette.PaletteConfig(size=size), "palette needs whole numbers size >= 1|palette size must "
                                                             "be an int; got 2.5")
    assert type(palette.PaletteConfig(size=np.int64(48)).size) is int        # a plain int, as JSON saves it


def test_success_radius_is_0_05_m_a_point_just_beyond_it_fails():
    target = np.array([0.1, 0.0])
    far = np.tile([0.0, 0.15], (20, 1))
    beyond = far.copy()
    beyond[-1] = [0.1, 0.0501]                     # 0.0501 m away, in the final fifth
    assert not is_success(beyond, target)          # default radius is the paper's 0.05 (mutant W04: 0.06)
    assert not is_success(beyond, target, WorldConfig().success_radius)
    assert is_success(beyond, target, 0.06)        # ... and the radius argument is what decides
    within = far.copy()
    within[-1] = [0.1, 0.049]
    assert is_success(within, target)              # and not below 0.05 either


# --- added by the mutation audit of oneshot/world (each names the mutants it kills) ----------------------

PIXEL = 0.44 / 32                               # metres per pixel of the default 32x32 image


def test_render_puts_a_disc_and_the_arm_on_hand_computed_pixels():
    """Without world_to_pixels: a red disc centred on pixel (row 8, col 7) is the upper left (world y up),
    pure red there and black at its mirror image (row 23); antialiased (rim pixels between 0 and 255); of
    about pi r^2 pixels; both links of the arm drawn (white at each link's midpoint); and a disc drawn over
    the arm. Kills: y not flipped, radius halved, link 2 not drawn, nearest-neighbour shrinking instead of
    the box filter, the arm drawn over the discs."""
    centre = np.array([7.5 * PIXEL - 0.22, 0.22 - 8.5 * PIXEL])
    joints = np.array([[0.0, 0.0], [0.1, 0.0], [0.1, 0.11]])      # in the right half, far from the disc
    image = render(joints, centre[None], np.array([[255, 0, 0]], np.uint8), arena_half_width=0.22).astype(int)
    assert image[8, 7].tolist() == [255, 0, 0] and image[23, 7].tolist() == [0, 0, 0]
    disc = image[3:14, 2:13, 0]                                    # +-5 pixels around it
    assert image[3:14, 2:13, 1:].max() == 0 and np.any((disc > 0) & (disc < 255))
    area = disc.sum() / 255
    assert 1.0 < area / (np.pi * (0.025 / PIXEL) ** 2) < 1.25     # Pillow's ellipse: +20% at this size
    assert image[12, 23].min() > 100 and len(set(image[12, 23])) == 1          # link 2's midpoint (0.1, 0.055)
    assert image[15:17, 19].min(axis=1).max() > 100                            # link 1's midpoint (0.05, 0)
    on_arm = np.array([23.5 * PIXEL - 0.22, 0.22 - 12.5 * PIXEL])             # a disc over link 2 hides it
    image = render(joints, on_arm[None], np.array([[255, 0, 0]], np.uint8), arena_half_width=0.22)
    assert image[12, 23].tolist() == [255, 0, 0]


def test_the_world_draws_discs_at_its_configured_radius():
    """object_radius=0.035 gives a disc of about pi (0.035 m)^2, not the renderer's default 0.025 m. Kills:
    ReachWorld.render not passing cfg.object_radius."""
    world = ReachWorld(WorldConfig(object_radius=0.035, max_object_radius=0.18))
    centre = np.array([7.5 * PIXEL - 0.22, 0.22 - 23.5 * PIXEL])                # lower left, far from the arm
    obs, _ = world.reset(options={"scene": Scene(np.array([0]), centre[None], 0)})   # colour 0: (255, 0, 0)
    area = obs["image"][16:32, 0:16, 0].astype(int).sum() / 255
    assert 1.0 < area / (np.pi * (0.035 / PIXEL) ** 2) < 1.25, area


def test_success_and_closest_object_use_exactly_the_final_fifth():
    """A single near step at the first step of the final fifth counts (the 16th of 20, the 40th of 50), one
    step earlier does not; closest_object takes each object's minimum over that window, not its last or
    largest distance. Kills: a window of the last 3 (horizon // 5 - 1), max over the window."""
    target = np.array([0.1, 0.0])
    for T, window in ((20, 4), (50, 10)):
        path = np.tile([0.0, 0.15], (T, 1))
        path[-window] = target
        assert is_success(path, target)
        path = np.tile([0.0, 0.15], (T, 1))
        path[-window - 1] = target
        assert not is_success(path, target)
    positions = np.array([[0.1, 0.0], [0.0, 0.15], [-0.1, 0.0]])
    path = np.tile([-0.1, 0.1], (20, 1))                 # 0.1 m from objects 1 and 2 throughout
    path[-3] = [0.0, 0.16]                               # one step of the window 0.01 m from object 1
    index, distance = closest_object(path, positions)
    assert index == 1 and distance == pytest.approx(0.01)


def test_the_worlds_success_flag_is_raised_at_the_end_for_the_target_only():
    """The arm at rest stays at its start pose q0 = (0, pi/2): end effector (l1, l2) = (0.1, 0.11) (no gravity,
    no torque). With the target there (object 1, not object 0) success is False until step T and True at
    T; with a distractor there, False. Kills: success judged before the episode ends; success judged
    against object 0 instead of the target."""
    world = ReachWorld()
    start = np.array([0.1, 0.11])
    for target, expected in ((1, True), (0, False)):
        scene = Scene(np.array([8, 24, 40]), np.array([[-0.1, -0.1], start, [0.1, -0.15]]), target)
        world.reset(options={"scene": scene})
        flags = [world.step(np.zeros(2))[4]["success"] for _ in range(world.config.horizon)]
        assert flags == [False] * (world.config.horizon - 1) + [expected], target


def test_start_noise_moves_the_start_pose_and_pymunk_builds_the_arm_there():
    """With start_noise the start angles differ from q0 and from seed to seed, and the Pymunk links are
    built at them: the end effector is the forward kinematics of the joint angles and link 2 starts at link
    1's elbow. Kills: start_noise ignored; link 2 built at angle q2 instead of q1 + q2 (the same at q1 = 0)."""
    world = ReachWorld(WorldConfig(start_noise=0.3))
    cfg = world.config.arm
    starts = []
    for seed in range(3):
        obs, _ = world.reset(seed=seed)
        q = obs["joint_angles"]
        starts.append(q)
        assert np.abs(q - np.array(cfg.q0)).max() > 1e-3
        np.testing.assert_allclose(arm.forward_kinematics(q, cfg), obs["end_effector"], atol=1e-12)
        elbow = world._link2.local_to_world((-cfg.l2 / 2, 0))
        np.testing.assert_allclose([elbow.x, elbow.y], world.joints()[1], atol=1e-12)
    assert len({tuple(q) for q in starts}) == 3


def test_observation_state_is_angles_velocities_end_effector():
    """datasets.STATE_LAYOUT's order: the last two numbers are the forward kinematics of the first two.
    Kills: the end effector and velocities swapped."""
    world = ReachWorld()
    world.reset(seed=0)
    obs = world.step(np.array([0.4, -0.3]))[0]
    state = observation_state(obs)
    assert state.shape == (6,) and state.dtype == np.float32 and STATE_LAYOUT[4:] == ("end effector x", "end effector y")
    np.testing.assert_allclose(state[4:], arm.forward_kinematics(state[:2].astype(float), world.config.arm), atol=2e-3)
    np.testing.assert_allclose(state, np.concatenate([obs["joint_angles"], obs["joint_velocities"],
                                                      obs["end_effector"]]), rtol=1e-6)


def test_every_seed_gives_its_own_scene():
    """Twelve seeds, twelve scenes (not one per seed's parity). Kills: a seed partly ignored."""
    world = ReachWorld()
    scenes = {world.reset(seed=seed)[1]["scene"].positions.tobytes() for seed in range(12)}
    assert len(scenes) == 12


def test_sampled_discs_are_min_separation_apart_not_just_two_success_radii():
    """Pairwise > min_separation (0.12 m), which is what sample_positions promises. Kills: 2 * success_radius
    (0.10 m) used instead."""
    cfg = WorldConfig()
    rng = np.random.default_rng(1)
    for _ in range(100):
        p = sample_scene(5, rng, cfg).positions
        d = np.linalg.norm(p[:, None] - p[None], axis=-1)
        assert d[np.triu_indices(3, 1)].min() > cfg.min_separation


def test_a_given_scene_is_refused_outside_the_arena_or_the_palette_and_its_colours_copied():
    """A centre 0.23 m out (outside the arena, though within a disc radius of it) is refused, 0.22 m taken;
    colours 72 and -1 (not palette indices; -1 would draw the last colour) refused, 71 taken. Writing into
    the caller's colours afterwards changes nothing. Kills: the arena check loosened by the disc radius,
    colour n accepted, negative colours accepted, colours not copied."""
    world = ReachWorld()
    colours, positions = np.array([0, 16, 32]), np.array([[0.1, 0.0], [-0.1, 0.0], [0.0, 0.15]])
    edge = positions.copy()
    edge[2] = [0.0, 0.22]
    world.reset(options={"scene": Scene(colours, edge, 0)})
    edge[2] = [0.0, 0.23]
    one_line_error(lambda: world.reset(options={"scene": Scene(colours, edge, 0)}), "inside the arena")
    for bad in (72, -1):
        one_line_error(lambda: world.reset(options={"scene": Scene(np.array([0, 16, bad]), positions, 0)}),
                       r"palette indices in \[0, 72\)")
    mine = np.array([0, 16, 71])
    obs, _ = world.reset(options={"scene": Scene(mine, positions, 0)})
    mine[:] = 40
    assert world.scene.colours.tolist() == [0, 16, 71]
    assert np.array_equal(world.render(), obs["image"])
