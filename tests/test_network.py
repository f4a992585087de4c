"""Tests for oneshot/network.py: the policy network of MIL Section IV.

Each test checks a property against something independent: finite differences (to second order,
since MAML differentiates through the gradient), a naive loop convolution, the adjoint identity,
a hand count of FLOPs, and the per-task `predict` for the batched `predict_tasks`.
"""

import autograd.numpy as anp
import numpy as np
import pytest
from autograd import grad
from autograd.core import primitive_vjps
from autograd.test_util import check_grads

from oneshot.layers import (_col2im_3x3_stride2, _col2im_any, add_bias, bias_grad, broadcast_bias, col2im,
                            concat_last, conv2d, im2col, matmul, matmul_dw, matmul_dx, relu, spatial_soft_argmax)
from oneshot.network import (NetworkConfig, count_flops, forward, forward_reference, images_to_float, init_params,
                             param_shapes, predict, predict_tasks)

TINY = NetworkConfig(image_size=8, channels=(2, 3), hidden=(5, 4), state_dim=3, action_dim=2)


def naive_conv2d(x, w, b, stride):
    """Reference 'same' convolution with explicit loops over output pixels (independent of im2col)."""
    n, h, width, c_in = x.shape
    k, _, _, c_out = w.shape
    p = k // 2
    h_out, w_out = (h + 2 * p - k) // stride + 1, (width + 2 * p - k) // stride + 1
    out = np.zeros((n, h_out, w_out, c_out))
    for i in range(h_out):
        for j in range(w_out):
            for dy in range(k):
                for dx in range(k):
                    y, xx = i * stride + dy - p, j * stride + dx - p
                    if 0 <= y < h and 0 <= xx < width:
                        out[:, i, j, :] += x[:, y, xx, :] @ w[dy, dx]
    return out + b


def tiny_problem(config=TINY, T=2, dtype=np.float64, seed=0):
    rng = np.random.default_rng(seed)
    params = init_params(config, rng, dtype=dtype)
    params = {k: v + 0.1 * rng.standard_normal(v.shape).astype(dtype) for k, v in params.items()}  # nonzero biases
    s = config.image_size
    images = rng.random((T, s, s, 3)).astype(dtype)
    states = rng.standard_normal((T, config.state_dim)).astype(dtype)
    actions = rng.standard_normal((T, config.action_dim)).astype(dtype)
    return params, images, states, actions


