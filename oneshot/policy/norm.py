"""Layer normalisation after each convolution (paper Section IV's network as MIL's released code runs it:
`norm='layer_norm'`, center=True, scale=False), as autograd primitives whose VJPs are written with primitives and autograd.numpy, so that
MAML's second-order meta-gradient differentiates it twice.

Per frame, over its H x W x C map of n values, with s = 1 / sqrt(var + eps):

    normalise(x)  = x_hat = (x - mean(x)) s
    its VJP       = s (g - mean(g) - x_hat mean(g x_hat))            (`normalise_dx`)
    layer_norm    = normalise(x) + offset                            (offset per channel)

Written with autograd.numpy's sums and divisions (`layer_norm_reference`, what the plain network
`reference.forward_reference` does), one layer norm records about a dozen nodes whose VJPs broadcast and
promote; in the released profile's meta-iteration that took about a third of the time (docs/results.md,
"Speed"). The tests prove both give the same values and gradients to second order.
"""
import numpy as np
from autograd.extend import defvjp, primitive

import autograd.numpy as anp

LN_EPSILON = 1e-6   # layer norm's variance floor (float32: an all-equal map is not divided by zero)
AXES = (-3, -2, -1)  # a frame's map: H, W, C


def _count(x):
    return x.shape[-3] * x.shape[-2] * x.shape[-1]


def _mean(x):
    """The mean over each frame's map, (..., H, W, C) -> (..., 1, 1, 1), in x's dtype (a sum over an
    integer count: autograd's VJP of anp.mean would promote float32)."""
    return anp.sum(x, axis=AXES, keepdims=True) / _count(x)


def _frame_sum(x):
    """Sum over each frame's map: (..., H, W, C) -> (..., 1, 1, 1)."""
    return x.reshape(*x.shape[:-3], -1).sum(-1)[..., None, None, None]


def _frame_dot(a, b):
    """Sum of a * b over each frame's map: -> (..., 1, 1, 1). One BLAS dot product per frame: one pass and
    no product array, and in float32 as accurate as NumPy's pairwise sum (einsum's running sum was not:
    a released-profile meta-gradient 4x further from its float64 value)."""
    lead = np.broadcast_shapes(a.shape[:-3], b.shape[:-3])
    a, b = (np.broadcast_to(v, lead + v.shape[-3:]).reshape(*lead, -1) for v in (a, b))
    return np.matmul(a[..., None, :], b[..., :, None])[..., None]      # (..., 1, 1, 1)


def _centred_and_inv_std(x):
    """(x - mean, s) of each frame's map: x (..., H, W, C) -> (same shape, (..., 1, 1, 1))."""
    n = _count(x)
    c = x - _frame_sum(x) / n
    return c, 1 / np.sqrt(_frame_dot(c, c) / n + LN_EPSILON)


@primitive
def inv_std(x):
    """s = 1 / sqrt(var + LN_EPSILON) of each frame's map: (..., H, W, C) -> (..., 1, 1, 1)."""
    return _centred_and_inv_std(x)[1]


@primitive
def normalise(x):
    """x_hat = (x - mean) s, each frame's map to mean 0 and variance var / (var + eps): same shape as x."""
    c, s = _centred_and_inv_std(x)
    c *= s
    return c


@primitive
def normalise_dx(g, x_hat, s):
    """The VJP of `normalise` at x (x_hat = normalise(x), s = inv_std(x)) for the cotangent g:
    s (g - mean(g) - x_hat mean(g x_hat)). Linear and symmetric in g.
    g, x_hat: (..., H, W, C); s: (..., 1, 1, 1) -> (..., H, W, C)."""
    n = _count(g)
    out = x_hat * (_frame_dot(g, x_hat) / n)
    out += _frame_sum(g) / n
    np.subtract(g, out, out=out)
    out *= s
    return out


defvjp(normalise, lambda ans, x: lambda g: normalise_dx(g, ans, inv_std(x)))
defvjp(inv_std,                                  # ds/dx = -s^2 x_hat / n
       lambda ans, x: lambda g: -(g * ans * ans / _count(x)) * normalise(x))
defvjp(normalise_dx,
       lambda ans, g, x_hat, s: lambda h: normalise_dx(h, x_hat, s),                     # symmetric in g
       lambda ans, g, x_hat, s: lambda h: -s * (h * _mean(g * x_hat) + g * _mean(h * x_hat)),
       lambda ans, g, x_hat, s: lambda h: anp.sum(h * ans, axis=AXES, keepdims=True) / s)  # ans is linear in s


def layer_norm(x, offset):
    """Layer normalisation of each frame's feature map, offset only, between a convolution and its ReLU:
    x (..., H, W, C) -> the same shape, (x - mean) / sqrt(var + LN_EPSILON) + offset, mean and var over
    the frame's H, W and C. offset: (C,) shared, or (B, C) per task against x (B, T, H, W, C)."""
    return normalise(x) + _per_task(offset, anp.ndim(x))


def layer_norm_reference(x, offset):
    """`layer_norm` in plain autograd.numpy (what the tests compare it with)."""
    mean = _mean(x)
    centred = x - mean
    return centred / anp.sqrt(_mean(centred * centred) + LN_EPSILON) + _per_task(offset, anp.ndim(x))


def _per_task(offset, ndim):
    """(C,) stays; per task (B, C) -> (B, 1, ..., 1, C), against x (B, ..., C) of `ndim` axes."""
    if anp.ndim(offset) > 1:
        return anp.reshape(offset, (anp.shape(offset)[0],) + (1,) * (ndim - 2) + (anp.shape(offset)[-1],))
    return offset
