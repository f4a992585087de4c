"""Tests for oneshot/maml.py (paper Section II, eq. 1).

The model is a tiny tanh MLP (tests/helpers.py), independent of oneshot/network.py. Eq. (1) is
checked against the update written out by hand with autograd's `grad`. Gradients are checked
against central finite differences of the meta-objective, against autograd's own recursive
second-order check, and against closed forms for linear least squares.
"""
import autograd.numpy as anp
import numpy as np
import pytest
from autograd import grad
from autograd.test_util import check_grads

from helpers import make_demo, make_mlp, make_tasks, mlp_loss
from oneshot.maml import batched, inner
from oneshot.policy import network
from oneshot.maml.inner import (STEP_PREFIX, InnerLoop, clip_gradients, init_step_sizes, inner_update,
                                meta_gradient, meta_objective)


def axpy(a, x, y):
    """a * x + y for parameter dicts."""
    return {k: a * x[k] + y[k] for k in y}


def dot(x, y):
    return sum(float(np.sum(x[k] * y[k])) for k in x)


# ----- second-order meta-gradient vs. finite differences -----

@pytest.mark.parametrize("steps", [1, 3])
def test_meta_gradient_matches_central_differences(steps):
    rng = np.random.default_rng(0)
    params, tasks = make_mlp(rng), make_tasks(rng)
    alpha = 0.05  # large enough that the second-order term matters

    def f(p):
        return meta_objective(p, tasks, mlp_loss, alpha, steps)

    value, grads = meta_gradient(params, tasks, mlp_loss, alpha, steps)
    assert value == pytest.approx(f(params), rel=1e-14)
    h = 1e-5
    for _ in range(5):
        direction = {k: rng.normal(size=v.shape) for k, v in params.items()}
        numeric = (f(axpy(h, direction, params)) - f(axpy(-h, direction, params))) / (2 * h)
        assert dot(grads, direction) == pytest.approx(numeric, rel=1e-7, abs=1e-9)


def test_meta_objective_passes_autograd_second_order_check():
    rng = np.random.default_rng(1)
    params = make_mlp(rng, d_in=2, d_hidden=3, d_out=1)
    tasks = make_tasks(rng, n_tasks=2, T=3, d_in=2, d_out=1)
    check_grads(lambda p: meta_objective(p, tasks, mlp_loss, 0.1, 2), modes=["rev"], order=2)(params)


# ----- first-order approximation -----

def test_first_order_gradient_is_eval_gradient_at_adapted_params():
    rng = np.random.default_rng(2)
    params, tasks = make_mlp(rng), make_tasks(rng)
    alpha, steps = 0.05, 3
    grad_loss = grad(mlp_loss)

    # Independent reference: adapt with a hand-written loop, then average the plain eval gradients.
    expected = {k: np.zeros_like(v) for k, v in params.items()}
    expected_value = 0.0
    for adapt_demo, eval_demo in tasks:
        adapted = dict(params)
        for _ in range(steps):
            g = grad_loss(adapted, adapt_demo)
            adapted = {k: adapted[k] - alpha * g[k] for k in adapted}
        # First order changes the gradient only: the adapted parameters are eq. (1)'s, bit for bit.
        adapted_fo = inner_update(params, adapt_demo, mlp_loss, alpha, steps, first_order=True)
        adapted_so = inner_update(params, adapt_demo, mlp_loss, alpha, steps, first_order=False)
        for k in params:
            np.testing.assert_array_equal(adapted_fo[k], adapted_so[k])
            np.testing.assert_allclose(adapted_fo[k], adapted[k], rtol=1e-13, atol=1e-15)
        g_eval = grad_loss(adapted, eval_demo)
        expected = {k: expected[k] + g_eval[k] / len(tasks) for k in expected}
        expected_value += mlp_loss(adapted, eval_demo) / len(tasks)

    value_fo, grads_fo = meta_gradient(params, tasks, mlp_loss, alpha, steps, first_order=True)
    value_so, grads_so = meta_gradient(params, tasks, mlp_loss, alpha, steps, first_order=False)
    assert value_fo == pytest.approx(expected_value, rel=1e-12)
    assert value_so == pytest.approx(value_fo, rel=1e-12)  # same objective, different gradient
    for k in params:
        np.testing.assert_allclose(grads_fo[k], expected[k], rtol=1e-10, atol=1e-12)
    # On a nonlinear model the second-order terms are not negligible at this alpha.
    diff = np.sqrt(sum(np.sum((grads_fo[k] - grads_so[k]) ** 2) for k in params))
    norm = np.sqrt(sum(np.sum(grads_so[k] ** 2) for k in params))
    assert diff > 1e-2 * norm


