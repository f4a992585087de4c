"""A layer's affine maps as autograd primitives closed under differentiation: the matrix product
y = x @ w and the bias add, with their transposes (paper Section IV's dense layers, and the
convolutions once their patches are rows: `oneshot.policy.conv`).

Each primitive's vector-Jacobian product (VJP) is written with primitives of the same family, so every
order of derivative works (MAML's second-order meta-gradient differentiates the network twice) while
the recorded graph stays a few large nodes per layer. `oneshot.policy.layers` gathers them with the
rest of the network's primitives; `reference.forward_reference` is the same network in plain
`autograd.numpy`, and the tests prove the two equal (docs/network.md).
"""
import numpy as np
from autograd.extend import defvjp, primitive


# Written with autograd.numpy's small operations (reshape, matmul, swapaxes, +, *, sum), one
# second-order meta-gradient records thousands of nodes, most of them bookkeeping inside autograd's
# own VJPs (broadcast sums, shape queries, transposes), each costing tens of microseconds of Python.
#
# The matrix product of a layer, y = x @ w, is a bilinear map; its two VJPs are bilinear maps of the
# same kind, and so are theirs (u is the incoming gradient):
#     matmul(x, w)     = x w          VJPs: x <- matmul_dx(g, w),  w <- matmul_dw(x, g)
#     matmul_dx(g, w)  = g w^T        VJPs: g <- matmul(u, w),     w <- matmul_dw(u, g)
#     matmul_dw(x, g)  = x^T g        VJPs: x <- matmul_dx(g, u),  g <- matmul(x, u)
# A convolution is matmul(im2col(x), w) (`oneshot.policy.conv`). The weight w
# is shared by all tasks, (K, M), or has a leading task axis, (B, K, M): one copy per task, as after
# MAML's inner step. x: (..., K), every row times w; with per-task w its rows are task-major
# (the first 1/B of the rows belong to task 0, ...), as `im2col` and the (B, T, n) activations give.


def _rows(x, w):
    """x as a matrix of rows: (R, K) for a shared weight (every task's rows), (B, R / B, K) per task."""
    return x.reshape((w.shape[0], -1, x.shape[-1]) if w.ndim == 3 else (-1, x.shape[-1]))


def _tasks(w):
    """B for a per-task weight (B, K, M), 0 for a shared one (K, M)."""
    return w.shape[0] if w.ndim == 3 else 0


@primitive
def matmul(x, w):
    """y = x @ w for a layer: x (..., K), w (K, M) or per task (B, K, M) -> (..., M)."""
    return (_rows(x, w) @ w).reshape(x.shape[:-1] + (w.shape[-1],))


@primitive
def matmul_dx(g, w):
    """VJP of `matmul` with respect to x: g @ w^T. g: (..., M) -> (..., K)."""
    return (_rows(g, w) @ np.swapaxes(w, -1, -2)).reshape(g.shape[:-1] + (w.shape[-2],))


@primitive
def matmul_dw(x, g, tasks):
    """VJP of `matmul` with respect to w: x^T @ g summed over rows: over each task's rows for a
    per-task w (tasks = B; result (B, K, M)), over all of them for a shared w (tasks = 0; (K, M))."""
    shape = (tasks, -1) if tasks else (-1,)
    return np.swapaxes(x.reshape(shape + x.shape[-1:]), -1, -2) @ g.reshape(shape + g.shape[-1:])


defvjp(matmul,
       lambda ans, x, w: lambda g: matmul_dx(g, w),
       lambda ans, x, w: lambda g: matmul_dw(x, g, _tasks(w)))
defvjp(matmul_dx,
       lambda ans, g, w: lambda u: matmul(u, w),
       lambda ans, g, w: lambda u: matmul_dw(u, g, _tasks(w)))
defvjp(matmul_dw,
       lambda ans, x, g, tasks: lambda u: matmul_dx(g, u),
       lambda ans, x, g, tasks: lambda u: matmul(x, u))


def _bias_view(b, ndim):
    """Bias (C,) shared, or (B, C) per task -> broadcastable against an activation with ndim axes."""
    return b if b.ndim == 1 else b.reshape((b.shape[0],) + (1,) * (ndim - 2) + (b.shape[-1],))


@primitive
def add_bias(y, b):
    """y: (..., C) plus bias b: (C,) shared, or (B, C) one per task (y then (B, ..., C))."""
    if b.ndim == 1 and y.size % (16 * b.size) == 0:
        # The same sum, but NumPy's inner loop runs over 16 C entries instead of C: ~2.8x faster
        # for C = 40 (measured on (60, 16, 16, 40) activations: 0.29 ms instead of 0.82 ms).
        return (y.reshape(-1, 16 * b.size) + np.tile(b, 16)).reshape(y.shape)
    return y + _bias_view(b, y.ndim)


@primitive
def bias_grad(g, b_shape):
    """VJP of `add_bias` with respect to b: g summed over every axis the bias was broadcast along.
    Written as a product with a vector of ones (BLAS), ~7x faster than `g.sum(axis=...)` here."""
    rows = g.reshape((-1, g.shape[-1]) if len(b_shape) == 1 else (g.shape[0], -1, g.shape[-1]))
    return np.ones(rows.shape[-2], g.dtype) @ rows


@primitive
def broadcast_bias(u, y_shape):
    """VJP of `bias_grad`: the bias-shaped u broadcast back to the activation's shape."""
    return np.broadcast_to(_bias_view(u, len(y_shape)), y_shape)


defvjp(add_bias, lambda ans, y, b: lambda g: g, lambda ans, y, b: lambda g: bias_grad(g, b.shape))
defvjp(bias_grad, lambda ans, g, b_shape: lambda u: broadcast_bias(u, g.shape))
defvjp(broadcast_bias, lambda ans, u, y_shape: lambda g: bias_grad(g, u.shape))
