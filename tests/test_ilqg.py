"""iLQG (oneshot.expert.ilqg) against an exact reference, and the expert (oneshot.expert.controller) against the
paper's success criterion."""
import dataclasses

import numpy as np

from oneshot.expert import controller, ilqg
from oneshot.world import arm
from oneshot.world.reach import ReachWorld, WorldConfig, observation_state


class Linear:
    def __init__(self, A, B):
        self.A, self.B = A, B

    def step(self, x, u):
        return x @ self.A.T + u @ self.B.T

    def derivatives(self, x, u):
        T = len(x)
        return np.broadcast_to(self.A, (T,) + self.A.shape), np.broadcast_to(self.B, (T,) + self.B.shape)


class Quadratic:
    def __init__(self, Q, R, Qf):
        self.Q, self.R, self.Qf = Q, R, Qf

    def total(self, x, u):
        return (np.einsum("ti,ij,tj->", x[:-1], self.Q, x[:-1]) + np.einsum("ti,ij,tj->", u, self.R, u)
                + x[-1] @ self.Qf @ x[-1])

    def derivatives(self, x, u):
        T = len(u)
        Qs = np.concatenate([np.broadcast_to(self.Q, (T, 4, 4)), self.Qf[None]])
        lx = 2 * np.einsum("tij,tj->ti", Qs, x)
        return (lx, 2 * u @ self.R, 2 * Qs, np.broadcast_to(2 * self.R, (T, 2, 2)), np.zeros((T, 2, 4)))


def test_ilqg_solves_a_linear_quadratic_problem_exactly():
    """Reference: write x = Phi x0 + Gamma U and minimise the quadratic in U by least squares."""
    rng = np.random.default_rng(0)
    A = np.eye(4) + 0.1 * rng.normal(size=(4, 4))
    B = 0.1 * rng.normal(size=(4, 2))
    Q, R, Qf = np.diag([1.0, 2, 0.5, 0.1]), 0.01 * np.eye(2), 10 * np.eye(4)
    T, x0 = 15, rng.normal(size=4)
    result = ilqg.solve(x0, np.zeros((T, 2)), Linear(A, B), Quadratic(Q, R, Qf),
                        ilqg.ILQGConfig(tol_cost=1e-12, tol_grad=1e-12, mu_init=0.0))
    # batch reference
    Phi = np.stack([np.linalg.matrix_power(A, t) for t in range(T + 1)])          # (T+1, 4, 4)
    Gamma = np.zeros((T + 1, 4, T, 2))
    for t in range(1, T + 1):
        for s in range(t):
            Gamma[t, :, s] = np.linalg.matrix_power(A, t - 1 - s) @ B
    G = Gamma.reshape((T + 1) * 4, T * 2)
    W = np.kron(np.eye(T + 1), Q)
    W[-4:, -4:] = Qf
    H = G.T @ W @ G + np.kron(np.eye(T), R)
    U = -np.linalg.solve(H, G.T @ W @ (Phi @ x0).reshape(-1))
    np.testing.assert_allclose(result.u, U.reshape(T, 2), rtol=1e-6, atol=1e-8)
    assert result.converged


def test_ilqg_on_the_arm_descends_and_converges():
    world = ReachWorld()
    _, info = world.reset(seed=7)
    result = controller.plan(world.state, info["target_position"], world.config.arm, world.config.horizon)
    history = np.array(result.cost_history)
    assert result.converged
    assert np.all(np.diff(history) <= 0)                     # every accepted step lowers the cost
    assert history[-1] < 0.3 * history[0]
    final = arm.forward_kinematics(result.x[-1, :2], world.config.arm)
    assert np.linalg.norm(final - info["target_position"]) < 0.01


