"""The reaching world as a Gymnasium environment, `oneshot/Reach-v0` (optional extra: pip install ".[gym]").

`oneshot.world.reach.ReachWorld` already follows Gymnasium's API; this module makes it a real
`gymnasium.Env`, with spaces, Gymnasium's seeding (`np_random`), `render_mode` and registration, so
RL libraries and Gymnasium's tools (`check_env`, `gymnasium.make`, wrappers) accept it:

    import gymnasium
    import oneshot.world.gym                       # registers oneshot/Reach-v0
    env = gymnasium.make("oneshot/Reach-v0", target_colour=5, render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

`gymnasium.make("oneshot.world.gym:oneshot/Reach-v0")` imports the module itself.

Observation: a dict, exactly the world's: "image" (H, W, 3) uint8, "joint_angles" (2,) rad,
"joint_velocities" (2,) rad/s, "end_effector" (2,) m, all float64 but the image.
Action: (2,) joint torques in N m, float64, within +-0.5 N m. Reward: minus the end-effector-to-target
distance in metres. An episode never terminates; it truncates after `horizon` steps (20), when
info["success"] tells whether the end effector reached the target (paper Section IV).
info: "success" bool, "target_colour" int, "target_position" (2,) m, "object_colours" (n,),
"object_positions" (n, 2) m: plain values and fresh arrays, so Gymnasium can compare and stack them.
"""
try:
    import gymnasium
    from gymnasium import spaces
except ImportError as error:
    raise ImportError('oneshot.world.gym needs Gymnasium; install the extra: pip install ".[gym]"') from error
import numpy as np

from oneshot.world import palette
from oneshot.world.palette import PaletteConfig
from oneshot.world.reach import ReachWorld, WorldConfig

ENV_ID = "oneshot/Reach-v0"
OPTIONS = ("target_colour", "scene")


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


class ReachEnv(gymnasium.Env):
    """Reach the disc of one colour among distractors with a planar 2-link arm (paper Section IV).

    split: which colours scenes are drawn from, "train" or "heldout"; palette_mode: "hues" (48
    colours) or "grid" (648; `oneshot.world.palette`); image_size: H = W in pixels; horizon: T, steps per
    episode; target_colour: a palette index of the split that every episode uses, or None for a
    random colour per episode; render_mode: None or "rgb_array".
    """
    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}   # 20 fps: one frame per 0.05 s step

    def __init__(self, split="train", palette_mode="hues", image_size=32, horizon=20,
                 target_colour=None, render_mode=None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}; "
                             f"got {render_mode!r}")
        config = WorldConfig(palette=PaletteConfig(mode=palette_mode), split=split,
                             image_size=image_size, horizon=horizon)
        if target_colour is not None:
            palette.check_colour(target_colour, split, config.palette)
        self.world = ReachWorld(config)
        self.target_colour = target_colour
        self.render_mode = render_mode

        max_angle, max_velocity = state_bounds(config)
        arena = config.arena_half_width
        self.observation_space = spaces.Dict({
            "image": spaces.Box(0, 255, (image_size, image_size, 3), np.uint8),
            "joint_angles": spaces.Box(-max_angle, max_angle, (2,), np.float64),
            "joint_velocities": spaces.Box(-max_velocity, max_velocity, (2,), np.float64),
            "end_effector": spaces.Box(-arena, arena, (2,), np.float64),
        })
        torque = config.arm.max_torque
        self.action_space = spaces.Box(-torque, torque, (2,), np.float64)

    def reset(self, *, seed=None, options=None):
        """Start an episode in a new scene. options: {"target_colour": palette index} (this episode's
        task, overriding the constructor's) or {"scene": oneshot.world.reach.Scene}. Returns (obs, info).

        The world's seed is drawn from `self.np_random`, so seeding follows Gymnasium: reset(seed=s)
        gives the same scene every time, and later resets without a seed continue that stream.
        """
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - set(OPTIONS)
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; use {OPTIONS}")
        if "scene" not in options and options.get("target_colour") is None:
            options["target_colour"] = self.target_colour
        world_seed = int(self.np_random.integers(2 ** 63))
        obs, info = self.world.reset(seed=world_seed, options=options)
        return self._observation(obs), self._info(info)

    def step(self, action):
        """Apply joint torques for one 0.05 s step. action: (2,) N m (clipped to +-max_torque).

        Returns (obs, reward, terminated, truncated, info): terminated is always False; truncated is
        True after `horizon` steps, and then info["success"] is the episode's outcome.
        """
        obs, reward, terminated, truncated, info = self.world.step(action)
        return self._observation(obs), reward, terminated, truncated, self._info(info)

    def render(self):
        """The current image, (H, W, 3) uint8, if render_mode is "rgb_array"; None otherwise."""
        if self.render_mode == "rgb_array":
            return self.world.render()
        return None

    def close(self):
        """Nothing to release: the world holds only a Pymunk space in memory, no window or file."""

    @staticmethod
    def _observation(obs):
        # The world also keeps obs["end_effector"] in its success history; hand out a copy so that
        # writing into the observation cannot change the episode's outcome.
        return {**obs, "end_effector": obs["end_effector"].copy()}

    @staticmethod
    def _info(info):
        scene = info["scene"]       # the world's info already holds copies
        return {"success": info["success"], "target_colour": scene.target_colour,
                "target_position": info["target_position"],
                "object_colours": scene.colours, "object_positions": scene.positions}


# The env truncates itself after `horizon` steps, so no TimeLimit wrapper (max_episode_steps).
if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="oneshot.world.gym:ReachEnv")
