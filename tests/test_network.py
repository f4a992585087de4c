"""Tests for oneshot/network.py: the policy network of MIL Section IV.

Each test checks a property against something independent: finite differences (to second order,
since MAML differentiates through the gradient), the plain-autograd.numpy `forward_reference` for the
fast `forward` (values and gradients), a naive loop convolution for `conv2d_reference`, a hand count
of FLOPs, and the per-task `predict` for the batched `predict_tasks`. The layer primitives themselves:
tests/test_layers.py.
"""
import dataclasses

import autograd.numpy as anp
import numpy as np
import pytest
from autograd import grad
from autograd.core import primitive_vjps
from autograd.test_util import check_grads

from helpers import naive_conv2d, squared_error
from oneshot.policy.norm import layer_norm, layer_norm_reference
from oneshot.policy.network import (STRIDE, NetworkConfig, count_flops, forward, images_to_float, init_params,
                                    param_shapes, predict, predict_tasks)
from oneshot.policy.reference import conv2d_reference, forward_reference

TINY = NetworkConfig(image_size=8, channels=(2, 3), hidden=(5, 4), state_dim=3, action_dim=2)


def tiny_problem(config=TINY, T=2, dtype=np.float64, seed=0):
    rng = np.random.default_rng(seed)
    params = init_params(config, rng, dtype=dtype)
    params = {k: v + 0.1 * rng.standard_normal(v.shape).astype(dtype) for k, v in params.items()}  # nonzero biases
    s = config.image_size
    images = rng.random((T, s, s, 3)).astype(dtype)
    states = rng.standard_normal((T, config.state_dim)).astype(dtype)
    actions = rng.standard_normal((T, config.action_dim)).astype(dtype)
    return params, images, states, actions


# ----- the fast forward against the plain-autograd.numpy reference -----

OPTIONS = {"flattened": {}, "feature_points": {"feature_points": True}, "bias_transform": {"bias_transform": 3},
           "both": {"feature_points": True, "bias_transform": 2}, "layer_norm": {"layer_norm": True},
           "released": {"layer_norm": True, "bias_transform": 2}}


@pytest.mark.parametrize("options", OPTIONS.values(), ids=OPTIONS.keys())
def test_forward_equals_the_reference_values_and_gradients(options):
    """`forward` (custom primitives) computes `forward_reference` (plain autograd.numpy): the actions,
    the gradient of eq. (2) w.r.t. every parameter, and the MAML pattern's second-order gradient."""
    params, images, states, actions = tiny_problem(dataclasses.replace(TINY, **options), T=3)
    np.testing.assert_allclose(forward(params, images, states), forward_reference(params, images, states),
                               rtol=1e-10, atol=1e-12)
    fast, ref = squared_error(forward, images, states, actions), squared_error(forward_reference, images, states, actions)
    g_fast, g_ref = grad(fast)(params), grad(ref)(params)
    assert g_fast.keys() == g_ref.keys() == params.keys()
    for k in params:
        assert np.abs(g_ref[k]).max() > 1e-6, k                     # a real comparison, not 0 == 0
        np.testing.assert_allclose(g_fast[k], g_ref[k], rtol=1e-10, atol=1e-12, err_msg=k)

    def after_one_step(loss):   # the meta-gradient of one inner step of eq. (1) on the same demo
        return grad(lambda p: loss({k: p[k] - 0.01 * g for k, g in grad(loss)(p).items()}))(params)

    m_fast, m_ref = after_one_step(fast), after_one_step(ref)
    for k in params:
        np.testing.assert_allclose(m_fast[k], m_ref[k], rtol=1e-9, atol=1e-12, err_msg=k)


def test_reference_passes_the_second_order_gradient_check():
    params, images, states, actions = tiny_problem(dataclasses.replace(TINY, feature_points=True, bias_transform=2))
    check_grads(squared_error(forward_reference, images, states, actions), modes=["rev"], order=2)(params)


