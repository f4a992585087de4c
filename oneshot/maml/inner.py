"""Model-agnostic meta-learning (MAML), Section II of Finn et al. (2017), "One-Shot Visual
Imitation Learning via Meta-Learning" (MIL), which builds on Finn, Abbeel & Levine (2017), "MAML".

This is the plain path, to read: one task at a time, in autograd's own terms. The training loop
uses `oneshot.maml.batched`, which computes the same numbers for a whole meta-batch in one graph (the
tests prove the two equal).

Everything here is generic over the model: parameters are a dict of arrays, and the model enters
only through a loss function

    loss_fn(params, demo) -> scalar

which in MIL is eq. (2), the behavioural-cloning loss summed over a demo's frames. `demo` is opaque
to this module. A *task* is a pair `(adapt_demo, eval_demo)` of two demos of the same task: the
first is used for the inner (one-shot) update, the second scores the adapted parameters.

Dtypes: float32 parameters stay float32 everywhere (adapted parameters, meta-objective,
meta-gradients). Under NumPy 2 a python float times a float32 array stays float32, but an
np.float64 scalar promotes it to float64, so step sizes are converted to python floats on entry.
"""
import dataclasses
import numbers
from dataclasses import dataclass

import autograd.numpy as np  # autograd's wrapper: the operations below are recorded for the meta-gradient
from autograd import grad, value_and_grad
from autograd.extend import defvjp, primitive
from autograd.tracer import getval

from oneshot.tools.checks import real_number


def check_step(alpha, steps):
    """Validate inner-loop settings (alpha >= 0 finite, steps an int >= 0); return alpha as a python
    float, which keeps float32 parameters float32 (NumPy 2's weak scalars)."""
    if isinstance(steps, bool) or not isinstance(steps, numbers.Integral) or steps < 0:   # np.int64 too
        raise ValueError(f"inner steps must be a non-negative int; got {steps!r}")
    alpha = real_number("inner step size alpha", alpha, "pass a real number >= 0")
    if alpha < 0:
        raise ValueError(f"inner step size alpha must be finite and >= 0; got {alpha!r}")
    return alpha


# Learnt step sizes (Meta-SGD, Li et al. 2017, "Meta-SGD: Learning to Learn Quickly for Few-Shot
# Learning"): params[STEP_PREFIX + k], an array shaped like params[k], replaces the scalar alpha for
# parameter k in eq. (1), element by element. They are meta-parameters: the meta-gradient reaches
# them like any other parameter, and they never enter the model itself.
STEP_PREFIX = "inner_lr/"


def adapted_keys(params, only=None, frozen=()):
    """The keys eq. (1) updates: all of them (only=None), or those starting with one of the prefixes
    in `only` (e.g. ("conv",): adapt the convolution layers only; the rest stays shared), but none
    starting with a prefix in `frozen` (parameters that never adapt, e.g. the layer norm's offsets in
    MIL's released code). Learnt step sizes (STEP_PREFIX keys) are never adapted."""
    # An `only` prefix naming nothing is a typo; a `frozen` one is harmless (a profile's "ln" without LN).
    typos = [] if only is None else unmatched(params, only)
    if typos:
        raise ValueError(f"no parameter starts with {typos} of only={tuple(only)} (a typo?); the parameters are "
                         f"{list(params)}")
    keys = [k for k in params if not k.startswith(STEP_PREFIX) and (only is None or k.startswith(tuple(only)))
            and not k.startswith(tuple(frozen))]
    if not keys:
        raise ValueError(f"no parameter adapts: no parameter starts with any of {only}"
                         f"{' but not with any of ' + str(tuple(frozen)) if frozen else ''}; parameters are {list(params)}")
    return keys


def unmatched(names, prefixes):
    """The prefixes that no name starts with: a `frozen` or `only` prefix naming no parameter (a typo, say
    conv_0 for conv0_) would silently change nothing."""
    return [p for p in prefixes if not any(name.startswith(p) for name in names)]


def init_step_sizes(params, alpha, only=None, frozen=()):
    """Learnt step sizes for Meta-SGD: {STEP_PREFIX + k: alpha everywhere, shaped like params[k]} for
    every key eq. (1) adapts. Add them to params to meta-learn one step size per adapted element."""
    alpha = check_step(alpha, 1)
    return {STEP_PREFIX + k: np.full_like(params[k], alpha) for k in adapted_keys(params, only, frozen)}


def split(params, only, alpha, frozen=()):
    """(fixed, keys, steps): the model parameters eq. (1) leaves alone, the keys it adapts, and each
    adapted key's step size: the learnt array params[STEP_PREFIX + key] if there is one, else alpha."""
    keys = adapted_keys(params, only, frozen)
    learnt = {k[len(STEP_PREFIX):]: v for k, v in params.items() if k.startswith(STEP_PREFIX)}
    if learnt and set(learnt) != set(keys):
        raise ValueError(f"learnt step sizes are for {sorted(learnt)} but eq. (1) adapts {sorted(keys)}; "
                         f"build them with inner.init_step_sizes(params, alpha, only, frozen) for the same options")
    fixed = {k: v for k, v in params.items() if k not in keys and not k.startswith(STEP_PREFIX)}
    return fixed, keys, {k: learnt.get(k, alpha) for k in keys}


