"""The reaching world as a Gymnasium environment, `oneshot/Reach-v0` (optional extra: pip install ".[gym]").

`oneshot.world.reach.ReachWorld` already follows Gymnasium's API; this module makes it a real
`gymnasium.Env`, with spaces, Gymnasium's seeding (`np_random`), `render_mode`, a vector entry point,
and a goal in the observation, so RL libraries and Gymnasium's tools (`check_env`, `make`, `make_vec`,
wrappers) accept it. `import oneshot` registers it (`oneshot/__init__.py`), as Gymnasium's conventions
ask:

    import gymnasium
    import oneshot                                 # registers oneshot/Reach-v0
    env = gymnasium.make("oneshot/Reach-v0", render_mode="rgb_array")    # a random target per episode
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    envs = gymnasium.make_vec("oneshot/Reach-v0", num_envs=4)           # `vector_env`

`gymnasium.make("oneshot:oneshot/Reach-v0")` imports `oneshot` itself.

Observation: a dict, the world's "image" (H, W, 3) uint8, "joint_angles" (2,) rad, "joint_velocities"
(2,) rad/s, "end_effector" (2,) m (float64), and the goal, "target_rgb" (3,) uint8: the target disc's
colour, the task (paper Section IV). With a random target colour per episode the image alone does not
say which disc to reach; the goal does, as in Gymnasium-Robotics' goal-conditioned environments. It is
not their `desired_goal`: the goal is a colour, not a place the arm can be compared with.
Action: (2,) joint torques in N m, float64, within +-0.5 N m (real numbers; larger ones are clipped).
Reward: minus the end-effector-to-target distance in metres. An episode never terminates; it truncates
after `horizon` steps (20 unless `horizon=T`; no TimeLimit is registered), when info["success"] tells
whether the end effector reached the target (paper Section IV).
info: "success" bool, "target_colour" int (palette index), "target_position" (2,) m, "object_colours"
(n,), "object_positions" (n, 2) m: plain values and fresh arrays, so Gymnasium can compare and stack them.
"""
try:
    import gymnasium
    from gymnasium import spaces
except ImportError as error:
    raise ImportError('oneshot.world.gym needs Gymnasium; install the extra: pip install ".[gym]"') from error
import functools

import numpy as np

from oneshot import GYM_ENV_ID as ENV_ID  # noqa: F401 (re-exported: the id, here too)
from oneshot.tools import viz
from oneshot.tools.checks import whole_number
from oneshot.world import palette, render
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import ReachWorld, WorldConfig

RENDER_SCALE = 4          # render() shows each image pixel as a 4x4 block: 128x128 for 32x32 images


def state_bounds(config):
    """Bounds that |joint angle| (rad) and |joint velocity| (rad/s) cannot exceed within an episode.

    Gymnasium's checker rejects infinite Box bounds, and the arm's angles are not wrapped, so the
    bounds come from energy: the torque u does work u . qd <= |u| |qd| (damping only removes energy),
    and the kinetic energy E = 1/2 qd^T M qd >= 1/2 lambda_min |qd|^2, with lambda_min the smallest
    eigenvalue of M(q2) over all elbow angles. Together, after t seconds
        |qd| <= |u| t / lambda_min,     |q - q0| <= |u| t^2 / (2 lambda_min),
    with |u| = sqrt(2) max_torque and t = horizon * dt. For the default arm: 744 rad/s and
    pi/2 + 372 rad, about 18x what torques that pump energy in reach in Pymunk (41 rad/s, 20 rad),
    so Pymunk's small integration error cannot cross them. Returns (angle bound, velocity bound).
    """
    arm = config.arm
    a, d, h = arm.mass_coefficients
    c = np.cos(np.linspace(0, np.pi, 1001))                   # cos q2 over every elbow angle
    trace, det = a + d + 2 * h * c, d * (a - d) - (h * c) ** 2
    lambda_min = np.min((trace - np.sqrt(trace ** 2 - 4 * det)) / 2)
    u, t = np.sqrt(2) * arm.max_torque, config.horizon * arm.dt
    # start_noise draws q0 from a Gaussian: 8 standard deviations are never exceeded in practice.
    start = np.max(np.abs(arm.q0)) + 8 * config.start_noise
    return start + u * t ** 2 / (2 * lambda_min), u * t / lambda_min


def vector_env(num_envs=1, max_episode_steps=None, **kwargs):
    """Gymnasium's vector entry point (make_vec's default mode, "vector_entry_point"): `num_envs`
    ReachEnvs built with `kwargs`, stepped one after another by a `gymnasium.vector.SyncVectorEnv`
    (each world is its own Pymunk space, so there is nothing to batch). A max_episode_steps given to
    make_vec must equal the horizon, where the env truncates itself.
    """
    num_envs = whole_number("num_envs", num_envs, "pass a positive number of environments")
    if num_envs < 1:
        raise ValueError(f"num_envs must be at least 1; got {num_envs}")
    horizon = kwargs.get("horizon", WorldConfig().horizon)
    if max_episode_steps is not None and max_episode_steps != horizon:
        raise ValueError(f"max_episode_steps ({max_episode_steps}) must equal the horizon ({horizon}), where the "
                         f"env truncates itself; leave it out (horizon={horizon} alone is enough)")
    return gymnasium.vector.SyncVectorEnv([functools.partial(ReachEnv, **kwargs)] * num_envs)


