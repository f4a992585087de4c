"""The same meta-iteration in PyTorch and in JAX, to time ours against (`python -m oneshot.benchmark maml
--peer torch|jax`): the policy network of `oneshot.policy.network` (same config, same parameters,
float32), eq. (2) summed over frames, eq. (1) on the parameters the profile adapts, and the gradient of
the mean over tasks of eq. (2) after adaptation, second order (MAML, Section II), on the same demos.

    PyTorch   a loop over the tasks; eq. (1) by `torch.autograd.grad(..., create_graph=True)`
    JAX       `jax.grad` for eq. (1), `jax.vmap` over the tasks, the whole meta-gradient `jax.jit`ed

Neither is a dependency of the package: `pip install -e .[peers]` (or torch, jax) where they are
wanted. `meta_gradient(peer, ...)` builds a function that returns the value and gradients as NumPy
arrays, which the tests compare with ours; `peer` is "torch" or "jax".
"""
import importlib.util

import numpy as np

from oneshot.maml.inner import adapted_keys

PEERS = {"torch": "PyTorch", "jax": "JAX"}


def available(peer):
    """True when the peer's package can be imported here."""
    return importlib.util.find_spec(peer) is not None


def require(peer):
    """Raise ValueError saying what to install when the peer cannot be imported."""
    if peer not in PEERS:
        raise ValueError(f"peer must be one of {sorted(PEERS)}; got {peer!r}")
    if not available(peer):
        raise ValueError(f"{PEERS[peer]} is not installed in this Python ({peer} cannot be imported): "
                         f"pip install -e .[peers] (or pip install {'torch' if peer == 'torch' else 'jax jaxlib'})")


def meta_gradient(peer, net_cfg, inner):
    """f(params, adapt, evaluate) -> (value, grads) for the peer, numbers as ours: params a dict of
    float32 NumPy arrays (`network.init_params`), adapt and evaluate batched demos (images (B, T, H, W,
    C), states (B, T, 6), actions (B, T, 2)) in network units; value a float, grads NumPy arrays.
    inner: the `inner.InnerLoop` (alpha, steps, first_order, only). The peers are written for the
    paper's loop: what the released code adds (or learnt step sizes) is refused, not silently left out.
    """
    require(peer)
    missing = [name for name, used in (("an inner clip", inner.clip), ("an inner loss scale", inner.loss_scale != 1),
                                       ("parameters that never adapt", inner.frozen),
                                       ("layer norm", net_cfg.layer_norm)) if used]
    if missing:
        raise ValueError(f"the {peer} peer does not do {' or '.join(missing)}; time a profile without them "
                         f"(default, literal)")
    return (_torch if peer == "torch" else _jax)(net_cfg, inner)


def _positions(h, w):
    """Pixel x and y in [-1, 1] of each of the H * W positions (row-major), as `spatial_soft_argmax`."""
    return np.tile(np.linspace(-1, 1, w, dtype=np.float32), h), np.repeat(np.linspace(-1, 1, h, dtype=np.float32), w)