@pytest.mark.parametrize("stride, size, kernel", [(1, 5, 3), (1, 6, 3), (2, 7, 3), (2, 8, 3), (2, 7, 5), (1, 6, 5)])
def test_conv2d_reference_matches_naive_loops(stride, size, kernel):
    rng = np.random.default_rng(9)
    x = rng.standard_normal((2, size, size + 1, 3))                 # odd and even sides in one image
    w = rng.standard_normal((kernel, kernel, 3, 4))
    b = rng.standard_normal(4)
    out = conv2d_reference(x, w, b, stride)
    assert out.shape == (2, (size - 1) // stride + 1, size // stride + 1, 4)
    np.testing.assert_allclose(out, naive_conv2d(x, w, b, stride), rtol=1e-12, atol=1e-12)
    if stride == STRIDE:                                            # the network's stride is the default
        np.testing.assert_array_equal(conv2d_reference(x, w, b), out)


@pytest.mark.parametrize("options", [OPTIONS["flattened"], OPTIONS["both"], OPTIONS["layer_norm"]],
                         ids=["flattened", "both", "layer_norm"])
def test_per_task_forward_equals_the_reference_task_by_task(options):
    """MAML's batched path: parameters with a leading task axis (some or all of them) and a batch of
    demos give, task by task, the reference's actions and the reference's gradients (a per-task
    parameter's gradient row b is task b's; a shared parameter's is the sum over tasks)."""
    params, _, _, _ = tiny_problem(dataclasses.replace(TINY, **options))
    rng = np.random.default_rng(10)
    B = 3
    images, states, actions = rng.random((B, 2, 8, 8, 3)), rng.standard_normal((B, 2, 3)), rng.standard_normal((B, 2, 2))
    for adapted in (("conv0_w", "conv0_b"), tuple(params)):
        p = {k: np.stack([v + 0.1 * rng.standard_normal(v.shape) for _ in range(B)]) if k in adapted else v
             for k, v in params.items()}
        task = [{k: v[b] if k in adapted else v for k, v in p.items()} for b in range(B)]
        out = forward(p, images, states)
        assert out.shape == (B, 2, 2)
        for b in range(B):
            np.testing.assert_allclose(out[b], forward_reference(task[b], images[b], states[b]), rtol=1e-10, atol=1e-12)
        g = grad(squared_error(forward, images, states, actions))(p)
        g_tasks = [grad(squared_error(forward_reference, images[b], states[b], actions[b]))(task[b]) for b in range(B)]
        for k in params:
            expected = np.stack([gt[k] for gt in g_tasks]) if k in adapted else sum(gt[k] for gt in g_tasks)
            np.testing.assert_allclose(g[k], expected, rtol=1e-10, atol=1e-12, err_msg=k)


def test_network_second_order_gradients_with_per_task_parameters():
    # MAML's batched meta-objective: some parameters with a leading task axis (adapted), the rest
    # shared. Exercises the per-task branches of every layer primitive, to second order.
    params, _, _, _ = tiny_problem()
    rng = np.random.default_rng(7)
    images, states, actions = rng.random((3, 2, 8, 8, 3)), rng.standard_normal((3, 2, 3)), rng.standard_normal((3, 2, 2))
    for adapted in (("conv0_w", "conv0_b"), tuple(params)):
        p = {k: np.stack([v + 0.1 * b for b in range(3)]) if k in adapted else v for k, v in params.items()}
        check_grads(squared_error(predict_tasks, images, states, actions), modes=["rev"], order=2)(p)


def test_network_second_order_gradients():
    params, images, states, actions = tiny_problem()
    check_grads(squared_error(predict, images, states, actions), modes=["rev"], order=2)(params)


def test_network_second_order_gradients_with_bias_transform():
    params, images, states, actions = tiny_problem(NetworkConfig(**{**TINY.__dict__, "bias_transform": 2}))
    check_grads(squared_error(predict, images, states, actions), modes=["rev"], order=2)(params)


@pytest.mark.parametrize("image_size, flat", [(32, 4 * 4 * 40), (64, 8 * 8 * 40)])
def test_paper_shapes(image_size, flat):
    config = NetworkConfig(image_size=image_size)
    shapes = param_shapes(config)
    assert shapes["conv0_w"] == (3, 3, 3, 40) and shapes["conv2_w"] == (3, 3, 40, 40)
    assert shapes["fc0_w"] == (flat + 6, 100) and shapes["fc3_w"] == (100, 100) and shapes["out_w"] == (100, 2)
    assert list(shapes) == [f"conv{i}_{t}" for i in range(3) for t in "wb"] + [
        f"fc{i}_{t}" for i in range(4) for t in "wb"
    ] + ["out_w", "out_b"]
    params = init_params(config, np.random.default_rng(0))
    assert list(params) == list(shapes) and all(params[k].shape == shapes[k] for k in shapes)
    rng = np.random.default_rng(1)
    images = rng.random((5, image_size, image_size, 3), dtype=np.float32)
    actions = predict(params, images, np.zeros((5, 6), np.float32))
    assert actions.shape == (5, 2) and actions.dtype == np.float32


def test_init_scales_and_determinism():
    config = NetworkConfig()
    a, b = init_params(config, np.random.default_rng(7)), init_params(config, np.random.default_rng(7))
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert all(v.dtype == np.float32 for v in a.values())
    # He init: std of conv1 weights is sqrt(2 / (3 * 3 * 40)).
    assert np.std(a["conv1_w"]) == pytest.approx(np.sqrt(2 / 360), rel=0.05)
    assert not np.any(a["fc0_b"])


@pytest.mark.parametrize("init", ["he", "released"])
def test_biases_offsets_and_the_bias_transformation_start_at_zero(init):
    """As in MIL's released code (init_bias, `context`, layer_norm's beta): every additive parameter,
    the layer norm's offsets included, starts at zero, whatever the weights' init."""
    config = NetworkConfig(layer_norm=True, bias_transform=10, init=init)
    params = init_params(config, np.random.default_rng(0))
    additive = [k for k in params if k.endswith(("_b", "_offset")) or k == "bias_transform"]
    assert len(additive) == 3 + 3 + 1 + 4 + 1 and not any(np.any(params[k]) for k in additive)
    assert all(np.any(params[k]) for k in params if k not in additive)


def test_the_released_init_is_glorot_uniform_convolutions_and_small_dense_weights():
    """init="released" (--init=xavier): conv weights uniform on [-r, r], r = sqrt(6 / (9 C_in + 9 C_out)),
    so variance r^2 / 3; every dense weight N(0, 0.01^2); the default "he" differs from both."""
    released = init_params(NetworkConfig(init="released"), np.random.default_rng(0))
    he = init_params(NetworkConfig(), np.random.default_rng(0))
    for name, c_in in (("conv0_w", 3), ("conv1_w", 40), ("conv2_w", 40)):
        r = np.sqrt(6 / (9 * c_in + 9 * 40))
        w = released[name]
        assert np.abs(w).max() <= r and np.abs(w).max() > 0.95 * r
        assert np.std(w) == pytest.approx(r / np.sqrt(3), rel=0.1)
        assert np.std(he[name]) == pytest.approx(np.sqrt(2 / (9 * c_in)), rel=0.1)
    for name in ("fc0_w", "fc3_w", "out_w"):
        assert np.std(released[name]) == pytest.approx(0.01, rel=0.1) and np.std(he[name]) > 0.05
    with pytest.raises(ValueError, match="init must be one of he, released; got 'xavier'"):
        NetworkConfig(init="xavier")


def test_widths_and_init_are_checked_when_a_config_is_made_and_lists_become_tuples():
    from oneshot.training.config import TrainConfig
    for make in (NetworkConfig, TrainConfig):
        assert make(channels=[30, 30], hidden=[200]).channels == (30, 30) == make(channels=(30, 30)).channels
        assert make(hidden=[200]) == make(hidden=(200,)) and make(hidden=()).hidden == ()
        for bad, says in (({"channels": (30, 0)}, "channels must be whole numbers >= 1"),
                          ({"hidden": (2.5,)}, "hidden must be whole numbers >= 1"),
                          ({"hidden": (True,)}, "hidden must be whole numbers >= 1"),
                          ({"init": "xavier"}, "init must be one of he, released")):
            with pytest.raises(ValueError, match=says):
                make(**bad)


def test_bias_transform_adds_a_parameter_and_changes_the_output():
    config = NetworkConfig(bias_transform=10)
    params = init_params(config, np.random.default_rng(0))
    assert params["bias_transform"].shape == (10,)
    assert params["fc0_w"].shape[0] == param_shapes(NetworkConfig())["fc0_w"][0] + 10
    assert "bias_transform" not in init_params(NetworkConfig(), np.random.default_rng(0))
    rng = np.random.default_rng(1)
    images, states = rng.random((4, 32, 32, 3), dtype=np.float32), rng.standard_normal((4, 6)).astype(np.float32)
    before = predict(params, images, states)
    assert before.shape == (4, 2)
    # The vector feeds the first dense layer of every frame: moving it moves the actions.
    moved = dict(params, bias_transform=params["bias_transform"] + 1.0)
    after = predict(moved, images, states)
    assert after.shape == (4, 2) and not np.allclose(before, after)
    # ...and it gets a gradient (MAML adapts it in the inner loop).
    g = grad(lambda p: anp.sum(predict(p, images, states) ** 2))(params)
    assert np.any(g["bias_transform"] != 0)


def record_float_dtypes(monkeypatch):
    """Wrap every autograd VJP so that the dtype of each value and gradient it sees is recorded.

    The final gradient can come back float32 even when intermediate VJPs silently computed in
    float64 (e.g. autograd's VJP of `maximum` divides a mask by `1.0 + mask`), which costs speed, not
    correctness; only looking inside the backward pass catches that.
    """
    seen = set()

    def note(x):
        dtype = getattr(x, "dtype", None)
        if dtype is not None and np.issubdtype(dtype, np.floating):
            seen.add(np.dtype(dtype).name)

    def wrap(vjpmaker):
        def recording_vjpmaker(argnums, ans, args, kwargs):
            note(ans)
            vjp = vjpmaker(argnums, ans, args, kwargs)

            def recording_vjp(g):
                grads = tuple(vjp(g))
                for x in grads:
                    note(x)
                return grads

            return recording_vjp

        return recording_vjpmaker

    for fun, vjpmaker in list(primitive_vjps.items()):
        monkeypatch.setitem(primitive_vjps, fun, wrap(vjpmaker))
    return seen


@pytest.mark.parametrize("options", [{}, OPTIONS["released"]], ids=["default", "layer_norm"])
def test_float32_stays_float32_through_second_order(monkeypatch, options):
    params, images, states, actions = tiny_problem(dataclasses.replace(TINY, **options), dtype=np.float32)
    loss = squared_error(predict, images, states, actions)   # anp.sum: anp.mean's VJP would promote

    seen = record_float_dtypes(monkeypatch)
    g = grad(loss)(params)
    assert {v.dtype for v in g.values()} == {np.dtype(np.float32)}
    # The MAML pattern: differentiate the loss after one inner gradient step (second order).
    meta = grad(lambda p: loss({k: p[k] - np.float32(0.01) * gk for k, gk in grad(loss)(p).items()}))(params)
    assert {x.dtype for x in meta.values()} == {np.dtype(np.float32)}
    assert seen == {"float32"}, f"some VJP computed in {seen - {'float32'}}"


def test_float64_inputs_are_cast_to_params_dtype():
    params, images, states, _ = tiny_problem(dtype=np.float32)
    assert predict(params, images.astype(np.float64), states.astype(np.float64)).dtype == np.float32


def test_predict_tasks_matches_predict_per_task():
    params, _, _, _ = tiny_problem()
    rng = np.random.default_rng(5)
    images = rng.random((3, 2, 8, 8, 3))
    states = rng.standard_normal((3, 2, 3))
    per_task = {k: np.stack([v + 0.01 * b for b in range(3)]) for k, v in params.items()}
    for p in (params, per_task):  # shared params, then one set per task
        batched = predict_tasks(p, images, states)
        for b in range(3):
            p_b = {k: v[b] for k, v in per_task.items()} if p is per_task else params
            np.testing.assert_allclose(batched[b], predict(p_b, images[b], states[b]), rtol=1e-12)


def test_images_to_float():
    images = np.array([[[[0, 128, 255]]]], np.uint8)
    out = images_to_float(images)
    assert out.dtype == np.float32 and out.shape == images.shape
    np.testing.assert_allclose(out, [[[[0, 128 / 255, 1]]]], rtol=1e-7)
    with pytest.raises(ValueError, match="uint8"):
        images_to_float(out)


def test_bad_inputs_raise_actionable_errors():
    params = init_params(NetworkConfig(), np.random.default_rng(0))
    images = np.zeros((4, 32, 32, 3), np.float32)
    states = np.zeros((4, 6), np.float32)
    with pytest.raises(ValueError, match=r"images_to_float"):
        predict(params, images.astype(np.uint8), states)
    with pytest.raises(ValueError, match=r"\(T, H, W, 3\).*\(4, 32, 32\)"):
        predict(params, images[..., 0], states)
    with pytest.raises(ValueError, match=r"\(T, H, W, 3\).*\(4, 32, 32, 1\)"):
        predict(params, images[..., :1], states)
    with pytest.raises(ValueError, match=r"states must be \(4, 6\).*got \(4, 7\)"):
        predict(params, images, np.zeros((4, 7), np.float32))
    with pytest.raises(ValueError, match=r"states must be \(4, 6\).*got \(3, 6\)"):
        predict(params, images, states[:3])
    with pytest.raises(ValueError, match=r"image_size"):  # 64x64 images for params built for 32x32
        predict(params, np.zeros((4, 64, 64, 3), np.float32), states)
    with pytest.raises(ValueError, match=r"task axis of size 2"):
        bad = dict(params, out_b=np.zeros((3, 2), np.float32))  # 3 per-task copies, 2 tasks of images
        predict_tasks(bad, images[None].repeat(2, 0), states[None].repeat(2, 0))
    with pytest.raises(ValueError, match="odd"):
        NetworkConfig(kernel=4)


def test_count_flops_by_hand():
    # image 4x4x3 -> conv (3x3, 2 filters, stride 2) -> 2x2x2 = 8 features; + 1 state -> dense 5 -> out 2.
    config = NetworkConfig(image_size=4, channels=(2,), hidden=(5,), state_dim=1, action_dim=2)
    T = 3
    conv = 2 * T * (2 * 2) * (3 * 3 * 3) * 2  # 2 FLOPs x T x output pixels x patch size x filters = 1296
    dense = 2 * T * (8 + 1) * 5  # 270
    out = 2 * T * 5 * 2  # 60
    assert count_flops(config, T) == conv + dense + out == 1626
    # The paper network at 32x32: conv layers dominate.
    conv_macs = 16 * 16 * 27 * 40 + 8 * 8 * 360 * 40 + 4 * 4 * 360 * 40
    assert count_flops(NetworkConfig(), 1) == 2 * (conv_macs + 646 * 100 + 3 * 100 * 100 + 100 * 2)


def test_feature_points_second_order_gradients():
    """The network with the spatial soft-argmax option (and a bias transformation): exact
    second-order gradients through predict (the layer itself: tests/test_layers.py)."""
    cfg = NetworkConfig(image_size=8, channels=(3, 4), hidden=(5,), feature_points=True, bias_transform=2)
    rng = np.random.default_rng(0)
    params = init_params(cfg, rng, dtype=np.float64)
    assert params["fp_temperature"].shape == (1,)
    images, states = rng.random((2, 8, 8, 3)), rng.normal(size=(2, 6))
    check_grads(lambda p: predict(p, images, states), modes=["rev"], order=2)(params)


@pytest.mark.parametrize("per_task", [False, True], ids=["shared offset", "offset per task"])
def test_layer_norm_primitives_equal_the_plain_version_to_second_order(per_task):
    """norm.layer_norm (primitives with hand-written VJPs) against norm.layer_norm_reference (autograd.numpy):
    values, gradients, and the gradient of a gradient step's loss (MAML's second order), in float64."""
    rng = np.random.default_rng(4)
    x = rng.normal(1.0, 3.0, (2, 3, 4, 4, 5))
    offset = rng.normal(size=(2, 5) if per_task else (5,))
    w = rng.normal(size=x.shape)

    def loss(norm):          # a smooth, non-linear loss of the normalised map, as the next layers are
        return lambda x, offset: anp.sum(anp.tanh(norm(x, offset)) * w)

    def after_a_step(norm):  # the loss after one gradient step on x and offset: second order
        def f(x, offset):
            gx, go = grad(loss(norm), argnum=(0, 1))(x, offset)
            return loss(norm)(x - 0.1 * gx, offset - 0.1 * go)
        return f

    np.testing.assert_allclose(layer_norm(x, offset), layer_norm_reference(x, offset), rtol=1e-12, atol=1e-12)
    for f in (loss, after_a_step):
        for argnum in (0, 1):
            np.testing.assert_allclose(grad(f(layer_norm), argnum)(x, offset),
                                       grad(f(layer_norm_reference), argnum)(x, offset), rtol=1e-9, atol=1e-11)
    check_grads(lambda x: anp.sum(anp.tanh(layer_norm(x, offset)) * w), modes=["rev"], order=3)(x)


def test_layer_norm_second_order_gradients_and_what_it_normalises():
    """Layer norm (MIL's released code, offset only) passes the second-order check, on the plain path and
    the fast one; each frame's map, before the offset, has mean 0 and variance 1 over H, W and C."""
    config = dataclasses.replace(TINY, layer_norm=True, bias_transform=2)
    params, images, states, actions = tiny_problem(config)
    assert {k for k in params if k.startswith("ln")} == {"ln0_offset", "ln1_offset"}
    check_grads(squared_error(forward_reference, images, states, actions), modes=["rev"], order=2)(params)
    check_grads(squared_error(predict, images, states, actions), modes=["rev"], order=2)(params)
    x = np.random.default_rng(3).normal(2.0, 5.0, (4, 3, 5, 5, 6))
    y = layer_norm(x, np.zeros(6))
    np.testing.assert_allclose(y.mean(axis=(-3, -2, -1)), 0, atol=1e-12)
    np.testing.assert_allclose(y.var(axis=(-3, -2, -1)), 1, rtol=1e-6)
    offsets = np.arange(4 * 6).reshape(4, 6) / 10.0                 # per task: (B, C) for x's leading axis B = 4
    np.testing.assert_allclose(layer_norm(x, offsets) - y, np.broadcast_to(offsets[:, None, None, None, :], x.shape),
                               atol=1e-12)


def test_layer_norm_variance_floor_is_1e_minus_6():
    """A map of variance 1e-6 normalises to variance 1e-6 / (1e-6 + LN_EPSILON) = 0.5 (hand computation)."""
    z = np.random.default_rng(0).normal(size=(2, 4, 4, 3))
    z = (z - z.mean(axis=(1, 2, 3), keepdims=True)) / z.std(axis=(1, 2, 3), keepdims=True)
    y = layer_norm(5.0 + 1e-3 * z, np.zeros(3))
    np.testing.assert_allclose(y.var(axis=(1, 2, 3)), 0.5, rtol=1e-6)
    np.testing.assert_allclose(y, z / np.sqrt(2.0), rtol=1e-6, atol=1e-9)
