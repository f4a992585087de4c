"""The analytic model of the planar 2-link arm, with its derivatives (paper Section IV).

The same arm is simulated by Pymunk in `oneshot.world.reach`; this module is the model the iLQG expert
plans on (`oneshot.expert.ilqg`, `oneshot.expert.controller`). It uses the masses and the moments of inertia that
Pymunk computes for the links, and integrates with the same semi-implicit Euler substeps Pymunk
uses (positions first, then velocities; Chipmunk's order), so the two agree closely (tested in `tests/test_arm.py`).

Coordinates: joint angles q = (q1, q2) in radians, q1 the shoulder angle from the +x axis, q2 the
elbow angle relative to link 1; joint velocities qd in rad/s; torques u in newton-metres.
The state is x = (q1, q2, qd1, qd2). All functions are vectorised over leading axes.

Equations of motion (a standard result, e.g. Spong et al., "Robot Modeling and Control", Ch. 7):

    M(q2) qdd + c(q2, qd) = u - b qd

    M = [[a + 2 h cos q2, d + h cos q2],        a = I1 + I2 + m1 lc1^2 + m2 (l1^2 + lc2^2)
         [d + h cos q2,   d           ]]        d = I2 + m2 lc2^2,  h = m2 l1 lc2
    c = h sin q2 (-(2 qd1 qd2 + qd2^2), qd1^2)
"""
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pymunk


@dataclass(frozen=True)
class ArmConfig:
    """Physical constants of the arm and its integrator. Defaults are the project's reaching arm.

    Link lengths 0.1 and 0.11 m follow the reacher of MIL's simulated reaching task. The control
    step dt = 0.05 s with 10 substeps of 0.005 s: torques are held for dt and re-applied every substep.
    """
    l1: float = 0.1            # link lengths, metres
    l2: float = 0.11
    m1: float = 1.0            # link masses, kilograms
    m2: float = 1.0
    radius: float = 0.01       # link half-thickness (enters Pymunk's moment of inertia), metres
    damping: float = 0.02      # joint viscous damping, N m s / rad
    max_torque: float = 0.5    # torque bound per joint, N m
    dt: float = 0.05           # control step, seconds
    substeps: int = 10         # physics substeps per control step
    q0: tuple = (0.0, np.pi / 2)   # start pose, radians

    @cached_property
    def inertias(self):
        """Moments of inertia of the links about their centres, as Pymunk computes them (kg m^2)."""
        i1 = pymunk.moment_for_segment(self.m1, (-self.l1 / 2, 0), (self.l1 / 2, 0), self.radius)
        i2 = pymunk.moment_for_segment(self.m2, (-self.l2 / 2, 0), (self.l2 / 2, 0), self.radius)
        return i1, i2

    @cached_property
    def mass_coefficients(self):
        """(a, d, h) of the mass matrix in the module docstring."""
        i1, i2 = self.inertias
        lc1, lc2 = self.l1 / 2, self.l2 / 2
        a = i1 + i2 + self.m1 * lc1 ** 2 + self.m2 * (self.l1 ** 2 + lc2 ** 2)
        d = i2 + self.m2 * lc2 ** 2
        h = self.m2 * self.l1 * lc2
        return a, d, h


def forward_kinematics(q, cfg):
    """End-effector position. q: (..., 2) radians -> (..., 2) metres, arm base at the origin."""
    q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
    return np.stack([cfg.l1 * np.cos(q1) + cfg.l2 * np.cos(q12),
                     cfg.l1 * np.sin(q1) + cfg.l2 * np.sin(q12)], axis=-1)


