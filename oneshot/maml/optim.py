"""Adam (Kingma & Ba, 2015, "Adam: A Method for Stochastic Optimization", Algorithm 1) as pure
functions over explicit state. MIL meta-trains with Adam on the (clipped) meta-gradient.

Parameters and gradients are dicts of arrays. The optimiser state is a dict

    {"step": int, "m": {key: array}, "v": {key: array}}

with first moments `m` and second moments `v` shaped and typed like the parameters. Nothing is
mutated: `adam_step` returns new parameters and a new state. For checkpoints, `state_to_arrays`
flattens the state into plain arrays for `np.savez`, and `state_from_arrays` reads them back, so
training resumes bit-for-bit.
"""
import numpy as np


def adam_init(params):
    """Zero Adam state for `params` (dict of arrays): step 0, m = v = 0 with each param's dtype."""
    return {
        "step": 0,
        "m": {k: np.zeros_like(p) for k, p in params.items()},
        "v": {k: np.zeros_like(p) for k, p in params.items()},
    }


def _check_grads(params, grads, state):
    """Raise ValueError, naming the key, if grads/state do not match params or grads are not finite."""
    for name, other in (("grads", grads), ("optimiser state", state["m"])):
        if other.keys() != params.keys():
            missing = sorted(set(params) - set(other))
            extra = sorted(set(other) - set(params))
            raise ValueError(f"{name} and params disagree in keys: missing {missing}, unexpected {extra}")
    for k, p in params.items():
        g = grads[k]
        if np.shape(g) != np.shape(p):
            raise ValueError(f"grads[{k!r}] has shape {np.shape(g)} but params[{k!r}] has shape {np.shape(p)}")
        if not np.all(np.isfinite(g)):
            bad = np.size(g) - np.count_nonzero(np.isfinite(g))
            raise ValueError(f"grads[{k!r}] has {bad} NaN/inf entries of {np.size(g)}: training has "
                             f"diverged; try a lower learning rate (meta or inner) or gradient clipping")


def adam_step(params, grads, state, lr=1e-3, b1=0.9, b2=0.999, eps=1e-8):
    """One Adam update with bias correction (Kingma & Ba 2015, Algorithm 1; their defaults).

        t = t + 1
        m = b1 m + (1 - b1) g          v = b2 v + (1 - b2) g^2
        theta = theta - lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)

    params, grads: dicts of arrays with the same keys and shapes. state: from `adam_init` or a
    previous `adam_step`. Returns (new_params, new_state); the inputs are not modified, and float32
    stays float32 (the hyperparameters are python floats).
    """
    _check_grads(params, grads, state)
    t = state["step"] + 1
    lr, b1, b2, eps = float(lr), float(b1), float(b2), float(eps)
    step_size = lr / (1.0 - b1**t)  # bias correction of m folded into the step size
    v_scale = 1.0 / (1.0 - b2**t)  # bias correction of v
    new_params, new_m, new_v = {}, {}, {}
    for k, p in params.items():
        g = grads[k]
        new_m[k] = b1 * state["m"][k] + (1.0 - b1) * g
        new_v[k] = b2 * state["v"][k] + (1.0 - b2) * (g * g)
        new_params[k] = p - step_size * new_m[k] / (np.sqrt(v_scale * new_v[k]) + eps)
    return new_params, {"step": t, "m": new_m, "v": new_v}


def state_to_arrays(state, prefix="adam/"):
    """Flatten an Adam state into {name: array} for np.savez: `{prefix}step`, `{prefix}m/{key}`,
    `{prefix}v/{key}`. The arrays are the state's own (no copies)."""
    arrays = {f"{prefix}step": np.array(state["step"], dtype=np.int64)}
    for k in state["m"]:
        arrays[f"{prefix}m/{k}"] = state["m"][k]
        arrays[f"{prefix}v/{k}"] = state["v"][k]
    return arrays


def state_from_arrays(arrays, prefix="adam/"):
    """Inverse of `state_to_arrays`: rebuild the state from a mapping such as an `np.load` result.
    Entries not starting with `prefix` (e.g. the parameters saved in the same file) are ignored."""
    if f"{prefix}step" not in arrays:
        raise ValueError(f"no Adam state with prefix {prefix!r} found (missing '{prefix}step'); "
                         f"was it saved with state_to_arrays(state, {prefix!r})?")
    m_prefix, v_prefix = f"{prefix}m/", f"{prefix}v/"
    m = {name[len(m_prefix):]: np.array(arrays[name]) for name in arrays if name.startswith(m_prefix)}
    v = {name[len(v_prefix):]: np.array(arrays[name]) for name in arrays if name.startswith(v_prefix)}
    if m.keys() != v.keys():
        raise ValueError(f"saved Adam state is incomplete: first-moment keys {sorted(m)} "
                         f"but second-moment keys {sorted(v)}")
    return {"step": int(arrays[f"{prefix}step"]), "m": m, "v": v}
