"""The Gymnasium environment (oneshot.world.gym) and the world guards it relies on (oneshot.world.reach)."""
import subprocess
import sys
import warnings

import numpy as np
import pytest

from oneshot.world import arm
from oneshot.world.reach import ReachWorld, Scene, is_success

gymnasium = pytest.importorskip("gymnasium")    # the optional extra: pip install ".[gym]"
from gymnasium.utils.env_checker import check_env

from oneshot.world.gym import ENV_ID, ReachEnv


def reach_torque(obs, q_goal):
    """A PD controller on the joint angles that reaches the target (independent of the expert)."""
    return np.clip(2.0 * (q_goal - obs["joint_angles"]) - 0.15 * obs["joint_velocities"], -0.5, 0.5)


@pytest.mark.parametrize("kwargs", [{}, {"split": "heldout", "palette_mode": "grid", "image_size": 64,
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
    env = gymnasium.make(ENV_ID, split="heldout", target_colour=8, image_size=64, horizon=10)
    obs, info = env.reset(seed=0)
    assert env.unwrapped.world.config.split == "heldout" and env.unwrapped.world.config.horizon == 10
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


def test_the_observation_is_the_worlds_for_the_same_scene():
    env = ReachEnv(target_colour=5)
    obs, info = env.reset(seed=3)
    scene = Scene(info["object_colours"], info["object_positions"],
                  int(np.flatnonzero(info["object_colours"] == info["target_colour"])[0]))
    world = ReachWorld()
    world_obs, _ = world.reset(options={"scene": scene})
    actions = np.random.default_rng(0).uniform(-0.5, 0.5, (20, 2))
    for a in actions:
        assert all(np.array_equal(obs[k], world_obs[k]) and obs[k].dtype == world_obs[k].dtype for k in obs)
        assert obs in env.observation_space
        obs, reward, *_ = env.step(a)
        world_obs, world_reward, *_ = world.step(a)
        assert reward == world_reward


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


def test_render_before_reset_raises_and_rgb_array_renders_the_observation():
    with pytest.raises(RuntimeError, match=r"call reset\(\) before render\(\)"):
        ReachWorld().render()
    env = ReachEnv(render_mode="rgb_array", image_size=64)
    with pytest.raises(RuntimeError, match=r"call reset\(\) before render\(\)"):
        env.render()
    obs, _ = env.reset(seed=1)
    obs, *_ = env.step(np.array([0.5, 0.5]))
    frame = env.render()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8
    assert np.array_equal(frame, obs["image"])
    no_render = ReachEnv()
    no_render.reset(seed=1)
    assert no_render.render() is None
    env.close()
    env.close()      # closing twice is allowed


def test_bad_arguments_are_rejected_with_a_message_naming_the_fix():
    with pytest.raises(ValueError, match="render_mode must be None or one of"):
        ReachEnv(render_mode="human")
    with pytest.raises(ValueError, match="choose a palette index from"):
        ReachEnv(split="heldout", target_colour=1)       # hue 1 is a training colour
    with pytest.raises(ValueError, match="unknown reset options"):
        ReachEnv().reset(options={"colour": 5})


def test_without_gymnasium_the_import_error_says_how_to_install_it():
    code = "import sys; sys.modules['gymnasium'] = None; import oneshot.world.gym"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode != 0
    assert 'ImportError: oneshot.world.gym needs Gymnasium; install the extra: pip install ".[gym]"' in result.stderr
