"""Convolution as a matrix product (paper Section IV: 3 layers of 40 3x3 filters, stride 2): the
patches of an image as the rows of a matrix (`im2col`, and its adjoint `col2im`), and a layer's
convolution, its transpose and its weight gradient as three autograd primitives closed under
differentiation (`conv`, `conv_dx`, `conv_dw`).

    conv2d(x, w, b, stride)    the layer: conv(x, w, b) = im2col(x) @ w + b, for the network

`conv2d` is the same convolution as `reference.conv2d_reference` (9 shifted slices and an einsum, to
read); the tests prove them equal, values and gradients to second order (docs/network.md).

Everything runs in the dtype of its inputs: float32 for training, float64 for gradient checks.
"""
import numpy as np
from autograd.extend import defvjp, primitive
from autograd.tracer import isbox
from numpy.lib.stride_tricks import as_strided

import autograd.numpy as anp
from oneshot.policy.affine import add_bias, bias_grad, matmul


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
    # The reshape makes the one copy. Faster than 9 slice copies (one per (dy, dx)), measured on
    # (20, 32, 32, 3) images: 0.48 ms vs 1.32 ms; on (20, 16, 16, 40): 0.31 ms vs 0.55 ms.
    return _patch_view(x_pad, kernel, stride, h_out, w_out).reshape(n * h_out * w_out, kernel * kernel * c)


def _patch_view(x_pad, kernel, stride, h_out, w_out):
    """patches[n, i, j, dy, dx, c] = x_pad[n, i*stride + dy, j*stride + dx, c]: every patch of a padded
    (N, H_pad, W_pad, C) image, (N, H_out, W_out, kernel, kernel, C), as a read-only view (no copy)."""
    sn, sh, sw, sc = x_pad.strides
    return as_strided(x_pad, x_pad.shape[:1] + (h_out, w_out, kernel, kernel, x_pad.shape[3]),
                      (sn, stride * sh, stride * sw, sh, sw, sc), writeable=False)


@primitive
def col2im(cols, x_shape, kernel, stride, padding):
    """Adjoint of `im2col`: scatter-add each patch row back onto the image it came from.

    cols: (N * H_out * W_out, kernel * kernel * C) -> (N, H, W, C) with x_shape = (N, H, W, C).
    Overlapping patches add up; contributions that fall on the zero padding are dropped.
    """
    return _col2im_into(cols, x_shape, kernel, stride, padding)


def _col2im_into(cols, x_shape, kernel, stride, padding, out=None):
    """`col2im`, written into `out` (a contiguous array of x_shape) if given: the network's layers (3x3,
    stride 2, padding 1, even H and W) by `_col2im_3x3_stride2` (the same numbers, faster), any other
    by `_col2im_any`."""
    if (kernel, stride, padding) == (3, 2, 1) and x_shape[1] % 2 == 0 and x_shape[2] % 2 == 0:
        return _col2im_3x3_stride2(cols, x_shape, out)
    if out is None:
        return _col2im_any(cols, x_shape, kernel, stride, padding)
    out[...] = _col2im_any(cols, x_shape, kernel, stride, padding)
    return out


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