@dataclass(frozen=True)
class InnerLoop:
    """Every option of eq. (1) in one place: exactly the keyword options of `inner_update`, which
    training (`batched.adapt_batch`) and meta-test (`imitation.adapt`) both pass on whole, so the
    policy that is trained is the policy that is tested.

    alpha: step size (MIL reaching: 0.001); steps: inner gradient steps (MIL: 3);
    first_order: the inner gradient as a constant (first-order MAML);
    only: None (every parameter adapts, as MIL) or key prefixes of the parameters that adapt;
    frozen: key prefixes of parameters that never adapt, whatever `only` says (the released code's
        layer-norm offsets are not among its adapted weights);
    clip: each element of the inner gradient clipped to [-clip, clip] before the step (0: off; the
        released code: `--clip=True --clip_min=-20 --clip_max=20`, on its loss);
    loss_scale: the inner loss is loss_scale x the loss function (1: eq. (2) as we sum it; the released
        code's mean((100 (u - u_hat))^2) is 10^4 / (T x 2) times it: 250 for our T = 20, 2 torques).
    """
    alpha: float = 0.001
    steps: int = 3
    first_order: bool = False
    only: tuple = None
    frozen: tuple = ()
    clip: float = 0.0
    loss_scale: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "alpha", check_step(self.alpha, self.steps))
        object.__setattr__(self, "steps", int(self.steps))
        if self.only is not None:
            if isinstance(self.only, str) or not isinstance(self.only, (tuple, list)) \
                    or not all(isinstance(p, str) for p in self.only):
                raise ValueError(f"only must be None or a tuple of key prefixes; got {self.only!r}")
            object.__setattr__(self, "only", tuple(self.only))
        if not isinstance(self.first_order, (bool, np.bool_)):
            raise ValueError(f"first_order must be True or False; got {self.first_order!r}")
        if isinstance(self.frozen, str) or not isinstance(self.frozen, (tuple, list)) \
                or not all(isinstance(p, str) for p in self.frozen):
            raise ValueError(f"frozen must be a tuple of key prefixes ((): none); got {self.frozen!r}")
        object.__setattr__(self, "frozen", tuple(self.frozen))
        for name in ("clip", "loss_scale"):
            given = getattr(self, name)
            value = real_number(name, given, f"pass a number {'> 0' if name == 'loss_scale' else '>= 0 (0: off)'}")
            if value < 0 or (name == "loss_scale" and value == 0):
                raise ValueError(f"{name} must be finite and {'> 0' if name == 'loss_scale' else '>= 0 (0: off)'}; "
                                 f"got {getattr(self, name)!r}")
            object.__setattr__(self, name, value)

    def options(self):
        """The keyword options of `inner_update`: every field, by name."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


@primitive
def descend(theta, g, alpha):
    """theta - alpha * g for a python-float step size alpha: eq. (1) for one parameter array.

    One recorded operation whose VJPs are the identity (theta) and `scale` (g), instead of a
    product and a difference whose generic VJPs check broadcasting at every call: with 3 inner steps
    on every parameter that bookkeeping is a large part of a meta-iteration's Python time
    (docs/results.md, "Speed")."""
    return theta - alpha * g


@primitive
def scale(x, a):
    """a * x for a python float a (the VJP of `descend` with respect to g; its own VJP)."""
    return a * x


defvjp(descend, lambda ans, theta, g, alpha: lambda u: u, lambda ans, theta, g, alpha: lambda u: scale(u, -alpha))
defvjp(scale, lambda ans, x, a: lambda u: scale(u, a))


def step(theta, g, alpha):
    """Eq. (1) for one array, theta - alpha * g: `descend` for a scalar step size, plain operations for
    a learnt (array) one, whose own gradient the meta-objective needs."""
    if isinstance(alpha, float) and np.shape(theta) == np.shape(g):
        return descend(theta, g, alpha)
    return theta - alpha * g


def gradient(f, theta):
    """df/dtheta for a dict of arrays theta, by autograd's `grad` (the plain route)."""
    return grad(f)(theta)


