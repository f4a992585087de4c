"""iLQG (oneshot.expert.ilqg) against an exact reference, and the expert (oneshot.expert.controller) against the
paper's success criterion."""
import dataclasses

import numpy as np
import pytest

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


def _lq_problem(seed=0, T=6):
    """A small random linear-quadratic problem: (x0, dynamics, cost)."""
    rng = np.random.default_rng(seed)
    A = np.eye(4) + 0.1 * rng.normal(size=(4, 4))
    B = 0.1 * rng.normal(size=(4, 2))
    return rng.normal(size=4), Linear(A, B), Quadratic(np.diag([1.0, 2, 0.5, 0.1]), 0.01 * np.eye(2), 10 * np.eye(4)), T


def test_the_closed_loop_rollout_takes_the_step_alpha_k_and_the_feedback_on_the_deviation():
    """u_t = u_bar_t + alpha k_t + K_t (x_t - x_bar_t), x_{t+1} = f(x_t, u_t), written out step by step on a
    linear system: the line search's alpha scales only the open-loop step."""
    x0, dynamics, _, T = _lq_problem()
    rng = np.random.default_rng(1)
    u_bar, k, K = rng.normal(size=(T, 2)), rng.normal(size=(T, 2)), 0.3 * rng.normal(size=(T, 2, 4))
    x_bar = rng.normal(size=(T + 1, 4))
    for alpha in (1.0, 0.25):
        x, u = ilqg.rollout(x0, u_bar, dynamics, x_bar, k, K, alpha)
        state = x0
        for t in range(T):
            expected = u_bar[t] + alpha * k[t] + K[t] @ (state - x_bar[t])
            np.testing.assert_allclose(u[t], expected, rtol=1e-12)
            np.testing.assert_allclose(x[t], state, rtol=1e-12)
            state = dynamics.A @ state + dynamics.B @ expected
        np.testing.assert_allclose(x[T], state, rtol=1e-12)
    x, u = ilqg.rollout(x0, u_bar, dynamics)                     # no gains: open loop
    assert np.array_equal(u, u_bar)


def test_the_expected_reduction_is_exact_on_a_linear_quadratic_problem():
    """For linear dynamics and a quadratic cost, the backward pass's prediction alpha dV[0] + alpha^2 dV[1]
    (mu = 0) is the cost change the closed-loop rollout with step alpha really makes, for any alpha."""
    x0, dynamics, cost, T = _lq_problem()
    u0 = np.random.default_rng(2).normal(size=(T, 2))
    x, u = ilqg.rollout(x0, u0, dynamics)
    A, B = dynamics.derivatives(x[:-1], u)
    k, K, dV = ilqg.backward_pass(A, B, *cost.derivatives(x, u), mu=0.0)
    J = cost.total(x, u)
    for alpha in (1.0, 0.5, 0.1):
        x_new, u_new = ilqg.rollout(x0, u, dynamics, x, k, K, alpha)
        assert cost.total(x_new, u_new) - J == pytest.approx(alpha * dV[0] + alpha ** 2 * dV[1], rel=1e-9)
    assert dV[0] < 0 < dV[1]


def test_regularisation_adds_mu_to_v_xx_in_the_gains_of_the_last_step():
    """Tassa et al. eq. 10 on a one-step problem, by hand: with V_xx = l_f'' the gains are
    k = -(luu + B^T (V_xx + mu I) B)^-1 (lu + B^T V_x) and K = -(...)^-1 (lux + B^T (V_xx + mu I) A)."""
    rng = np.random.default_rng(3)
    A, B = rng.normal(size=(1, 4, 4)), rng.normal(size=(1, 4, 2))
    lx, lu = rng.normal(size=(2, 4)), rng.normal(size=(1, 2))
    S = rng.normal(size=(4, 4))
    lxx = np.stack([np.eye(4), S @ S.T + np.eye(4)])
    luu, lux = np.eye(2)[None] * 0.5, rng.normal(size=(1, 2, 4))
    for mu in (0.0, 0.7):
        k, K, _ = ilqg.backward_pass(A, B, lx, lu, lxx, luu, lux, mu)
        V = lxx[1] + mu * np.eye(4)
        H = luu[0] + B[0].T @ V @ B[0]
        np.testing.assert_allclose(k[0], -np.linalg.solve(H, lu[0] + B[0].T @ lx[1]), rtol=1e-10)
        np.testing.assert_allclose(K[0], -np.linalg.solve(H, lux[0] + B[0].T @ V @ A[0]), rtol=1e-10)