def _first_order_reference_only_w1(params, tasks, alpha, steps):
    """First-order MAML adapting W1 alone, by hand: the mean over tasks of the plain gradient of the
    eval loss at the adapted parameters (every inner gradient a constant)."""
    expected = {k: np.zeros_like(v) for k, v in params.items()}
    for adapt_demo, eval_demo in tasks:
        adapted = dict(params)
        for _ in range(steps):
            adapted["W1"] = adapted["W1"] - alpha * grad(mlp_loss)(adapted, adapt_demo)["W1"]
        g_eval = grad(mlp_loss)(adapted, eval_demo)
        expected = {k: expected[k] + g_eval[k] / len(tasks) for k in params}
    return expected


def test_first_order_gradient_of_the_adapted_parameters_with_only():
    rng = np.random.default_rng(12)
    params, tasks = make_mlp(rng), make_tasks(rng, n_tasks=2)
    expected = _first_order_reference_only_w1(params, tasks, 0.05, 2)
    _, grads = meta_gradient(params, tasks, mlp_loss, 0.05, 2, first_order=True, only=("W1",))
    np.testing.assert_allclose(grads["W1"], expected["W1"], rtol=1e-10, atol=1e-12)


def test_first_order_gradient_of_the_shared_parameters_with_only():
    """The shared parameters' first-order meta-gradient is the plain eval gradient too: with the inner
    gradient a constant, they reach the eval loss directly and through no inner step."""
    rng = np.random.default_rng(12)
    params, tasks = make_mlp(rng), make_tasks(rng, n_tasks=2)
    expected = _first_order_reference_only_w1(params, tasks, 0.05, 2)
    _, grads = meta_gradient(params, tasks, mlp_loss, 0.05, 2, first_order=True, only=("W1",))
    # the batched training path (tasks stacked on a leading axis; W1 gets one copy per task) agrees
    adapt, evaluate = (tuple(np.stack(parts) for parts in zip(*side)) for side in zip(*tasks))
    _, batched_grads = batched.meta_gradient_batched(params, adapt, evaluate, mlp_loss, InnerLoop(0.05, 2, True, ("W1",)))
    for k in ("b1", "W2", "b2"):
        np.testing.assert_allclose(grads[k], expected[k], rtol=1e-10, atol=1e-12, err_msg=k)
        np.testing.assert_allclose(batched_grads[k], expected[k], rtol=1e-10, atol=1e-12, err_msg=k)


# ----- the inner update itself -----

@pytest.mark.parametrize("steps", [1, 2])
def test_inner_update_is_eq1_written_out(steps):
    """theta' = theta - alpha * grad L(theta, demo), repeated: against autograd's `grad` by hand."""
    rng = np.random.default_rng(13)
    params, demo = make_mlp(rng), make_demo(rng)
    alpha = 0.05
    theta = dict(params)
    for _ in range(steps):
        g = grad(mlp_loss)(theta, demo)
        theta = {k: theta[k] - alpha * g[k] for k in theta}
    adapted = inner_update(params, demo, mlp_loss, alpha, steps)
    assert list(adapted) == list(params)
    for k in params:
        np.testing.assert_allclose(adapted[k], theta[k], rtol=1e-13, atol=1e-15, err_msg=k)
        assert np.abs(adapted[k] - params[k]).min() > 0, k          # every element moved
    if steps == 2:   # the second step takes the gradient at the once-adapted parameters, not the first again
        g0 = grad(mlp_loss)(params, demo)
        assert not np.allclose(adapted["W1"], params["W1"] - 2 * alpha * g0["W1"], rtol=1e-6, atol=1e-9)


