"""What the policy accepts: the checks `network.predict` and `network.predict_tasks` make at their
entry, so that a wrong input is one ValueError saying what to pass instead of a reshape error (no
frames), a bare KeyError (a missing parameter) or, worse, actions silently computed from images in
0..255 instead of [0, 1]. `network.forward`, the hot path inside training, checks nothing.
"""
import math
import re

import numpy as np
from autograd.tracer import getval, isbox

from oneshot.policy.layers import conv_output_size

MADE_BY = ("a network's params are the dict init_params(NetworkConfig(...), rng) makes, or a trained "
           "policy's, checkpoint.policy_params(checkpoint.load(path))")


def check(params, images, states, task_axes, stride):
    """Validate params, shapes, dtypes and pixel values; return (images, states) cast to the parameters'
    dtype (so nothing silently promotes float32 training to float64).

    task_axes: 0 for `predict` (images (T, H, W, 3)), 1 for `predict_tasks` (images (B, T, H, W, 3)).
    stride: the network's convolution stride.
    """
    check_params(params)
    conv0_w = params["conv0_w"]
    dtype, c_img = conv0_w.dtype, conv0_w.shape[-2]
    given_images, given_states = images, states     # boxes, if differentiated with respect to them (saliency)
    images, states = np.asarray(getval(images)), np.asarray(getval(states))
    want = "(T, H, W, 3)" if task_axes == 0 else "(B, T, H, W, 3)"
    if images.dtype == np.uint8:
        raise ValueError(
            f"images must be {want} float in [0, 1]; got uint8 {images.shape}. Convert once with "
            f"oneshot.policy.network.images_to_float(images) before training or rollouts."
        )
    if images.ndim != 4 + task_axes or images.shape[-1] != c_img or not np.issubdtype(images.dtype, np.floating):
        raise ValueError(f"images must be {want} float in [0, 1]; got {images.shape} {images.dtype}")
    if 0 in images.shape:
        raise ValueError(f"images must be {want} with at least one {'task, ' if task_axes else ''}frame and pixel; "
                         f"got {images.shape}")
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
            f"first dense layer: the params were built for smaller images (NetworkConfig.image_size)"
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
    check_pixels(images, want)
    if not np.all(np.isfinite(states)):
        raise ValueError(f"states must be finite; they hold NaN or inf (states {states.shape})")
    return _cast(given_images, images, dtype), _cast(given_states, states, dtype)


def _cast(given, value, dtype):
    """`given` in `dtype`: through autograd's astype if it is differentiated (a box), else its array `value`."""
    if isbox(given):
        return given if getval(given).dtype == dtype else given.astype(dtype)
    return value.astype(dtype, copy=False)


