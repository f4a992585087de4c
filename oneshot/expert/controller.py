"""The expert demonstrator of paper Section IV: iLQG on the analytic arm, executed in Pymunk.

`plan` solves for a torque sequence and feedback gains on the analytic model (`oneshot.world.arm`,
`oneshot.expert.ilqg`); `demonstrate` runs that feedback controller, u = u_bar + K (x - x_bar), in the Pymunk
world, so a recorded demonstration is what the simulator really did, with the images the policy sees.

Torque bounds: iLQG plans in an unbounded control v and the arm receives u = u_max tanh(v / u_max)
(a squashing function, as in Tassa et al. 2012), so every plan respects the bound.

Cost: reach the target and stay there, with small torques, arriving at rest:
    l(x, v)  = w_dist |ee(q) - g|^2 + w_ctrl |v|^2 + w_vel |qd|^2        for t < T
    l_f(x)   = w_dist_final |ee(q) - g|^2 + w_vel_final |qd|^2
The position terms use the Gauss-Newton Hessian 2 J^T J (positive semi-definite, hence robust).
"""
import dataclasses
from dataclasses import dataclass, field

import numpy as np

from oneshot.expert import ilqg
from oneshot.world import arm
from oneshot.expert.ilqg import ILQGConfig
from oneshot.world.reach import observation_state


@dataclass(frozen=True)
class ExpertConfig:
    """The expert's cost weights (the cost of the module docstring is in arbitrary units, so each weight
    is per unit of what it multiplies), its planner's resolution, and DART noise."""
    w_dist: float = 1.0          # per m^2 of squared end-effector-to-target distance, every step
    w_ctrl: float = 1e-3         # per (N m)^2 of squared (unsquashed) control v, every step
    w_vel: float = 1e-4          # per (rad/s)^2 of squared joint velocity, every step
    w_dist_final: float = 10.0   # per m^2, final state only
    w_vel_final: float = 1e-2    # per (rad/s)^2, final state only
    # The planner integrates its model with this many substeps per control step (Pymunk uses the
    # world's 10): the same equations on a coarser grid halve the cost of a plan, and the feedback
    # gains absorb the small difference (`python -m oneshot.benchmark expert`: still 100% success).
    model_substeps: int = 5
    # DART (Laskey et al., 2017): execute the expert's torque plus Gaussian noise of this std (N m)
    # but record the expert's command, so the data shows how the expert corrects the deviations a
    # learned policy will make. 0 records the noiseless expert.
    action_noise: float = 0.0
    ilqg: ILQGConfig = field(default_factory=ILQGConfig)


class SquashedArm:
    """The analytic arm driven through u = u_max tanh(v / u_max): the dynamics iLQG plans on."""

    def __init__(self, cfg):
        self.cfg = cfg

    def torque(self, v):
        return self.cfg.max_torque * np.tanh(v / self.cfg.max_torque)

    def step(self, x, v):
        return arm.step(x, self.torque(v), self.cfg)

    def derivatives(self, x, v):
        _, A, B = arm.step_derivatives(x, self.torque(v), self.cfg)
        return A, B * (1 - np.tanh(v / self.cfg.max_torque) ** 2)[:, None, :]


