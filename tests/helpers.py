"""Helpers shared by the tests (tests/ is on sys.path under pytest's default import mode, so test files
`from helpers import ...`). Each is an independent reference or a check, written here once:

    mlp_loss, make_mlp, make_demo, make_tasks   a tiny tanh MLP, independent of oneshot/network.py
    naive_conv2d                                'same' convolution as explicit loops over output pixels
    squared_error                               the summed squared error of a network's actions
    assert_batched_equals_loop                  oneshot.maml.batched == oneshot.maml.inner's per-task loop
    RIGHT_1, RIGHT_9                            students' right answers to exercises 1 and 9, as source text
    one_line_error, check_hostile_scenes        what the world, and the Gymnasium env on it, refuse in one line
    keep_figures                                the matplotlib Figures a module draws, kept to be read back
"""
import inspect

import autograd.numpy as anp
import numpy as np
import pytest

from oneshot.exercises import EXERCISES, SOLUTIONS, solutions
from oneshot.maml import batched, inner
from oneshot.maml.inner import InnerLoop
from oneshot.world.scene import Scene


# ----- a tiny model: 2-layer tanh MLP with a summed squared-error loss (stands in for eq. 2) -----

def mlp_loss(params, demo):
    """demo = (x: (T, d_in), y: (T, d_out)); summed squared error of a 1-hidden-layer tanh MLP."""
    x, y = demo
    hidden = anp.tanh(x @ params["W1"] + params["b1"])
    return anp.sum((hidden @ params["W2"] + params["b2"] - y) ** 2)


def make_mlp(rng, d_in=3, d_hidden=5, d_out=2, dtype=np.float64):
    params = {
        "W1": rng.normal(0, 0.7, (d_in, d_hidden)),
        "b1": rng.normal(0, 0.1, d_hidden),
        "W2": rng.normal(0, 0.7, (d_hidden, d_out)),
        "b2": rng.normal(0, 0.1, d_out),
    }
    return {k: v.astype(dtype) for k, v in params.items()}


def make_demo(rng, T=6, d_in=3, d_out=2, dtype=np.float64):
    return rng.normal(size=(T, d_in)).astype(dtype), rng.normal(size=(T, d_out)).astype(dtype)


def make_tasks(rng, n_tasks=3, **kw):
    return [(make_demo(rng, **kw), make_demo(rng, **kw)) for _ in range(n_tasks)]


# ----- the network -----

def naive_conv2d(x, w, b, stride):
    """Reference 'same' convolution with explicit loops over output pixels (independent of im2col).

    x: (N, H, W, C_in), w: (k, k, C_in, C_out), b: (C_out,) -> (N, H_out, W_out, C_out) float64.
    """
    n, h, width, c_in = x.shape
    k, _, _, c_out = w.shape
    p = k // 2
    h_out, w_out = (h + 2 * p - k) // stride + 1, (width + 2 * p - k) // stride + 1
    out = np.zeros((n, h_out, w_out, c_out))
    for i in range(h_out):
        for j in range(w_out):
            for dy in range(k):
                for dx in range(k):
                    y, xx = i * stride + dy - p, j * stride + dx - p
                    if 0 <= y < h and 0 <= xx < width:
                        out[:, i, j, :] += x[:, y, xx, :] @ w[dy, dx]
    return out + b


def squared_error(predict_fn, images, states, actions):
    """p -> sum over frames of ||predict_fn(p, images, states) - actions||^2 (eq. 2 for one demo).

    anp.sum, not anp.mean: mean's VJP divides by a float64 count and would promote float32."""
    def loss(p):
        r = predict_fn(p, images, states) - actions
        return anp.sum(r * r)
    return loss


# ----- MAML: the batched training path against the plain per-task loop -----

def _task(demos, b):
    """Task b of a batched demo (a tuple of arrays with a leading task axis, or one such array)."""
    return tuple(a[b] for a in demos) if isinstance(demos, (tuple, list)) else demos[b]


def assert_batched_equals_loop(params, adapt, evaluate, loss, alpha, steps, **kwargs):
    """`batched.meta_gradient_batched` on the batched demos equals `inner.meta_gradient` over the
    per-task (adapt, evaluate) pairs: the value (rel 1e-10) and the gradient of every parameter
    (rtol 1e-8, atol 1e-12). loss serves both: per task, and summed over a leading task axis.
    kwargs: first_order, only. Returns ((loop value, loop grads), (batched value, batched grads))."""
    B = len(adapt[0]) if isinstance(adapt, (tuple, list)) else len(adapt)
    tasks = [(_task(adapt, b), _task(evaluate, b)) for b in range(B)]
    v_loop, g_loop = inner.meta_gradient(params, tasks, loss, alpha, steps, **kwargs)
    v_batched, g_batched = batched.meta_gradient_batched(params, adapt, evaluate, loss, InnerLoop(alpha, steps, **kwargs))
    assert v_batched == pytest.approx(v_loop, rel=1e-10)
    assert g_batched.keys() == g_loop.keys() == params.keys()
    for k in params:
        np.testing.assert_allclose(g_batched[k], g_loop[k], rtol=1e-8, atol=1e-12, err_msg=k)
    return (v_loop, g_loop), (v_batched, g_batched)


