"""Eq. (1) for a whole meta-batch in one computation graph: the training path of Section II.

`inner.inner_update` is eq. (1), written once. Training applies that same function to a meta-batch
(`adapt_batch`): every adapted parameter gets a leading task axis, one copy per task, so that task b's
loss depends only on copy b and the gradient of the summed loss with respect to the copies is, row by
row, each task's own inner gradient. autograd then records one graph instead of B; and the gradients
take a cheaper route than autograd's boxed dict (`value_and_grads`). Both give the numbers of the plain
per-task path, which the tests prove (docs/results.md, "Speed", has what each buys).
"""
import autograd.numpy as np
import numpy as onp
from autograd.core import SparseObject, VJPNode, add_outgrads, vspace
from autograd.extend import defvjp, defvjp_argnum, primitive
from autograd.tracer import isbox, new_box, trace_stack
from autograd.util import toposort

from oneshot.maml.inner import adapted_keys, inner_update


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
    What it buys is measured in docs/results.md ("Speed").

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


def adapt_batch(params, adapt, loss_tasks, inner, reduce=None):
    """Eq. (1) for every task of a meta-batch at once: `inner.inner_update`, applied to B copies of the
    adapted parameters (a leading task axis) with `value_and_grads` as its gradient.

    params: dict of arrays (no task axis). adapt: batched demos with B tasks, opaque here.
    loss_tasks(params_b, demos) -> scalar: the SUM over tasks of eq. (2), where an array of params_b
        may have a leading task axis of size B.
    inner: `inner.InnerLoop`, every option of eq. (1); parameters that do not adapt stay shared.
    reduce: None, or a function applied to every inner gradient before the clip and the step
        (`oneshot.maml.shards`: the sum over processes of their frames' parts, since eq. (2) sums over
        frames); it acts element by element, and the arrays of each inner gradient go through it
        together, packed into one vector (`_reduced`).
    Returns the adapted parameters: a dict like params, each adapted array with a task axis (B, ...).
    """
    B = _batch_size(adapt)
    copies = {k: np.ones((B,) + (1,) * np.ndim(params[k]), dtype=params[k].dtype) * params[k]
              for k in adapted_keys(params, inner.only, inner.frozen)}
    gradient = _gradient if reduce is None else lambda f, theta: _reduced(_gradient(f, theta), reduce)
    return inner_update({**params, **copies}, adapt, loss_tasks, **inner.options(), gradient=gradient)


def _gradient(f, theta):
    return value_and_grads(f, theta)[1]


# ----------------------------------------------------------------------------------------------------
# One reduce for all the arrays of an inner gradient
# ----------------------------------------------------------------------------------------------------
# `reduce` (the sum over processes, `oneshot.maml.shards`) acts element by element, so the arrays of an
# inner gradient can go through it together, packed into one vector: one exchange between the processes
# per inner gradient (and one for its VJP) instead of one per parameter array, the same numbers. What
# this buys: docs/results.md, "Speed". `pack` and `piece` are each other's VJP, as `concat_last` and
# `slice_last`; a piece's cotangent is added into the packed vector's in place (`embed`, a sparse
# object, as autograd's own indexing does), not as a vector of zeros per piece.


def _reduced(grads, reduce):
    """{k: reduce(g_k)} with one call of reduce on every array packed into one vector."""
    total, start, out = reduce(pack(*grads.values())), 0, {}
    for k, g in grads.items():
        out[k] = piece(total, start, np.shape(g))
        start += np.size(g)
    return out


@primitive
def pack(*arrays):
    """Every array raveled, one after the other: one vector."""
    return onp.concatenate([onp.ravel(a) for a in arrays])


@primitive
def piece(flat, start, shape):
    """flat[start : start + size] as an array of `shape` (a view)."""
    return flat[start : start + int(onp.prod(shape, dtype=int))].reshape(shape)


@primitive
def embed(x, start, flat_vspace):
    """The VJP of `piece`: x in [start, start + size) of a vector of `flat_vspace`, zero elsewhere,
    as a sparse object that autograd adds into the vector's gradient in place."""
    def add_into(flat):
        flat[start : start + x.size] += onp.ravel(x)
        return flat
    return SparseObject(flat_vspace, add_into)


def _pack_vjp(argnum, ans, args, kwargs):
    start = sum(onp.size(a) for a in args[:argnum])
    return lambda g: piece(g, start, onp.shape(args[argnum]))


defvjp_argnum(pack, _pack_vjp)
defvjp(piece, lambda ans, flat, start, shape: lambda g: embed(g, start, vspace(flat)))
defvjp(embed, lambda ans, x, start, flat_vspace: lambda g: piece(g, start, onp.shape(x)))


def meta_objective_batched(params, adapt, evaluate, loss_tasks, inner, reduce=None):
    """`inner.meta_objective` for a whole meta-batch in one computation graph (the same value, faster):
    the mean over the B tasks of eq. (2) on the evaluate demos after `adapt_batch` on the adapt demos.

    params, adapt, loss_tasks, inner, reduce: as in `adapt_batch`. evaluate: batched demos, B tasks.
    """
    return loss_tasks(adapt_batch(params, adapt, loss_tasks, inner, reduce), evaluate) / _batch_size(adapt)


def _batch_size(demos):
    """B from a batched demo: a tuple of arrays with a leading task axis, or one such array."""
    first = demos[0] if isinstance(demos, (tuple, list)) else demos
    return int(np.shape(first)[0])


def meta_gradient_batched(params, adapt, evaluate, loss_tasks, inner, reduce=None):
    """Value and gradient of `meta_objective_batched` with respect to `params` (a dict like it)."""
    return value_and_grads(meta_objective_batched, params, adapt, evaluate, loss_tasks, inner, reduce)