class ReachCost:
    """The reaching cost of the module docstring for target g: (2,) metres."""

    def __init__(self, target, arm_cfg, cfg):
        self.g, self.arm_cfg, self.cfg = np.asarray(target, float), arm_cfg, cfg

    def total(self, x, v):
        """x: (..., T+1, 4), v: (..., T, 2) -> (...)."""
        c = self.cfg
        d2 = np.sum((arm.forward_kinematics(x[..., :2], self.arm_cfg) - self.g) ** 2, axis=-1)
        qd2 = np.sum(x[..., 2:] ** 2, axis=-1)
        running = c.w_dist * d2[..., :-1] + c.w_vel * qd2[..., :-1] + c.w_ctrl * np.sum(v ** 2, axis=-1)
        return running.sum(-1) + c.w_dist_final * d2[..., -1] + c.w_vel_final * qd2[..., -1]

    def derivatives(self, x, v):
        """Gradients and (Gauss-Newton) Hessians, see `oneshot.expert.ilqg` for the shapes."""
        c = self.cfg
        T1 = x.shape[0]
        w_dist = np.full(T1, c.w_dist)
        w_dist[-1] = c.w_dist_final
        w_vel = np.full(T1, c.w_vel)
        w_vel[-1] = c.w_vel_final
        e = arm.forward_kinematics(x[:, :2], self.arm_cfg) - self.g          # (T+1, 2)
        J = arm.end_effector_jacobian(x[:, :2], self.arm_cfg)                # (T+1, 2, 2)
        lx = np.zeros((T1, 4))
        lx[:, :2] = 2 * w_dist[:, None] * np.einsum("tij,ti->tj", J, e)
        lx[:, 2:] = 2 * w_vel[:, None] * x[:, 2:]
        lxx = np.zeros((T1, 4, 4))
        lxx[:, :2, :2] = 2 * w_dist[:, None, None] * np.einsum("tki,tkj->tij", J, J)
        lxx[:, 2, 2] = lxx[:, 3, 3] = 2 * w_vel
        lu = 2 * c.w_ctrl * v
        luu = np.broadcast_to(2 * c.w_ctrl * np.eye(2), (len(v), 2, 2))
        lux = np.zeros((len(v), 2, 4))
        return lx, lu, lxx, luu, lux


def plan(x0, target, arm_cfg, horizon, cfg=ExpertConfig()):
    """iLQG plan from state x0 (4,) to target (2,) m over `horizon` steps, from zero controls.

    Returns an ILQGResult whose u is in the squashed control v (torque = u_max tanh(v / u_max)).
    """
    model_cfg = dataclasses.replace(arm_cfg, substeps=cfg.model_substeps or arm_cfg.substeps)
    return ilqg.solve(x0, np.zeros((horizon, 2)), SquashedArm(model_cfg), ReachCost(target, model_cfg, cfg), cfg.ilqg)


def feedback_torque(plan_result, t, x, arm_cfg):
    """The expert's action at step t in state x (4,): u = u_max tanh(v_bar + K (x - x_bar)), N m."""
    v = plan_result.u[t] + plan_result.K[t] @ (x - plan_result.x[t])
    return arm_cfg.max_torque * np.tanh(v / arm_cfg.max_torque)


def demonstrate(world, seed=None, options=None, cfg=ExpertConfig()):
    """Record one expert demonstration in `world` (a ReachWorld), reset with seed and options.

    Returns a dict: images (T, H, W, 3) uint8, states (T, 6) float32, actions (T, 2) float32 (the
    expert's torque command at each observed frame), applied (T, 2) float32 (the torques Pymunk got:
    the commands, plus noise if cfg.action_noise > 0), end_effector (T, 2) positions after each
    step, scene, success (bool, the paper's criterion), ilqg_iterations.
    """
    obs, info = world.reset(seed=seed, options=options)
    T, lim = world.config.horizon, world.config.arm.max_torque
    result = plan(world.state, info["target_position"], world.config.arm, T, cfg)
    noise = np.random.default_rng([seed if seed is not None else 0, 7]).normal(0, cfg.action_noise, (T, 2))
    images, states, actions, applied, ee = [], [], [], [], []
    for t in range(T):
        # Rounded to float32 before it is applied, so the stored torque is exactly what Pymunk got.
        u = feedback_torque(result, t, world.state, world.config.arm).astype(np.float32)
        u_applied = np.clip(u + noise[t], -lim, lim).astype(np.float32) if cfg.action_noise else u
        images.append(obs["image"])
        states.append(observation_state(obs))
        actions.append(u)
        applied.append(u_applied)
        obs, _, _, _, info = world.step(u_applied)
        ee.append(obs["end_effector"])
    return {"images": np.stack(images), "states": np.stack(states), "actions": np.stack(actions),
            "applied": np.stack(applied), "end_effector": np.stack(ee), "scene": info["scene"],
            "success": info["success"], "ilqg_iterations": result.iterations}
