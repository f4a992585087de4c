"""Tests for oneshot/policy/layers.py (and the affine and conv modules it gathers): the autograd primitives the policy network is built from.

Each test checks a property against something independent: a naive loop convolution
(tests/helpers.py), the adjoint identity <f(x), y> == <x, f^T(y)> for every linear primitive,
plain NumPy, bit-for-bit equality of col2im's fast path with its general scatter-add, and autograd's
recursive second-order gradient check (MAML differentiates the network twice).
"""
import warnings

import autograd.numpy as anp
import numpy as np
import pytest
from autograd import grad
from autograd.test_util import check_grads

from helpers import naive_conv2d
from oneshot.policy.conv import _col2im_3x3_stride2, _col2im_any
from oneshot.policy.layers import (add_bias, bias_grad, broadcast_bias, col2im, concat_last, conv2d, im2col, matmul,
                                   matmul_dw, matmul_dx, relu, spatial_soft_argmax, tanh)


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


def test_tanh_gives_autograds_bits_and_second_order_gradients_without_overflow_warnings():
    # the LSTM's tanh: values and first-order gradients are autograd.numpy's own, to the bit (so a seeded
    # LSTM run trains as before), second order by finite differences, and where cosh(x)^2 overflows
    # float32 (|x| > 45.05) the gradient is 0 (beyond 50: exactly) with no RuntimeWarning (autograd's own VJP warned)
    x = np.random.default_rng(0).normal(0, 20, (64, 32)).astype(np.float32)
    g = np.random.default_rng(1).normal(size=x.shape).astype(np.float32)
    mine = grad(lambda v: anp.sum(tanh(v) * g))(x)
    with np.errstate(over="ignore"):
        theirs = grad(lambda v: anp.sum(anp.tanh(v) * g))(x)
    np.testing.assert_array_equal(tanh(x), anp.tanh(x))
    np.testing.assert_array_equal(mine, theirs)
    far = np.abs(x) > 50
    assert mine.dtype == np.float32 and far.sum() > 10 and not mine[far].any()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        grad(lambda v: anp.sum(tanh(v) * g))(x)
        with pytest.raises(RuntimeWarning, match="overflow"):                       # what it replaces
            grad(lambda v: anp.sum(anp.tanh(v) * g))(x)
    y = np.random.default_rng(2).normal(size=(3, 4))
    check_grads(lambda v: anp.sum(anp.sin(3 * tanh(v)) * tanh(0.5 * v)), modes=["rev"], order=2)(y)


def test_feature_points_are_the_expected_positions_with_exact_second_order_gradients():
    """The spatial soft-argmax: a lone hot spot's expected position is that spot's coordinates
    (x right, y down, in [-1, 1]); a flat channel's is the centre; second-order gradients are exact."""
    x = np.zeros((1, 5, 5, 2))
    x[0, 1, 3, 0] = 50.0                    # channel 0: a spike at row 1, column 3
    points = spatial_soft_argmax(x, np.ones(1))
    np.testing.assert_allclose(points[0, [0, 2]], [0.5, -0.5], atol=1e-6)   # (x, y) of channel 0
    np.testing.assert_allclose(points[0, [1, 3]], [0.0, 0.0], atol=1e-12)   # flat channel 1: the centre
    rng = np.random.default_rng(8)
    x, temperature = rng.standard_normal((2, 4, 3, 2)), np.array([1.3])
    check_grads(lambda x, t: anp.sum(anp.sin(3 * spatial_soft_argmax(x, t))), modes=["rev"], order=2)(x, temperature)