def test_the_plan_drives_the_arm_through_the_torque_squashing():
    """The plan's controls v are unbounded; the arm gets u_max tanh(v / u_max) (written out here, not
    taken from oneshot.expert.controller). Its planned states are the analytic arm driven by those torques; in this
    scene the plan asks for more than the bound, where the squashing really changes the torque; and the
    expert's first command in Pymunk (the state is the plan's start, so no feedback) is the squashed
    first control."""
    world = ReachWorld()
    _, info = world.reset(seed=7)
    x0, lim = world.state.copy(), world.config.arm.max_torque
    result = controller.plan(x0, info["target_position"], world.config.arm, world.config.horizon)
    torque = lim * np.tanh(result.u / lim)                                   # (T, 2) N m
    model = dataclasses.replace(world.config.arm, substeps=controller.ExpertConfig().model_substeps)
    x = [x0]
    for u in torque:
        x.append(arm.step(x[-1], u, model))
    np.testing.assert_allclose(np.array(x), result.x, rtol=0, atol=1e-12)
    over = np.abs(result.u) > lim
    assert over.any() and np.abs(result.u).max() > 1.5 * lim                 # the bound binds in this scene
    assert np.all(np.abs(torque[over]) < lim) and np.all(np.abs(torque[over]) > 0.7 * lim)
    x = [x0]                                                                 # unsquashed (the arm clips):
    for u in result.u:                                                       # not the planned states
        x.append(arm.step(x[-1], u, model))
    assert np.abs(np.array(x) - result.x).max() > 0.1
    demo = controller.demonstrate(world, seed=7)
    np.testing.assert_allclose(demo["actions"][0], torque[0].astype(np.float32), rtol=1e-6)
    assert np.abs(demo["actions"]).max() <= lim and np.abs(demo["actions"]).max() > 0.5 * lim


def test_expert_meets_the_success_criterion_on_a_sample_of_scenes():
    """Issue requirement: >= 99% over 500 scenes (`python -m oneshot.benchmark expert`). Here a
    sample of 40 scenes, from both colour splits: at 99% all 40 pass with probability 0.67, and in
    the 500-scene benchmark the expert did not fail once."""
    for split, seeds in (("train", range(30)), ("validation", range(100, 110))):
        world = ReachWorld(WorldConfig(split=split))
        for seed in seeds:
            demo = controller.demonstrate(world, seed=seed)
            assert demo["success"], (split, seed)
            assert np.abs(demo["actions"]).max() <= world.config.arm.max_torque


def test_a_demonstration_is_what_the_simulator_did():
    """Replaying the recorded torques open loop in Pymunk reproduces the recorded frames exactly."""
    world = ReachWorld()
    demo = controller.demonstrate(world, seed=11)
    obs, _ = world.reset(seed=11)
    for t, u in enumerate(demo["actions"]):
        assert np.array_equal(obs["image"], demo["images"][t])
        assert np.array_equal(observation_state(obs), demo["states"][t])
        obs, *_ = world.step(u.astype(float))
    assert np.allclose(obs["end_effector"], demo["end_effector"][-1], atol=1e-6)


def test_dart_noise_is_executed_but_not_recorded_and_the_expert_still_succeeds():
    """With action noise the labels are the expert's commands; replaying the *applied* torques
    reproduces the recorded frames, and the commands differ from them by the noise."""
    world = ReachWorld()
    cfg = controller.ExpertConfig(action_noise=0.1)
    for seed in range(5):
        demo = controller.demonstrate(world, seed=seed, cfg=cfg)
        assert demo["success"]
        gap = np.abs(demo["applied"] - demo["actions"])
        assert 0.03 < gap.mean() < 0.15                           # about the noise's mean |N(0, 0.1)| = 0.08
    obs, _ = world.reset(seed=4)
    for t, u in enumerate(demo["applied"]):
        assert np.array_equal(obs["image"], demo["images"][t])
        obs, *_ = world.step(u.astype(float))
    again = controller.demonstrate(world, seed=4, cfg=cfg)
    assert np.array_equal(again["actions"], demo["actions"])       # the noise is seeded
