"""The policy network: pixels + robot state -> joint torques (MIL, Section IV and appendix).

Finn et al. (2017), "One-Shot Visual Imitation Learning via Meta-Learning", use for simulated reaching
a small convolutional policy:

    image (H, W, 3) --conv 3x3/2, 40, ReLU--> --conv--> --conv--> flatten
        --concat [features, bias transformation, robot state]-->
        4 x (fully connected 100, ReLU) --> linear --> 2 joint torques

Everything here is a pure function of an explicit parameter dict, written in `autograd.numpy`, so MAML
(Section II) can differentiate the imitation loss through it twice. The convolution is an im2col
matrix product, with `im2col` and `col2im` registered as autograd primitives that are each other's
vector-Jacobian product (both are linear maps), so derivatives of every order come for free. The
layers' matrix products, bias adds, ReLUs and the concatenation are primitives of the same kind (their
VJPs are built from each other), which keeps the graph of a second-order meta-gradient small.

Everything runs in the dtype of the parameters: float32 for training, float64 for gradient checks.
"""

from dataclasses import dataclass

import autograd.numpy as anp
from autograd.tracer import getval
import numpy as np
from autograd.extend import defvjp, defvjp_argnum, primitive
from numpy.lib.stride_tricks import as_strided


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture of the policy (MIL, Section IV; defaults reproduce the simulated-reaching network).

    image_size:     side of the square input image, pixels (32 by default; 64 works the same way).
    channels:       filters per convolution layer (3 layers of 40).
    kernel:         convolution kernel side (3x3); padding is kernel // 2 ("same").
    stride:         convolution stride (2: each layer halves the image side).
    hidden:         widths of the fully connected ReLU layers (4 layers of 100).
    state_dim:      size of the robot state concatenated to the image features.
    action_dim:     size of the output (2 joint torques, newton-metres).
    bias_transform: size of the learned bias-transformation vector concatenated to the first fully
                    connected layer's input (MIL, "bias transformation"); 0 turns it off.
    """

    image_size: int = 32
    channels: tuple = (40, 40, 40)
    kernel: int = 3
    stride: int = 2
    hidden: tuple = (100, 100, 100, 100)
    state_dim: int = 6
    action_dim: int = 2
    bias_transform: int = 0
    feature_points: bool = False

    def __post_init__(self):
        if self.kernel % 2 != 1:
            raise ValueError(f"kernel must be odd so that 'same' padding is kernel // 2; got {self.kernel}")
        if self.image_size < 1 or self.stride < 1 or self.bias_transform < 0:
            raise ValueError(
                f"need image_size >= 1, stride >= 1, bias_transform >= 0; got image_size={self.image_size}, "
                f"stride={self.stride}, bias_transform={self.bias_transform}"
            )


# ----------------------------------------------------------------------------------------------------
# Shapes
# ----------------------------------------------------------------------------------------------------


def conv_output_size(size, kernel, stride):
    """Side of a 'same'-padded (padding = kernel // 2) strided convolution's output: 32 -> 16 at stride 2."""
    return (size + 2 * (kernel // 2) - kernel) // stride + 1


def feature_sizes(config):
    """Image side after each convolution layer, e.g. [16, 8, 4] for a 32x32 input and stride 2."""
    sizes, size = [], config.image_size
    for _ in config.channels:
        size = conv_output_size(size, config.kernel, config.stride)
        sizes.append(size)
    return sizes


def param_shapes(config):
    """Name -> shape of every parameter, in the fixed key order used by `init_params` and `predict`.

    conv{i}_w: (kernel, kernel, C_in, C_out)   conv{i}_b: (C_out,)
    bias_transform: (bias_transform,)          (only when config.bias_transform > 0)
    fc{i}_w: (n_in, n_out)                     fc{i}_b: (n_out,)
    out_w: (hidden[-1], action_dim)            out_b: (action_dim,)
    """
    shapes, c_in = {}, 3
    for i, c_out in enumerate(config.channels):
        shapes[f"conv{i}_w"] = (config.kernel, config.kernel, c_in, c_out)
        shapes[f"conv{i}_b"] = (c_out,)
        c_in = c_out
    side = feature_sizes(config)[-1] if config.channels else config.image_size
    n_image = 2 * c_in if config.feature_points else side * side * c_in
    n_in = n_image + config.bias_transform + config.state_dim
    if config.feature_points:
        shapes["fp_temperature"] = (1,)
    if config.bias_transform:
        shapes["bias_transform"] = (config.bias_transform,)
    for i, n_out in enumerate(config.hidden):
        shapes[f"fc{i}_w"] = (n_in, n_out)
        shapes[f"fc{i}_b"] = (n_out,)
        n_in = n_out
    shapes["out_w"] = (n_in, config.action_dim)
    shapes["out_b"] = (config.action_dim,)
    return shapes


def init_params(config, rng, dtype=np.float32):
    """Random initial parameters: dict name -> array, keys in `param_shapes` order.

    Weights feeding a ReLU get He-normal init (std sqrt(2 / fan_in)); the linear output layer gets
    Glorot-normal (std sqrt(2 / (fan_in + fan_out))). Biases and the bias-transformation vector start
    at zero (as in the authors' MIL code). rng: np.random.Generator. Arrays are `dtype` (float32).
    """
    params = {}
    for name, shape in param_shapes(config).items():
        if name.endswith("_b") or name == "bias_transform":
            params[name] = np.zeros(shape, dtype)
            continue
        if name == "fp_temperature":
            params[name] = np.ones(shape, dtype)
            continue
        fan_in = int(np.prod(shape[:-1]))  # conv: kernel * kernel * C_in; fc: n_in
        std = np.sqrt(2.0 / (fan_in + shape[-1])) if name == "out_w" else np.sqrt(2.0 / fan_in)
        params[name] = (std * rng.standard_normal(shape)).astype(dtype)
    return params


def count_flops(config, T):
    """Floating-point operations of one forward pass on T frames, counting 2 per multiply-add.

    Only the matrix products are counted (bias adds and ReLUs are O(activations), under 2% here):
    conv layer: 2 * T * H_out * W_out * (k * k * C_in) * C_out;  dense layer: 2 * T * n_in * n_out.
    """
    flops = 0
    for name, shape in param_shapes(config).items():
        if name.startswith("conv") and name.endswith("_w"):
            side = feature_sizes(config)[int(name[4:-2])]
            flops += 2 * T * side * side * int(np.prod(shape))
        elif name.endswith("_w"):
            flops += 2 * T * shape[0] * shape[1]
    return flops


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
    # tap on (60, 16, 16, 40) activations; docs/network.md, "Speed"). Same order of additions as one
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
    (60, 16, 16, 40), 1.7x on (60, 8, 8, 40) (docs/network.md, "Speed").
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


# ----------------------------------------------------------------------------------------------------
# The policy
# ----------------------------------------------------------------------------------------------------


def images_to_float(images):
    """uint8 camera images -> float32 in [0, 1]. Do this once per data set, outside the training loop.

    images: (..., H, W, 3) uint8 -> same shape, float32.
    """
    images = np.asarray(images)
    if images.dtype != np.uint8:
        raise ValueError(f"images_to_float expects uint8 images; got dtype {images.dtype}")
    return images.astype(np.float32) / np.float32(255.0)


def predict(params, images, states, stride=2):
    """The policy pi_theta(o_t) of MIL Section IV: actions for T observations (image + robot state).

    params: dict from `init_params` (float32 or float64; inputs are cast to the same dtype).
    images: (T, H, W, 3) float in [0, 1] (convert uint8 with `images_to_float` first).
    states: (T, state_dim) float.
    stride: convolution stride; must equal the `NetworkConfig.stride` the params were built with.
    Returns actions: (T, action_dim), joint torques in newton-metres, same dtype as params.
    """
    images, states = _check_inputs(params, images, states, stride, task_axes=0)
    return forward(params, images, states, stride)


def predict_tasks(params, images, states, stride=2):
    """`predict` for B tasks at once, each with its own demo and (optionally) its own parameters.

    params: dict with the keys of `init_params`; each array either has its usual shape (shared by all
            tasks) or an extra leading axis of size B (per task, e.g. after MAML's inner updates).
    images: (B, T, H, W, 3) float in [0, 1];  states: (B, T, state_dim) float.
    Returns actions: (B, T, action_dim). Same numbers as calling `predict` once per task, but autograd
    records one graph instead of B: see "Speed" in docs/network.md for why that matters for MAML.
    """
    images, states = _check_inputs(params, images, states, stride, task_axes=1)
    return forward(params, images, states, stride)


def forward(params, images, states, stride=2):
    """The network itself, without input checks (the hot path of `predict` and `predict_tasks`).

    images: (..., T, H, W, 3), states: (..., T, state_dim) -> (..., T, action_dim), where the optional
    leading task axis matches that of any per-task parameter.
    """
    x, i = images, 0
    while f"conv{i}_w" in params:  # (T, H, W, 3) -> (T, H/2, W/2, 40) -> ... -> (T, H/8, W/8, 40)
        x = relu(conv2d(x, params[f"conv{i}_w"], params[f"conv{i}_b"], stride))
        i += 1
    if "fp_temperature" in params:  # feature points: (T, 2 * 40) expected (x, y) of each channel
        parts = [spatial_soft_argmax(x, params["fp_temperature"])]
    else:
        parts = [anp.reshape(x, (*states.shape[:-1], -1))]  # (T, H/8 * W/8 * 40) image features
    if "bias_transform" in params:  # the same learned vector appended to every frame: (T, bias_transform)
        parts.append(np.ones((*states.shape[:-1], 1), states.dtype) * _per_frame(params["bias_transform"]))
    parts.append(states)
    h, i = concat_last(*parts), 0  # (T, n_in of fc0)
    while f"fc{i}_w" in params:  # 4 x (T, 100)
        h = relu(add_bias(matmul(h, params[f"fc{i}_w"]), params[f"fc{i}_b"]))
        i += 1
    return add_bias(matmul(h, params["out_w"]), params["out_b"])  # (T, action_dim)


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


def _per_frame(v):
    """(n,) -> (n,) or per-task (B, n) -> (B, 1, n), ready to broadcast against (..., T, n)."""
    return v if v.ndim == 1 else anp.expand_dims(v, -2)


def _check_inputs(params, images, states, stride, task_axes):
    """Validate shapes and dtypes at the public entry; cast inputs to the parameters' dtype.

    task_axes: 0 for `predict` (images (T, H, W, 3)), 1 for `predict_tasks` (images (B, T, H, W, 3)).
    """
    conv0_w = params["conv0_w"]
    dtype, c_img = conv0_w.dtype, conv0_w.shape[-2]
    images, states = np.asarray(images), np.asarray(states)
    want = "(T, H, W, 3)" if task_axes == 0 else "(B, T, H, W, 3)"
    if images.dtype == np.uint8:
        raise ValueError(
            f"images must be {want} float in [0, 1]; got uint8 {images.shape}. Convert once with "
            f"oneshot.network.images_to_float(images) before training or rollouts."
        )
    if images.ndim != 4 + task_axes or images.shape[-1] != c_img or not np.issubdtype(images.dtype, np.floating):
        raise ValueError(f"images must be {want} float in [0, 1]; got {images.shape} {images.dtype}")
    lead, (side_h, side_w) = images.shape[:-3], images.shape[-3:-1]  # lead = (T,) or (B, T)
    i, c_last = 0, c_img
    while f"conv{i}_w" in params:
        k, c_last = params[f"conv{i}_w"].shape[-4], params[f"conv{i}_w"].shape[-1]
        side_h, side_w = conv_output_size(side_h, k, stride), conv_output_size(side_w, k, stride)
        i += 1
    n_features = 2 * c_last if "fp_temperature" in params else side_h * side_w * c_last
    n_in = params["fc0_w"].shape[-2] if "fc0_w" in params else params["out_w"].shape[-2]
    n_bias = params["bias_transform"].shape[-1] if "bias_transform" in params else 0
    state_dim = n_in - n_features - n_bias
    if state_dim <= 0:
        raise ValueError(
            f"images {images.shape} give {n_features} conv features, more than the {n_in} inputs of the "
            f"first dense layer: the params were built for smaller images (NetworkConfig.image_size) or "
            f"another stride (got stride={stride})"
        )
    if states.shape != (*lead, state_dim) or not np.issubdtype(states.dtype, np.floating):
        raise ValueError(
            f"states must be {(*lead, state_dim)} float for these params and images {images.shape}; got "
            f"{states.shape} {states.dtype}. If state_dim looks wrong, check that the images have the size "
            f"the params were built for (NetworkConfig.image_size)."
        )
    if task_axes:
        n_tasks = images.shape[0]
        for name, value in params.items():
            if value.ndim not in (_base_ndim(name), _base_ndim(name) + 1) or (
                value.ndim == _base_ndim(name) + 1 and value.shape[0] != n_tasks
            ):
                raise ValueError(
                    f"params[{name!r}] must be shared (no task axis) or have a leading task axis of size "
                    f"{n_tasks} to match images {images.shape}; got {value.shape}"
                )
    # Same dtype as the params, so nothing silently promotes float32 training to float64.
    return images.astype(dtype, copy=False), states.astype(dtype, copy=False)


def _base_ndim(name):
    """Number of axes of parameter `name` without a task axis: 4 for conv weights, 2 for dense, else 1."""
    return 4 if name.startswith("conv") and name.endswith("_w") else 2 if name.endswith("_w") else 1
