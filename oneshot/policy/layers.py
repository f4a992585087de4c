"""The network's layers as autograd primitives (paper Section IV): everything `oneshot.policy.network`
builds the policy from, in one place.

    oneshot.policy.conv      convolution as im2col + matrix product: conv2d, im2col, col2im, and a
                             layer's convolution, transpose and weight gradient (conv, conv_dx, conv_dw)
    oneshot.policy.affine    the dense layers' matrix products and bias adds, with their transposes
    oneshot.policy.norm      layer normalisation (the released code's, offset only)
    here                     ReLU, tanh, concatenation, the spatial soft-argmax (feature points)

Each is an autograd primitive whose vector-Jacobian product (VJP) is written with primitives of the
same family, so derivatives of every order work (MAML's second-order meta-gradient differentiates the
network twice) while the recorded graph stays a few large nodes per layer: written with
autograd.numpy's small operations, one second-order meta-gradient records thousands of nodes, most of
them bookkeeping inside autograd's own VJPs, each costing tens of microseconds of Python.
`reference.forward_reference` is the same network in plain `autograd.numpy`; the tests prove the two
equal (docs/network.md; the speed-ups measured: docs/results.md).

Everything runs in the dtype of its inputs: float32 for training, float64 for gradient checks.
"""
import numpy as np
from autograd.extend import defvjp, defvjp_argnum, primitive
from autograd.tracer import getval

import autograd.numpy as anp
from oneshot.policy.affine import add_bias, bias_grad, broadcast_bias, matmul, matmul_dw, matmul_dx
from oneshot.policy.conv import col2im, conv, conv2d, conv_dw, conv_dx, conv_output_size, im2col
from oneshot.policy.norm import LN_EPSILON, layer_norm

__all__ = ["add_bias", "bias_grad", "broadcast_bias", "matmul", "matmul_dw", "matmul_dx",          # affine
           "col2im", "conv", "conv2d", "conv_dw", "conv_dx", "conv_output_size", "im2col",          # conv
           "relu", "mask", "tanh", "tanh_dx", "concat_last", "slice_last", "pad_last", "spatial_soft_argmax",
           "per_frame",                                                                             # here
           "layer_norm", "LN_EPSILON"]                                                              # norm


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
def tanh(x):
    """tanh of any array, same shape and dtype (the LSTM baseline's gates and cell). Its VJP is
    autograd's own, g / cosh(x)^2, to the bit, but `tanh_dx` computes it without NumPy's overflow
    warning: where |x| > 45.05, cosh(x)^2 overflows float32 and g / inf = 0 is the derivative's right
    limit, so the warning said nothing."""
    return np.tanh(x)


@primitive
def tanh_dx(g, x):
    """g / cosh(x)^2, the VJP of `tanh` at x for the cotangent g (both the same shape; the result too),
    silent where cosh(x)^2 overflows."""
    with np.errstate(over="ignore"):
        return g / np.cosh(x) ** 2


defvjp(tanh, lambda ans, x: lambda g: tanh_dx(g, x))
defvjp(tanh_dx,                                      # d/dx g sech^2(x) = -2 g sech^2(x) tanh(x)
       lambda ans, g, x: lambda h: tanh_dx(h, x),
       lambda ans, g, x: lambda h: -2 * tanh_dx(h * g, x) * tanh(x))


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