def test_inner_update_with_only_moves_only_the_chosen_parameters():
    """only=("W1",): eq. (1) on W1 alone (its gradient taken with the others fixed); the rest keep
    their values exactly. Prefixes match: only=("W",) moves W1 and W2 and neither bias."""
    rng = np.random.default_rng(14)
    params, demo = make_mlp(rng), make_demo(rng)
    alpha = 0.05
    w1 = params["W1"]
    for _ in range(2):
        w1 = w1 - alpha * grad(mlp_loss)({**params, "W1": w1}, demo)["W1"]
    adapted = inner_update(params, demo, mlp_loss, alpha, 2, only=("W1",))
    assert adapted.keys() == params.keys()
    np.testing.assert_allclose(adapted["W1"], w1, rtol=1e-13, atol=1e-15)
    assert np.abs(adapted["W1"] - params["W1"]).min() > 0
    for k in ("b1", "W2", "b2"):
        np.testing.assert_array_equal(adapted[k], params[k])
    moved = inner_update(params, demo, mlp_loss, alpha, 1, only=("W",))
    assert [k for k in params if not np.array_equal(moved[k], params[k])] == ["W1", "W2"]


def test_adaptation_lowers_adaptation_loss():
    rng = np.random.default_rng(3)
    for _ in range(5):
        params, demo = make_mlp(rng), make_demo(rng)
        adapted = inner_update(params, demo, mlp_loss, alpha=0.005, steps=3)
        assert mlp_loss(adapted, demo) < mlp_loss(params, demo)


def test_zero_step_size_or_zero_steps_returns_original_params_exactly():
    rng = np.random.default_rng(4)
    params, demo = make_mlp(rng), make_demo(rng)
    for adapted in (inner_update(params, demo, mlp_loss, alpha=0.0, steps=3),
                    inner_update(params, demo, mlp_loss, alpha=0.1, steps=0)):
        assert adapted.keys() == params.keys()
        for k in params:
            assert np.array_equal(adapted[k], params[k])


def test_inner_update_does_not_modify_params():
    rng = np.random.default_rng(5)
    params, demo = make_mlp(rng), make_demo(rng)
    before = {k: v.copy() for k, v in params.items()}
    inner_update(params, demo, mlp_loss, alpha=0.1, steps=3)
    meta_gradient(params, [(demo, demo)], mlp_loss, 0.1, 3)
    for k in params:
        assert np.array_equal(params[k], before[k])


# ----- closed forms for linear least squares: loss = ||X w - y||^2 -----

def lsq_loss(params, demo):
    X, y = demo
    return anp.sum((X @ params["w"] - y) ** 2)


def test_linear_least_squares_inner_update_and_meta_gradient_match_closed_form():
    rng = np.random.default_rng(7)
    d, alpha = 4, 0.02
    w = rng.normal(size=d)
    Xa, ya = rng.normal(size=(8, d)), rng.normal(size=8)
    Xe, ye = rng.normal(size=(8, d)), rng.normal(size=8)

    w_adapted = w - alpha * 2 * Xa.T @ (Xa @ w - ya)
    np.testing.assert_allclose(inner_update({"w": w}, (Xa, ya), lsq_loss, alpha, 1)["w"], w_adapted, rtol=1e-13)

    # d L(w'(w)) / dw = (dw'/dw)^T grad L(w') with dw'/dw = I - 2 alpha Xa^T Xa (symmetric).
    expected = (np.eye(d) - 2 * alpha * Xa.T @ Xa) @ (2 * Xe.T @ (Xe @ w_adapted - ye))
    value, grads = meta_gradient({"w": w}, [((Xa, ya), (Xe, ye))], lsq_loss, alpha, 1)
    assert value == pytest.approx(np.sum((Xe @ w_adapted - ye) ** 2), rel=1e-13)
    np.testing.assert_allclose(grads["w"], expected, rtol=1e-11)
    # First order drops the Jacobian: just the eval gradient at w'.
    _, grads_fo = meta_gradient({"w": w}, [((Xa, ya), (Xe, ye))], lsq_loss, alpha, 1, first_order=True)
    np.testing.assert_allclose(grads_fo["w"], 2 * Xe.T @ (Xe @ w_adapted - ye), rtol=1e-11)