class ReachEnv(gymnasium.Env):
    """Reach the disc of one colour among distractors with a planar 2-link arm (paper Section IV).

    split: which colours scenes are drawn from, "train", "validation" or "test"; palette_mode: "hues"
    (72 colours) or "grid" (696; `oneshot.world.palette`); image_size: H = W in pixels; horizon: T, steps per
    episode, after which the env truncates itself and judges success (no TimeLimit is registered: a
    `make(..., max_episode_steps=K)` below T would end episodes before that); target_colour: a palette index of the split that every episode uses, or None for a
    random colour per episode; render_mode: None or "rgb_array".
    """
    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}   # 20 fps: one frame per 0.05 s step

    def __init__(self, split="train", palette_mode="hues", image_size=32, horizon=20,
                 target_colour=None, render_mode=None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}; "
                             f"got {render_mode!r}")
        config = WorldConfig(palette=PaletteConfig(mode=palette_mode), split=split,
                             image_size=image_size, horizon=horizon)         # checks that both are ints
        if target_colour is not None:           # every episode's, so refused now, not at the first reset
            palette.check_colour(target_colour, split, config.palette, name="target_colour")
            target_colour = int(target_colour)
        self.world = ReachWorld(config)
        self.target_colour = target_colour
        self.render_mode = render_mode

        max_angle, max_velocity = state_bounds(config)
        arena = config.arena_half_width
        self.observation_space = spaces.Dict({
            "image": spaces.Box(0, 255, (config.image_size, config.image_size, 3), np.uint8),
            "joint_angles": spaces.Box(-max_angle, max_angle, (2,), np.float64),
            "joint_velocities": spaces.Box(-max_velocity, max_velocity, (2,), np.float64),
            "end_effector": spaces.Box(-arena, arena, (2,), np.float64),
            "target_rgb": spaces.Box(0, 255, (3,), np.uint8),
        })
        torque = config.arm.max_torque
        self.action_space = spaces.Box(-torque, torque, (2,), np.float64)

    def reset(self, *, seed=None, options=None):
        """Start an episode in a new scene. options: {"target_colour": palette index} (this episode's
        task, overriding the constructor's) or {"scene": oneshot.world.scene.Scene}. Returns (obs, info).

        The world's seed is drawn from `self.np_random`, so seeding follows Gymnasium: reset(seed=s)
        gives the same scene every time, and later resets without a seed continue that stream.
        """
        super().reset(seed=seed)
        options = {} if options is None else dict(options) if isinstance(options, dict) else options  # the world
        # checks what it is, and the scene or target colour (it copies the scene), as for any caller
        if isinstance(options, dict) and "scene" not in options and options.get("target_colour") is None:
            options["target_colour"] = self.target_colour
        world_seed = int(self.np_random.integers(2 ** 63))
        obs, info = self.world.reset(seed=world_seed, options=options)
        return self._observation(obs), self._info(info)

    def step(self, action):
        """Apply joint torques for one 0.05 s step. action: (2,) real, N m (clipped to +-max_torque).

        Returns (obs, reward, terminated, truncated, info): terminated is always False; truncated is
        True after `horizon` steps, and then info["success"] is the episode's outcome.
        """
        obs, reward, terminated, truncated, info = self.world.step(action)
        return self._observation(obs), reward, terminated, truncated, self._info(info)

    def render(self):
        """What a person watching sees, if render_mode is "rgb_array": the image enlarged RENDER_SCALE
        times, (4 H, 4 W, 3) uint8, with the target ringed and the arm's base (a square) and hand (a
        circle) marked (`oneshot.tools.viz.marked_frame`); None otherwise. The observation's image stays
        unmarked: it is what a policy sees."""
        if self.render_mode != "rgb_array":
            return None
        image, cfg = self.world.render(), self.world.config      # render() first: it asks for reset()
        base, _, hand = render.world_to_pixels(self.world.joints(), cfg.arena_half_width, cfg.image_size)
        target = render.world_to_pixels(self.world.scene.target_position, cfg.arena_half_width, cfg.image_size)
        frame = viz.marked_frame(image, RENDER_SCALE, target, viz.ring_radius(cfg), hand=hand, base=base)
        return np.array(frame)                                   # writable, as the observation's image is

    def close(self):
        """Nothing to release: the world holds only a Pymunk space in memory, no window or file."""

    def _observation(self, obs):
        # The world also keeps obs["end_effector"] in its success history; hand out a copy so that
        # writing into the observation cannot change the episode's outcome.
        return {**obs, "end_effector": obs["end_effector"].copy(),
                "target_rgb": self.world._rgb[self.world.scene.target_colour].copy()}   # the world's palette

    @staticmethod
    def _info(info):
        scene = info["scene"]       # the world's info already holds copies
        return {"success": info["success"], "target_colour": scene.target_colour,
                "target_position": info["target_position"],
                "object_colours": scene.colours, "object_positions": scene.positions}