def _torch(net_cfg, inner):
    import torch
    import torch.nn.functional as F

    def forward(p, images, states):
        """images (T, C, H, W) (PyTorch's layout, converted once outside the timing), states (T, 6)."""
        x, i = images, 0
        while f"conv{i}_w" in p:
            w = p[f"conv{i}_w"].permute(3, 2, 0, 1)                  # (k, k, C, M) -> (M, C, k, k)
            x = F.relu(F.conv2d(x, w, p[f"conv{i}_b"], stride=2, padding=net_cfg.kernel // 2))
            i += 1
        T, c, h, w = x.shape
        if "fp_temperature" in p:                                   # feature points
            prob = torch.softmax(x.reshape(T, c, h * w) * p["fp_temperature"], dim=-1)
            xs, ys = (torch.from_numpy(a) for a in _positions(h, w))
            parts = [prob @ xs, prob @ ys]
        else:
            parts = [x.permute(0, 2, 3, 1).reshape(T, -1)]          # flattened as ours: (H, W, C) order
        if "bias_transform" in p:
            parts.append(p["bias_transform"].expand(T, -1))
        h = torch.cat(parts + [states], dim=-1)
        i = 0
        while f"fc{i}_w" in p:
            h = F.relu(h @ p[f"fc{i}_w"] + p[f"fc{i}_b"])
            i += 1
        return h @ p["out_w"] + p["out_b"]

    def loss(p, images, states, actions):
        r = forward(p, images, states) - actions
        return (r * r).sum()

    def meta_objective(p, adapt, evaluate):
        keys, total = adapted_keys(p, inner.only), 0.0
        for b in range(len(adapt[0])):
            fast = dict(p)
            for _ in range(inner.steps):                            # eq. (1)
                g = torch.autograd.grad(loss(fast, *(a[b] for a in adapt)), [fast[k] for k in keys],
                                        create_graph=not inner.first_order)
                fast.update({k: fast[k] - inner.alpha * gk for k, gk in zip(keys, g)})
            total = total + loss(fast, *(e[b] for e in evaluate))
        return total / len(adapt[0])

    def run(params, adapt, evaluate):
        p = {k: torch.from_numpy(np.asarray(v)).requires_grad_() for k, v in params.items()}
        value = meta_objective(p, _torch_demos(torch, adapt), _torch_demos(torch, evaluate))
        grads = torch.autograd.grad(value, list(p.values()))
        return value.item(), {k: g.numpy() for k, g in zip(p, grads)}

    return run


def _torch_demos(torch, demos):
    images, states, actions = (torch.from_numpy(np.asarray(a)) for a in demos)
    return images.permute(0, 1, 4, 2, 3).contiguous(), states, actions     # (B, T, C, H, W)


def _jax(net_cfg, inner):
    import jax
    import jax.numpy as jnp

    def forward(p, images, states):
        x, i = images, 0
        while f"conv{i}_w" in p:
            pad = net_cfg.kernel // 2
            x = jax.lax.conv_general_dilated(x, p[f"conv{i}_w"], (2, 2), [(pad, pad), (pad, pad)],
                                             dimension_numbers=("NHWC", "HWIO", "NHWC"))
            x = jax.nn.relu(x + p[f"conv{i}_b"])
            i += 1
        T, h, w, c = x.shape
        if "fp_temperature" in p:
            prob = jax.nn.softmax(x.reshape(T, h * w, c) * p["fp_temperature"], axis=1)
            xs, ys = _positions(h, w)
            parts = [jnp.einsum("tpc,p->tc", prob, xs), jnp.einsum("tpc,p->tc", prob, ys)]
        else:
            parts = [x.reshape(T, -1)]
        if "bias_transform" in p:
            parts.append(jnp.broadcast_to(p["bias_transform"], (T, p["bias_transform"].shape[0])))
        h = jnp.concatenate(parts + [states], axis=-1)
        i = 0
        while f"fc{i}_w" in p:
            h = jax.nn.relu(h @ p[f"fc{i}_w"] + p[f"fc{i}_b"])
            i += 1
        return h @ p["out_w"] + p["out_b"]

    def loss(p, demo):
        r = forward(p, demo[0], demo[1]) - demo[2]
        return jnp.sum(r * r)

    def task_objective(p, adapt, evaluate):
        keys = adapted_keys(p, inner.only)
        theta, fixed = {k: p[k] for k in keys}, {k: v for k, v in p.items() if k not in keys}
        for _ in range(inner.steps):                                # eq. (1)
            g = jax.grad(lambda th: loss({**fixed, **th}, adapt))(theta)
            if inner.first_order:
                g = jax.lax.stop_gradient(g)
            theta = {k: theta[k] - inner.alpha * g[k] for k in keys}
        return loss({**fixed, **theta}, evaluate)

    def meta_objective(p, adapt, evaluate):
        return jnp.mean(jax.vmap(task_objective, in_axes=(None, 0, 0))(p, adapt, evaluate))

    step = jax.jit(jax.value_and_grad(meta_objective))

    def run(params, adapt, evaluate):
        value, grads = step(params, tuple(adapt), tuple(evaluate))
        grads = jax.block_until_ready(grads)
        return float(value), {k: np.asarray(g) for k, g in grads.items()}

    return run
