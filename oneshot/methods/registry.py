"""Every method of the paper's comparison (Section IV) behind one surface, for `train` and `evaluate`:

    method       learns from a meta-batch by                       one demonstration makes of it
    mil          MAML: eq. (1) on the adapt demo, eq. (2) on the     the adapted parameters (eq. 1)
                 evaluate demo, second-order meta-gradient
    contextual   eq. (2) on the evaluate demo, the adapt demo's      a policy that sees the demo's
                 final image as 3 more input channels                final image beside each frame
    lstm         eq. (2) on the evaluate demo, after an LSTM has     a policy conditioned on the
                 read the adapt demo                                 LSTM's summary of the demo
    random       nothing (the best of `random_stds` on the           Gaussian torques
                 meta-training colours is kept)

All share the trunk and widths of `oneshot.policy.network`, the meta-batches of `imitation.sample_meta_batch`,
Adam, clipping, checkpoints and the evaluation protocol.
"""
import dataclasses

import numpy as np

from oneshot.maml import batched, imitation, inner, shards
from oneshot.methods import baselines
from oneshot.policy import network
from oneshot.training.config import METHODS, inner_only


def check(cfg):
    """Raise ValueError unless cfg.method is known."""
    if cfg.method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}; got {cfg.method!r}")


def network_config(cfg, image_size):
    """The NetworkConfig a method's policy is built from (stored in its checkpoints)."""
    check(cfg)
    net_cfg = network.NetworkConfig(image_size=image_size, bias_transform=cfg.bias_transform,
                                    feature_points=cfg.feature_points)
    if cfg.method == "contextual":
        return dataclasses.replace(net_cfg, image_channels=6)
    if cfg.method == "lstm":
        return baselines.lstm_network_config(net_cfg, cfg.lstm_units)
    return net_cfg


def init_params(cfg, net_cfg, rng):
    """A method's initial parameters (dict of float32 arrays). For mil, plus learnt inner step sizes
    (all `alpha`) if cfg.learn_alpha; for random, its torque std."""
    check(cfg)
    if cfg.method == "random":
        return {"std": np.array([cfg.random_stds[0]], np.float32)}
    if cfg.method == "lstm":
        return baselines.lstm_init_params(net_cfg, cfg.lstm_units, rng)
    params = network.init_params(net_cfg, rng)
    if cfg.method == "mil" and cfg.learn_alpha:
        params.update(inner.init_step_sizes(params, cfg.alpha, inner_only(cfg)))
    return params


def meta_gradient(cfg, params, adapt, evaluate, pool=None):
    """(loss, grads) of one meta-batch: adapt, evaluate are batched demos (B, T, ...), network units.
    pool: `shards.make_pool(cfg.shards)` for mil with cfg.shards > 1."""
    check(cfg)
    if cfg.method == "mil":
        settings = (cfg.alpha, cfg.inner_steps, cfg.first_order, inner_only(cfg))
        return shards.meta_gradient(params, adapt, evaluate, settings, cfg.shards, pool)
    if cfg.method == "contextual":
        return batched.value_and_grads(baselines.contextual_loss, params, adapt, evaluate)
    if cfg.method == "lstm":
        return batched.value_and_grads(baselines.lstm_loss, params, adapt, evaluate)
    raise ValueError("the random policy has nothing to train by gradient (`train` picks its std)")


def conditioner(cfg, params, adapt=True, seed=0):
    """condition(demo) -> policy for `imitation.one_shot_success`: what ONE demonstration (network
    units) makes of the trained policy. adapt=False: mil's unadapted policy. seed: the random policy's."""
    check(cfg)
    if cfg.method == "mil":
        only = inner_only(cfg)
        return (lambda demo: imitation.adapt(params, demo, cfg.alpha, cfg.inner_steps, only)) if adapt else \
            (lambda demo: params)
    if cfg.method == "contextual":
        return lambda demo: baselines.contextual_policy(params, demo)
    if cfg.method == "lstm":
        return lambda demo: baselines.lstm_policy(params, demo)
    rng = np.random.default_rng(seed)
    return lambda demo: baselines.random_policy(float(params["std"][0]), rng)
