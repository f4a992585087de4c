"""The reaching world of paper Section IV: a planar 2-link arm in Pymunk, coloured discs, Pillow images.

A *task* is a target colour (`oneshot.world.palette`). A *scene* places one target and distractors, each a
coloured disc, where the arm can reach them; positions change from scene to scene within a task.
The API follows Gymnasium, which RL users know:

    world = ReachWorld()
    obs, info = world.reset(seed=0, options={"target_colour": 5})
    obs, reward, terminated, truncated, info = world.step(np.array([0.1, -0.2]))

Observation: a dict with "image" (H, W, 3) uint8, "joint_angles" (2,) rad, "joint_velocities" (2,)
rad/s, "end_effector" (2,) m. `observation_state(obs)` stacks the last three into the (6,) state
vector the policy reads. Action: (2,) joint torques in N m, clipped to the torque bound.
Reward: minus the end-effector-to-target distance in metres.

Defaults: T = 20 control steps of 0.05 s (a 1 s episode), 32x32 images. 1 s is enough for the expert
to reach any reachable point and settle with bounded torques; T = 20 keeps the second-order
meta-gradient cheap (its cost grows linearly with the number of frames). Success (the paper: "within
0.05 distance of the goal") is judged on the final fifth of the episode, as in MIL's released code
(last 10 of 50 steps): here the last 4 of 20.
"""
from dataclasses import dataclass, field

import numpy as np
import pymunk

from oneshot.tools.checks import real_number, whole_number
from oneshot.world import palette, render
from oneshot.world.arm import ArmConfig
from oneshot.world.palette import PaletteConfig
from oneshot.world.scene import Scene, check_scene, sample_scene


RESET_OPTIONS = ("target_colour", "scene")    # what `ReachWorld.reset` takes


@dataclass(frozen=True)
class WorldConfig:
    """Everything a scene and an episode depend on: the arm, the colours, the arena, the task's
    horizon and success radius (Section IV). Lengths in metres, angles in radians."""
    arm: ArmConfig = field(default_factory=ArmConfig)          # the arm's physics (oneshot.world.arm)
    palette: PaletteConfig = field(default_factory=PaletteConfig)   # colours, so tasks (oneshot.world.palette)
    split: str = "train"              # which colours scenes are drawn from: "train", "validation" or "test"
    horizon: int = 20                 # T, control steps per episode
    image_size: int = 32              # 32 by default; 64 also works
    n_objects: int = 3                # one target and two distractors
    arena_half_width: float = 0.22    # the square arena and image span [-0.22, 0.22]^2 metres
    object_radius: float = 0.025      # disc radius, metres
    min_object_radius: float = 0.07   # objects lie at this to max_object_radius from the base, metres
    max_object_radius: float = 0.19   # (the arm reaches 0.01 to 0.21)
    success_radius: float = 0.05      # paper: "within 0.05 distance of the goal"
    min_separation: float = 0.12      # > 2 * success_radius, so success is never ambiguous
    start_noise: float = 0.0          # std of noise on the start pose, radians

    def __post_init__(self):
        for name, fix in (("image_size", "pass the image's side in pixels, e.g. 32"),
                          ("horizon", "pass the number of steps per episode, e.g. 20"),
                          ("n_objects", "pass the number of discs per scene, e.g. 3")):
            object.__setattr__(self, name, whole_number(name, getattr(self, name), fix))
        if self.image_size < 8:
            raise ValueError(f"image_size must be at least 8 pixels; got {self.image_size}")
        if self.horizon < 5:
            raise ValueError(f"horizon must be at least 5 steps (success uses its final fifth); "
                             f"got {self.horizon}")
        for name in ("arena_half_width", "object_radius", "min_object_radius", "max_object_radius",
                     "success_radius", "min_separation", "start_noise"):
            least, unit = (">= 0", "radians") if name == "start_noise" else ("> 0", "metres")
            value = real_number(name, getattr(self, name), f"pass {unit} {least}")
            if value < 0 or (value == 0 and least == "> 0"):
                raise ValueError(f"{name} must be {least} {unit}; got {value!r}")
        if self.n_objects < 1:
            raise ValueError(f"n_objects must be at least 1 (the target); got {self.n_objects}")
        if not self.min_object_radius < self.max_object_radius <= self.arena_half_width - self.object_radius:
            raise ValueError(f"objects lie between min_object_radius and max_object_radius from the base, inside "
                             f"the arena: need {self.min_object_radius} < {self.max_object_radius} <= arena_half_width "
                             f"- object_radius = {self.arena_half_width - self.object_radius:.3g}")
        if self.min_separation <= 2 * self.success_radius:
            raise ValueError("min_separation must exceed 2 * success_radius, or success is ambiguous")
        if self.image_size > 1024:
            raise ValueError(f"image_size must be at most 1024 pixels (the policy's images are 32 or 64); got "
                             f"{self.image_size}")
        palette.split_colours(self.split, self.palette)   # validates the split name


