"""The Gymnasium environment (oneshot.world.gym): Gymnasium's conventions (registration, make, make_vec,
check_env, seeding, TimeLimit), the goal in the observation, what render() shows, and hostile inputs."""
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import oneshot
from helpers import check_hostile_scenes, one_line_error
from oneshot.expert.controller import feedback_torque, plan
from oneshot.world import arm, palette, render
from oneshot.world.reach import ReachWorld, WorldConfig, is_success
from oneshot.world.scene import Scene

gymnasium = pytest.importorskip("gymnasium")    # the optional extra: pip install ".[gym]"
from gymnasium.utils.env_checker import check_env

from oneshot.world.gym import ENV_ID, RENDER_SCALE, ReachEnv, state_bounds

CHECKOUT = str(Path(oneshot.__file__).resolve().parent.parent)   # where this test imports oneshot from
WORLD_KEYS = ("image", "joint_angles", "joint_velocities", "end_effector")


def python(code):
    """Run `code` in a fresh interpreter that finds this checkout's oneshot; returns the CompletedProcess."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (CHECKOUT, os.environ.get("PYTHONPATH")) if p))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=CHECKOUT)


def reach_torque(obs, q_goal):
    """A PD controller on the joint angles that reaches the target (independent of the expert)."""
    return np.clip(2.0 * (q_goal - obs["joint_angles"]) - 0.15 * obs["joint_velocities"], -0.5, 0.5)


@pytest.mark.parametrize("kwargs", [{}, {"split": "validation", "palette_mode": "grid", "image_size": 64,
                                         "horizon": 10, "render_mode": "rgb_array"}])
def test_check_env_passes_without_a_single_warning(kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # any Gymnasium warning fails the test
        env = gymnasium.make(ENV_ID, **kwargs)
        check_env(env.unwrapped)
        env.reset(seed=0)
        env.step(env.action_space.sample())     # through make's checking wrappers too
    assert isinstance(env.unwrapped, ReachEnv)


def test_make_passes_its_arguments_to_the_world():
    env = gymnasium.make(ENV_ID, split="validation", target_colour=8, image_size=64, horizon=10)
    obs, info = env.reset(seed=0)
    assert env.unwrapped.world.config.split == "validation" and env.unwrapped.world.config.horizon == 10
    assert obs["image"].shape == (64, 64, 3) and info["target_colour"] == 8
    assert env.observation_space["image"].shape == (64, 64, 3)
    assert env.action_space.low.tolist() == [-0.5, -0.5] and env.action_space.high.tolist() == [0.5, 0.5]
    _, info = env.reset(options={"target_colour": 20})       # options override the constructor
    assert info["target_colour"] == 20


def test_seeding_is_gymnasiums_same_seed_same_scene_then_the_same_stream():
    def episode_starts(seed):
        env = ReachEnv()
        first = env.reset(seed=seed)
        return first, env.reset()                  # no seed: continues env.np_random's stream

    (o1, i1), (o2, i2) = episode_starts(7)
    (p1, j1), (p2, j2) = episode_starts(7)
    for a, b in ((o1, p1), (o2, p2)):
        assert all(np.array_equal(a[k], b[k]) for k in a)
    assert np.array_equal(i1["object_positions"], j1["object_positions"])
    assert np.array_equal(i2["object_positions"], j2["object_positions"])
    assert not np.array_equal(i1["object_positions"], i2["object_positions"])   # a new scene
    (q1, k1), _ = episode_starts(8)
    assert not np.array_equal(i1["object_positions"], k1["object_positions"])


def test_an_episode_truncates_at_the_horizon_and_reports_the_papers_success():
    env = ReachEnv()
    for policy, expected in (("reach", True), ("still", False)):
        obs, info = env.reset(seed=0)
        q_goal = arm.inverse_kinematics(info["target_position"], obs["joint_angles"], env.world.config.arm)
        trail = []
        for t in range(20):
            action = reach_torque(obs, q_goal) if policy == "reach" else np.zeros(2)
            obs, reward, terminated, truncated, info = env.step(action)
            trail.append(obs["end_effector"])
            assert terminated is False and truncated is (t == 19)
            assert reward == pytest.approx(-np.linalg.norm(obs["end_effector"] - info["target_position"]))
            assert type(info["success"]) is bool
        assert info["success"] is expected is is_success(np.array(trail), info["target_position"])
        with pytest.raises(RuntimeError, match="call reset"):
            env.step(np.zeros(2))


def test_the_observation_is_the_worlds_for_the_same_scene_plus_the_goal():
    env = ReachEnv(target_colour=5)
    obs, info = env.reset(seed=3)
    scene = Scene(info["object_colours"], info["object_positions"],
                  int(np.flatnonzero(info["object_colours"] == info["target_colour"])[0]))
    world = ReachWorld()
    world_obs, _ = world.reset(options={"scene": scene})
    actions = np.random.default_rng(0).uniform(-0.5, 0.5, (20, 2))
    for a in actions:
        assert set(obs) == set(WORLD_KEYS) | {"target_rgb"}
        assert all(np.array_equal(obs[k], world_obs[k]) and obs[k].dtype == world_obs[k].dtype for k in WORLD_KEYS)
        assert obs["target_rgb"].tolist() == palette.palette_rgb()[5].tolist()
        assert obs in env.observation_space
        obs, reward, *_ = env.step(a)
        world_obs, world_reward, *_ = world.step(a)
        assert reward == world_reward


def test_the_goal_in_the_observation_names_the_disc_to_reach_in_the_image():
    """With a random target per episode, obs["target_rgb"] is the colour of the image's pixel at the
    target's centre, and of no other disc's: an agent can tell from the observation which disc to reach."""
    env = gymnasium.make(ENV_ID)                       # target_colour=None: a random colour per episode
    space = env.observation_space["target_rgb"]
    assert isinstance(space, gymnasium.spaces.Box) and space.shape == (3,) and space.dtype == np.uint8
    goals = set()
    for seed in range(6):
        obs, info = env.reset(seed=seed)
        centres = np.round(render.world_to_pixels(info["object_positions"], 0.22, 32) - 0.5).astype(int)
        shown = [tuple(obs["image"][y, x]) for x, y in centres]               # each disc's centre pixel
        target = int(np.flatnonzero(info["object_colours"] == info["target_colour"])[0])
        assert [c == tuple(obs["target_rgb"]) for c in shown] == [i == target for i in range(len(shown))]
        goals.add(tuple(obs["target_rgb"]))
    assert len(goals) > 3                              # the goal changes from episode to episode


def test_observations_stay_in_the_space_under_torques_that_pump_in_energy():
    env = ReachEnv()
    fastest = 0.0
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        for _ in range(20):
            # max torque along the joint velocity: the most power the bound allows
            obs, *_ = env.step(0.5 * np.sign(obs["joint_velocities"] + 1e-9))
            assert obs in env.observation_space
            fastest = max(fastest, np.abs(obs["joint_velocities"]).max())
    assert fastest > 20        # the arm really went fast, so the bounds were tested


def test_writing_into_info_or_obs_changes_nothing_in_the_env():
    """(The world itself: tests/test_world.py.)"""
    env = ReachEnv()
    for vandal in (False, True):
        _, info = env.reset(seed=0)
        for _ in range(20):
            obs, _, _, _, info = env.step(np.zeros(2))
            if vandal:     # the world keeps end effectors for the success test; these are copies
                obs["end_effector"][:] = info["target_position"]
                info["target_position"][:] = obs["end_effector"]
        assert info["success"] is False


def test_render_before_reset_raises_and_rgb_array_marks_the_target_base_and_hand():
    with pytest.raises(RuntimeError, match=r"call reset\(\) before render\(\)"):
        ReachWorld().render()
    env = ReachEnv(render_mode="rgb_array", image_size=64)
    with pytest.raises(RuntimeError, match=r"call reset\(\) before render\(\)"):
        env.render()
    obs, info = env.reset(seed=1)
    for _ in range(3):
        obs, *_ = env.step(np.array([0.5, 0.5]))
    frame, s = env.render(), RENDER_SCALE
    assert frame.shape == (64 * s, 64 * s, 3) and frame.dtype == np.uint8
    plain = np.repeat(np.repeat(obs["image"], s, axis=0), s, axis=1)      # the observation, enlarged
    marked = (frame != plain).any(axis=-1)
    assert (frame[marked] == 255).all()                                    # marks are white, drawn over it
    ys, xs = np.nonzero(marked)
    pixels = np.stack([xs + 0.5, ys + 0.5], -1) / s                        # in the observation's pixels

    def near(point_m, radius_px):
        return np.linalg.norm(pixels - render.world_to_pixels(point_m, 0.22, 64), axis=-1) <= radius_px

    ring_r = 2 * 0.025 * 64 / 0.44                                          # twice the disc's radius, 7.3 px
    ring = near(info["target_position"], ring_r + 0.5) & ~near(info["target_position"], ring_r - 1)
    base, hand = near(np.zeros(2), 2.5), near(obs["end_effector"], 3.0)
    assert ring.sum() > 100 and base.sum() > 10 and hand.sum() > 10        # each mark is there ...
    assert (ring | base | hand).all()                                      # ... and nothing else
    no_render = ReachEnv()
    no_render.reset(seed=1)
    assert no_render.render() is None
    env.close()
    env.close()      # closing twice is allowed


def test_bad_arguments_are_rejected_with_a_message_naming_the_fix():
    with pytest.raises(ValueError, match="render_mode must be None or one of"):
        ReachEnv(render_mode="human")
    with pytest.raises(ValueError, match="choose a palette index from"):
        ReachEnv(split="validation", target_colour=1)       # hue 1 is a training colour
    with pytest.raises(ValueError, match="unknown reset options"):
        ReachEnv().reset(options={"colour": 5})


def test_without_gymnasium_the_import_error_says_how_to_install_it():
    result = python("import sys; sys.modules['gymnasium'] = None; import oneshot.world.gym")
    assert result.returncode != 0
    assert 'ImportError: oneshot.world.gym needs Gymnasium; install the extra: pip install ".[gym]"' in result.stderr


def test_import_oneshot_registers_the_env_and_make_imports_oneshot_itself():
    """Gymnasium's conventions, each in a fresh interpreter: make("oneshot/Reach-v0") after `import
    oneshot` alone (as docs/world.md writes it), and make("oneshot:oneshot/Reach-v0") with no import."""
    after_import = python(
        "import sys, gymnasium, oneshot\n"
        "assert 'oneshot.world.gym' not in sys.modules       # registration imports nothing of the env\n"
        f"env = gymnasium.make({ENV_ID!r}, target_colour=9)\n"
        "print(env.reset(seed=0)[1]['target_colour'], type(env.unwrapped).__module__)")
    assert after_import.returncode == 0, after_import.stderr
    assert after_import.stdout.split() == ["9", "oneshot.world.gym"]
    without_import = python(
        "import sys, gymnasium\n"
        "assert 'oneshot' not in sys.modules\n"
        f"env = gymnasium.make('oneshot:{ENV_ID}')\n"
        "print(env.spec.id, env.spec.max_episode_steps, sorted(env.reset(seed=0)[0]))")
    assert without_import.returncode == 0, without_import.stderr
    assert without_import.stdout.startswith(f"{ENV_ID} None ['end_effector', 'image', 'joint_angles',")


@pytest.mark.parametrize("horizon", [20, 10, 30])
def test_an_episode_of_any_horizon_runs_to_its_end_where_the_env_judges_success(horizon):
    """No TimeLimit is registered: one of 20 ended a 30-step episode at step 20, before the env judged
    success, so even the expert's episode reported failure."""
    assert gymnasium.spec(ENV_ID).max_episode_steps is None and WorldConfig().horizon == 20
    env = gymnasium.make(ENV_ID, **({} if horizon == 20 else {"horizon": horizon}))
    world = env.unwrapped.world
    assert world.config.horizon == horizon
    for motionless in (True, False):
        _, info = env.reset(seed=1)
        expert = plan(world.state, info["target_position"], world.config.arm, horizon)
        for t in range(horizon):
            action = np.zeros(2) if motionless else feedback_torque(expert, t, world.state, world.config.arm)
            _, _, terminated, truncated, info = env.step(action)
            assert terminated is False and truncated is (t == horizon - 1)
        assert info["success"] is not motionless       # judged at the last step: the expert reaches
        assert world.t == horizon                      # the env itself ended the episode there


@pytest.mark.parametrize("mode", ["vector_entry_point", "sync", "async"])
def test_make_vec_steps_the_same_episodes_as_single_envs(mode):
    """Every vectorization mode: env i is reset with seed + i (Gymnasium's rule), so it shows the scene a
    single ReachEnv shows for that seed; all truncate together at the horizon, and reset next step."""
    envs = gymnasium.make_vec(ENV_ID, num_envs=2, vectorization_mode=mode)
    try:
        assert envs.spec.kwargs["vectorization_mode"] == mode
        obs, info = envs.reset(seed=3)
        assert obs in envs.observation_space and obs["target_rgb"].shape == (2, 3)
        actions = np.random.default_rng(0).uniform(-0.5, 0.5, (20, 2, 2))
        singles = [ReachEnv() for _ in range(2)]
        for i, single in enumerate(singles):
            single_obs, single_info = single.reset(seed=3 + i)
            assert all(np.array_equal(obs[k][i], single_obs[k]) for k in single_obs)
            assert info["target_colour"][i] == single_info["target_colour"]
        for t in range(20):
            obs, reward, terminated, truncated, info = envs.step(actions[t])
            expected = [single.step(actions[t, i]) for i, single in enumerate(singles)]
            assert reward.tolist() == [e[1] for e in expected]
            assert truncated.tolist() == [t == 19] * 2 and not terminated.any()
        assert info["success"].tolist() == [e[4]["success"] for e in expected]
        envs.step(actions[0])                          # Gymnasium's next-step autoreset: a new episode
        assert envs.step(actions[0])[3].tolist() == [False, False]
    finally:
        envs.close()


def test_the_vector_entry_point_refuses_a_timelimit_other_than_the_horizon():
    with pytest.raises(ValueError, match=r"max_episode_steps \(20\) must equal the horizon \(10\).*"
                                         r"leave it out \(horizon=10 alone is enough\)"):
        gymnasium.make_vec(ENV_ID, num_envs=2, horizon=10, max_episode_steps=20)
    envs = gymnasium.make_vec(ENV_ID, num_envs=2, horizon=10, max_episode_steps=10)
    envs.reset(seed=0)
    assert [envs.step(np.zeros((2, 2)))[3].any() for _ in range(10)] == [False] * 9 + [True]


def test_hostile_scenes_are_refused_naming_the_option_and_the_fix():
    """A NaN position once made every reward NaN; float colours were a raw IndexError."""
    env = ReachEnv()
    check_hostile_scenes(env.reset, env.step)


def test_bool_and_float_target_colours_are_refused_not_read_as_indices():
    """target_colour=True was colour 1; 5.0 said "not a 'train' colour" though 5 is one."""
    for colour in (True, np.True_, False, 5.0, np.float64(5.0), "5"):
        one_line_error(lambda: ReachEnv(target_colour=colour),
                        r"target_colour must be an int; .* choose one of oneshot.world.palette.split_colours\('train'\)")
        one_line_error(lambda: ReachEnv().reset(options={"target_colour": colour}), r"target_colour must be an int")
    assert ReachEnv(target_colour=np.int64(5)).reset(seed=0)[1]["target_colour"] == 5
    for name, value in (("image_size", 32.0), ("horizon", True)):
        one_line_error(lambda: ReachEnv(**{name: value}), rf"{name} must be an int")



def test_a_reset_checks_its_target_colour_once(monkeypatch):
    """The world checks the colour it is given; the env no longer checks it a second time first."""
    calls, check = [], palette.check_colour
    monkeypatch.setattr(palette, "check_colour", lambda *a, **k: calls.append(a[0]) or check(*a, **k))
    env = ReachEnv()
    env.reset(seed=0, options={"target_colour": 5})
    assert calls == [5]

def test_complex_or_non_numeric_actions_are_refused_not_truncated():
    env = ReachEnv()
    env.reset(seed=0)
    for action in (np.array([0.1 + 0.4j, 0.0]), [0.1j, 0], np.array(["0.1", "0.2"]), np.array([True, False])):
        one_line_error(lambda: env.step(action), r"action must be \(2,\) real joint torques in N m; got .* float array")
    assert env.world.t == 0                            # nothing was applied
    for action in (np.array([0.1, -0.2], np.float32), np.array([0, 1]), [0.1, -0.2]):
        env.step(action)                               # real torques of any real dtype still work
    assert env.world.t == 3


def test_images_are_writable_and_a_non_real_action_is_refused_in_its_own_words():
    """np.asarray of a Pillow image is read-only: in-place preprocessing of obs["image"] raised."""
    env = ReachEnv(render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    for image in (obs["image"], env.step(np.zeros(2))[0]["image"], env.render()):
        image[:] = 0                                   # raised "assignment destination is read-only"
    with pytest.raises(ValueError, match=r"got bool \[True, False\]; pass a float array$"):
        env.step(np.array([True, False]))
    with pytest.raises(ValueError, match=r"pass a float array \(np.real\(action\) drops an imaginary part\)"):
        env.step(np.array([1j, 0]))


def test_the_state_bounds_come_from_the_smallest_eigenvalue_of_the_mass_matrix():
    """state_bounds by its docstring's argument, with lambda_min found here by np.linalg.eigvalsh of the
    mass matrix (the inverse of the dynamics' own M^-1) over elbow angles: |qd| <= |u| t / lambda_min and
    |q| <= |q0| + 8 start_noise + |u| t^2 / (2 lambda_min), |u| = sqrt(2) max_torque, t = T dt. For the
    default arm, the docstring's 744 rad/s and pi/2 + 372 rad."""
    for config in (WorldConfig(), WorldConfig(horizon=10, start_noise=0.05, arm=arm.ArmConfig(m2=0.3, max_torque=0.8))):
        a = config.arm
        lam = min(np.linalg.eigvalsh(np.linalg.inv(np.array([[i11, i12], [i12, i22]]))).min()
                  for i11, i12, i22 in zip(*arm._inverse_mass(np.cos(np.linspace(0, np.pi, 181)), a)))
        u, t = np.sqrt(2) * a.max_torque, config.horizon * a.dt
        angle, velocity = state_bounds(config)
        assert velocity == pytest.approx(u * t / lam, rel=1e-4)
        assert angle == pytest.approx(max(np.abs(a.q0)) + 8 * config.start_noise + u * t ** 2 / (2 * lam), rel=1e-4)
    angle, velocity = state_bounds(WorldConfig())
    assert round(velocity) == 744 and angle - np.pi / 2 == pytest.approx(372, abs=0.5)
