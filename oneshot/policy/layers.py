"""The network's layers as autograd primitives: convolution as im2col + matrix product, and the
matrix products, bias adds, ReLUs and concatenation of the policy (paper Section IV).

`oneshot.policy.network` builds the policy from these. Each is an autograd primitive whose vector-Jacobian
product (VJP) is written with primitives of the same family, so derivatives of every order work (MAML's
second-order meta-gradient differentiates the network twice) while the recorded graph stays a few
large nodes per layer: written with autograd.numpy's small operations, one second-order meta-gradient
records thousands of nodes, most of them bookkeeping inside autograd's own VJPs, each costing tens of
microseconds of Python. `network.forward_reference` is the same network in plain `autograd.numpy`;
the tests prove the two equal (docs/network.md; the speed-ups measured: docs/results.md).

Everything runs in the dtype of its inputs: float32 for training, float64 for gradient checks.
"""
import numpy as np
from autograd.extend import defvjp, defvjp_argnum, primitive
from autograd.tracer import getval
from numpy.lib.stride_tricks import as_strided

import autograd.numpy as anp


def conv_output_size(size, kernel, stride):
    """Side of a 'same'-padded (padding = kernel // 2) strided convolution's output: 32 -> 16 at stride 2."""
    return (size + 2 * (kernel // 2) - kernel) // stride + 1


# ----------------------------------------------------------------------------------------------------
# Convolution as a matrix product: im2col / col2im, a pair of mutually adjoint autograd primitives
# ----------------------------------------------------------------------------------------------------


@primitive
def im2col(x, kernel, stride, padding):
    """Gather every kernel-sized patch of x into a row: the convolution becomes one matrix product.

    x: (N, H, W, C) -> cols: (N * H_out * W_out, kernel * kernel * C); row r = (n, i, j) holds the
    zero-padded patch x_pad[n, i*stride : i*stride+kernel, j*stride : j*stride+kernel, :] flattened in
    (dy, dx, c) order, matching a (kernel, kernel, C, C_out) weight reshaped to (kernel*kernel*C, C_out).
    Linear in x; its adjoint (and so its VJP) is `col2im`.
    """
    n, h, w, c = x.shape
    h_out = (h + 2 * padding - kernel) // stride + 1
    w_out = (w + 2 * padding - kernel) // stride + 1
    x_pad = np.zeros((n, h + 2 * padding, w + 2 * padding, c), x.dtype)
    x_pad[:, padding : padding + h, padding : padding + w, :] = x
    # patches[n, i, j, dy, dx, c] = x_pad[n, i*stride + dy, j*stride + dx, c], a view (no copy); the
    # reshape below makes the one copy. Faster than 9 slice copies (one per (dy, dx)), measured on
    # (20, 32, 32, 3) images: 0.48 ms vs 1.32 ms; on (20, 16, 16, 40): 0.31 ms vs 0.55 ms.
    sn, sh, sw, sc = x_pad.strides
    patches = as_strided(
        x_pad, (n, h_out, w_out, kernel, kernel, c), (sn, stride * sh, stride * sw, sh, sw, sc), writeable=False
    )
    return patches.reshape(n * h_out * w_out, kernel * kernel * c)


@primitive
def col2im(cols, x_shape, kernel, stride, padding):
    """Adjoint of `im2col`: scatter-add each patch row back onto the image it came from.

    cols: (N * H_out * W_out, kernel * kernel * C) -> (N, H, W, C) with x_shape = (N, H, W, C).
    Overlapping patches add up; contributions that fall on the zero padding are dropped.
    """
    if (kernel, stride, padding) == (3, 2, 1) and x_shape[1] % 2 == 0 and x_shape[2] % 2 == 0:
        return _col2im_3x3_stride2(cols, x_shape)           # the network's layers: the same numbers, faster
    return _col2im_any(cols, x_shape, kernel, stride, padding)


def _col2im_any(cols, x_shape, kernel, stride, padding):
    """`col2im` for any kernel, stride and padding: one vectorised add per block of taps."""
    n, h, w, c = x_shape
    h_out = (h + 2 * padding - kernel) // stride + 1
    w_out = (w + 2 * padding - kernel) // stride + 1
    cols = cols.reshape(n, h_out, w_out, kernel, kernel * c)
    # Patch (i, j)'s tap (dy, dx) lands on padded pixel (stride*i + dy, stride*j + dx). The `stride`
    # taps dx = q*stride ... q*stride + stride-1 of one row land side by side: viewing the padded image
    # as (N, H_pad, W_pad / stride, stride * C), they are ONE contiguous run per patch, so a whole
    # block of taps is one vectorised add with longer inner loops (about 1.3x faster than one add per
    # tap on (60, 16, 16, 40) activations; docs/results.md, "Speed"). Same order of additions as one
    # tap at a time, so the same bits.
    blocks = (kernel - 1) // stride + 1                       # blocks of taps along dx
    width = stride * max(w_out + blocks - 1, -(-(w + 2 * padding) // stride))
    x_pad = np.zeros((n, h + 2 * padding, width // stride, stride * c), cols.dtype)
    for dy in range(kernel):
        rows = slice(dy, dy + stride * h_out, stride)
        for q in range(blocks):
            m = min(stride, kernel - q * stride) * c            # taps in this block, times C
            x_pad[:, rows, q : q + w_out, :m] += cols[:, :, :, dy, q * stride * c : q * stride * c + m]
    x_pad = x_pad.reshape(n, h + 2 * padding, width, c)
    return x_pad[:, padding : padding + h, padding : padding + w, :]


def _col2im_3x3_stride2(cols, x_shape):
    """`col2im` for 3x3 kernels, stride 2, padding 1 and an even H and W (every layer of the policy):
    the same numbers as `_col2im_any`, bit for bit, written output pixel by pixel instead of tap by tap.

    Output row 2a receives tap row dy = 1 of patch row a; output row 2a + 1 receives dy = 0 of patch
    row a + 1 (none in the last row) and dy = 2 of patch row a; columns likewise. So each of the four
    phases of the output (even or odd row, even or odd column) sums 1, 2 or 4 taps, and is written
    once, its taps added in `_col2im_any`'s order (dy, then dx, ascending): no zeroed padded image, no
    read-modify-write of it per tap, no padding to cut off, and a contiguous result. 1.3x faster on
    (60, 16, 16, 40), 1.7x on (60, 8, 8, 40) (docs/results.md, "Speed").
    """
    n, h, w, c = x_shape
    t = cols.reshape(n, h // 2, w // 2, 3, 3 * c)
    tap = lambda dy, dx: t[:, :, :, dy, dx * c : (dx + 1) * c]           # (N, H/2, W/2, C) views
    x = np.empty((n, h // 2, 2, w // 2, 2, c), cols.dtype)     # x[:, a, ry, b, rx]: pixel (2a+ry, 2b+rx)
    x[:, :, 0, :, 0] = tap(1, 1)
    np.add(tap(1, 0)[:, :, 1:], tap(1, 2)[:, :, :-1], out=x[:, :, 0, :-1, 1])
    x[:, :, 0, -1, 1] = tap(1, 2)[:, :, -1]
    np.add(tap(0, 1)[:, 1:], tap(2, 1)[:, :-1], out=x[:, :-1, 1, :, 0])
    x[:, -1, 1, :, 0] = tap(2, 1)[:, -1]
    odd = x[:, :-1, 1, :-1, 1]                                          # 4 taps: ((00 + 02) + 20) + 22
    np.add(tap(0, 0)[:, 1:, 1:], tap(0, 2)[:, 1:, :-1], out=odd)
    odd += tap(2, 0)[:, :-1, 1:]
    odd += tap(2, 2)[:, :-1, :-1]
    np.add(tap(2, 0)[:, -1, 1:], tap(2, 2)[:, -1, :-1], out=x[:, -1, 1, :-1, 1])
    np.add(tap(0, 2)[:, 1:, -1], tap(2, 2)[:, :-1, -1], out=x[:, :-1, 1, -1, 1])
    x[:, -1, 1, -1, 1] = tap(2, 2)[:, -1, -1]
    return x.reshape(n, h, w, c)


# Both maps are linear, so each one's VJP is the other one applied to the incoming gradient. Because
# the VJPs call the primitives (not raw NumPy), autograd can differentiate them again: every order works.
defvjp(im2col, lambda ans, x, kernel, stride, padding: lambda g: col2im(g, x.shape, kernel, stride, padding))
defvjp(col2im, lambda ans, cols, x_shape, kernel, stride, padding: lambda g: im2col(g, kernel, stride, padding))


# ----------------------------------------------------------------------------------------------------
# Layers as a few large primitives, closed under differentiation
# ----------------------------------------------------------------------------------------------------
# Written with autograd.numpy's small operations (reshape, matmul, swapaxes, +, *, sum), one
# second-order meta-gradient records thousands of nodes, most of them bookkeeping inside autograd's
# own VJPs (broadcast sums, shape queries, transposes), each costing tens of microseconds of Python.
# Instead, each layer is a handful of primitives whose VJPs are written with primitives of the same
# family, so every order of derivative works and the graph holds a few large nodes per layer.
#
# The matrix product of a layer, y = x @ w, is a bilinear map; its two VJPs are bilinear maps of the
# same kind, and so are theirs (u is the incoming gradient):
#     matmul(x, w)     = x w          VJPs: x <- matmul_dx(g, w),  w <- matmul_dw(x, g)
#     matmul_dx(g, w)  = g w^T        VJPs: g <- matmul(u, w),     w <- matmul_dw(u, g)
#     matmul_dw(x, g)  = x^T g        VJPs: x <- matmul_dx(g, u),  g <- matmul(x, u)
# A convolution is matmul(im2col(x), w), and im2col/col2im are each other's VJP (above). The weight w
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


@primitive
def relu(x):
    """max(x, 0). Its VJP multiplies by the constant mask x > 0 (`mask`), whose VJP is itself: every
    order works, and float32 stays float32 (autograd's VJPs of `maximum`/`where` promote it under
    NumPy 2; see docs/network.md)."""
    return x * (x > 0)


@primitive
def mask(g, m):
    """g * m for a constant boolean mask m (the ReLU's derivative); linear in g."""
    return g * m


defvjp(relu, lambda ans, x: lambda g: mask(g, getval(ans) > 0))
defvjp(mask, lambda ans, g, m: lambda u: mask(u, m))


@primitive
def concat_last(*parts):
    """Concatenate along the last axis (autograd's own `concatenate` differentiates through indexing
    whose second derivative is a slow scatter-add, `np.add.at`)."""
    return np.concatenate(parts, axis=-1)


@primitive
def slice_last(x, start, stop):
    """x[..., start:stop] (a copy); the VJP of `concat_last` for one part."""
    return np.ascontiguousarray(x[..., start:stop])


@primitive
def pad_last(x, start, total):
    """x placed at [start, start + n) of a zero array with `total` entries on the last axis."""
    out = np.zeros(x.shape[:-1] + (total,), x.dtype)
    out[..., start : start + x.shape[-1]] = x
    return out


def _concat_vjp(argnum, ans, args, kwargs):
    start = sum(a.shape[-1] for a in args[:argnum])
    return lambda g: slice_last(g, start, start + args[argnum].shape[-1])


defvjp_argnum(concat_last, _concat_vjp)
defvjp(slice_last, lambda ans, x, start, stop: lambda g: pad_last(g, start, x.shape[-1]))
defvjp(pad_last, lambda ans, x, start, total: lambda g: slice_last(g, start, start + x.shape[-1]))


def conv2d(x, w, b, stride):
    """'Same'-padded strided 2-D convolution (cross-correlation, as in TensorFlow), without activation.

    x: (N, H, W, C_in), w: (k, k, C_in, C_out), b: (C_out,) -> (N, H_out, W_out, C_out),
    H_out = (H + 2 * (k // 2) - k) // stride + 1. For a batch of tasks, x: (B, N, H, W, C_in) and w, b
    may carry the same leading B (one filter bank per task) or not (shared).
    """
    *batch, n, h, width, c_in = x.shape
    k, c_out = w.shape[-4], w.shape[-1]
    h_out, w_out = conv_output_size(h, k, stride), conv_output_size(width, k, stride)
    cols = im2col(anp.reshape(x, (-1, h, width, c_in)), k, stride, k // 2)  # (B * N * H_out * W_out, k*k*C_in)
    y = matmul(cols, anp.reshape(w, w.shape[:-4] + (k * k * c_in, c_out)))  # task-major rows
    return add_bias(anp.reshape(y, (*batch, n, h_out, w_out, c_out)), b)


def spatial_soft_argmax(x, temperature):
    """Feature points (Levine et al., 2016; an option of MIL's released code): for each channel, the
    expected image position under a softmax over the channel's activations.

    x: (..., H, W, C); temperature: (1,) shared or (B, 1) per task -> (..., 2 C) as (x_1..x_C, y_1..y_C)
    in [-1, 1], x to the right, y down. A gradient step on the next layer's weights then re-weights
    *whose* position drives the action, which suits one-shot adaptation to a colour.
    """
    *lead, h, w, c = x.shape
    t = temperature if temperature.ndim == 1 else anp.reshape(temperature, temperature.shape[:1] + (1,) * (len(lead) + 1))
    z = anp.reshape(x, (*lead, h * w, c)) * t
    z = z - getval(z).max(axis=-2, keepdims=True)  # softmax is shift-invariant: the shift is a constant
    e = anp.exp(z)
    p = e / anp.sum(e, axis=-2, keepdims=True)  # (..., H*W, C), sums to 1 over positions
    xs = np.tile(np.linspace(-1, 1, w, dtype=x.dtype), h)[:, None]  # (H*W, 1)
    ys = np.repeat(np.linspace(-1, 1, h, dtype=x.dtype), w)[:, None]
    return concat_last(anp.sum(p * xs, axis=-2), anp.sum(p * ys, axis=-2))


def per_frame(v):
    """(n,) -> (n,) or per-task (B, n) -> (B, 1, n), ready to broadcast against (..., T, n)."""
    return v if v.ndim == 1 else anp.expand_dims(v, -2)
