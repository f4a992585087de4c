"""The analytic arm model (oneshot.world.arm) against finite differences and against Pymunk."""
import dataclasses

import numpy as np
import pymunk
import pytest

from oneshot.world import arm
from oneshot.world.reach import ReachWorld, WorldConfig

CFG = arm.ArmConfig()


def test_step_derivatives_match_finite_differences():
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(-np.pi, np.pi, (5, 2)), rng.normal(0, 3, (5, 2))])
    u = rng.uniform(-0.4, 0.4, (5, 2))
    x_next, A, B = arm.step_derivatives(x, u, CFG)
    np.testing.assert_allclose(x_next, arm.step(x, u, CFG), rtol=0, atol=1e-12)
    eps = 1e-6
    A_fd = np.stack([(arm.step(x + eps * e, u, CFG) - arm.step(x - eps * e, u, CFG)) / (2 * eps)
                     for e in np.eye(4)], -1)
    B_fd = np.stack([(arm.step(x, u + eps * e, CFG) - arm.step(x, u - eps * e, CFG)) / (2 * eps)
                     for e in np.eye(2)], -1)
    np.testing.assert_allclose(A, A_fd, atol=1e-6)
    np.testing.assert_allclose(B, B_fd, atol=1e-6)


def test_single_state_fast_path_equals_batched_path():
    rng = np.random.default_rng(1)
    x, u = rng.normal(size=(7, 4)), rng.uniform(-1, 1, (7, 2))      # includes torques beyond the bound
    batched = arm.step(x, u, CFG)
    for i in range(7):
        np.testing.assert_allclose(arm.step(x[i], u[i], CFG), batched[i], rtol=1e-14, atol=1e-14)


def test_mass_matrix_inverse_against_numpy():
    q2 = np.linspace(-3, 3, 7)
    a, d, h = CFG.mass_coefficients
    for c in np.cos(q2):
        M = np.array([[a + 2 * h * c, d + h * c], [d + h * c, d]])
        i11, i12, i22 = arm._inverse_mass(c, CFG)
        np.testing.assert_allclose([[i11, i12], [i12, i22]], np.linalg.inv(M), rtol=1e-12)


def test_kinetic_energy_balances_torque_work_and_damping():
    """Energy check independent of the equations' derivation: with no torque and no damping the
    kinetic energy 1/2 qd^T M qd, computed from the link masses and inertias, is conserved."""
    cfg = arm.ArmConfig(damping=0.0, substeps=200)
    a, d, h = cfg.mass_coefficients

    def energy(x):
        c = np.cos(x[1])
        M = np.array([[a + 2 * h * c, d + h * c], [d + h * c, d]])
        return 0.5 * x[2:] @ M @ x[2:]

    x = np.array([0.3, 1.0, 2.0, -3.0])
    e0 = energy(x)
    for _ in range(20):
        x = arm.step(x, np.zeros(2), cfg)
    assert abs(energy(x) - e0) / e0 < 1e-3


def _model_vs_pymunk(cfg, seeds=range(4)):
    """Worst joint-angle (rad) and end-effector (m) gap between the model and Pymunk over episodes
    driven by smooth open-loop torques like the expert's."""
    world = ReachWorld(WorldConfig(arm=cfg))
    t = np.arange(world.config.horizon) * cfg.dt
    worst_q = worst_ee = 0.0
    for seed in seeds:
        rng = np.random.default_rng(seed)
        amp, freq, phase = rng.uniform(0.1, 0.4, 2), rng.uniform(0.5, 2.0, 2), rng.uniform(0, 6, 2)
        world.reset(seed=seed)
        x = world.state
        for u in amp * np.sin(2 * np.pi * freq * t[:, None] + phase):
            world.step(u)
            x = arm.step(x, u, cfg)
            worst_q = max(worst_q, np.abs(x[:2] - world.joint_angles).max())
            worst_ee = max(worst_ee, np.linalg.norm(arm.forward_kinematics(x[:2], cfg) - world.joints()[2]))
    return worst_q, worst_ee


def test_model_tracks_pymunk_over_an_episode():
    """At the defaults the end effector stays within a tenth of the success radius of Pymunk's."""
    worst_q, worst_ee = _model_vs_pymunk(CFG)
    assert worst_q < 0.03 and worst_ee < 0.005, (worst_q, worst_ee)


def test_model_converges_to_pymunk_as_substeps_shrink():
    """What gap remains is discretisation (Pymunk's maximal coordinates vs our joint coordinates), not
    a modelling error: it is first order, halving when the substep halves."""
    coarse = _model_vs_pymunk(dataclasses.replace(CFG, substeps=10))[0]
    fine = _model_vs_pymunk(dataclasses.replace(CFG, substeps=40))[0]
    assert fine < 0.35 * coarse, (coarse, fine)