def inverse_kinematics(target, q_near, cfg):
    """Joint angles (2,) placing the end effector at target (2,) m, of the two elbow solutions the
    one nearest q_near (2,) (angles unwrapped towards q_near). Raises ValueError if unreachable."""
    gx, gy = target
    c2 = (gx * gx + gy * gy - cfg.l1 ** 2 - cfg.l2 ** 2) / (2 * cfg.l1 * cfg.l2)
    if abs(c2) > 1:
        raise ValueError(f"target {tuple(target)} is out of the arm's reach "
                         f"({abs(cfg.l1 - cfg.l2)} to {cfg.l1 + cfg.l2} m from the base)")
    best = None
    for q2 in (np.arccos(c2), -np.arccos(c2)):
        q1 = np.arctan2(gy, gx) - np.arctan2(cfg.l2 * np.sin(q2), cfg.l1 + cfg.l2 * np.cos(q2))
        q = np.array([q1, q2])
        q = q_near + (q - q_near + np.pi) % (2 * np.pi) - np.pi
        if best is None or np.sum((q - q_near) ** 2) < np.sum((best - q_near) ** 2):
            best = q
    return best


def end_effector_jacobian(q, cfg):
    """d(end effector)/dq. q: (..., 2) -> (..., 2, 2), rows (x, y), columns (q1, q2)."""
    q1, q12 = q[..., 0], q[..., 0] + q[..., 1]
    s1, c1, s12, c12 = np.sin(q1), np.cos(q1), np.sin(q12), np.cos(q12)
    J = np.empty(q.shape[:-1] + (2, 2))
    J[..., 0, 0] = -cfg.l1 * s1 - cfg.l2 * s12
    J[..., 0, 1] = -cfg.l2 * s12
    J[..., 1, 0] = cfg.l1 * c1 + cfg.l2 * c12
    J[..., 1, 1] = cfg.l2 * c12
    return J


def _inverse_mass(cos_q2, cfg):
    """M(q2)^-1 as its three distinct entries (i11, i12, i22), each shaped like cos_q2.

    Uses det M = d (a - d) - h^2 cos^2 q2, which follows from the entries of M.
    """
    a, d, h = cfg.mass_coefficients
    hc2 = h * cos_q2
    det = d * (a - d) - hc2 * hc2
    return d / det, -(d + hc2) / det, (a + 2 * hc2) / det


def _joint_acceleration(q2, qd1, qd2, u1, u2, cfg, sin=np.sin, cos=np.cos):
    """qdd = M^-1 (u - b qd - c), component by component.

    Works on arrays of one shape, or on floats with sin=math.sin and cos=math.cos.
    """
    _, _, h = cfg.mass_coefficients
    hs2 = h * sin(q2)
    r1 = u1 - cfg.damping * qd1 + hs2 * (2 * qd1 * qd2 + qd2 * qd2)
    r2 = u2 - cfg.damping * qd2 - hs2 * qd1 * qd1
    i11, i12, i22 = _inverse_mass(cos(q2), cfg)
    return i11 * r1 + i12 * r2, i12 * r1 + i22 * r2


def acceleration(x, u, cfg):
    """Joint accelerations qdd = M^-1 (u - b qd - c). x: (..., 4), u: (..., 2) -> (..., 2) rad/s^2."""
    return np.stack(_joint_acceleration(x[..., 1], x[..., 2], x[..., 3], u[..., 0], u[..., 1], cfg), -1)


def step(x, u, cfg):
    """One control step: `cfg.substeps` semi-implicit Euler substeps with u held, in Pymunk's order.

    Chipmunk integrates positions with the old velocities, then velocities with the forces:
    q' = q + h qd,  qd' = qd + h qdd(q', qd, u). Matching that order cuts the model error ~10x.

    x: (..., 4), u: (..., 2) N m (clipped to the torque bound, as the world does) -> (..., 4).
    """
    hsub, lim = cfg.dt / cfg.substeps, cfg.max_torque
    one = np.ndim(x) == 1
    if one:
        # One state: plain floats and math.sin are ~20x faster than NumPy calls on scalars here
        # (~1-2 us per NumPy call on this machine), and this is iLQG's rollout, its hot path.
        q1, q2, qd1, qd2 = (float(v) for v in x)
        u1, u2 = (min(max(float(v), -lim), lim) for v in u)
        sin, cos = math.sin, math.cos
    else:
        q1, q2, qd1, qd2 = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
        u = np.clip(u, -lim, lim)
        u1, u2, sin, cos = u[..., 0], u[..., 1], np.sin, np.cos
    for _ in range(cfg.substeps):
        q1, q2 = q1 + hsub * qd1, q2 + hsub * qd2
        a1, a2 = _joint_acceleration(q2, qd1, qd2, u1, u2, cfg, sin, cos)
        qd1, qd2 = qd1 + hsub * a1, qd2 + hsub * a2
    return np.array([q1, q2, qd1, qd2]) if one else np.stack([q1, q2, qd1, qd2], axis=-1)