def inner_update(params, demo, loss_fn, alpha=0.001, steps=3, first_order=False, only=None, frozen=(), clip=0.0,
                 loss_scale=1.0, *, gradient=gradient):
    """Adapt parameters to one demo by gradient descent: paper eq. (1), repeated `steps` times.

        theta' = theta - alpha * grad_theta L(theta, demo)

    params: dict of arrays, float32 or float64; not modified. demo: whatever `loss_fn` takes (in
    MIL: (images, states, actions) of one demonstration). loss_fn(params, demo) -> scalar.
    alpha: step size (MIL reaching: 0.001, 3 steps); learnt step sizes in params (STEP_PREFIX keys,
        Meta-SGD) replace it element by element.
    first_order: treat each inner gradient as a constant (first-order MAML: d theta'/d theta = I).
    only: None (MIL: every parameter adapts) or key prefixes of the parameters that adapt; the
        others keep their values. frozen: key prefixes that never adapt, whatever `only` says.
    clip: each inner gradient element clipped to [-clip, clip] before the step (0: off).
    loss_scale: the inner loss is loss_scale x loss_fn (the released code's loss convention, `InnerLoop`).
    gradient(f, theta) -> df/dtheta: autograd's `grad`, or the batched path's faster route to the same
        numbers (`batched.adapt_batch`, which also gives every task its own copy of the parameters, and
        with frame shards sums the processes' parts: `oneshot.maml.shards`). The clip acts on what it
        returns, the whole inner gradient.
    Returns a new dict with the model's keys (learnt step sizes dropped), differentiable to any order
    with respect to `params` (first_order=False).
    """
    o = InnerLoop(alpha, steps, first_order, only, frozen, clip, loss_scale)     # every option checked, once
    fixed, keys, step_size = split(params, o.only, o.alpha, o.frozen)
    loss = loss_fn if o.loss_scale == 1.0 else (lambda p, d: o.loss_scale * loss_fn(p, d))
    theta = {k: params[k] for k in keys}
    for _ in range(o.steps):
        # first order: the gradient is taken at constants, cut from the outer graph
        at, shared = (constant(theta), constant(fixed)) if o.first_order else (theta, fixed)
        g = gradient(lambda th: loss({**shared, **th}, demo), at)
        if o.clip:
            g = {k: np.clip(v, -o.clip, o.clip) for k, v in g.items()}
        theta = {k: step(theta[k], g[k], step_size[k]) for k in theta}         # eq. (1)
    return {**fixed, **theta}


def constant(arrays):
    """The values of a dict of arrays, cut from any gradient being traced (autograd's `getval`)."""
    return {k: getval(v) for k, v in arrays.items()}


def meta_objective(params, tasks, loss_fn, *args, **options):
    """The MAML meta-objective: mean over tasks of the post-adaptation loss (paper Section II).

        L_meta(theta) = (1/N) sum_i L(theta - alpha grad L(theta, adapt_demo_i), eval_demo_i)

    (with `steps` inner steps instead of one). We average, rather than sum, over the N tasks of
    the meta-batch (MIL: N = 5), as the reference MIL code does (it divides by meta_batch_size),
    so that the meta-gradient scale, and hence the Adam/clipping behaviour, does not depend on N.

    params: dict of arrays, not modified.
    tasks: sequence of (adapt_demo, eval_demo) pairs, one per task in the meta-batch.
    loss_fn, args, options (alpha, steps, first_order, only, frozen, clip, loss_scale): as in `inner_update`.
    Returns a scalar of the parameters' dtype.
    """
    if len(tasks) == 0:
        raise ValueError("meta_objective needs at least one (adapt_demo, eval_demo) task; got none")
    total = 0.0  # python float: adding a float32 loss keeps it float32
    for task in tasks:
        if len(task) != 2:
            raise ValueError(f"each task must be a pair (adapt_demo, eval_demo); got {len(task)} items")
        adapt_demo, eval_demo = task
        adapted = inner_update(params, adapt_demo, loss_fn, *args, **options)
        total = total + loss_fn(adapted, eval_demo)
    return total / len(tasks)


_value_and_grad_meta = value_and_grad(meta_objective)  # gradient w.r.t. argument 0, `params`


def meta_gradient(params, tasks, loss_fn, *args, **options):
    """Value and gradient of `meta_objective` with respect to `params` (paper Section II).

    With first_order=False this differentiates through the inner updates, so Hessian-vector
    products of the inner loss appear (second order). With first_order=True every inner Jacobian
    d theta'/d theta is the identity, so this is the mean over tasks of the plain gradient of the
    eval loss at the adapted parameters.

    Returns (value, grads): value a scalar, grads a dict with the keys, shapes and dtypes of params.
    """
    return _value_and_grad_meta(params, tasks, loss_fn, *args, **options)


def clip_gradients(grads, limit=10.0):
    """Clip every gradient element to [-limit, limit] (MIL clips to [-10, 10]; appendix).

    grads: dict of arrays. Returns a new dict, same keys, shapes and dtypes; NaNs pass through
    (the optimiser reports them).
    """
    limit = float(limit)
    if not limit > 0:
        raise ValueError(f"gradient clip limit must be > 0; got {limit!r}")
    return {k: np.clip(g, -limit, limit) for k, g in grads.items()}