def test_forward_kinematics_matches_pymunk_bodies():
    world = ReachWorld()
    world.reset(seed=0)
    for u in np.random.default_rng(0).uniform(-0.3, 0.3, (10, 2)):
        world.step(u)
        np.testing.assert_allclose(arm.forward_kinematics(world.joint_angles, CFG), world.joints()[2], atol=2e-3)


def test_inverse_kinematics_round_trip_and_unreachable_target():
    rng = np.random.default_rng(2)
    for _ in range(20):
        r, a = rng.uniform(0.03, 0.2), rng.uniform(-np.pi, np.pi)
        g = np.array([r * np.cos(a), r * np.sin(a)])
        q = arm.inverse_kinematics(g, np.array(CFG.q0), CFG)
        np.testing.assert_allclose(arm.forward_kinematics(q, CFG), g, atol=1e-12)
    with pytest.raises(ValueError, match="out of the arm's reach"):
        arm.inverse_kinematics(np.array([0.3, 0.0]), np.zeros(2), CFG)


def test_end_effector_jacobian_matches_finite_differences():
    q = np.array([[0.4, -1.2], [2.0, 0.3]])
    eps = 1e-6
    J_fd = np.stack([(arm.forward_kinematics(q + eps * e, CFG) - arm.forward_kinematics(q - eps * e, CFG))
                     / (2 * eps) for e in np.eye(2)], -1)
    np.testing.assert_allclose(arm.end_effector_jacobian(q, CFG), J_fd, atol=1e-8)


def test_mass_matrix_is_the_kinetic_energy_of_the_two_links():
    """1/2 qd^T M(q) qd equals the links' kinetic energy summed body by body (centre-of-mass velocities
    from the kinematics, moments from Pymunk's formula for each link's own mass and length), for an arm
    whose links differ in mass and length, so that a mass or length of one link used for the other shows."""
    cfg = arm.ArmConfig(m1=2.0, m2=0.5, l1=0.09, l2=0.12)
    a, d, h = cfg.mass_coefficients
    i1 = pymunk.moment_for_segment(cfg.m1, (-cfg.l1 / 2, 0), (cfg.l1 / 2, 0), cfg.radius)
    i2 = pymunk.moment_for_segment(cfg.m2, (-cfg.l2 / 2, 0), (cfg.l2 / 2, 0), cfg.radius)
    rng = np.random.default_rng(3)
    for q1, q2, w1, w2 in np.column_stack([rng.uniform(-np.pi, np.pi, (6, 2)), rng.normal(0, 3, (6, 2))]):
        perp = lambda angle: np.array([-np.sin(angle), np.cos(angle)])        # d/dangle of (cos, sin)
        v1 = cfg.l1 / 2 * w1 * perp(q1)
        v2 = cfg.l1 * w1 * perp(q1) + cfg.l2 / 2 * (w1 + w2) * perp(q1 + q2)
        bodies = 0.5 * (cfg.m1 * v1 @ v1 + i1 * w1 ** 2 + cfg.m2 * v2 @ v2 + i2 * (w1 + w2) ** 2)
        c = np.cos(q2)
        M = np.array([[a + 2 * h * c, d + h * c], [d + h * c, d]])
        assert 0.5 * np.array([w1, w2]) @ M @ np.array([w1, w2]) == pytest.approx(bodies, rel=1e-12)


def test_inverse_kinematics_returns_the_solution_nearest_q_near():
    """Of the two elbow solutions, the one at the pose we started near, with its angles unwrapped to it
    (q1 up to 3 turns away from [-pi, pi])."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        q = np.array([rng.uniform(-6 * np.pi, 6 * np.pi), rng.choice([-1, 1]) * rng.uniform(0.3, 2.8)])
        g = arm.forward_kinematics(q, CFG)
        np.testing.assert_allclose(arm.inverse_kinematics(g, q + rng.normal(0, 0.05, 2), CFG), q, atol=1e-9)


def test_the_model_and_the_world_both_clip_torques_to_the_bound():
    """Torques beyond max_torque act as max_torque, in the model's single-state and batched paths and in
    the Pymunk world, bit for bit."""
    lim = CFG.max_torque
    x = np.array([[0.3, 1.0, 0.5, -1.0], [-1.0, 0.4, -2.0, 0.3]])
    big, bound = np.array([[3.0, -3.0], [-1.5, 0.9]]), np.array([[lim, -lim], [-lim, lim]])
    assert np.array_equal(arm.step(x, big, CFG), arm.step(x, bound, CFG))
    assert np.array_equal(arm.step(x[0], big[0], CFG), arm.step(x[0], bound[0], CFG))
    assert not np.allclose(arm.step(x, 0.9 * bound, CFG), arm.step(x, bound, CFG))   # the bound is not lower
    states = []
    for u in (big[0], bound[0]):
        world = ReachWorld()
        world.reset(seed=0)
        for _ in range(3):
            world.step(u)
        states.append(world.state)
    assert np.array_equal(*states)
