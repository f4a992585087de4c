"""Tests for oneshot/batched.py, the training path of MAML: `value_and_grads` against autograd's own
`value_and_grad`, to second order. (The batched meta-objective against the plain per-task loop of
oneshot/maml.py, on the real network: tests/test_imitation.py.)"""
import autograd.numpy as anp
import numpy as np
import pytest
from autograd import grad, value_and_grad
from autograd.test_util import check_grads

from helpers import make_demo, make_mlp, mlp_loss
from oneshot.maml import batched
from oneshot.maml.batched import value_and_grads
from oneshot.maml.inner import InnerLoop


# ----- value_and_grads: autograd's value_and_grad for a dict of arrays, one root per array -----

def test_value_and_grads_equals_autograd_value_and_grad_and_gives_zeros_for_unused_arrays():
    rng = np.random.default_rng(7)
    params, demo = make_mlp(rng), make_demo(rng)
    params["unused"] = rng.normal(size=(2, 3))
    value, grads = value_and_grads(mlp_loss, params, demo)
    ref_value, ref_grads = value_and_grad(mlp_loss)(params, demo)
    assert value == ref_value and grads.keys() == params.keys()
    for k in params:
        np.testing.assert_array_equal(grads[k], ref_grads[k])
    assert not grads["unused"].any() and grads["unused"].shape == (2, 3)
    # an output that does not depend on the arrays at all: its value, and zero gradients
    value, grads = value_and_grads(lambda p: 2.5, params)
    assert value == 2.5 and all(not g.any() and g.shape == params[k].shape for k, g in grads.items())


def test_value_and_grads_nests_to_second_order():
    """Inside an outer gradient (as in MAML's inner steps) its backward pass is recorded: the
    derivative of a function of the gradient matches autograd's own nesting and finite differences."""
    rng = np.random.default_rng(8)
    params, demo = make_mlp(rng), make_demo(rng)

    def gradient_norm(p, grads_of):
        g = grads_of(p)
        return sum(anp.sum(g[k] ** 2) for k in g)

    ours = lambda p: gradient_norm(p, lambda q: value_and_grads(mlp_loss, q, demo)[1])
    autograds = lambda p: gradient_norm(p, lambda q: grad(mlp_loss)(q, demo))
    assert ours(params) == pytest.approx(autograds(params), rel=1e-12)
    g1, g2 = grad(ours)(params), grad(autograds)(params)
    for k in params:
        np.testing.assert_allclose(g1[k], g2[k], rtol=1e-10, atol=1e-12)
    check_grads(lambda w1: ours({**params, "W1": w1}), modes=["rev"], order=2)(params["W1"])


def test_packed_reduce_equals_reducing_each_array_to_second_order():
    # The frame shards reduce an inner gradient's arrays together, packed into one vector
    # (`batched._reduced`); for a reduce that acts element by element that is reducing each array on
    # its own: the same values and, through `pack`, `piece` and `embed`, the same gradients.
    rng = np.random.default_rng(3)
    arrays = {"a": rng.standard_normal((2, 3)), "b": rng.standard_normal(4), "c": rng.standard_normal((2, 1, 2))}
    weights = {k: rng.standard_normal(v.shape) for k, v in arrays.items()}
    reduce = lambda v: 3.0 * v + v * v                                       # element by element

    def loss(reduce_all):
        return lambda arrays: sum(anp.sum(anp.sin(r) * weights[k]) for k, r in reduce_all(arrays).items())

    packed = loss(lambda g: batched._reduced(g, reduce))
    each = loss(lambda g: {k: reduce(v) for k, v in g.items()})
    assert packed(arrays) == pytest.approx(each(arrays), rel=1e-14)
    g_packed, g_each = grad(packed)(arrays), grad(each)(arrays)
    for k in arrays:
        np.testing.assert_allclose(g_packed[k], g_each[k], rtol=1e-13)
    check_grads(packed, modes=["rev"], order=2)(arrays)


def test_the_inner_clip_acts_after_the_reduce_over_processes():
    """theta' = theta - alpha clip(reduce(g)): with reduce = 3 g (three processes' equal parts) and clip
    0.5, an element whose part is 0.3 moves by alpha * 0.5; clipping each part first would move it by
    alpha * 0.9. By hand, on a loss linear in w (gradient d whatever w)."""
    d = np.array([[0.3, -0.05, 0.1], [-0.4, 0.2, 0.01]])                     # 2 tasks
    loss_tasks = lambda p, demos: anp.sum(demos * p["w"])
    adapted = batched.adapt_batch({"w": np.zeros(3)}, d, loss_tasks, InnerLoop(alpha=0.1, steps=1, clip=0.5),
                                  reduce=lambda v: 3.0 * v)
    np.testing.assert_allclose(adapted["w"], -0.1 * np.clip(3.0 * d, -0.5, 0.5), rtol=1e-15)