def test_meta_objective_is_the_mean_over_tasks():
    rng = np.random.default_rng(8)
    params, tasks = make_mlp(rng), make_tasks(rng, n_tasks=4)
    per_task = [meta_objective(params, [t], mlp_loss, 0.01, 2) for t in tasks]
    assert meta_objective(params, tasks, mlp_loss, 0.01, 2) == pytest.approx(np.mean(per_task), rel=1e-13)


# ----- clipping -----

def test_clip_gradients_clips_large_and_keeps_small_values():
    grads = {"a": np.array([-25.0, -10.0, -3.5, 0.0, 9.99, 11.0]), "b": np.array([[1e6]], dtype=np.float32)}
    clipped = clip_gradients(grads, limit=10.0)
    np.testing.assert_array_equal(clipped["a"], [-10.0, -10.0, -3.5, 0.0, 9.99, 10.0])
    np.testing.assert_array_equal(clipped["b"], [[10.0]])
    assert clipped["b"].dtype == np.float32
    assert grads["a"][0] == -25.0  # input untouched
    with pytest.raises(ValueError, match="limit"):
        clip_gradients(grads, limit=0.0)


# ----- dtypes and errors -----

@pytest.mark.parametrize("first_order", [False, True])
def test_float32_stays_float32(first_order):
    rng = np.random.default_rng(9)
    params, tasks = make_mlp(rng, dtype=np.float32), make_tasks(rng, dtype=np.float32)
    alpha = np.float64(0.01)  # a float64 scalar step size must not promote the params
    adapted = inner_update(params, tasks[0][0], mlp_loss, alpha, 3, first_order)
    value, grads = meta_gradient(params, tasks, mlp_loss, alpha, 3, first_order)
    released = meta_gradient(params, tasks, mlp_loss, alpha, 1, first_order, clip=0.5, loss_scale=250.0)[1]
    assert all(g.dtype == np.float32 for g in released.values())      # the clip and the scale keep float32
    assert all(v.dtype == np.float32 for v in adapted.values())
    assert np.asarray(value).dtype == np.float32
    assert all(g.dtype == np.float32 for g in grads.values())
    assert all(g.dtype == np.float32 for g in clip_gradients(grads).values())


def test_bad_settings_raise_actionable_errors():
    rng = np.random.default_rng(10)
    params, demo = make_mlp(rng), make_demo(rng)
    with pytest.raises(ValueError, match="alpha"):
        inner_update(params, demo, mlp_loss, alpha=-0.1)
    with pytest.raises(ValueError, match="steps"):
        inner_update(params, demo, mlp_loss, steps=1.5)
    for option, bad in [("clip", -1.0), ("loss_scale", 0.0), ("first_order", 1), ("only", "W1")]:  # the InnerLoop checks
        with pytest.raises(ValueError, match=option):
            inner_update(params, demo, mlp_loss, **{option: bad})
    with pytest.raises(ValueError, match="at least one"):
        meta_objective(params, [], mlp_loss, 0.01, 1)
    with pytest.raises(ValueError, match="pair"):
        meta_objective(params, [(demo,)], mlp_loss, 0.01, 1)


# ----- learnt step sizes (Meta-SGD) -----

