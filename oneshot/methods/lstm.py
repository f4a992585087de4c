"""The LSTM policy, a baseline of paper Section IV: a recurrent network reads the demonstration, then acts.

A recurrent network reads the demonstration frame by frame (the trunk's features of the frame, the robot
state and the demonstrated action); its final hidden state is appended to the current observation's
features and the state, and the fully connected layers output the action (Duan et al. 2017, "One-Shot
Imitation Learning"; the paper: an LSTM of 512 units on the trunk's final-layer features). Trained on
the same demonstrations, loss (eq. 2), meta-batches, trunk and widths as MIL's policy.
"""
import dataclasses

import autograd.numpy as anp
import numpy as np

from oneshot.maml import batched
from oneshot.methods.base import INNER_LOOP_FIELDS, Method
from oneshot.policy import inputs, network
from oneshot.policy.layers import add_bias, concat_last, matmul, tanh
from oneshot.policy.network import head, init_params, trunk


def lstm_network_config(net_cfg, units):
    """The NetworkConfig of the LSTM policy's trunk and head: the head's input is the current frame's
    features, the state and the LSTM's summary of the demo (`units` numbers, counted as extra state); no
    bias transformation (the summary takes its place)."""
    return dataclasses.replace(net_cfg, state_dim=net_cfg.state_dim + units, bias_transform=0)


def lstm_init_params(net_cfg, units, rng, dtype=np.float32):
    """Parameters of the LSTM policy for net_cfg = `lstm_network_config(...)`: its trunk and head
    (network init), plus lstm_w (n_in + units, 4 units) and lstm_b (4 units,), n_in = features +
    state + action per demo frame. Gates in the order input, forget, cell, output; the forget gate's
    bias starts at 1 (remember by default)."""
    params = init_params(net_cfg, rng, dtype)
    shape = lstm_weight_shape(net_cfg, units)
    params["lstm_w"] = (rng.standard_normal(shape) / np.sqrt(shape[0])).astype(dtype)
    params["lstm_b"] = np.zeros(4 * units, dtype)
    params["lstm_b"][units:2 * units] = 1.0
    return params


def lstm_weight_shape(net_cfg, units):
    """lstm_w's shape, (n_in + units, 4 units): n_in = the trunk's features + the robot state + the action
    of a demo frame, for net_cfg = `lstm_network_config(...)`."""
    n_features = network.param_shapes(net_cfg)["fc0_w"][0] - net_cfg.state_dim
    n_in = n_features + (net_cfg.state_dim - units) + net_cfg.action_dim
    return n_in + units, 4 * units


def lstm_step(w_h, xw, h, c):
    """One LSTM step (Hochreiter & Schmidhuber 1997, with a forget gate): h, c (B, units), the
    recurrent weights w_h (units, 4 units), and the input's share of the gates xw = x W_x + b
    (B, 4 units), computed for all frames at once:

        i, f, g, o = split(x W_x + b + h W_h);  c' = s(f) c + s(i) tanh(g);  h' = s(o) tanh(c')
    """
    units = h.shape[-1]
    z = matmul(h, w_h) + xw                                                          # (B, 4 units)
    i, f, g, o = (z[..., k * units:(k + 1) * units] for k in range(4))
    c = _sigmoid(f) * c + _sigmoid(i) * tanh(g)
    return _sigmoid(o) * tanh(c), c


def _sigmoid(x):
    return 0.5 * (tanh(0.5 * x) + 1.0)            # = 1 / (1 + exp(-x)), without overflow


def lstm_summary(params, demo):
    """Read a batch of demos: images (B, T, H, W, 3), states (B, T, 6), actions (B, T, 2) -> the final
    hidden state (B, units), after one LSTM step per frame on x = [features, state, action]."""
    images, states, actions = demo
    x = concat_last(trunk(params, images), states, actions)          # (B, T, n_in)
    units = params["lstm_b"].shape[0] // 4
    w_x, w_h = params["lstm_w"][:-units], params["lstm_w"][-units:]
    xw = add_bias(matmul(x, w_x), params["lstm_b"])                  # (B, T, 4 units): every frame at once
    h = c = np.zeros((images.shape[0], units), x.dtype)
    for t in range(images.shape[1]):
        h, c = lstm_step(w_h, xw[:, t], h, c)
    return h


def lstm_act(params, summary, images, states):
    """Actions for observations images (B, T, H, W, 3), states (B, T, 6) given the demo summaries
    (B, units) -> (B, T, 2): the head on [features, state, summary] of every frame."""
    context = np.ones(states.shape[:-1] + (1,), states.dtype) * summary[:, None, :]
    return head(params, concat_last(trunk(params, images), states, context))


def lstm_loss(params, adapt, evaluate):
    """Mean over the B tasks of eq. (2) on the evaluate demo, the policy having read the adapt demo."""
    residual = lstm_act(params, lstm_summary(params, adapt), evaluate[0], evaluate[1]) - evaluate[2]
    return anp.sum(residual * residual) / len(residual)


def lstm_policy(params, demo):
    """The LSTM policy after reading one demo (images (T, H, W, 3), ...): a function (image (1, H, W, 3),
    state (1, 6), scene) -> action (1, 2) for `imitation.rollout`. The demo is checked first
    (`inputs.check_demo`: network units)."""
    inputs.check_demo(demo)
    summary = lstm_summary(params, tuple(a[None] for a in demo))                  # (1, units)
    return lambda image, state, scene: lstm_act(params, summary, image[None], state[None])[0]


class LSTM(Method):
    """The LSTM baseline: it reads the demonstration, then acts; `cfg.lstm_units` wide."""

    name = "lstm"
    ignores = (*INNER_LOOP_FIELDS, "random_stds")
    width_flags = (*Method.width_flags, "--lstm-units")

    def network_config(self, image_size):
        return lstm_network_config(super().network_config(image_size), self.cfg.lstm_units)

    def init_params(self, net_cfg, rng):
        return lstm_init_params(net_cfg, self.cfg.lstm_units, rng)

    def parameter_count(self, net_cfg):
        rows, columns = lstm_weight_shape(net_cfg, self.cfg.lstm_units)
        return super().parameter_count(net_cfg) + rows * columns + columns       # + lstm_w and lstm_b

    def check(self, net_cfg):
        if self.cfg.lstm_units > net_cfg.state_dim:           # the head's state includes the units
            raise ValueError(f"lstm_units is {self.cfg.lstm_units} but the network's state_dim is only "
                             f"{net_cfg.state_dim}")

    def meta_gradient(self, params, adapt, evaluate, pool=None):
        return batched.value_and_grads(lstm_loss, params, adapt, evaluate)

    def meta_gradient_flops(self, net_cfg, T, tasks):
        """The trunk and head on the evaluate demo and the trunk again on the adapt demo, forward and
        backward: 6 forward passes per task (the LSTM's own products are not counted)."""
        return tasks * 6 * network.count_flops(net_cfg, T)

    def conditioner(self, params, seed=0):
        return lambda demo: lstm_policy(params, demo)
