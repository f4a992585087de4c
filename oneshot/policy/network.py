"""The policy network: pixels + robot state -> joint torques (MIL, Section IV and appendix).

Finn et al. (2017), "One-Shot Visual Imitation Learning via Meta-Learning", use for simulated reaching
a small convolutional policy:

    image (H, W, 3) --conv 3x3/2, 40, ReLU--> --conv--> --conv--> flatten (or feature points)
        --concat [features, bias transformation, robot state]-->
        4 x (fully connected 100, ReLU) --> linear --> 2 joint torques

Everything here is a pure function of an explicit parameter dict, so MAML (Section II) can
differentiate the imitation loss through it twice. Two versions of the same network:

    forward                       the fast path: the layers of `oneshot.policy.layers`, autograd primitives
                                  that keep the graph of a second-order meta-gradient small
    reference.forward_reference   the same numbers in plain `autograd.numpy`, to read: a convolution is 9
                                  shifted slices and an einsum (`oneshot/policy/reference.py`)

The tests prove the two equal, values and gradients. Everything runs in the dtype of the parameters:
float32 for training, float64 for gradient checks.
"""
from dataclasses import dataclass

import autograd.numpy as anp
import numpy as np

from oneshot.policy import inputs
from oneshot.policy.layers import (add_bias, concat_last, conv2d, conv_output_size, layer_norm, matmul, per_frame,
                                   relu, spatial_soft_argmax)

STRIDE = 2   # every convolution halves the image side (MIL: stride 2)


INITS = ("he", "released")   # NetworkConfig.init


def check_architecture(init, channels, hidden):
    """Raise ValueError unless init is one of INITS and every width is a whole number >= 1."""
    if init not in INITS:
        raise ValueError(f"init must be one of {', '.join(INITS)}; got {init!r}")
    for name, widths in (("channels", channels), ("hidden", hidden)):
        if not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n >= 1 for n in widths):
            raise ValueError(f"{name} must be whole numbers >= 1 (one per layer); got {widths!r}")


@dataclass(frozen=True)
class NetworkConfig:
    """Architecture of the policy (MIL, Section IV; defaults reproduce the simulated-reaching network).

    image_size:     side of the square input image, pixels (32 by default; 64 works the same way).
    channels:       filters per convolution layer (3 layers of 40); stride `STRIDE`, "same" padding.
    kernel:         convolution kernel side (3x3); padding is kernel // 2 ("same").
    hidden:         widths of the fully connected ReLU layers (4 layers of 100).
    state_dim:      size of the robot state concatenated to the image features (6: joint angles,
                    joint velocities, end-effector position, each scaled to order one).
    action_dim:     size of the output (2 joint torques, divided by the torque bound).
    bias_transform: size of the learned bias-transformation vector concatenated to the first fully
                    connected layer's input (MIL, "bias transformation"); 0 turns it off.
    feature_points: if True, the last convolution's channels become (x, y) feature points by a
                    spatial soft-argmax (`spatial_soft_argmax`), 2 per channel, instead of being
                    flattened (an option of MIL's released code; the default profile uses it).
    layer_norm:     if True, each convolution's output is layer-normalised per frame before its ReLU, with
                    a learnt offset per channel and no scale (MIL's released code); `layer_norm`.
    image_channels: channels of the input image: 3 (RGB), or 6 for the contextual baseline, which
                    stacks the demonstration's final image on the current one (`oneshot.methods.contextual`).
    init:           the initial weights (`init_params`): "he" (He-normal before a ReLU, Glorot-normal at
                    the output), or "released" (MIL's released code, `--init=xavier`: Glorot-uniform
                    convolutions and N(0, 0.01^2) dense weights, tf_utils.init_weights).
    """

    image_size: int = 32
    channels: tuple = (40, 40, 40)
    kernel: int = 3
    hidden: tuple = (100, 100, 100, 100)
    state_dim: int = 6
    action_dim: int = 2
    bias_transform: int = 0
    feature_points: bool = False
    image_channels: int = 3
    layer_norm: bool = False
    init: str = "he"

    def __post_init__(self):
        check_architecture(self.init, self.channels, self.hidden)
        object.__setattr__(self, "channels", tuple(self.channels))   # a list (from JSON, a caller) compares unequal
        object.__setattr__(self, "hidden", tuple(self.hidden))
        if self.kernel % 2 != 1:
            raise ValueError(f"kernel must be odd so that 'same' padding is kernel // 2; got {self.kernel}")
        if self.image_size < 1 or self.bias_transform < 0:
            raise ValueError(f"need image_size >= 1 and bias_transform >= 0; got image_size={self.image_size}, "
                             f"bias_transform={self.bias_transform}")


