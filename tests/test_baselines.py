"""The baselines of Section IV (oneshot/methods/) and the one interface over every method
(oneshot/methods/base.py): shapes, gradients against finite differences, and the property that makes each
baseline what it is (the contextual policy sees the demo's final image, the LSTM remembers the demo,
the random policy is as good as chance)."""
import dataclasses

import numpy as np
import pytest
from autograd.test_util import check_grads

from oneshot import methods
from oneshot.maml import batched, imitation
from oneshot.methods.contextual import contextual_images, contextual_loss, contextual_policy
from oneshot.methods.lstm import lstm_init_params, lstm_loss, lstm_network_config, lstm_policy, lstm_step
from oneshot.methods.random_policy import random_policy
from oneshot.policy import network
from oneshot.training import config
from oneshot.world.reach import ReachWorld, WorldConfig, success_window

NET = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5,), feature_points=True)
B, T = 2, 3


def _demos(rng, dtype=np.float64):
    return (rng.random((B, T, 8, 8, 3)).astype(dtype), rng.normal(size=(B, T, 6)).astype(dtype),
            rng.normal(size=(B, T, 2)).astype(dtype))


def _cfg(method, **overrides):
    return dataclasses.replace(config.PROFILES["smoke"], method=method, feature_points=True, **overrides)


@pytest.mark.parametrize("method", ["mil", "contextual", "lstm"])
def test_every_method_has_the_right_shapes_and_finite_difference_gradients(rng, method):
    cfg = _cfg(method, lstm_units=4, inner_steps=1, alpha=0.1, inner_params="conv0")
    method = methods.of(cfg)
    net_cfg = dataclasses.replace(method.network_config(8), channels=(3, 4), hidden=(5,))
    params = {k: v.astype(np.float64) for k, v in method.init_params(net_cfg, rng).items()}
    adapt, evaluate = _demos(rng), _demos(rng)
    loss, grads = method.meta_gradient(params, adapt, evaluate)
    assert np.ndim(loss) == 0 and grads.keys() == params.keys()
    assert all(grads[k].shape == params[k].shape and np.any(grads[k] != 0) for k in ("conv0_w", "out_w"))
    objective = {"mil": lambda p: batched.meta_objective_batched(p, adapt, evaluate, imitation.imitation_loss,
                                                                 methods.mil.inner_loop(cfg)),
                 "contextual": lambda p: contextual_loss(p, adapt, evaluate),
                 "lstm": lambda p: lstm_loss(p, adapt, evaluate)}[cfg.method]
    assert float(objective(params)) == pytest.approx(float(loss), rel=1e-12)
    check_grads(objective, modes=["rev"], order=2 if method.adapts else 1)(params)
    policy = method.conditioner(params)(tuple(a[0] for a in adapt))
    image, state = evaluate[0][0, :1], evaluate[1][0, :1]
    action = policy(image, state, None) if callable(policy) else network.forward(policy, image, state)
    assert np.shape(action) == (1, 2)


def test_the_contextual_policy_sees_the_demos_final_image(rng):
    params = network.init_params(dataclasses.replace(NET, image_channels=6), rng, np.float64)
    params = {k: v + 0.3 * rng.normal(size=v.shape) for k, v in params.items()}   # no dead ReLU, live biases
    demo = tuple(a[0] for a in _demos(rng))
    image, state = rng.random((1, 8, 8, 3)), rng.normal(size=(1, 6))
    before = contextual_policy(params, demo)(image, state, None)
    early = (demo[0].copy(), demo[1], demo[2])
    early[0][0] = 1 - early[0][0]                                        # another first frame: no change
    np.testing.assert_array_equal(contextual_policy(params, early)(image, state, None), before)
    final = (demo[0].copy(), demo[1], demo[2])
    final[0][-1] = 1 - final[0][-1]                                      # another final frame: new action
    assert np.abs(contextual_policy(params, final)(image, state, None) - before).max() > 1e-6
    stacked = contextual_images(demo[0], demo[0][-1])
    assert stacked.shape == (T, 8, 8, 6) and np.array_equal(stacked[1, ..., 3:], demo[0][-1])