def test_learnt_step_sizes_equal_to_alpha_reproduce_scalar_alpha_and_are_dropped():
    rng = np.random.default_rng(9)
    params, tasks = make_mlp(rng), make_tasks(rng)
    with_steps = {**params, **init_step_sizes(params, 0.05, only=("W",))}
    assert sorted(k for k in with_steps if k.startswith(STEP_PREFIX)) == [STEP_PREFIX + "W1", STEP_PREFIX + "W2"]
    adapted = inner_update(with_steps, tasks[0][0], mlp_loss, alpha=123.0, steps=2, only=("W",))
    expected = inner_update(params, tasks[0][0], mlp_loss, alpha=0.05, steps=2, only=("W",))
    assert adapted.keys() == params.keys()           # the step sizes are not part of the model
    for k in params:
        np.testing.assert_array_equal(adapted[k], expected[k])
    # an element's own step size scales only that element's update
    scaled = dict(with_steps)
    scaled[STEP_PREFIX + "W1"] = with_steps[STEP_PREFIX + "W1"].copy()
    scaled[STEP_PREFIX + "W1"][0, 0] = 0.0
    adapted0 = inner_update(scaled, tasks[0][0], mlp_loss, alpha=0.05, steps=1, only=("W",))
    assert adapted0["W1"][0, 0] == params["W1"][0, 0] and adapted0["W1"][0, 1] != params["W1"][0, 1]


def test_meta_gradient_reaches_learnt_step_sizes_second_order():
    rng = np.random.default_rng(10)
    params = make_mlp(rng, d_in=2, d_hidden=3, d_out=1)
    params = {**params, **init_step_sizes(params, 0.1, only=("W1", "b1"))}
    params = {k: v + (0.02 * rng.normal(size=v.shape) if k.startswith(STEP_PREFIX) else 0) for k, v in params.items()}
    tasks = make_tasks(rng, n_tasks=2, T=3, d_in=2, d_out=1)
    def f(p):
        return meta_objective(p, tasks, mlp_loss, 0.0, 2, only=("W1", "b1"))

    check_grads(f, modes=["rev"], order=2)(params)
    _, g = meta_gradient(params, tasks, mlp_loss, 0.0, 2, only=("W1", "b1"))
    assert np.abs(g[STEP_PREFIX + "W1"]).max() > 0


def test_learnt_step_sizes_must_match_the_adapted_keys():
    rng = np.random.default_rng(11)
    params = make_mlp(rng)
    params = {**params, **init_step_sizes(params, 0.1, only=("W1",))}
    with pytest.raises(ValueError, match="init_step_sizes"):
        inner_update(params, make_demo(rng), mlp_loss, 0.1, 1, only=("W",))


def test_numpy_integers_are_step_counts():
    """`inner_update(steps=np.int64(2))` (a count from a NumPy array, as researchers pass) is two steps."""
    rng = np.random.default_rng(11)
    params, demo = make_mlp(rng), make_demo(rng)
    counted, two = (inner_update(params, demo, mlp_loss, alpha=0.05, steps=s) for s in (np.int64(2), 2))
    assert set(counted) == set(two)
    for k in two:
        np.testing.assert_array_equal(counted[k], two[k])
    with pytest.raises(ValueError, match="non-negative int"):
        inner_update(params, demo, mlp_loss, steps=np.float64(2.0))


def test_inner_loop_options_are_refused_in_one_line_when_they_cannot_mean_anything(rng):
    """A typo in `only` (fc_0 for fc0_) adapted only the other prefixes, silently; None for clip or frozen
    was a TypeError; a string step size was taken as a number."""
    params = network.init_params(network.NetworkConfig(image_size=8, channels=(3,), hidden=(4,)), rng)
    with pytest.raises(ValueError, match=r"no parameter starts with \['fc_0'\] of only=\('conv0', 'fc_0'\) \(a typo\?\)"):
        inner.adapted_keys(params, only=("conv0", "fc_0"))
    assert inner.adapted_keys(params, frozen=("ln",)) == list(params)          # a frozen prefix naming nothing
    for options, says in (({"clip": None}, "clip must be a finite number; got None"), ({"frozen": None}, "frozen must be a tuple"),
                          ({"alpha": "0.1"}, "alpha must be a finite number; got '0.1'"), ({"loss_scale": True}, "loss_scale")):
        with pytest.raises(ValueError, match=says):
            inner.InnerLoop(**options)
