"""Model-agnostic meta-learning (MAML), Section II of Finn et al. (2017), "One-Shot Visual
Imitation Learning via Meta-Learning" (MIL), which builds on Finn, Abbeel & Levine (2017), "MAML".

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
import autograd.numpy as np  # autograd's wrapper, so np.clip inside inner_update is differentiable
from autograd import grad, value_and_grad
from autograd.core import VJPNode, add_outgrads, vspace
from autograd.extend import defvjp, primitive
from autograd.tracer import getval, isbox, new_box, trace_stack
from autograd.util import toposort


def _check_step(alpha, steps, inner_clip):
    """Validate inner-loop settings; return alpha and inner_clip as python floats (or None)."""
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise ValueError(f"inner steps must be a non-negative int; got {steps!r}")
    try:
        alpha = float(alpha)  # a python float keeps float32 params float32 (NumPy 2 weak scalars)
    except TypeError:
        raise ValueError(f"inner step size alpha must be a real number; got {alpha!r}") from None
    if not np.isfinite(alpha) or alpha < 0:
        raise ValueError(f"inner step size alpha must be finite and >= 0; got {alpha!r}")
    if inner_clip is not None:
        inner_clip = float(inner_clip)
        if not inner_clip > 0:
            raise ValueError(f"inner_clip must be None or > 0; got {inner_clip!r}")
    return alpha, inner_clip


# Learnt step sizes (Meta-SGD, Li et al. 2017, "Meta-SGD: Learning to Learn Quickly for Few-Shot
# Learning"): params[STEP_PREFIX + k], an array shaped like params[k], replaces the scalar alpha for
# parameter k in eq. (1), element by element. They are meta-parameters: the meta-gradient reaches
# them like any other parameter, and they never enter the model itself.
STEP_PREFIX = "inner_lr/"


def adapted_keys(params, only=None):
    """The keys eq. (1) updates: all of them (only=None), or those starting with one of the prefixes
    in `only` (e.g. ("conv",): adapt the convolution layers only; the rest stays shared). Learnt step
    sizes (STEP_PREFIX keys) are never adapted."""
    keys = [k for k in params if not k.startswith(STEP_PREFIX) and (only is None or k.startswith(tuple(only)))]
    if not keys:
        raise ValueError(f"no parameter starts with any of {tuple(only)}; parameters are {list(params)}")
    return keys


def init_step_sizes(params, alpha, only=None):
    """Learnt step sizes for Meta-SGD: {STEP_PREFIX + k: alpha everywhere, shaped like params[k]} for
    every key eq. (1) adapts. Add them to params to meta-learn one step size per adapted element."""
    alpha, _ = _check_step(alpha, 1, None)
    return {STEP_PREFIX + k: np.full_like(params[k], alpha) for k in adapted_keys(params, only)}


def _split(params, only, alpha):
    """(fixed, keys, steps): the model parameters eq. (1) leaves alone, the keys it adapts, and each
    adapted key's step size: the learnt array params[STEP_PREFIX + key] if there is one, else alpha."""
    keys = adapted_keys(params, only)
    learnt = {k[len(STEP_PREFIX):]: v for k, v in params.items() if k.startswith(STEP_PREFIX)}
    if learnt and set(learnt) != set(keys):
        raise ValueError(f"learnt step sizes are for {sorted(learnt)} but eq. (1) adapts {sorted(keys)}; "
                         f"build them with maml.init_step_sizes(params, alpha, only) for the same `only`")
    fixed = {k: v for k, v in params.items() if k not in keys and not k.startswith(STEP_PREFIX)}
    return fixed, keys, {k: learnt.get(k, alpha) for k in keys}


@primitive
def gradient_step(theta, g, alpha):
    """theta - alpha * g for a python-float step size alpha: eq. (1) for one parameter array.

    One recorded operation whose VJPs are the identity (theta) and `scale` (g), instead of a
    product and a difference whose generic VJPs check broadcasting at every call; with 3 inner steps
    on every parameter that bookkeeping is a large part of a meta-iteration's Python time."""
    return theta - alpha * g


@primitive
def scale(x, a):
    """a * x for a python float a (the VJP of `gradient_step` with respect to g; its own VJP)."""
    return a * x


defvjp(gradient_step, lambda ans, theta, g, alpha: lambda u: u,
       lambda ans, theta, g, alpha: lambda u: scale(u, -alpha))
defvjp(scale, lambda ans, x, a: lambda u: scale(u, a))


def _step(theta, g, alpha):
    """Eq. (1) for one array: the primitive for a scalar step size, plain operations for a learnt
    (array) one, whose own gradient the meta-objective needs."""
    if isinstance(alpha, float) and np.shape(theta) == np.shape(g):
        return gradient_step(theta, g, alpha)
    return theta - alpha * g