def test_the_lstm_carries_the_demo_in_its_state(rng):
    cfg = lstm_network_config(NET, 4)
    params = lstm_init_params(cfg, 4, rng, np.float64)
    assert params["lstm_w"].shape[1] == 16 and np.all(params["lstm_b"][4:8] == 1.0)     # forget gate opens
    params = {k: v + 0.3 * rng.normal(size=v.shape) for k, v in params.items()}   # no dead ReLU, live biases
    demo = tuple(a[0] for a in _demos(rng))
    image, state = rng.random((1, 8, 8, 3)), rng.normal(size=(1, 6))
    before = lstm_policy(params, demo)(image, state, None)
    for k in range(3):                                # the demo's first frame: its image, state, action
        changed = [a.copy() for a in demo]
        changed[k][0] = 1.0 - changed[k][0] if k == 0 else changed[k][0] + 1.0    # images stay in [0, 1]
        assert np.abs(lstm_policy(params, tuple(changed))(image, state, None) - before).max() > 1e-6, k
    # one step by hand: c' = s(f) c + s(i) tanh(g), h' = s(o) tanh(c')
    h, c, xw = rng.normal(size=(1, 4)), rng.normal(size=(1, 4)), rng.normal(size=(1, 16))
    w_h = params["lstm_w"][-4:]
    z = xw + h @ w_h
    s = lambda x: 1 / (1 + np.exp(-x))
    c_ref = s(z[:, 4:8]) * c + s(z[:, :4]) * np.tanh(z[:, 8:12])
    h1, c1 = lstm_step(w_h, xw, h, c)
    np.testing.assert_allclose(c1, c_ref, rtol=1e-12)
    np.testing.assert_allclose(h1, s(z[:, 12:]) * np.tanh(c_ref), rtol=1e-12)


def test_a_random_policy_of_zero_torque_succeeds_exactly_when_the_target_is_already_within_reach():
    """Analytic expectation on a tiny case: with std 0 the arm never moves (a planar arm at rest,
    no gravity), so a trial succeeds iff the target lies within the success radius of the start."""
    world = ReachWorld(WorldConfig(split="validation"))
    policy = random_policy(0.0, np.random.default_rng(0))
    start = None
    for seed in range(40):
        trial = imitation.rollout(policy, world, seed)
        start = trial["end_effector"][0] if start is None else start
        np.testing.assert_allclose(trial["end_effector"], np.broadcast_to(start, trial["end_effector"].shape),
                                   atol=1e-6)
        expected = np.linalg.norm(trial["scene"].target_position - start) <= world.config.success_radius
        assert trial["success"] == expected
    assert success_window(world.config.horizon) == 4


def test_the_random_policy_is_reproducible_and_its_std_is_what_it_draws():
    a = random_policy(0.3, np.random.default_rng(5))
    b = random_policy(0.3, np.random.default_rng(5))
    draws = np.concatenate([a(None, None, None) for _ in range(4000)])
    assert np.array_equal(draws[:10], np.concatenate([b(None, None, None) for _ in range(10)]))
    assert draws.std() == pytest.approx(0.3, rel=0.05) and abs(draws.mean()) < 0.02


def test_methods_refuse_unknown_names_and_the_random_policy_has_no_gradient():
    with pytest.raises(ValueError, match="method must be one of"):
        methods.of(_cfg("maml"))
    with pytest.raises(NotImplementedError, match="does not learn by gradient"):
        methods.of(_cfg("random")).meta_gradient({}, None, None)


def test_the_contextual_loss_is_eq2_on_the_evaluate_demo_beside_the_adapt_demos_final_image(rng):
    """contextual_loss by hand: for each task, the network on the evaluate frames with the ADAPT demo's
    final image as channels 3..5 of every frame; eq. (2) summed over frames, averaged over the B tasks."""
    params = network.init_params(dataclasses.replace(NET, image_channels=6), rng, np.float64)
    params = {k: v + 0.3 * rng.normal(size=v.shape) for k, v in params.items()}
    adapt, evaluate = _demos(rng), _demos(rng)
    losses = []
    for b in range(B):
        context = np.repeat(adapt[0][b, -1][None], T, axis=0)                    # (T, 8, 8, 3)
        u = network.forward(params, np.concatenate([evaluate[0][b], context], axis=-1), evaluate[1][b])
        losses.append(np.sum((u - evaluate[2][b]) ** 2))
    assert float(contextual_loss(params, adapt, evaluate)) == pytest.approx(np.mean(losses), rel=1e-12)