def test_a_matrix_that_is_not_positive_definite_has_no_inverse():
    """The 2x2 closed form and the general case: the inverse of a positive definite matrix (np.linalg's),
    None for a negative definite or indefinite one (a negative definite 2x2 has a positive determinant)."""
    for n in (2, 3):
        S = np.random.default_rng(n).normal(size=(n, n))
        pd = S @ S.T + np.eye(n)
        np.testing.assert_allclose(ilqg._inverse_pd(pd), np.linalg.inv(pd), rtol=1e-12)
        assert ilqg._inverse_pd(-pd) is None
        assert ilqg._inverse_pd(np.diag([1.0] + [-1.0] * (n - 1))) is None


def test_the_stopping_rules_are_relative_so_the_cost_units_do_not_matter():
    """The same problem with its cost in units 10^8 times smaller (and 10^8 times larger):
    the same controls. (An absolute tolerance on the expected reduction stopped the small one at once.)"""
    x0, dynamics, cost, T = _lq_problem(T=10)
    results = []
    for scale in (1.0, 1e-8, 1e8):
        scaled = Quadratic(scale * cost.Q, scale * cost.R, scale * cost.Qf)
        results.append(ilqg.solve(x0, np.zeros((T, 2)), dynamics, scaled, ilqg.ILQGConfig(mu_init=0.0)))
    for r in results[1:]:
        assert r.converged
        np.testing.assert_allclose(r.u, results[0].u, rtol=1e-6, atol=1e-9)
    assert np.abs(results[0].u).max() > 0.1


def test_mu_follows_the_quadratic_schedule_down_to_zero(monkeypatch):
    """Tassa et al. Sec. II-F: after an accepted step delta = min(1 / 1.6, delta / 1.6) and mu = mu delta,
    set to 0 once below mu_min: the values the backward pass gets, from mu_init = 1e-3 with mu_min = 3e-4
    (1e-3, then x 1/1.6 = 6.25e-4, then x 1/1.6^2 = 2.4e-4 < mu_min: 0, and 0 from then on)."""
    x0, dynamics, cost, T = _lq_problem(T=10)
    seen, backward = [], ilqg.backward_pass
    monkeypatch.setattr(ilqg, "backward_pass", lambda *a: seen.append(a[-1]) or backward(*a))
    result = ilqg.solve(x0, np.zeros((T, 2)), dynamics, cost,
                        ilqg.ILQGConfig(mu_init=1e-3, mu_min=3e-4, tol_cost=1e-14, tol_grad=1e-14))
    assert result.converged and len(seen) >= 3 and len(result.cost_history) == len(seen)   # every step accepted
    np.testing.assert_allclose(seen[:2], [1e-3, 1e-3 / 1.6], rtol=1e-12)
    assert all(mu == 0.0 for mu in seen[2:])


def _fd_gradient(f, x, eps=1e-6):
    """Central differences of the scalar f at the array x: an array of x's shape."""
    g = np.zeros_like(x)
    for i in np.ndindex(x.shape):
        d = np.zeros_like(x)
        d[i] = eps
        g[i] = (f(x + d) - f(x - d)) / (2 * eps)
    return g


