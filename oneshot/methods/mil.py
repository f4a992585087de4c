"""MIL, the method of the paper (Sections II-III): MAML on behavioural cloning.

A meta-batch teaches it by eq. (1) on each task's adapt demo and eq. (2) on its evaluate demo, through
the second-order meta-gradient; at meta-test ONE demonstration makes the adapted parameters (eq. 1).
Which parameters adapt, how many steps and how large are `TrainConfig` fields, gathered into one
`inner.InnerLoop` that training and meta-test share.
"""
import numpy as np

from oneshot.maml import imitation, inner, shards
from oneshot.maml.imitation import imitation_loss
from oneshot.methods.base import Method
from oneshot.policy import network

# TrainConfig.inner_params -> `inner.inner_update`'s `only`: which parameters eq. (1) adapts.
INNER_PARAMS = {"all": None, "conv": ("conv",), "conv0": ("conv0_",)}


def inner_loop(cfg):
    """The `inner.InnerLoop` of a config: every option of eq. (1), for training and meta-test alike."""
    if cfg.inner_params not in INNER_PARAMS:
        raise ValueError(f"inner_params must be one of {sorted(INNER_PARAMS)}; got {cfg.inner_params!r}")
    return inner.InnerLoop(alpha=cfg.alpha, steps=cfg.inner_steps, first_order=cfg.first_order,
                           only=INNER_PARAMS[cfg.inner_params], frozen=cfg.never_adapt, clip=cfg.inner_clip,
                           loss_scale=cfg.inner_loss_scale)


def describe(cfg):
    """Eq. (1) of a config in words, in both loss conventions: ours (eq. (2) summed over frames and
    torques) and MIL's released code's (mean((100 (u - u_hat))^2), 10^4 / (T x 2) times ours; T = 20)."""
    loop = inner_loop(cfg)
    released = 1e4 / (20 * 2)
    step = loop.alpha * loop.loss_scale                            # the step on eq. (2) summed
    words = [f"eq. (1): {loop.steps} step(s) of {loop.alpha:g} on {loop.loss_scale:g} x eq. (2)",
             f"= {step:g} on eq. (2) summed = {step / released:g} on the released code's mean((100 du)^2)"]
    if loop.clip:
        words.append(f"inner gradient clipped to +-{loop.clip:g} on that loss (+-{loop.clip / loop.loss_scale:g} "
                     f"on eq. (2) summed, +-{loop.clip * released / loop.loss_scale:g} on the released code's)")
    if cfg.learn_alpha:
        words.append("the step sizes meta-learnt per element, from that step")
    words.append(f"adapting {cfg.inner_params}" + (f" but {', '.join(loop.frozen)}*" if loop.frozen else ""))
    return "; ".join(words)


class MIL(Method):
    """MAML (eq. 1) with behavioural cloning (eq. 2) as its loss."""

    name = "mil"
    adapts = True
    ignores = ("lstm_units", "random_stds")

    def __init__(self, cfg):
        super().__init__(cfg)
        self.inner = inner_loop(cfg)

    def init_params(self, net_cfg, rng):
        """The network's parameters, plus learnt inner step sizes (all `alpha`) if cfg.learn_alpha."""
        params = network.init_params(net_cfg, rng)
        if self.cfg.learn_alpha:
            params.update(inner.init_step_sizes(params, self.cfg.alpha, self.inner.only, self.inner.frozen))
        return params

    def parameter_count(self, net_cfg):
        """The network's parameters, and with cfg.learn_alpha one learnt step size per adapted number."""
        shapes = network.param_shapes(net_cfg)
        steps = inner.adapted_keys(shapes, self.inner.only, self.inner.frozen) if self.cfg.learn_alpha else []
        return super().parameter_count(net_cfg) + sum(int(np.prod(shapes[k])) for k in steps)

    def adapted_floats(self, net_cfg):
        """How many numbers eq. (1) adapts (`inner.adapted_keys` of its InnerLoop), counted from shapes."""
        shapes = network.param_shapes(net_cfg)
        return sum(int(np.prod(shapes[k])) for k in inner.adapted_keys(shapes, self.inner.only, self.inner.frozen))

    @property
    def shards(self):
        return self.cfg.shards

    def make_pool(self):
        return shards.make_pool(self.cfg.shards)

    def meta_gradient(self, params, adapt, evaluate, pool=None):
        """The second-order meta-gradient, each of cfg.shards processes on its block of frames."""
        return shards.meta_gradient(params, adapt, evaluate, (imitation_loss, self.inner), self.cfg.shards, pool)

    def describe(self):
        """Eq. (1) of its config in both loss conventions (`describe`)."""
        return describe(self.cfg)

    def meta_gradient_flops(self, net_cfg, T, tasks):
        """3 (3 s + 1) forward passes per task for s inner steps: each inner step records a forward and a
        backward pass (~3 forward passes), the outer loss one more, and the meta-gradient's backward pass
        costs about twice the recorded forward graph. First order: the inner steps are not recorded, so
        3 s + 3. Matrix products only (`network.count_flops`)."""
        s = self.inner.steps
        passes = 3 * s + 3 if self.inner.first_order else 3 * (3 * s + 1)
        return tasks * passes * network.count_flops(net_cfg, T)

    def conditioner(self, params, seed=0):
        """condition(demo) -> the adapted parameters: eq. (1) on the one demo."""
        return lambda demo: imitation.adapt(params, demo, **self.inner.options())

    def unadapted(self, params):
        return lambda demo: params