def inner_update(params, demo, loss_fn, alpha=0.001, steps=3, first_order=False, inner_clip=None, only=None):
    """Adapt parameters to one demo by gradient descent: paper eq. (1), repeated `steps` times.

        theta' = theta - alpha * grad_theta L(theta, demo)

    MIL uses steps = 3 and alpha = 0.001 in its simulated-reaching experiment.

    params: dict of arrays (any shapes), float32 or float64; not modified.
    demo: whatever `loss_fn` takes (in MIL: (images, states, actions) of one demonstration).
    loss_fn: loss_fn(params, demo) -> scalar; must be autograd-differentiable.
    alpha: inner step size (python float or number); learnt step sizes in params (STEP_PREFIX keys,
        Meta-SGD) replace it element by element.
    steps: number of inner gradient steps (0 returns `params` unchanged).
    first_order: if True, treat each inner gradient as a constant (stop-gradient): the
        "first-order MAML" approximation, so d theta' / d theta = I.
    inner_clip: if a number c, clip each inner-gradient element to [-c, c] before the step (the
        reference MIL code does this when its `clip` flag is on); None = plain eq. (1).
    only: None (MIL: every parameter adapts) or key prefixes of the parameters that adapt
        (`adapted_keys`); the others keep their values.
    Returns a new dict with the model's keys (learnt step sizes dropped), shapes and dtypes. With
    first_order=False the result is differentiable (to any order) with respect to `params` by autograd.
    """
    alpha, inner_clip = _check_step(alpha, steps, inner_clip)
    fixed, keys, step = _split(params, only, alpha)
    grad_loss = grad(lambda sub, d: loss_fn({**fixed, **sub}, d))
    adapted = {k: params[k] for k in keys}
    for _ in range(steps):
        if first_order:
            # Stop-gradient: evaluate the gradient on the raw values, off the outer autograd tape.
            # Also cheaper: the inner backward pass is not recorded for the outer one (measured ~2x
            # faster meta_gradient on a small MLP, 3 steps).
            g = grad_loss({k: getval(v) for k, v in adapted.items()}, demo)
        else:
            g = grad_loss(adapted, demo)
        if inner_clip is not None:
            g = {k: np.clip(v, -inner_clip, inner_clip) for k, v in g.items()}
        adapted = {k: _step(adapted[k], g[k], step[k]) for k in adapted}
    return {**fixed, **adapted}


def meta_objective(params, tasks, loss_fn, alpha, steps, first_order=False, inner_clip=None, only=None):
    """The MAML meta-objective: mean over tasks of the post-adaptation loss (paper Section II).

        L_meta(theta) = (1/N) sum_i L(theta - alpha grad L(theta, adapt_demo_i), eval_demo_i)

    (with `steps` inner steps instead of one). We average, rather than sum, over the N tasks of
    the meta-batch (MIL: N = 5), as the reference MIL code does (it divides by meta_batch_size),
    so that the meta-gradient scale, and hence the Adam/clipping behaviour, does not depend on N.

    params: dict of arrays, not modified.
    tasks: sequence of (adapt_demo, eval_demo) pairs, one per task in the meta-batch.
    loss_fn, alpha, steps, first_order, inner_clip, only: as in `inner_update`.
    Returns a scalar of the parameters' dtype.
    """
    if len(tasks) == 0:
        raise ValueError("meta_objective needs at least one (adapt_demo, eval_demo) task; got none")
    total = 0.0  # python float: adding a float32 loss keeps it float32
    for task in tasks:
        if len(task) != 2:
            raise ValueError(f"each task must be a pair (adapt_demo, eval_demo); got {len(task)} items")
        adapt_demo, eval_demo = task
        adapted = inner_update(params, adapt_demo, loss_fn, alpha, steps, first_order, inner_clip, only)
        total = total + loss_fn(adapted, eval_demo)
    return total / len(tasks)


_value_and_grad_meta = value_and_grad(meta_objective)  # gradient w.r.t. argument 0, `params`


def meta_gradient(params, tasks, loss_fn, alpha, steps, first_order=False, inner_clip=None, only=None):
    """Value and gradient of `meta_objective` with respect to `params` (paper Section II).

    With first_order=False this differentiates through the inner updates, so Hessian-vector
    products of the inner loss appear (second order). With first_order=True every inner Jacobian
    d theta'/d theta is the identity, so this is the mean over tasks of the plain gradient of the
    eval loss at the adapted parameters.

    Returns (value, grads): value a scalar, grads a dict with the keys, shapes and dtypes of params.
    """
    return _value_and_grad_meta(params, tasks, loss_fn, alpha, steps, first_order, inner_clip, only)


def clip_gradients(grads, limit=10.0):
    """Clip every gradient element to [-limit, limit] (MIL clips to [-10, 10]; appendix).

    grads: dict of arrays. Returns a new dict, same keys, shapes and dtypes; NaNs pass through
    (the optimiser reports them).
    """
    limit = float(limit)
    if not limit > 0:
        raise ValueError(f"gradient clip limit must be > 0; got {limit!r}")
    return {k: np.clip(g, -limit, limit) for k, g in grads.items()}