def test_the_reaching_costs_derivatives_are_its_gradient_and_gauss_newton_hessian():
    """ReachCost.derivatives against central differences of ReachCost.total: lx and lu are the gradient;
    lxx is 2 w J^T J on the angles (J: the end effector's finite-difference Jacobian) and 2 w on the
    velocities, with the final weights at the last state; luu = 2 w_ctrl I, lux = 0."""
    world_arm = WorldConfig().arm
    cfg = controller.ExpertConfig()
    rng = np.random.default_rng(4)
    T, target = 3, np.array([0.1, 0.15])
    x, v = rng.normal(size=(T + 1, 4)), rng.normal(size=(T, 2))
    cost = controller.ReachCost(target, world_arm, cfg)
    lx, lu, lxx, luu, lux = cost.derivatives(x, v)
    np.testing.assert_allclose(lx, _fd_gradient(lambda y: cost.total(y, v), x), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(lu, _fd_gradient(lambda w: cost.total(x, w), v), rtol=1e-6, atol=1e-9)
    for t in range(T + 1):
        J = np.stack([_fd_gradient(lambda q: arm.forward_kinematics(q, world_arm)[i], x[t, :2]) for i in range(2)])
        w_dist, w_vel = (cfg.w_dist_final, cfg.w_vel_final) if t == T else (cfg.w_dist, cfg.w_vel)
        np.testing.assert_allclose(lxx[t, :2, :2], 2 * w_dist * J.T @ J, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(lxx[t, 2:, 2:], 2 * w_vel * np.eye(2), rtol=1e-12)
        assert np.all(lxx[t, :2, 2:] == 0) and np.all(lxx[t, 2:, :2] == 0)
    np.testing.assert_allclose(luu, np.broadcast_to(2 * cfg.w_ctrl * np.eye(2), (T, 2, 2)), rtol=1e-12)
    assert np.all(lux == 0)


def test_the_squashed_arms_derivatives_are_those_of_its_step():
    """SquashedArm.derivatives against central differences of SquashedArm.step, where the squashing bends
    (controls of the order of the torque bound and beyond)."""
    model = dataclasses.replace(WorldConfig().arm, substeps=5)
    squashed = controller.SquashedArm(model)
    rng = np.random.default_rng(5)
    x = np.concatenate([rng.uniform(-1, 1, (3, 2)), rng.normal(size=(3, 2))], axis=1)
    v = np.array([[0.2, -0.3], [0.6, -0.8], [1.2, 0.4]])                  # max_torque is 0.5 N m
    A, B = squashed.derivatives(x, v)
    for t in range(3):
        for i in range(4):
            np.testing.assert_allclose(A[t, i], _fd_gradient(lambda y: squashed.step(y, v[t])[i], x[t]),
                                       rtol=1e-5, atol=1e-8)
            np.testing.assert_allclose(B[t, i], _fd_gradient(lambda w: squashed.step(x[t], w)[i], v[t]),
                                       rtol=1e-5, atol=1e-8)


def test_dart_noise_is_drawn_from_the_demonstrations_seed():
    """The noise on the expert's torques (applied - commanded, where no clip bound it) is its seed's: the
    same seed draws the same noise, another seed other noise, and its spread is the configured 0.1 N m."""
    world = ReachWorld()
    cfg = controller.ExpertConfig(action_noise=0.1)

    def noise(seed):
        demo = controller.demonstrate(world, seed=seed, cfg=cfg)
        inside = np.abs(demo["applied"]) < world.config.arm.max_torque
        return (demo["applied"] - demo["actions"])[inside]
    drawn = {seed: noise(seed) for seed in range(8)}
    np.testing.assert_array_equal(noise(0), drawn[0])
    assert not np.allclose(drawn[0][:10], drawn[1][:10])
    pooled = np.concatenate(list(drawn.values()))                      # about 300 draws
    assert len(pooled) > 200 and 0.08 < pooled.std() < 0.12 and abs(pooled.mean()) < 0.02
