"""Tests for oneshot/optim.py: Adam (Kingma & Ba 2015, Algorithm 1) as pure functions."""
import numpy as np
import pytest

from oneshot.maml.optim import adam_init, adam_step, state_from_arrays, state_to_arrays


def test_two_steps_match_hand_computed_adam():
    lr, b1, b2, eps = 0.01, 0.9, 0.999, 1e-8
    p0 = np.array([1.0, -2.0, 0.5])
    g1 = np.array([0.3, -4.0, 0.0])
    g2 = np.array([-0.1, 2.0, 1.0])
    params, state = {"x": p0}, adam_init({"x": p0})
    params, state = adam_step(params, {"x": g1}, state, lr, b1, b2, eps)
    params, state = adam_step(params, {"x": g2}, state, lr, b1, b2, eps)

    # Algorithm 1 of Kingma & Ba, written out by hand for t = 1, 2.
    m1, v1 = 0.1 * g1, 0.001 * g1**2
    p1 = p0 - lr * (m1 / 0.1) / (np.sqrt(v1 / 0.001) + eps)  # = p0 - lr * g1 / (|g1| + eps)
    m2, v2 = 0.9 * m1 + 0.1 * g2, 0.999 * v1 + 0.001 * g2**2
    p2 = p1 - lr * (m2 / (1 - 0.9**2)) / (np.sqrt(v2 / (1 - 0.999**2)) + eps)

    np.testing.assert_allclose(p1, p0 - lr * np.sign(g1), atol=1e-9)  # first step is lr * sign(g)
    np.testing.assert_allclose(params["x"], p2, rtol=1e-12)
    np.testing.assert_allclose(state["m"]["x"], m2, rtol=1e-12)
    np.testing.assert_allclose(state["v"]["x"], v2, rtol=1e-12)
    assert state["step"] == 2


def test_minimises_an_ill_conditioned_quadratic():
    # f(x) = sum(c * (x - x_star)^2), curvatures spanning 4 orders of magnitude.
    c = np.array([100.0, 1.0, 0.01])
    x_star = np.array([1.0, -2.0, 3.0])
    params = {"x": np.zeros(3)}
    state = adam_init(params)
    for _ in range(3000):
        params, state = adam_step(params, {"x": 2 * c * (params["x"] - x_star)}, state, lr=0.05)
    np.testing.assert_allclose(params["x"], x_star, atol=1e-3)


def test_adam_step_is_pure_and_keeps_float32():
    rng = np.random.default_rng(0)
    params = {"W": rng.normal(size=(3, 2)).astype(np.float32), "b": np.zeros(2, np.float32)}
    grads = {k: rng.normal(size=v.shape).astype(np.float32) for k, v in params.items()}
    state = adam_init(params)
    copies = [{k: v.copy() for k, v in d.items()} for d in (params, grads, state["m"], state["v"])]
    new_params, new_state = adam_step(params, grads, state)
    for original, copy in zip((params, grads, state["m"], state["v"]), copies):
        for k in copy:
            assert np.array_equal(original[k], copy[k])
    assert state["step"] == 0 and new_state["step"] == 1
    for k in params:
        assert new_params[k].dtype == new_state["m"][k].dtype == new_state["v"][k].dtype == np.float32


def test_resuming_from_saved_state_is_bit_identical(tmp_path):
    rng = np.random.default_rng(1)
    params0 = {"W": rng.normal(size=(4, 3)).astype(np.float32), "b": np.zeros(3, np.float32)}
    grad_seq = [{k: rng.normal(size=v.shape).astype(np.float32) for k, v in params0.items()} for _ in range(20)]

    # Uninterrupted run.
    params, state = params0, adam_init(params0)
    for g in grad_seq:
        params, state = adam_step(params, g, state, lr=1e-2)

    # Interrupted after 10 steps: save params + state to one .npz, reload, continue.
    resumed, rstate = params0, adam_init(params0)
    for g in grad_seq[:10]:
        resumed, rstate = adam_step(resumed, g, rstate, lr=1e-2)
    np.savez(tmp_path / "ckpt.npz", **{f"params/{k}": v for k, v in resumed.items()}, **state_to_arrays(rstate))
    del resumed, rstate
    with np.load(tmp_path / "ckpt.npz") as f:
        resumed = {name[len("params/"):]: np.array(f[name]) for name in f.files if name.startswith("params/")}
        rstate = state_from_arrays(f)
    assert rstate["step"] == 10
    for g in grad_seq[10:]:
        resumed, rstate = adam_step(resumed, g, rstate, lr=1e-2)

    assert rstate["step"] == state["step"] == 20
    for k in params0:
        assert np.array_equal(resumed[k], params[k])
        assert np.array_equal(rstate["m"][k], state["m"][k])
        assert np.array_equal(rstate["v"][k], state["v"][k])


def test_state_from_arrays_reports_missing_prefix():
    arrays = state_to_arrays(adam_init({"w": np.zeros(2)}), prefix="meta_adam/")
    assert state_from_arrays(arrays, prefix="meta_adam/")["m"].keys() == {"w"}
    with pytest.raises(ValueError, match="prefix"):
        state_from_arrays(arrays, prefix="adam/")


def test_nonfinite_gradient_error_names_key_and_suggests_lower_learning_rate():
    params = {"W1": np.zeros((2, 2)), "b1": np.zeros(2)}
    state = adam_init(params)
    for bad in (np.nan, np.inf):
        grads = {"W1": np.zeros((2, 2)), "b1": np.array([0.0, bad])}
        with pytest.raises(ValueError, match=r"grads\['b1'\].*NaN/inf.*learning rate"):
            adam_step(params, grads, state)


def test_key_and_shape_mismatches_name_the_key():
    params = {"W1": np.zeros((2, 2)), "b1": np.zeros(2)}
    state = adam_init(params)
    with pytest.raises(ValueError, match=r"missing \['b1'\].*unexpected \['b2'\]"):
        adam_step(params, {"W1": np.zeros((2, 2)), "b2": np.zeros(2)}, state)
    with pytest.raises(ValueError, match=r"grads\['W1'\] has shape \(2, 3\).*\(2, 2\)"):
        adam_step(params, {"W1": np.zeros((2, 3)), "b1": np.zeros(2)}, state)
    with pytest.raises(ValueError, match=r"optimiser state.*unexpected \['b1'\]"):
        adam_step({"W1": np.zeros((2, 2))}, {"W1": np.zeros((2, 2))}, state)