def _lstm_by_hand(params, demo, units):
    """The LSTM of Hochreiter & Schmidhuber with a forget gate, in plain NumPy on one demo (images (T, H, W,
    3), states, actions): x_t = [features, state, action], [i, f, g, o] = [x_t, h] lstm_w + lstm_b,
    c = s(f) c + s(i) tanh(g), h = s(o) tanh(c). Returns the final h (units,)."""
    s = lambda z: 1 / (1 + np.exp(-z))
    features = network.trunk(params, demo[0])
    h, c = np.zeros(units), np.zeros(units)
    for t in range(len(demo[0])):
        z = np.concatenate([features[t], demo[1][t], demo[2][t], h]) @ params["lstm_w"] + params["lstm_b"]
        i, f, g, o = np.split(z, 4)
        c = s(f) * c + s(i) * np.tanh(g)
        h = s(o) * np.tanh(c)
    return h


def test_the_lstm_policy_reads_every_frame_of_the_demo_and_acts_on_features_state_and_summary(rng):
    """Against a plain NumPy LSTM (`_lstm_by_hand`): the policy after reading a demo is the head on
    [the frame's features, its state, the final hidden state]; lstm_loss is eq. (2) of that policy on
    the evaluate demo after reading the adapt demo, averaged over the B tasks. Its demo's last frame
    counts (changing only it changes the action)."""
    units = 4
    params = lstm_init_params(lstm_network_config(NET, units), units, rng, np.float64)
    params = {k: v + 0.3 * rng.normal(size=v.shape) for k, v in params.items()}
    adapt, evaluate = _demos(rng), _demos(rng)
    image, state = rng.random((1, 8, 8, 3)), rng.normal(size=(1, 6))
    demo = tuple(a[0] for a in adapt)
    h = _lstm_by_hand(params, demo, units)
    expected = network.head(params, np.concatenate([network.trunk(params, image), state, h[None]], axis=1))
    np.testing.assert_allclose(lstm_policy(params, demo)(image, state, None), expected, rtol=1e-10)
    losses = []
    for b in range(B):
        h = _lstm_by_hand(params, tuple(a[b] for a in adapt), units)
        context = np.repeat(h[None], T, axis=0)
        u = network.head(params, np.concatenate([network.trunk(params, evaluate[0][b]), evaluate[1][b], context], 1))
        losses.append(np.sum((u - evaluate[2][b]) ** 2))
    assert float(lstm_loss(params, adapt, evaluate)) == pytest.approx(np.mean(losses), rel=1e-10)
    last = (demo[0], demo[1], demo[2].copy())
    last[2][-1] += 1.0                                             # only the last frame's action
    assert np.abs(lstm_policy(params, last)(image, state, None) - expected).max() > 1e-6


def test_the_random_policy_keeps_the_std_that_scored_best_and_draws_from_its_seed(monkeypatch):
    """fit: of cfg.random_stds the one whose trials scored best (the first of equals), each scored with the
    seed it is given; conditioner: torques of the std's spread drawn from its seed, one stream through
    every demo it is shown (so trials differ), the same stream again for the same seed, another for
    another seed."""
    method = methods.of(_cfg("random", random_stds=(0.1, 0.5, 1.0, 2.0)))
    rates, seen = iter([0.2, 0.6, 0.6, 0.1]), []

    def scored(condition, dataset, trials, seed, progress):
        seen.append(seed)
        return {"rate": next(rates)}
    monkeypatch.setattr(imitation, "one_shot_success", scored)
    best, scores = method.fit(method.init_params(None, None), "dataset", 3, seed=7)
    assert scores == {0.1: 0.2, 0.5: 0.6, 1.0: 0.6, 2.0: 0.1} and best["std"].tolist() == [0.5] and seen == [7] * 4

    def trials(seed, n):                      # the torques of n trials of one conditioner: (n, 2)
        condition = method.conditioner({"std": np.array([0.5], np.float32)}, seed=seed)
        return np.concatenate([condition(None)(None, None, None) for _ in range(n)])
    drawn = trials(3, 1000)
    assert drawn.shape == (1000, 2) and not np.allclose(drawn[0], drawn[1])     # trials differ
    assert 0.46 < drawn.std() < 0.54 and abs(drawn.mean()) < 0.05              # N(0, 0.5^2)
    np.testing.assert_array_equal(trials(3, 2), drawn[:2])                    # the seed's stream again
    assert not np.allclose(trials(4, 2), drawn[:2])