@pytest.mark.parametrize("stride, size", [(2, 7), (2, 8), (1, 5)])
def test_conv2d_matches_naive_loops(stride, size):
    rng = np.random.default_rng(1)
    x = rng.standard_normal((2, size, size + 1, 3))
    w = rng.standard_normal((3, 3, 3, 4))
    b = rng.standard_normal(4)
    np.testing.assert_allclose(conv2d(x, w, b, stride), naive_conv2d(x, w, b, stride), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("shape, kernel, stride", [((2, 7, 6, 3), 3, 2), ((1, 8, 8, 2), 3, 2), ((2, 5, 5, 3), 3, 1),
                                                   ((2, 9, 8, 2), 5, 3), ((1, 6, 7, 2), 5, 2), ((1, 4, 4, 1), 1, 2),
                                                   ((2, 6, 4, 3), 3, 2)])
def test_im2col_col2im_are_adjoint(shape, kernel, stride):
    # <im2col(x), y> == <x, col2im(y)> for every x, y: col2im is exactly the transpose of im2col.
    # Kernels that are not a multiple of the stride exercise col2im's partial blocks of taps.
    rng = np.random.default_rng(2)
    x = rng.standard_normal(shape)
    y = rng.standard_normal(im2col(x, kernel, stride, kernel // 2).shape)
    lhs = np.sum(im2col(x, kernel, stride, kernel // 2) * y)
    rhs = np.sum(x * col2im(y, shape, kernel, stride, kernel // 2))
    assert lhs == pytest.approx(rhs, rel=1e-12)


@pytest.mark.parametrize("shape, dtype", [((1, 2, 2, 1), np.float64), ((2, 4, 6, 3), np.float64),
                                          ((3, 16, 16, 40), np.float32), ((2, 8, 4, 5), np.float32)])
def test_col2im_fast_path_gives_the_same_bits(shape, dtype):
    # The policy's layers (3x3, stride 2, even sides) take `_col2im_3x3_stride2`, which must give
    # exactly the numbers of the general scatter-add, bit for bit: otherwise retraining with the same
    # seed would no longer reproduce the shipped policy.
    rng = np.random.default_rng(5)
    n, h, w, c = shape
    cols = rng.standard_normal((n * (h // 2) * (w // 2), 9 * c)).astype(dtype)
    fast = _col2im_3x3_stride2(cols, shape)
    slow = np.ascontiguousarray(_col2im_any(cols, shape, 3, 2, 1))
    assert fast.shape == shape and fast.dtype == dtype
    assert fast.tobytes() == slow.tobytes()
    assert col2im(cols, shape, 3, 2, 1).tobytes() == fast.tobytes()         # and col2im takes it


@pytest.mark.parametrize("shape", [(2, 5, 6, 2), (2, 6, 4, 2)])    # odd side: general col2im; even: fast
def test_conv_layer_second_order_gradients(shape):
    # The conv layer on a non-input activation exercises im2col, col2im and their mutual VJPs.
    rng = np.random.default_rng(3)
    x = rng.standard_normal(shape)
    w = rng.standard_normal((3, 3, 2, 3))
    b = rng.standard_normal(3)
    check_grads(lambda x, w, b: anp.sum(anp.sin(conv2d(x, w, b, 2))), modes=["rev"], order=2)(x, w, b)


@pytest.mark.parametrize("tasks", [0, 3])
def test_layer_primitives_are_adjoint_pairs(tasks):
    # Each primitive is linear in each argument, and its VJP must be its exact transpose:
    # <f(x), y> == <x, f^T(y)>. Checked for shared weights and per-task weights (a leading task axis).
    rng = np.random.default_rng(4)
    lead = (tasks, 2, 5) if tasks else (2, 5)  # (B, T, rows) activations, or (T, rows)
    x, g = rng.standard_normal(lead + (4,)), rng.standard_normal(lead + (3,))
    w = rng.standard_normal(((tasks,) if tasks else ()) + (4, 3))
    ip = lambda a, b: float(np.sum(a * b))
    assert ip(matmul(x, w), g) == pytest.approx(ip(x, matmul_dx(g, w)), rel=1e-12)
    assert ip(matmul(x, w), g) == pytest.approx(ip(w, matmul_dw(x, g, tasks)), rel=1e-12)
    np.testing.assert_allclose(matmul(x, w), x @ (w[:, None] if tasks else w), rtol=1e-12)
    b = rng.standard_normal(((tasks,) if tasks else ()) + (3,))
    assert ip(add_bias(np.zeros_like(g), b), g) == pytest.approx(ip(b, bias_grad(g, b.shape)), rel=1e-12)
    assert ip(broadcast_bias(b, g.shape), g) == pytest.approx(ip(b, bias_grad(g, b.shape)), rel=1e-12)
    y = rng.standard_normal((6, 16 * 3))  # add_bias's fast path (a multiple of 16 C entries)
    np.testing.assert_array_equal(add_bias(y.reshape(6, 16, 3), b[0] if tasks else b), y.reshape(6, 16, 3) + (b[0] if tasks else b))


def test_concat_relu_primitives_match_numpy_and_have_exact_second_order_gradients():
    rng = np.random.default_rng(6)
    a, b = rng.standard_normal((2, 3, 2)), rng.standard_normal((2, 3, 4))
    np.testing.assert_array_equal(concat_last(a, b), np.concatenate([a, b], axis=-1))
    np.testing.assert_array_equal(relu(a), np.maximum(a, 0))
    # sin(...) makes the second derivative of the composition non-zero through every primitive.
    check_grads(lambda a, b: anp.sum(anp.sin(concat_last(relu(a), b)) * concat_last(b, a)), modes=["rev"], order=2)(a, b)


def test_network_second_order_gradients_with_per_task_parameters():
    # MAML's batched meta-objective: some parameters with a leading task axis (adapted), the rest
    # shared. Exercises the per-task branches of every layer primitive, to second order.
    params, _, _, _ = tiny_problem()
    rng = np.random.default_rng(7)
    images, states, actions = rng.random((3, 2, 8, 8, 3)), rng.standard_normal((3, 2, 3)), rng.standard_normal((3, 2, 2))
    for adapted in (("conv0_w", "conv0_b"), tuple(params)):
        p = {k: np.stack([v + 0.1 * b for b in range(3)]) if k in adapted else v for k, v in params.items()}

        def loss(p):
            r = predict_tasks(p, images, states) - actions
            return anp.sum(r * r)

        check_grads(loss, modes=["rev"], order=2)(p)


def test_network_second_order_gradients():
    params, images, states, actions = tiny_problem()

    def loss(p):
        r = predict(p, images, states) - actions
        return anp.sum(r * r)

    check_grads(loss, modes=["rev"], order=2)(params)


def test_network_second_order_gradients_with_bias_transform():
    params, images, states, actions = tiny_problem(NetworkConfig(**{**TINY.__dict__, "bias_transform": 2}))

    def loss(p):
        r = predict(p, images, states) - actions
        return anp.sum(r * r)

    check_grads(loss, modes=["rev"], order=2)(params)


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


def test_float32_stays_float32_through_second_order(monkeypatch):
    params, images, states, actions = tiny_problem(dtype=np.float32)

    def loss(p):
        r = predict(p, images, states) - actions
        return anp.sum(r * r)  # (anp.mean here would promote: its VJP divides by a float64 count)

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


def test_feature_points_second_order_gradients_and_positions():
    """The spatial soft-argmax option: exact second-order gradients, and a lone hot spot's
    expected position is that spot's coordinates (x right, y down, in [-1, 1])."""
    cfg = NetworkConfig(image_size=8, channels=(3, 4), hidden=(5,), feature_points=True, bias_transform=2)
    rng = np.random.default_rng(0)
    params = init_params(cfg, rng, dtype=np.float64)
    assert params["fp_temperature"].shape == (1,)
    images, states = rng.random((2, 8, 8, 3)), rng.normal(size=(2, 6))
    check_grads(lambda p: predict(p, images, states), modes=["rev"], order=2)(params)
    x = np.zeros((1, 5, 5, 2))
    x[0, 1, 3, 0] = 50.0                    # channel 0: a spike at row 1, column 3
    points = spatial_soft_argmax(x, np.ones(1))
    np.testing.assert_allclose(points[0, [0, 2]], [0.5, -0.5], atol=1e-6)   # (x, y) of channel 0
    np.testing.assert_allclose(points[0, [1, 3]], [0.0, 0.0], atol=1e-12)   # flat channel 1: the centre