def check_demo(demo):
    """Raise ValueError unless `demo` is one demonstration in network units (`imitation.prepare_demos`):
    (images (T, H, W, C) float in [0, 1], states (T, S) and actions (T, A) float, finite), T >= 1. What
    every method's conditioner takes; camera images in 0..255 would make eq. (1)'s step 255 times too
    large, or a baseline's input, and a policy that fails without saying why."""
    if not (isinstance(demo, (tuple, list)) and len(demo) == 3):
        raise ValueError(f"a demo is (images, states, actions) in network units (imitation.prepare_demos); got "
                         f"{type(demo).__name__}{' of ' + str(len(demo)) if isinstance(demo, (tuple, list)) else ''}")
    images, states, actions = (np.asarray(getval(a)) for a in demo)
    if images.dtype == np.uint8:
        raise ValueError(f"demo images must be (T, H, W, 3) float in [0, 1]; got uint8 {images.shape}: "
                         f"imitation.prepare_demos converts a dataset's demo")
    if images.ndim != 4 or not images.shape[0] or not np.issubdtype(images.dtype, np.floating):
        raise ValueError(f"demo images must be (T, H, W, 3) float in [0, 1] with T >= 1; got {images.shape} {images.dtype}")
    check_pixels(images, "(T, H, W, 3)")
    for name, a in (("states", states), ("actions", actions)):
        if a.ndim != 2 or a.shape[0] != images.shape[0] or not np.issubdtype(a.dtype, np.floating):
            raise ValueError(f"demo {name} must be ({images.shape[0]}, n) float to match images {images.shape} "
                             f"(network units: imitation.prepare_demos); got {a.shape} {a.dtype}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"demo {name} must be finite; they hold NaN or inf ({name} {a.shape})")


def check_adapt_demo(params, demo, stride):
    """`check_demo`, and the demo against the network's parameters (`check`, and the actions' width): the
    demo eq. (1) adapts on, cast to the parameters' dtype."""
    check_demo(demo)
    images, states = check(params, demo[0], demo[1], 0, stride)
    actions, n_out = np.asarray(getval(demo[2])), params["out_b"].shape[-1]
    if actions.shape[-1] != n_out:
        raise ValueError(f"actions must be {(images.shape[0], n_out)} float (torques divided by the torque bound: "
                         f"imitation.prepare_demos) to match images {images.shape}; got {actions.shape} {actions.dtype}")
    return images, states, _cast(demo[2], actions, params["out_b"].dtype)


def check_params(params):
    """Raise ValueError, naming the first missing key, unless `params` is a dict of arrays with every
    array the network reads: conv0_w, conv0_b, ... and fc0_w, fc0_b, ... numbered without gaps (at
    least one convolution), and out_w, out_b."""
    if not (hasattr(params, "keys") and hasattr(params, "__getitem__")):     # a dict (autograd: a DictBox)
        raise ValueError(f"params must be a dict of arrays ({MADE_BY}); got {type(params).__name__}")
    needed = ["conv0_w", "out_w", "out_b"]
    for layer in ("conv", "fc"):
        n = 0
        while f"{layer}{n}_w" in params:
            n += 1
        needed += [f"{layer}{i}_b" for i in range(n)]
        for name in params:
            number = re.fullmatch(rf"{layer}(\d+)_[wb]", name)
            if number and int(number.group(1)) >= n:
                raise ValueError(f"params has {name!r} but no '{layer}{n}_w' ({_role(f'{layer}{n}_w')}); {MADE_BY}")
    for name in needed:
        if name not in params:
            have = ", ".join(map(str, params)) or "nothing"
            raise ValueError(f"params has no {name!r} ({_role(name)}); {MADE_BY}; it has {have}")
    for name, value in params.items():
        if not (hasattr(value, "shape") and hasattr(value, "dtype")):
            raise ValueError(f"params[{name!r}] must be an array; got {type(value).__name__}; {MADE_BY}")


def check_pixels(images, want):
    """Raise ValueError unless every value of `images` (float, not empty) lies in [0, 1]: camera images
    in 0..255 give the network inputs 255 times too large, and actions that look like any others."""
    low, high = float(np.min(images)), float(np.max(images))
    if not (math.isfinite(low) and math.isfinite(high)):
        raise ValueError(f"images must be {want} float in [0, 1]; they hold NaN or inf")
    if high > 1:
        raise ValueError(f"images must be {want} float in [0, 1]; got values up to {high:.8g}: divide images "
                         f"in 0..255 by 255 (oneshot.policy.network.images_to_float does it for uint8 images)")
    if low < 0:
        raise ValueError(f"images must be {want} float in [0, 1]; got values down to {low:.8g}")


def _role(name):
    """What parameter `name` is, in words: 'conv1_b' -> "convolution 1's bias"."""
    layer, kind = name.rsplit("_", 1)
    what = {"w": "weights", "b": "bias"}[kind]
    if layer == "out":
        return f"the output layer's {what}"
    number = layer.lstrip("convfc")
    return f"{'convolution' if layer.startswith('conv') else 'dense layer'} {number}'s {what}"


def _base_ndim(name):
    """Number of axes of parameter `name` without a task axis: 4 for conv weights, 2 for dense, else 1."""
    return 4 if name.startswith("conv") and name.endswith("_w") else 2 if name.endswith("_w") else 1