def step_derivatives(x, u, cfg):
    """One control step and its Jacobians, for iLQG.

    x: (N, 4), u: (N, 2) -> (x_next (N, 4), A = dx_next/dx (N, 4, 4), B = dx_next/du (N, 4, 2)).
    u must lie within the torque bound (the expert squashes its controls so that it does).
    Vectorised over N (all time steps of a trajectory at once); the substeps chain by the product rule.
    """
    a_, d_, h = cfg.mass_coefficients
    b, hsub = cfg.damping, cfg.dt / cfg.substeps
    n = x.shape[0]
    eye2 = np.eye(2)
    A = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    B = np.zeros((n, 4, 2))
    q, qd = x[:, :2].copy(), x[:, 2:].copy()
    for _ in range(cfg.substeps):
        q = q + hsub * qd                      # positions first, as in step()
        qd1, qd2 = qd[:, 0], qd[:, 1]
        s2, c2 = np.sin(q[:, 1]), np.cos(q[:, 1])
        r = np.stack([u[:, 0] - b * qd1 + h * s2 * (2 * qd1 * qd2 + qd2 ** 2),
                      u[:, 1] - b * qd2 - h * s2 * qd1 ** 2], axis=-1)
        i11, i12, i22 = _inverse_mass(c2, cfg)
        Minv = np.stack([np.stack([i11, i12], -1), np.stack([i12, i22], -1)], -2)   # (N, 2, 2)
        qdd = np.einsum("nij,nj->ni", Minv, r)
        # f = qdd(q, qd, u). df/dq2 = M^-1 (dr/dq2 - dM/dq2 qdd), dM/dq2 = -h sin q2 [[2, 1], [1, 0]]
        dr_dq2 = np.stack([h * c2 * (2 * qd1 * qd2 + qd2 ** 2), -h * c2 * qd1 ** 2], -1)
        dM_qdd = -h * s2[:, None] * np.stack([2 * qdd[:, 0] + qdd[:, 1], qdd[:, 0]], -1)
        f_q = np.zeros((n, 2, 2))
        f_q[:, :, 1] = np.einsum("nij,nj->ni", Minv, dr_dq2 - dM_qdd)
        # df/dqd = M^-1 dr/dqd
        dr_dqd = np.empty((n, 2, 2))
        dr_dqd[:, 0, 0] = -b + 2 * h * s2 * qd2
        dr_dqd[:, 0, 1] = 2 * h * s2 * (qd1 + qd2)
        dr_dqd[:, 1, 0] = -2 * h * s2 * qd1
        dr_dqd[:, 1, 1] = -b
        f_qd = Minv @ dr_dqd
        # Substep Jacobian S of (q, qd) -> (q' = q + h qd, qd' = qd + h f(q', qd, u)).
        S = np.empty((n, 4, 4))
        S[:, :2, :2] = eye2
        S[:, :2, 2:] = hsub * eye2
        S[:, 2:, :2] = hsub * f_q
        S[:, 2:, 2:] = eye2 + hsub * (hsub * f_q + f_qd)
        Su = np.zeros((n, 4, 2))
        Su[:, 2:] = hsub * Minv
        A = S @ A
        B = S @ B + Su
        qd = qd + hsub * qdd
    return np.concatenate([q, qd], axis=-1), A, B
