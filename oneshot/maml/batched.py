"""MAML for a whole meta-batch in one computation graph: the training path of Section II.

`oneshot.maml.inner` is the plain path (one task at a time, in autograd's own terms). This module computes
the same meta-objective and meta-gradient faster, three ways, each measured (docs/results.md) and each
tested equal to the plain path:

  - one graph for the B tasks of a meta-batch: every adapted parameter gets a leading task axis, one
    copy per task, so eq. (1) runs for all tasks at once (`meta_objective_batched`);
  - one root node per parameter array instead of autograd's boxed dict (`value_and_grads`);
  - eq. (1) for one array as a single recorded operation (the `gradient_step` primitive).
"""
import autograd.numpy as np
from autograd.core import VJPNode, add_outgrads, vspace
from autograd.extend import defvjp, primitive
from autograd.tracer import isbox, new_box, trace_stack
from autograd.util import toposort

from oneshot.maml.inner import check_step, constant, split


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
    3-step meta-gradient drops by about a third, a whole meta-iteration by 8-12% (docs/results.md).

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
    """`maml.meta_objective` for a whole meta-batch in one computation graph (same value, faster).

    Each of the B tasks gets its own copy of the parameters (a leading task axis). Task b's loss
    depends only on copy b, so the gradient of the summed loss with respect to the copies is, row by
    row, each task's own inner gradient: eq. (1) for all tasks at once. autograd then records one
    graph instead of B, which made a 5-task second-order meta-iteration ~1.7x faster
    (docs/results.md, "Speed").

    params: dict of arrays (no task axis). adapt, evaluate: batched demos, opaque here, with B tasks.
    loss_tasks(params_b, demos) -> scalar: the SUM over tasks of eq. (2), where every array of params_b
        has a leading task axis of size B.
    only: as in `maml.inner_update`; parameters that do not adapt stay shared (no task axis).
    reduce: None, or a differentiable function applied to every inner gradient (B, ...) before eq. (1):
        when several processes each hold some of the demos' frames, the sum over processes of their
        parts (`oneshot.maml.shards`), since eq. (2) sums over frames.
    Returns the mean over tasks of the post-adaptation loss, like `maml.meta_objective`.
    """
    alpha = check_step(alpha, steps)
    B = _batch_size(adapt)
    fixed, keys, step = split(params, only, alpha)
    adapted = {k: np.ones((B,) + (1,) * np.ndim(params[k]), dtype=params[k].dtype) * params[k] for k in keys}
    inner = constant(fixed) if first_order else fixed        # first order: the inner gradient is a constant
    loss = lambda sub, d: loss_tasks({**inner, **sub}, d)
    for _ in range(steps):
        _, g = value_and_grads(loss, constant(adapted) if first_order else adapted, adapt)
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
