"""What every method of paper Section IV's comparison is: one object behind one small interface.

    method = methods.of(cfg)                          # the method cfg.method names, bound to its config
    net_cfg = method.network_config(image_size)       # its network (stored in its checkpoints)
    params = method.init_params(net_cfg, rng)         # its parameters: a dict of arrays
    loss, grads = method.meta_gradient(params, adapt, evaluate, pool)   # what it learns from a meta-batch
    condition = method.conditioner(params, seed)      # what ONE demonstration makes of it:
    policy = condition(demo)                          #   a policy for `imitation.rollout`

Training, evaluation, checkpoints, the experiments and the benchmark ask the object; none of them tests
a method's name. A method that is not trained by gradient (`learns = False`, the random policy) is
fitted by `fit` instead. Adding a method is one module with a subclass and one line in the registry
(`oneshot.methods`).
"""
import numpy as np

from oneshot.policy import network
from oneshot.policy.network import NetworkConfig


# The TrainConfig fields of eq. (1): only a method that adapts reads them.
INNER_LOOP_FIELDS = ("alpha", "inner_steps", "first_order", "inner_params", "never_adapt", "inner_clip",
                     "inner_loss_scale", "learn_alpha")


class Method:
    """A method of the comparison, bound to `cfg` (a `training.config.TrainConfig`). The defaults are
    those of a method that learns by gradient on the shared trunk of `oneshot.policy.network`."""

    name = None           # the registry's key: what `TrainConfig.method` says
    adapts = False        # does one demonstration change the parameters (eq. 1)? Then `unadapted` exists
    learns = True         # trained by meta-gradient; False: `fit` chooses its parameters instead
    has_network = True    # are its parameters a network's (checked against `network.param_shapes`)?
    ignores = (*INNER_LOOP_FIELDS, "lstm_units", "random_stds")   # TrainConfig fields it never reads (`refuse_ignored`)
    width_flags = ("--channels", "--hidden", "--bias-transform")    # `train`'s flags that size its network

    def __init__(self, cfg):
        self.cfg = cfg

    def __repr__(self):
        return f"{type(self).__name__}({self.cfg.method!r})"

    # --- its policy ---------------------------------------------------------------------------------

    def network_config(self, image_size):
        """The NetworkConfig of its policy for images of `image_size` pixels (stored in checkpoints)."""
        return NetworkConfig(image_size=image_size, bias_transform=self.cfg.bias_transform,
                             feature_points=self.cfg.feature_points, layer_norm=self.cfg.layer_norm,
                             init=self.cfg.init, channels=self.cfg.channels, hidden=self.cfg.hidden)

    def init_params(self, net_cfg, rng):
        """Initial parameters: a dict of float32 arrays. rng: np.random.Generator."""
        return network.init_params(net_cfg, rng)

    def check(self, net_cfg):
        """Raise ValueError if the config and the network cannot belong together (read checkpoints)."""

    def refuse_ignored(self, fields):
        """Raise ValueError if a person set one of `fields` (TrainConfig names, from command-line flags)
        that this method never reads: `--inner-steps 5` for the LSTM would be recorded and do nothing."""
        ignored = [f for f in fields if f in self.ignores]
        if ignored:
            flags = ", ".join("--" + f.replace("_", "-") for f in ignored)
            raise ValueError(f"{flags} {'does' if len(ignored) == 1 else 'do'} not apply to the {self.cfg.method} "
                             f"method (it never reads {'it' if len(ignored) == 1 else 'them'}); drop "
                             f"{'it' if len(ignored) == 1 else 'them'}")

    def parameter_count(self, net_cfg):
        """How many numbers its parameters hold, counted from their shapes (nothing is allocated)."""
        return sum(int(np.prod(shape)) for shape in network.param_shapes(net_cfg).values())

    def memory_bytes(self, net_cfg):
        """Bytes its meta-training holds at least, whatever the data and the meta-batch: float32
        parameters, their gradient, Adam's two moments and (cfg.ema > 0) the moving average."""
        return 4 * self.parameter_count(net_cfg) * (4 + (self.cfg.ema > 0))

    def adapted_floats(self, net_cfg):
        """How many numbers eq. (1) adapts, of which each task of a meta-batch holds its own copies: none."""
        return 0

    def meta_batch_words(self, net_cfg):
        """(what a task of its meta-batch holds, how to need less), for a command's memory refusal."""
        if not self.adapts:
            return "their images and the activations the meta-gradient keeps", ""
        return (f"{self.cfg.inner_steps} inner steps: their images, the activations the meta-gradient keeps and "
                f"each task's copies of the {self.adapted_floats(net_cfg):,} numbers eq. (1) adapts",
                " or fewer --inner-steps, or adapt fewer parameters (--inner-params)")

    def task_bytes(self, net_cfg, frames):
        """Bytes one task of a meta-batch holds during a meta-iteration, at most about: the float32 images
        of its two demonstrations; for each forward pass through its `frames` frames (one, or with eq. (1)
        one per inner step and one after) the activations it keeps for the gradient
        (`network.activation_floats`, float32), with the backward pass and autograd's bookkeeping as much
        again and more: 10 bytes a number; and its own copies of the parameters eq. (1) adapts
        (`adapted_floats`), 4 + 2 per inner step (the step's gradient and result, kept for the
        second-order backward pass, and what that pass makes of them). Measured, as the slope of peak
        memory from meta-batch 4 to 16 (`python -m oneshot.benchmark maml --shards 1 --meta-batch N
        --profile P` or `--line L`), against this: the smoke profile (3 steps) 21 MB a task (45), the
        default (1 step) 10 MB (21), `mil-released+widths-flat+3steps` 28 MB (35), the LSTM 8.0 MB (11);
        with one dense layer of 20,000 and every parameter adapting, where the copies are most of it
        (`tests/test_methods.py`), 262 MB (326) with one step and 381 MB (552) with three. `train` refuses
        a meta-batch that would not fit (one of 1,000 had grown to 21 GB when the kernel killed it, and so
        did a dense layer of 1,000,000 adapting, which the copies now count)."""
        passes = self.cfg.inner_steps + 1 if self.adapts else 1
        images = 2 * frames * net_cfg.image_size ** 2 * net_cfg.image_channels * 4
        copies = 4 * self.adapted_floats(net_cfg) * (4 + 2 * self.cfg.inner_steps)
        return images + int(10 * network.activation_floats(net_cfg) * frames * passes) + copies

    # --- meta-training ------------------------------------------------------------------------------

    @property
    def shards(self):
        """Processes that share each meta-gradient (`oneshot.maml.shards`): 1 unless the method splits frames."""
        return 1

    def make_pool(self):
        """The worker processes its meta-gradient needs (None: this process alone)."""
        return None

    def meta_gradient(self, params, adapt, evaluate, pool=None):
        """(loss, grads) of one meta-batch: eq. (2) on the evaluate demos, given the adapt demos.
        adapt, evaluate: (images (B, T, H, W, 3), states (B, T, 6), actions (B, T, 2)), network units."""
        raise NotImplementedError(f"{type(self).__name__} does not learn by gradient; use fit")

    def meta_gradient_flops(self, net_cfg, T, tasks):
        """Matrix-product operations of one meta-gradient over `tasks` tasks of T frames (the benchmark)."""
        raise NotImplementedError

    def fit(self, params, dataset, trials, seed):
        """Parameters chosen without gradients (learns = False): (params, {choice: score})."""
        raise NotImplementedError(f"{type(self).__name__} learns by gradient; use meta_gradient")

    # --- meta-test: what one demonstration makes of it ------------------------------------------------

    def conditioner(self, params, seed=0):
        """condition(demo) -> policy (a parameter dict or a function, as `imitation.act` takes): what
        ONE demonstration (network units) makes of the trained policy. seed: for methods that draw."""
        raise NotImplementedError

    def unadapted(self, params):
        """condition(demo) -> the policy without adaptation (only for methods that adapt)."""
        raise ValueError(f"the {self.name!r} method does not adapt to a demonstration; it has no unadapted policy")

    def describe(self):
        """What training will do, in a line that `train` prints first ("" for nothing to add)."""
        return ""

    def notes(self, params):
        """What a Figure 2 row records about the trained parameters beyond its score (a dict)."""
        return {}