def success_window(horizon):
    """Number of final steps success is judged on: the final fifth (10 of 50, 4 of 20)."""
    return max(1, horizon // 5)


def is_success(end_effector, target, success_radius=0.05):
    """Paper Section IV success: min distance over the final fifth of the episode <= 0.05.

    end_effector: (T, 2) positions after each of the T steps, metres; target: (2,) metres.
    """
    end_effector = np.asarray(end_effector)
    window = end_effector[-success_window(len(end_effector)):]
    return bool(np.min(np.linalg.norm(window - np.asarray(target), axis=-1)) <= success_radius)


def closest_object(end_effector, positions):
    """The object the end effector came closest to over the final fifth, and that distance.

    end_effector: (T, 2) positions after each step, metres; positions: (n, 2) object centres, metres.
    Returns (index into positions, distance in metres). Tells apart the two ways a trial can fail: a
    near miss (closest to the target, but not within the success radius) and a wrong object.
    """
    end_effector, positions = np.asarray(end_effector), np.asarray(positions)
    window = end_effector[-success_window(len(end_effector)):]
    d = np.linalg.norm(window[:, None, :] - positions[None], axis=-1).min(axis=0)  # (n,) min over window
    return int(np.argmin(d)), float(d.min())


def observation_state(obs):
    """The policy's state vector from an observation: (6,) float32 = angles, velocities, end effector."""
    return np.concatenate([obs["joint_angles"], obs["joint_velocities"],
                           obs["end_effector"]]).astype(np.float32)


class ReachWorld:
    """The Pymunk reaching world with a Gymnasium-style API. See the module docstring."""

    def __init__(self, config=None):
        self.config = config or WorldConfig()
        self._rgb = palette.palette_rgb(self.config.palette)
        self._space = None

    # --- set-up ------------------------------------------------------------------------------
    def _build_arm(self, q):
        """A fresh Pymunk space (no cached solver state, so runs are reproducible) holding the arm."""
        a = self.config.arm
        i1, i2 = a.inertias
        space = pymunk.Space()
        space.iterations = 30
        link1, link2 = pymunk.Body(a.m1, i1), pymunk.Body(a.m2, i2)
        elbow = (a.l1 * np.cos(q[0]), a.l1 * np.sin(q[0]))
        link1.position = (a.l1 / 2 * np.cos(q[0]), a.l1 / 2 * np.sin(q[0]))
        link1.angle = q[0]
        link2.position = (elbow[0] + a.l2 / 2 * np.cos(q[0] + q[1]),
                          elbow[1] + a.l2 / 2 * np.sin(q[0] + q[1]))
        link2.angle = q[0] + q[1]
        shoulder = pymunk.PivotJoint(space.static_body, link1, (0, 0), (-a.l1 / 2, 0))
        elbow_joint = pymunk.PivotJoint(link1, link2, (a.l1 / 2, 0), (-a.l2 / 2, 0))
        space.add(link1, link2, shoulder, elbow_joint)
        return space, link1, link2

    def reset(self, seed=None, options=None):
        """Start an episode. options: {"scene": Scene} or {"target_colour": palette index}.

        Returns (obs, info); info has "scene", "target_position" and "success" (False).
        """
        options = {} if options is None else options
        if not isinstance(options, dict):
            raise ValueError(f"reset options must be a dict, {{'scene': Scene}} or {{'target_colour': palette index}}; "
                             f"got {type(options).__name__}")
        unknown = set(options) - set(RESET_OPTIONS)
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; use {RESET_OPTIONS}")
        if "scene" in options and options.get("target_colour") is not None:
            raise ValueError("reset options 'scene' and 'target_colour' both name the target: pass one of them "
                             "(a scene's target colour is its own)")
        rng = np.random.default_rng(seed)
        if "scene" in options:
            self.scene = check_scene(options["scene"], self.config)
        else:
            colour = options.get("target_colour")
            if colour is None:
                colour = int(rng.choice(palette.split_colours(self.config.split, self.config.palette)))
            self.scene = sample_scene(colour, rng, self.config)
        q0 = np.array(self.config.arm.q0, dtype=float)
        if self.config.start_noise > 0:
            q0 = q0 + rng.normal(0, self.config.start_noise, 2)
        self._space, self._link1, self._link2 = self._build_arm(q0)
        self.t = 0
        self.end_effector_history = []
        return self._observation(), self._info()

    # --- state ---------------------------------------------------------------------------------
    @property
    def joint_angles(self):
        return np.array([self._link1.angle, self._link2.angle - self._link1.angle])

    @property
    def joint_velocities(self):
        w1, w2 = self._link1.angular_velocity, self._link2.angular_velocity
        return np.array([w1, w2 - w1])

    @property
    def state(self):
        """Arm state x = (q1, q2, qd1, qd2), as in `oneshot.world.arm`."""
        return np.concatenate([self.joint_angles, self.joint_velocities])

    def joints(self):
        """(3, 2) world positions of base, elbow and end effector, metres (from Pymunk's bodies)."""
        a = self.config.arm
        elbow = self._link1.local_to_world((a.l1 / 2, 0))
        tip = self._link2.local_to_world((a.l2 / 2, 0))
        return np.array([[0.0, 0.0], [elbow.x, elbow.y], [tip.x, tip.y]])

    def render(self):
        """The current image, (H, W, 3) uint8."""
        if self._space is None:
            raise RuntimeError("call reset() before render()")
        cfg = self.config
        return render.render(self.joints(), self.scene.positions, self._rgb[self.scene.colours],
                             arena_half_width=cfg.arena_half_width, size=cfg.image_size,
                             object_radius=cfg.object_radius)

    def _observation(self):
        return {"image": self.render(), "joint_angles": self.joint_angles,
                "joint_velocities": self.joint_velocities, "end_effector": self.joints()[2]}

    def _info(self):
        # Copies, so a caller writing into info["target_position"] cannot move the world's target.
        scene = Scene(np.array(self.scene.colours), np.array(self.scene.positions), self.scene.target)
        return {"scene": scene, "target_position": scene.target_position.copy(),
                "success": is_success(self.end_effector_history, self.scene.target_position,
                                      self.config.success_radius)
                if len(self.end_effector_history) == self.config.horizon else False}

    # --- dynamics ------------------------------------------------------------------------------
    def step(self, action):
        """Apply joint torques for one control step. action: (2,) real, N m (clipped to the bound).

        Returns (obs, reward, terminated, truncated, info); truncated is True after T steps, and
        info["success"] then tells whether the episode met the success criterion.
        """
        if self._space is None:
            raise RuntimeError("call reset() before step()")
        if self.t >= self.config.horizon:
            raise RuntimeError(f"the episode ended after {self.config.horizon} steps; call reset()")
        action = np.asarray(action)
        if action.dtype.kind not in "iuf":       # a complex torque would lose its imaginary part unseen
            drop = " (np.real(action) drops an imaginary part)" if action.dtype.kind == "c" else ""
            raise ValueError(f"action must be (2,) real joint torques in N m; got {action.dtype} {action.tolist()}; "
                             f"pass a float array{drop}")
        action = action.astype(float, copy=False)
        if action.shape != (2,):
            raise ValueError(f"action must be (2,) joint torques in N m; got shape {action.shape}")
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action contains NaN or inf: {action}")
        a = self.config.arm
        u = np.clip(action, -a.max_torque, a.max_torque)
        hsub = a.dt / a.substeps
        for _ in range(a.substeps):
            # Torques reset after every Pymunk step, so joint torques and damping are re-applied.
            tau = u - a.damping * self.joint_velocities
            self._link1.torque = float(tau[0] - tau[1])
            self._link2.torque = float(tau[1])
            self._space.step(hsub)
        self.t += 1
        obs = self._observation()
        self.end_effector_history.append(obs["end_effector"].copy())   # the caller may write into obs
        reward = -float(np.linalg.norm(obs["end_effector"] - self.scene.target_position))
        return obs, reward, False, self.t >= self.config.horizon, self._info()