def _col2im_3x3_stride2(cols, x_shape, out=None):
    """`col2im` for 3x3 kernels, stride 2, padding 1 and an even H and W (every layer of the policy):
    the same numbers as `_col2im_any`, bit for bit, written output pixel by pixel instead of tap by tap.

    Output row 2a receives tap row dy = 1 of patch row a; output row 2a + 1 receives dy = 0 of patch
    row a + 1 (none in the last row) and dy = 2 of patch row a; columns likewise. So each of the four
    phases of the output (even or odd row, even or odd column) sums 1, 2 or 4 taps, and is written
    once, its taps added in `_col2im_any`'s order (dy, then dx, ascending): no zeroed padded image, no
    read-modify-write of it per tap, no padding to cut off, and a contiguous result. 1.3x faster on
    (60, 16, 16, 40), 1.7x on (60, 8, 8, 40) (docs/results.md, "Speed"). out: None, or a contiguous
    array of x_shape to write the result into.
    """
    n, h, w, c = x_shape
    t = cols.reshape(n, h // 2, w // 2, 3, 3 * c)
    tap = lambda dy, dx: t[:, :, :, dy, dx * c : (dx + 1) * c]           # (N, H/2, W/2, C) views
    x = np.empty(x_shape, cols.dtype) if out is None else out
    x = x.reshape(n, h // 2, 2, w // 2, 2, c)                  # x[:, a, ry, b, rx]: pixel (2a+ry, 2b+rx)
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
# A layer's convolution, its transpose and its weight gradient, a block of images at a time
# ----------------------------------------------------------------------------------------------------
# As `oneshot.policy.affine`'s matrix products, with the patches gathered inside (u: the incoming
# gradient of a VJP):
#     conv(x, w, b)      = im2col(x) w + b      VJPs: x <- conv_dx(g, w), w <- conv_dw(x, g), b <- bias_grad(g)
#     conv_dx(g, w)      = col2im(g w^T)        VJPs: g <- conv(u, w),    w <- conv_dw(u, g)
#     conv_dw(x, g)      = im2col(x)^T g        VJPs: x <- conv_dx(g, u), g <- conv(x, u)
# Each works through the images a block at a time: the block's patches (or its patches' gradient) are
# written to one small buffer, which stays in the CPU's cache between the copy and the matrix product,
# instead of a whole layer's patches (9.2 MB for 100 frames of 16x16x40) going out to memory and back.
# No (N * H_out * W_out, k * k * C) array is ever made. What this buys: docs/results.md, "Speed".
#
# x: (..., H, W, C), task-major images. w: (k, k, C, M) shared, or (B, k, k, C, M) one filter bank per
# task, x then (B, ..., H, W, C); b: (M,), or (B, M) per task. Padding is k // 2 ("same").

BLOCK_BYTES = 1 << 20      # patches per block: about the second-level cache of one core (1 MiB here)


def _layout(x_shape, w_shape, stride, b_shape=None):
    """(images, H, W, C, k, H_out, W_out, M, groups): groups = B when the weight or bias is per task
    (a block of images then holds whole tasks, or part of one), else 1."""
    *lead, h, w, c = x_shape
    k, m = w_shape[-4], w_shape[-1]
    tasks = [s[0] for s in (w_shape, b_shape) if s is not None and len(s) in (2, 5)]
    groups = tasks[0] if tasks else 1
    n = int(np.prod(lead, dtype=int))
    return n, h, w, c, k, conv_output_size(h, k, stride), conv_output_size(w, k, stride), m, groups


def _blocks(n, groups, image_bytes):
    """The blocks of images, each at most BLOCK_BYTES of patches (or one image), as (start, stop, first,
    last): its images, and the tasks first..last - 1 they belong to. A task larger than a block spans
    several (first + 1 == last); smaller ones share one, whole, one product for each (fewer, larger
    copies when the layer is small and the tasks many)."""
    per_task, size = n // groups, max(1, BLOCK_BYTES // image_bytes)
    if per_task > size:
        return [(s, min(s + size, (t + 1) * per_task), t, t + 1)
                for t in range(groups) for s in range(t * per_task, (t + 1) * per_task, size)]
    together = size // per_task
    return [(t * per_task, min(t + together, groups) * per_task, t, min(t + together, groups))
            for t in range(0, groups, together)]


def _patches(x, k, stride, blocks):
    """For each block, (start, stop, first, last, cols): the block's `im2col` rows, (images * H_out * W_out,
    k * k * C), in one buffer reused from block to block (use each before taking the next)."""
    n, h, w, c = x.shape
    p, largest = k // 2, max(stop - start for start, stop, _, _ in blocks)
    h_out, w_out = conv_output_size(h, k, stride), conv_output_size(w, k, stride)
    x_pad = np.zeros((largest, h + 2 * p, w + 2 * p, c), x.dtype)          # the border stays zero
    patches = _patch_view(x_pad, k, stride, h_out, w_out)
    cols = np.empty(patches.shape, x.dtype)
    for start, stop, first, last in blocks:
        f = stop - start
        x_pad[:f, p : p + h, p : p + w] = x[start:stop]
        np.copyto(cols[:f], patches[:f])
        yield start, stop, first, last, cols[:f].reshape(-1, k * k * c)


def _tasks(a, first, last, per_task_ndim):
    """a[first:last], the tasks' slices of a per-task array (a.ndim == per_task_ndim), or the shared a."""
    return a[first:last] if a.ndim == per_task_ndim else a


def _by_task(rows, first, last):
    """A block's rows (R, n) as (tasks, R / tasks, n): one matrix per task, for one stacked product."""
    return rows.reshape(last - first, -1, rows.shape[-1])


@primitive
def conv(x, w, b, stride):
    """im2col(x) @ w (+ b): the convolution of a layer, 'same' padding. x: (..., H, W, C), w: (k, k, C, M)
    or per task (B, k, k, C, M), b: None, (M,) or (B, M) -> (..., H_out, W_out, M)."""
    n, h, wd, c, k, h_out, w_out, m, groups = _layout(x.shape, w.shape, stride, None if b is None else b.shape)
    weight = w.reshape(w.shape[:-4] + (k * k * c, m))
    y = np.empty((n * h_out * w_out, m), np.result_type(x, w))
    rows = h_out * w_out
    blocks = _blocks(n, groups, rows * k * k * c * x.itemsize)
    for start, stop, first, last, cols in _patches(x.reshape(n, h, wd, c), k, stride, blocks):
        out = _by_task(y[start * rows : stop * rows], first, last)
        np.matmul(_by_task(cols, first, last), _tasks(weight, first, last, 3), out=out)
        if b is not None:
            out += _tasks(b, first, last, 2)[..., None, :] if b.ndim == 2 else b
    return y.reshape(x.shape[:-3] + (h_out, w_out, m))


@primitive
def conv_dx(g, w, x_shape, stride):
    """VJP of `conv` with respect to x: col2im(g @ w^T), the transposed convolution.
    g: (..., H_out, W_out, M) -> x_shape (..., H, W, C)."""
    n, h, wd, c, k, h_out, w_out, m, groups = _layout(x_shape, w.shape, stride)
    weight_t = np.swapaxes(w.reshape(w.shape[:-4] + (k * k * c, m)), -1, -2)     # (M, k k C) views
    g_rows, rows = g.reshape(-1, m), h_out * w_out
    dx = np.empty((n, h, wd, c), np.result_type(g, w))
    blocks = _blocks(n, groups, rows * k * k * c * dx.itemsize)
    dcols = np.empty((max(stop - start for start, stop, _, _ in blocks) * rows, k * k * c), dx.dtype)
    for start, stop, first, last in blocks:
        d = dcols[: (stop - start) * rows]
        np.matmul(_by_task(g_rows[start * rows : stop * rows], first, last), _tasks(weight_t, first, last, 3),
                  out=_by_task(d, first, last))
        _col2im_into(d, (stop - start, h, wd, c), k, stride, k // 2, out=dx[start:stop])
    return dx.reshape(x_shape)


@primitive
def conv_dw(x, g, w_shape, stride):
    """VJP of `conv` with respect to w: im2col(x)^T @ g, summed over every image of the weight's task
    (per task, w_shape (B, k, k, C, M)) or over all of them (shared, (k, k, C, M))."""
    n, h, wd, c, k, h_out, w_out, m, groups = _layout(x.shape, w_shape, stride)
    g_rows, rows = g.reshape(-1, m), h_out * w_out
    dw = np.zeros((groups, k * k * c, m), np.result_type(x, g))
    blocks = _blocks(n, groups, rows * k * k * c * x.itemsize)
    for start, stop, first, last, cols in _patches(x.reshape(n, h, wd, c), k, stride, blocks):
        dw[first:last] += np.matmul(np.swapaxes(_by_task(cols, first, last), -1, -2),
                                    _by_task(g_rows[start * rows : stop * rows], first, last))
    return dw.reshape(w_shape)


defvjp(conv,
       lambda ans, x, w, b, stride: lambda g: conv_dx(g, w, x.shape, stride),
       lambda ans, x, w, b, stride: lambda g: conv_dw(x, g, w.shape, stride),
       lambda ans, x, w, b, stride: lambda g: bias_grad(g, b.shape))
defvjp(conv_dx,
       lambda ans, g, w, x_shape, stride: lambda u: conv(u, w, None, stride),
       lambda ans, g, w, x_shape, stride: lambda u: conv_dw(u, g, w.shape, stride))
defvjp(conv_dw,
       lambda ans, x, g, w_shape, stride: lambda u: conv_dx(g, u, x.shape, stride),
       lambda ans, x, g, w_shape, stride: lambda u: conv(x, u, None, stride))


def conv2d(x, w, b, stride):
    """'Same'-padded strided 2-D convolution (cross-correlation, as in TensorFlow), without activation.

    x: (N, H, W, C_in), w: (k, k, C_in, C_out), b: (C_out,) -> (N, H_out, W_out, C_out),
    H_out = (H + 2 * (k // 2) - k) // stride + 1. For a batch of tasks, x: (B, N, H, W, C_in) and w, b
    may carry the same leading B (one filter bank per task) or not (shared).
    """
    if isbox(x):                     # an activation: `conv`, a block of images at a time
        return conv(x, w, b, stride)
    # The images are data, not differentiated: their patches are gathered once, and the weight
    # gradients reuse them (`conv_dw` would gather them again for each of its products).
    *batch, n, h, width, c_in = x.shape
    k, c_out = w.shape[-4], w.shape[-1]
    h_out, w_out = conv_output_size(h, k, stride), conv_output_size(width, k, stride)
    cols = im2col(np.reshape(x, (-1, h, width, c_in)), k, stride, k // 2)  # (B * N * H_out * W_out, k*k*C_in)
    y = matmul(cols, anp.reshape(w, w.shape[:-4] + (k * k * c_in, c_out)))  # task-major rows
    return add_bias(anp.reshape(y, (*batch, n, h_out, w_out, c_out)), b)