def value_and_grads(fun, arrays, *args):
    """fun(arrays, *args) and its gradient with respect to every array of the dict `arrays`: the
    numbers of autograd's `value_and_grad(fun)(arrays, *args)`, by a cheaper route.

    autograd differentiates with respect to a dict by boxing the dict as one container: every read
    of an entry records a node whose backward step builds a vector space of the whole dict and
    copies it, so reading 16 parameters costs 16 x 16 entries' work in Python. Instead each array
    gets its own root node on autograd's tape, and the backward pass (autograd's `backward_pass`
    with several roots) hands each array its gradient directly. It nests like `grad`: called while
    an outer gradient is being traced (MAML's inner steps), its backward pass is itself recorded
    and differentiable again.
    Measured (`python -m oneshot.benchmark maml --profile mil`): the Python time of a second-order
    3-step meta-gradient drops by about a third, a whole meta-iteration by 8-12% (docs/network.md).

    arrays: dict name -> array (or autograd box). fun(arrays, *args) -> scalar.
    Returns (value, grads): grads a dict with the keys of `arrays`; zeros for arrays fun ignores.
    """
    with trace_stack.new_trace() as trace:
        roots = {k: VJPNode.new_root() for k in arrays}
        end = fun({k: new_box(v, trace, roots[k]) for k, v in arrays.items()}, *args)
        if not (isbox(end) and end._trace == trace):      # fun does not depend on the arrays
            return end, {k: vspace(v).zeros() for k, v in arrays.items()}
        value, end_node = end._value, end._node
    key_of = {id(node): k for k, node in roots.items()}
    grads, outgrads = {}, {end_node: (vspace(value).ones(), False)}
    for node in toposort(end_node):                       # reverse topological order, as autograd
        g = outgrads.pop(node)[0]
        if id(node) in key_of:
            grads[key_of[id(node)]] = g
            continue
        for parent, ingrad in zip(node.parents, node.vjp(g)):
            outgrads[parent] = add_outgrads(outgrads.get(parent), ingrad)
    return value, {k: grads[k] if k in grads else vspace(v).zeros() for k, v in arrays.items()}


def meta_objective_batched(params, adapt, evaluate, loss_tasks, alpha, steps, first_order=False, only=None,
                           reduce=None):
    """`meta_objective` for a whole meta-batch in one computation graph (same value, faster).

    Each of the B tasks gets its own copy of the parameters (a leading task axis). Task b's loss
    depends only on copy b, so the gradient of the summed loss with respect to the copies is, row by
    row, each task's own inner gradient: eq. (1) for all tasks at once. autograd then records one
    graph instead of B, which made a 5-task second-order meta-iteration ~1.7x faster
    (docs/network.md, "Speed").

    params: dict of arrays (no task axis). adapt, evaluate: batched demos, opaque here, with B tasks.
    loss_tasks(params_b, demos) -> scalar: the SUM over tasks of eq. (2), where every array of params_b
        has a leading task axis of size B.
    only: as in `inner_update`; parameters that do not adapt stay shared (no task axis).
    reduce: None, or a differentiable function applied to every inner gradient (B, ...) before eq. (1):
        when several processes each hold some of the demos' frames, the sum over processes of their
        parts (`oneshot.shards`), since eq. (2) sums over frames.
    Returns the mean over tasks of the post-adaptation loss, like `meta_objective`.
    """
    alpha, _ = _check_step(alpha, steps, None)
    B = _batch_size(adapt)
    fixed, keys, step = _split(params, only, alpha)
    adapted = {k: np.ones((B,) + (1,) * np.ndim(params[k]), dtype=params[k].dtype) * params[k] for k in keys}
    loss = lambda sub, d: loss_tasks({**fixed, **sub}, d)
    for _ in range(steps):
        _, g = value_and_grads(loss, {k: getval(v) for k, v in adapted.items()} if first_order else adapted, adapt)
        if reduce is not None:
            g = {k: reduce(v) for k, v in g.items()}
        adapted = {k: _step(adapted[k], g[k], step[k]) for k in adapted}
    return loss_tasks({**fixed, **adapted}, evaluate) / B


def _batch_size(demos):
    """B from a batched demo: a tuple of arrays with a leading task axis, or one such array."""
    first = demos[0] if isinstance(demos, (tuple, list)) else demos
    return int(np.shape(first)[0])


def meta_gradient_batched(params, adapt, evaluate, loss_tasks, alpha, steps, first_order=False, only=None,
                          reduce=None):
    """Value and gradient of `meta_objective_batched` with respect to `params` (a dict like it)."""
    return value_and_grads(meta_objective_batched, params, adapt, evaluate, loss_tasks, alpha, steps,
                           first_order, only, reduce)
