"""The contextual policy, a baseline of paper Section IV: the demonstration's final image as input.

Trained on the same demonstrations with the same loss (eq. 2), meta-batches, trunk and widths as MIL's
policy (`oneshot.policy.network`). The paper says "the final image of the demonstration" is the input;
how it enters the network it does not say: we stack it on the current image as 3 more channels, so the
first convolution can compare the two images pixel by pixel. The policy acts in network units.
"""
import dataclasses

import numpy as np

from oneshot.maml import batched, imitation
from oneshot.methods.base import Method
from oneshot.policy import inputs, network
from oneshot.policy.network import forward


def contextual_images(images, context):
    """images (..., T, H, W, 3) and context (..., H, W, 3) -> (..., T, H, W, 6): the context image
    (the demo's final frame) stacked on every frame as 3 more channels."""
    context = np.broadcast_to(context[..., None, :, :, :], images.shape)
    return np.concatenate([images, context], axis=-1)


def contextual_loss(params, adapt, evaluate):
    """Mean over the B tasks of eq. (2) on the evaluate demo, the adapt demo's final image as context.

    params: `init_params(NetworkConfig(image_channels=6, ...))`. adapt, evaluate: (images (B, T, H, W,
    3), states (B, T, 6), actions (B, T, 2)) in network units. Returns a scalar.
    """
    images = contextual_images(evaluate[0], adapt[0][:, -1])
    return imitation.imitation_loss(params, (images, evaluate[1], evaluate[2])) / len(images)


def contextual_policy(params, demo):
    """The contextual policy conditioned on one demo (images (T, H, W, 3), ...): a function
    (image (1, H, W, 3), state (1, 6), scene) -> action (1, 2) for `imitation.rollout`. The demo is
    checked first (`inputs.check_demo`: network units)."""
    inputs.check_demo(demo)
    context = demo[0][-1]
    return lambda image, state, scene: forward(params, contextual_images(image, context), state)


class Contextual(Method):
    """The contextual baseline: no adaptation; the demo's final image is 3 more input channels."""

    name = "contextual"

    def network_config(self, image_size):
        return dataclasses.replace(super().network_config(image_size), image_channels=6)

    def meta_gradient(self, params, adapt, evaluate, pool=None):
        return batched.value_and_grads(contextual_loss, params, adapt, evaluate)

    def meta_gradient_flops(self, net_cfg, T, tasks):
        """One forward and backward pass (3 forward passes) on the evaluate demo per task."""
        return tasks * 3 * network.count_flops(net_cfg, T)

    def conditioner(self, params, seed=0):
        return lambda demo: contextual_policy(params, demo)