# ----- hostile inputs: refused in one line that names the option and the fix -----

def one_line_error(call, match):
    """call() raises ValueError matching the regex `match`, in one line; returns the message."""
    with pytest.raises(ValueError, match=match) as error:
        call()
    assert "\n" not in str(error.value)
    return str(error.value)


def check_hostile_scenes(reset, step):
    """reset(options={"scene": ...}) (the world's, or the Gymnasium env's) refuses non-finite, complex or
    out-of-arena positions, float or bool colours, a bool or float target and anything but a Scene, each
    in one line; a good scene is copied: NaNs written into the caller's positions after the reset do not
    move the target (step(torques)'s info says where it is)."""
    good = Scene(np.array([0, 16, 32]), np.array([[0.1, 0.0], [-0.1, 0.0], [0.0, 0.15]]), target=0)
    for positions in ([[np.nan, 0.0], [-0.1, 0.0], [0.0, 0.15]], [[0.1, np.inf], [-0.1, 0.0], [0.0, 0.15]],
                      [[0.1, 0.0], [-0.1, 0.0], [0.0, 0.3]], [[0.1 + 1j, 0], [-0.1, 0], [0, 0.15]]):
        one_line_error(lambda: reset(options={"scene": Scene(good.colours, np.array(positions), 0)}),
                       r"reset option 'scene': positions must be finite metres inside the arena .* replace the NaN")
    for colours in ([0.0, 16.0, 32.0], [0.5, 16, 32], [True, False, False]):
        one_line_error(lambda: reset(options={"scene": Scene(np.array(colours), good.positions, 0)}),
                       r"reset option 'scene': colours must be integer palette indices; .* dtype=int")
    for target in (True, 0.0):
        one_line_error(lambda: reset(options={"scene": Scene(good.colours, good.positions, target)}),
                       r"reset option 'scene': target must be an int")
    one_line_error(lambda: reset(options={"scene": {"colours": [0, 16, 32]}}),
                   r"reset option 'scene' must be a oneshot.world.scene.Scene; got dict")
    positions = good.positions.copy()
    reset(options={"scene": Scene(np.array([0, 16, 32]), positions, 0)})
    positions[:] = np.nan                                      # the caller's array, after the reset
    assert step(np.zeros(2))[4]["target_position"].tolist() == [0.1, 0.0]


# ----- students' right answers to exercises 1 (is_success) and 9 (wilson_interval), as source text -----

RIGHT_1 = """
import numpy as np
def is_success(end_effector, target, success_radius=0.05):
    e = np.asarray(end_effector)
    return bool(np.linalg.norm(e[-max(1, len(e) // 5):] - target, axis=-1).min() <= success_radius)
"""
RIGHT_9 = """
import math
def wilson_interval(successes, trials, z=1.96):
    if trials == 0:
        return 0.0, 1.0
    p, n = successes / trials, trials
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)
"""


def solution_source(number):
    """Exercise `number`'s reference solution as a student would type it into a cell: the solutions'
    imports, the function's source, and the exercise's name bound to it. A copy of the code: the
    package's own function is flagged by `check` and by the grader."""
    imports = [line for line in inspect.getsource(solutions).splitlines() if line.startswith(("import ", "from "))]
    function = SOLUTIONS[number]
    return "\n".join(imports) + f"\n\n{inspect.getsource(function)}\n{EXERCISES[number].name} = {function.__name__}\n"


def student_copy(number):
    """The function `solution_source(number)` defines, run as a student's cell is (a file of its own)."""
    namespace = {}
    exec(compile(solution_source(number), f"<a student's exercise {number}>", "exec"), namespace)
    return namespace[EXERCISES[number].name]


def keep_figures(monkeypatch, module):
    """[the matplotlib Figures `module` draws from now on, in order], each kept after it is saved (the
    module draws with a module-level `Figure`, matplotlib.figure.Figure)."""
    pytest.importorskip("matplotlib")
    drawn = []

    class Kept(module.Figure):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            drawn.append(self)
    monkeypatch.setattr(module, "Figure", Kept)
    return drawn
