"""Tests for oneshot/policy/conv.py: a layer's convolution, its transpose and its weight gradient as
three primitives (`conv`, `conv_dx`, `conv_dw`) that gather patches a block of images at a time.

Each is checked against the plain composition it replaces, `im2col` then a matrix product (itself
checked against naive loops in tests/test_layers.py), with blocks of every kind: one for all the
images, several tasks in one (the last block holding fewer), a task over several; against each other by the adjoint identity; and to second
order by autograd's recursive gradient check (MAML differentiates the network twice).
"""
import autograd.numpy as anp
import numpy as np
import pytest
from autograd.test_util import check_grads

from helpers import naive_conv2d
from oneshot.policy import conv as conv_module
from oneshot.policy.conv import col2im, conv, conv2d, conv_dw, conv_dx, conv_output_size, im2col

# (x shape, w shape, stride): shared and per-task filter banks (a leading task axis on x and w), the
# network's 3x3 stride 2 on even sides (the fast col2im) and odd ones, stride 1, and a 5x5 stride 3.
CASES = [((2, 3, 8, 6, 4), (2, 3, 3, 4, 5), 2), ((5, 8, 8, 3), (3, 3, 3, 4), 2), ((5, 7, 7, 3), (3, 3, 3, 4), 2),
         ((2, 3, 9, 8, 2), (5, 5, 2, 3), 3), ((3, 2, 5, 5, 2), (3, 3, 3, 2, 3), 1)]


@pytest.fixture(params=[1 << 20, 16000, 300], ids=["one block", "some tasks per block", "one image per block"])
def blocks(request, monkeypatch):
    monkeypatch.setattr(conv_module, "BLOCK_BYTES", request.param)


def composed(x, w, b, stride):
    """The plain composition: im2col, one matrix product per task, the bias."""
    *lead, h, width, c = x.shape
    k, m = w.shape[-4], w.shape[-1]
    tasks = w.shape[0] if w.ndim == 5 else 1
    cols = im2col(x.reshape(-1, h, width, c), k, stride, k // 2).reshape(tasks, -1, k * k * c)
    y = cols @ w.reshape(tasks, k * k * c, m)
    y = y.reshape(*lead, conv_output_size(h, k, stride), conv_output_size(width, k, stride), m)
    return y + (b.reshape((b.shape[0],) + (1,) * (y.ndim - 2) + (m,)) if b.ndim == 2 else b)


def problem(x_shape, w_shape, seed=0):
    rng = np.random.default_rng(seed)
    tasks = (w_shape[0],) if len(w_shape) == 5 else ()
    return rng.standard_normal(x_shape), rng.standard_normal(w_shape), rng.standard_normal(tasks + w_shape[-1:])


@pytest.mark.parametrize("x_shape, w_shape, stride", CASES)
def test_conv_and_its_transposes_equal_im2col_and_matrix_products(blocks, x_shape, w_shape, stride):
    x, w, b = problem(x_shape, w_shape)
    y = conv(x, w, b, stride)
    np.testing.assert_allclose(y, composed(x, w, b, stride), rtol=1e-12, atol=1e-12)
    g = np.random.default_rng(1).standard_normal(y.shape)
    k, tasks = w.shape[-4], w.shape[0] if w.ndim == 5 else 1
    g_rows = g.reshape(tasks, -1, w.shape[-1])
    cols = im2col(x.reshape(-1, *x.shape[-3:]), k, stride, k // 2).reshape(tasks, -1, k * k * x.shape[-1])
    dcols = g_rows @ np.swapaxes(w.reshape(tasks, -1, w.shape[-1]), -1, -2)
    images = (int(np.prod(x.shape[:-3])), *x.shape[-3:])
    dx = col2im(dcols.reshape(-1, dcols.shape[-1]), images, k, stride, k // 2)
    np.testing.assert_allclose(conv_dx(g, w, x.shape, stride), dx.reshape(x.shape), rtol=1e-12, atol=1e-12)
    dw = np.swapaxes(cols, -1, -2) @ g_rows
    np.testing.assert_allclose(conv_dw(x, g, w.shape, stride), dw.reshape(w.shape), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("x_shape, w_shape, stride", CASES)
def test_conv_transposes_are_its_adjoints(blocks, x_shape, w_shape, stride):
    # <conv(x, w), g> == <x, conv_dx(g, w)> == <w, conv_dw(x, g)>: each VJP is the exact transpose.
    x, w, _ = problem(x_shape, w_shape, seed=2)
    y = conv(x, w, None, stride)
    g = np.random.default_rng(3).standard_normal(y.shape)
    inner = float(np.sum(y * g))
    assert inner == pytest.approx(float(np.sum(x * conv_dx(g, w, x.shape, stride))), rel=1e-12)
    assert inner == pytest.approx(float(np.sum(w * conv_dw(x, g, w.shape, stride))), rel=1e-12)


@pytest.mark.parametrize("x_shape, w_shape, stride", CASES[:3] + CASES[4:])
def test_conv_second_order_gradients(blocks, x_shape, w_shape, stride):
    # sin(...) makes every second derivative non-zero: conv_dx and conv_dw are differentiated too.
    x, w, b = problem(x_shape, w_shape, seed=4)
    check_grads(lambda x, w, b: anp.sum(anp.sin(conv(x, w, b, stride))), modes=["rev"], order=2)(x, w, b)


def test_conv2d_on_data_and_on_activations_is_the_naive_convolution(blocks):
    # conv2d takes `conv` for a traced activation and im2col + a matrix product for data (images); both
    # are the naive loop convolution, and a shared bias with per-task weights is broadcast over tasks.
    x, w, b = problem((2, 3, 8, 6, 4), (2, 3, 3, 4, 5), seed=5)
    b = b[0]
    expected = np.stack([naive_conv2d(x[t], w[t], b, 2) for t in range(2)])
    np.testing.assert_allclose(conv2d(x, w, b, 2), expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(conv(x, w, b, 2), expected, rtol=1e-12, atol=1e-12)
    check_grads(lambda x, w: anp.sum(anp.sin(conv2d(x, w, b, 2))), modes=["rev"], order=2)(x, w)


def test_float32_stays_float32():
    x, w, b = (a.astype(np.float32) for a in problem((2, 3, 8, 8, 4), (2, 3, 3, 4, 5), seed=6))
    y = conv(x, w, b, 2)
    assert {y.dtype, conv_dx(y, w, x.shape, 2).dtype, conv_dw(x, y, w.shape, 2).dtype} == {np.dtype(np.float32)}


def test_a_shared_filter_bank_with_a_bias_per_task(blocks):
    # A parameter that adapts (the bias, one per task) beside one that does not (the filters).
    x, w, _ = problem((3, 2, 8, 8, 4), (3, 3, 4, 5), seed=7)
    b = np.random.default_rng(8).standard_normal((3, 5))
    np.testing.assert_allclose(conv(x, w, b, 2), composed(x, w, b, 2), rtol=1e-12, atol=1e-12)
    check_grads(lambda x, w, b: anp.sum(anp.sin(conv(x, w, b, 2))), modes=["rev"], order=2)(x, w, b)
