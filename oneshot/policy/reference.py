"""The policy network in plain `autograd.numpy`, to read: what `oneshot.policy.network.forward` computes
on its fast path (paper Section IV), with no custom primitive.

    conv2d_reference    a convolution as 9 shifted, strided slices of the padded image and an einsum
    forward_reference   the whole policy: convolutions, layer norm (`norm.layer_norm_reference`), ReLU,
                        feature points or flattening, bias transformation, dense layers

The tests prove this and the fast path equal, values and gradients to second order
(`tests/test_network.py`); a student reads this one first (docs/network.md).
"""
import autograd.numpy as anp
import numpy as np

from oneshot.policy.layers import conv_output_size
from oneshot.policy.network import STRIDE
from oneshot.policy.norm import layer_norm_reference


def conv2d_reference(x, w, b, stride=STRIDE):
    """'Same'-padded strided convolution (cross-correlation, as in TensorFlow), in plain autograd.numpy.

    x: (N, H, W, C_in), w: (k, k, C_in, C_out), b: (C_out,) -> (N, H_out, W_out, C_out):
        y[n, i, j, o] = b[o] + sum_{dy, dx, c} x_pad[n, stride*i + dy, stride*j + dx, c] w[dy, dx, c, o]
    One shifted, strided slice of the zero-padded image per kernel tap (9 for 3x3), then an einsum.
    """
    k = w.shape[0]
    n, h, width, c_in = x.shape
    h_out, w_out = conv_output_size(h, k, stride), conv_output_size(width, k, stride)
    x_pad = anp.pad(x, ((0, 0), (k // 2, k // 2), (k // 2, k // 2), (0, 0)), mode="constant")
    taps = [x_pad[:, dy : dy + stride * h_out : stride, dx : dx + stride * w_out : stride]
            for dy in range(k) for dx in range(k)]                  # k * k of (N, H_out, W_out, C_in)
    patches = anp.stack(taps, axis=3)                               # (N, H_out, W_out, k * k, C_in)
    return anp.einsum("nijtc,tco->nijo", patches, anp.reshape(w, (k * k, c_in, -1))) + b


def forward_reference(params, images, states):
    """The policy in plain autograd.numpy, no custom primitives: what `forward` computes, to read.

    params: dict from `init_params` (no task axis). images: (T, H, W, 3) float in [0, 1];
    states: (T, state_dim) -> actions (T, action_dim), torques divided by the torque bound.
    """
    x, i = images, 0
    while f"conv{i}_w" in params:                                   # (T, 32, 32, 3) -> ... -> (T, 4, 4, 40)
        x = conv2d_reference(x, params[f"conv{i}_w"], params[f"conv{i}_b"])
        if f"ln{i}_offset" in params:                               # normalise each frame's whole map
            x = layer_norm_reference(x, params[f"ln{i}_offset"])    # (plain autograd.numpy too)
        x = anp.maximum(x, 0.0)
        i += 1
    T, h, w, c = x.shape
    if "fp_temperature" in params:                                  # feature points: (T, 2 * 40)
        z = anp.reshape(x, (T, h * w, c)) * params["fp_temperature"]
        p = anp.exp(z - anp.max(z, axis=1, keepdims=True))
        p = p / anp.sum(p, axis=1, keepdims=True)                   # softmax over the H * W positions
        xs = np.tile(np.linspace(-1, 1, w, dtype=states.dtype), h)[:, None]   # (H * W, 1) pixel x in [-1, 1]
        ys = np.repeat(np.linspace(-1, 1, h, dtype=states.dtype), w)[:, None]  # (H * W, 1) pixel y
        parts = [anp.sum(p * xs, axis=1), anp.sum(p * ys, axis=1)]  # expected (x, y) per channel
    else:
        parts = [anp.reshape(x, (T, h * w * c))]                    # flattened: (T, 4 * 4 * 40)
    if "bias_transform" in params:                                  # the same learned vector every frame
        parts.append(anp.ones((T, 1), states.dtype) * params["bias_transform"])
    h = anp.concatenate(parts + [states], axis=1)                   # (T, n_in of fc0)
    i = 0
    while f"fc{i}_w" in params:                                     # 4 x (T, 100)
        h = anp.maximum(anp.dot(h, params[f"fc{i}_w"]) + params[f"fc{i}_b"], 0.0)
        i += 1
    return anp.dot(h, params["out_w"]) + params["out_b"]            # (T, action_dim)