# ----------------------------------------------------------------------------------------------------
# Shapes
# ----------------------------------------------------------------------------------------------------


def feature_sizes(config):
    """Image side after each convolution layer, e.g. [16, 8, 4] for a 32x32 input."""
    sizes, size = [], config.image_size
    for _ in config.channels:
        size = conv_output_size(size, config.kernel, STRIDE)
        sizes.append(size)
    return sizes


def activation_floats(config):
    """Numbers one frame's forward pass makes, about: the image, each convolution's im2col matrix and
    output, and the dense layers' outputs (what a gradient keeps for its backward pass). For the default
    network on 32x32 images: 3,072 + (6,912 + 10,240) + (23,040 + 2,560) + (5,760 + 640) + 402 = 52,626."""
    floats, c_in = config.image_size ** 2 * config.image_channels, config.image_channels
    for c_out, side in zip(config.channels, feature_sizes(config)):
        floats += side * side * (config.kernel ** 2 * c_in + c_out)         # im2col, then the output
        c_in = c_out
    return floats + sum(config.hidden) + config.action_dim


def param_shapes(config):
    """Name -> shape of every parameter, in the fixed key order used by `init_params` and `predict`.

    conv{i}_w: (kernel, kernel, C_in, C_out)   conv{i}_b: (C_out,)
    ln{i}_offset: (C_out,)                     (only with config.layer_norm)
    bias_transform: (bias_transform,)          (only when config.bias_transform > 0)
    fc{i}_w: (n_in, n_out)                     fc{i}_b: (n_out,)
    out_w: (hidden[-1], action_dim)            out_b: (action_dim,)
    """
    shapes, c_in = {}, config.image_channels
    for i, c_out in enumerate(config.channels):
        shapes[f"conv{i}_w"] = (config.kernel, config.kernel, c_in, c_out)
        shapes[f"conv{i}_b"] = (c_out,)
        if config.layer_norm:
            shapes[f"ln{i}_offset"] = (c_out,)
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

    config.init "he": weights feeding a ReLU get He-normal init (std sqrt(2 / fan_in)); the linear
    output layer gets Glorot-normal (std sqrt(2 / (fan_in + fan_out))). "released" (MIL's released
    code, tf_utils.py): convolutions Glorot-uniform on [-r, r], r = sqrt(6 / (fan_in + fan_out)) with
    fan_in = kernel^2 C_in and fan_out = kernel^2 C_out (`xavier_initializer_conv2d`); every dense
    weight N(0, 0.01^2) (`init_weights`). Either way biases, the bias-transformation vector and the
    layer norm's offsets start at zero (as in the released code: `init_bias`, `context`, and
    `layer_norm`'s beta), feature points' temperature at one. rng: np.random.Generator. Arrays are
    `dtype` (float32).
    """
    params = {}
    for name, shape in param_shapes(config).items():
        if name.endswith(("_b", "_offset")) or name == "bias_transform":
            params[name] = np.zeros(shape, dtype)
            continue
        if name == "fp_temperature":
            params[name] = np.ones(shape, dtype)
            continue
        fan_in = int(np.prod(shape[:-1]))  # conv: kernel * kernel * C_in; fc: n_in
        if config.init == "released" and name.startswith("conv"):
            r = np.sqrt(6.0 / (fan_in + int(np.prod(shape[:-2])) * shape[-1]))
            params[name] = rng.uniform(-r, r, shape).astype(dtype)
            continue
        if config.init == "released":
            std = 0.01
        else:
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


def predict(params, images, states):
    """The policy pi_theta(o_t) of MIL Section IV: actions for T observations (image + robot state).

    params: dict from `init_params` (float32 or float64; inputs are cast to the same dtype).
    images: (T, H, W, 3) float in [0, 1] (convert uint8 with `images_to_float` first).
    states: (T, state_dim) float, in network units (`imitation.prepare_demos`).
    Returns actions: (T, action_dim), joint torques divided by the torque bound (network units:
    multiply by `ArmConfig.max_torque` for N m), same dtype as params.
    Raises ValueError saying what to pass for anything else (`oneshot.policy.inputs`): images outside
    [0, 1] (camera images in 0..255: divide by 255), no frames, a missing parameter, wrong shapes.
    """
    images, states = inputs.check(params, images, states, 0, STRIDE)
    return forward(params, images, states)


def predict_tasks(params, images, states):
    """`predict` for B tasks at once, each with its own demo and (optionally) its own parameters.

    params: dict with the keys of `init_params`; each array either has its usual shape (shared by all
            tasks) or an extra leading axis of size B (per task, e.g. after MAML's inner updates).
    images: (B, T, H, W, 3) float in [0, 1];  states: (B, T, state_dim) float.
    Returns actions: (B, T, action_dim). Same numbers as calling `predict` once per task, but autograd
    records one graph instead of B, which is what makes MAML's batched meta-objective fast
    (`oneshot.maml.batched`; docs/results.md).
    """
    images, states = inputs.check(params, images, states, 1, STRIDE)
    return forward(params, images, states)


def forward(params, images, states):
    """The network on the fast path, without input checks (the hot path of `predict` and
    `predict_tasks`): the same numbers as `reference.forward_reference`, built from `oneshot.policy.layers`.

    images: (..., T, H, W, 3) float in [0, 1], states: (..., T, state_dim) -> (..., T, action_dim)
    in network units, where the optional leading task axis matches that of any per-task parameter.
    """
    parts = [trunk(params, images)]
    if "bias_transform" in params:  # the same learned vector appended to every frame: (T, bias_transform)
        parts.append(np.ones((*states.shape[:-1], 1), states.dtype) * per_frame(params["bias_transform"]))
    parts.append(states)
    return head(params, concat_last(*parts))  # fc0's input: (T, n_in)


def trunk(params, images):
    """The convolutional trunk: image features per frame. images (..., T, H, W, C) -> (..., T, F):
    F = 2 * 40 feature points (with "fp_temperature" in params) or H/8 * W/8 * 40 flattened."""
    x, i = images, 0
    while f"conv{i}_w" in params:  # (T, H, W, 3) -> (T, H/2, W/2, 40) -> ... -> (T, H/8, W/8, 40)
        x = conv2d(x, params[f"conv{i}_w"], params[f"conv{i}_b"], STRIDE)
        if f"ln{i}_offset" in params:
            x = layer_norm(x, params[f"ln{i}_offset"])
        x = relu(x)
        i += 1
    if "fp_temperature" in params:  # feature points: (T, 2 * 40) expected (x, y) of each channel
        return spatial_soft_argmax(x, params["fp_temperature"])
    return anp.reshape(x, (*x.shape[:-3], -1))  # (T, H/8 * W/8 * 40) image features


def head(params, h):
    """The fully connected layers: (..., T, n_in) -> 4 x (..., T, 100) with ReLU -> (..., T, action_dim)."""
    i = 0
    while f"fc{i}_w" in params:
        h = relu(add_bias(matmul(h, params[f"fc{i}_w"]), params[f"fc{i}_b"]))
        i += 1
    return add_bias(matmul(h, params["out_w"]), params["out_b"])
