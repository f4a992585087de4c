"""The exercises (oneshot/exercises/): every checker passes its reference solution and names the
mistake in answers a student could write (written here, not taken from the checkers' own lists);
functions that raise, return the wrong shape or change their inputs are reported, not crashed on; the
command line checks a file and grades a folder with a timeout; the notebooks follow the convention
their test relies on (tag `exercise-N` on the stub cell) and run both as stubs and with solutions."""
import concurrent.futures
import dataclasses
import json
import re
import sys
import threading
from pathlib import Path

import autograd.numpy as anp
import numpy as np
import pytest
from autograd import grad
from autograd.tracer import getval

from helpers import RIGHT_1, RIGHT_9, solution_source, student_copy
from oneshot.expert import ilqg
from oneshot.exercises import CHECKERS, EXERCISES, check, reference
from oneshot.exercises.__main__ import main
from oneshot.exercises.checking import run
from oneshot.exercises.compare import Out, compare
from oneshot.policy.network import forward

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks" / "exercises"


def message(number, function):
    result = check(number, function, quiet=True)
    assert not result.passed
    return result.message


@pytest.mark.parametrize("number", sorted(EXERCISES))
def test_every_reference_solution_is_correct(number, capsys):
    """Typed into a cell (a copy of its code), as a student would write it; its values, by the checker."""
    result = check(number, student_copy(number))
    assert result.passed and result.message == "correct"
    assert capsys.readouterr().out == f"exercise {number} ({EXERCISES[number].title}): correct\n"
    assert run(EXERCISES[number], CHECKERS[number], reference(number)).passed


@pytest.mark.parametrize("number", sorted(EXERCISES))
def test_check_flags_the_package_answers_as_the_grader_does(number):
    """check(9, wilson_interval) with the package's own function, reference(n), or a wrapper around
    either said "correct" in a notebook, and the grader then flagged it and scored 0."""
    package = CHECKERS[number].expected          # the package's function, or the checker's call of it
    for function in (reference(number), package, lambda *args: package(*args)):
        result = check(number, function, quiet=True)
        assert not result.passed and result.flagged, result.message
        assert re.search(r"calls oneshot\.[\w.]+, the package's own \(on .*\): write your own$", result.message)
    assert check(number, student_copy(number), quiet=True).passed and sys.getprofile() is None


def test_check_watches_threads_leaves_no_hook_and_stands_aside_for_a_profiler():
    def in_a_thread(successes, trials, z=1.96):
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            return pool.submit(reference(9), successes, trials, z).result()
    assert "calls oneshot.exercises.solutions.wilson_interval" in message(9, in_a_thread)

    def raises(*args):
        raise ValueError("no")
    assert "raised ValueError" in message(9, raises)
    assert sys.getprofile() is None and threading.getprofile() is None
    profiler = lambda frame, event, arg: None        # the user's own (cProfile's is not even callable)
    sys.setprofile(profiler)
    try:
        assert check(9, student_copy(9), quiet=True).passed
        assert sys.getprofile() is profiler
    finally:
        sys.setprofile(None)


def test_exercises_are_small_frozen_records_numbered_1_to_10():
    assert sorted(EXERCISES) == list(range(1, 11))
    assert EXERCISES[5].name == "imitation_loss" and EXERCISES[5].section == "III" and "eq. (2)" in EXERCISES[5].doc
    with pytest.raises(dataclasses.FrozenInstanceError):
        EXERCISES[5].name = "other"
    with pytest.raises(ValueError, match="exercises are 1-10"):
        reference(11)


# ----- wrong answers a student could write, and the words the checker must say -----

def _fifth(e):
    e = np.asarray(e)
    return e[-max(1, len(e) // 5):]


def _kinematics(first, second, transpose=False):
    def kinematics(q, l1, l2):
        a1, a2 = first(q), second(q)
        p = np.stack([l1 * np.cos(a1) + l2 * np.cos(a2), l1 * np.sin(a1) + l2 * np.sin(a2)], -1)
        J = np.stack([np.stack([-l1 * np.sin(a1) - l2 * np.sin(a2), -l2 * np.sin(a2)], -1),
                      np.stack([l1 * np.cos(a1) + l2 * np.cos(a2), l2 * np.cos(a2)], -1)], -2)
        return p, np.swapaxes(J, -1, -2) if transpose else J
    return kinematics


def _backward_step(bvb=True, mu_identity=False, K_sign=-1, closed_value=False, use_mu=True):
    def backward_step(Vx, Vxx, A, B, lx, lu, lxx, luu, lux, mu):
        mu = mu if use_mu else 0.0
        Quu = luu + (B.T @ Vxx @ B if bvb else 0)
        Qux = lux + B.T @ Vxx @ A
        Quu_r = Quu + (mu * np.eye(len(lu)) if mu_identity else mu * B.T @ B)
        Qux_r = Qux + (0 if mu_identity else mu * B.T @ A)
        k, K = -np.linalg.solve(Quu_r, lu + B.T @ Vx), K_sign * np.linalg.solve(Quu_r, Qux_r)
        Qx, Qxx = lx + A.T @ Vx, lxx + A.T @ Vxx @ A
        if closed_value:                                   # the textbook value update, right only when mu = 0
            Qu = lu + B.T @ Vx
            return k, K, Qx - Qux.T @ np.linalg.inv(Quu) @ Qu, Qxx - Qux.T @ np.linalg.inv(Quu) @ Qux
        return (k, K, Qx + K.T @ Quu @ k + K.T @ (lu + B.T @ Vx) + Qux.T @ k,
                Qxx + K.T @ Quu @ K + K.T @ Qux + Qux.T @ K)
    return backward_step


def _conv(pad=True, stride_used=True, channel_first=False):
    def conv2d(x, w, b, stride):
        s, k = (stride if stride_used else 1), w.shape[0]
        p = k // 2 if pad else 0
        x = np.pad(x, ((0, 0), (p, p), (p, p), (0, 0)))
        h_out, w_out = (x.shape[1] - k) // s + 1, (x.shape[2] - k) // s + 1
        out = np.empty((x.shape[0], h_out, w_out, w.shape[-1]))
        for i in range(h_out):
            for j in range(w_out):
                patch = x[:, s * i:s * i + k, s * j:s * j + k, :]
                patch = patch.transpose(0, 3, 1, 2) if channel_first else patch
                out[:, i, j] = patch.reshape(len(x), -1) @ w.reshape(-1, w.shape[-1]) + b
        return out
    return conv2d


def _loss(reduce):
    def imitation_loss(params, demo):
        images, states, actions = demo
        return reduce(forward(params, images, states) - actions)
    return imitation_loss


def _inner(sign=-1, everything=False, step=lambda alpha: alpha):
    def inner_update(params, demo, loss_fn, alpha, only=None):
        g = grad(loss_fn)(params, demo)
        adapt = lambda k: everything or only is None or any(k.startswith(o) for o in only)
        return {k: v + sign * step(alpha) * g[k] if adapt(k) else v for k, v in params.items()}
    return inner_update


def _meta(second_order=True, adapt=True, reduce=np.sum):
    def meta_gradients(w, alpha, adapt_demo, eval_demo):
        (xa, ya), (xe, ye) = adapt_demo, eval_demo
        w2 = w - alpha * 2 * reduce(xa * (w * xa - ya)) if adapt else w
        first = 2 * reduce(xe * (w2 * xe - ye))
        return first * (1 - 2 * alpha * reduce(xa ** 2) if second_order else 1), first
    return meta_gradients


def _context(frame=-1, axis=-1, transpose=False):
    def contextual_input(images, demo_images):
        final = demo_images[..., frame:frame + 1 or None, :, :, :]
        context = np.repeat(np.swapaxes(final, -2, -3) if transpose else final, images.shape[-4], axis=-4)
        return np.concatenate([images, context], axis=axis)
    return contextual_input


def _wald(successes, trials, z=1.96):
    p = successes / trials
    half = z * np.sqrt(p * (1 - p) / trials)
    return max(0.0, p - half), min(1.0, p + half)


def _lstm(gate, forget=True, order="ifgo", forget_bias=0.0):
    def lstm_step(w_h, xw, h, c):
        z = dict(zip(order, np.split(xw + h @ w_h, 4, axis=-1)))
        i, f, g, o = z["i"], z["f"] + forget_bias, z["g"], z["o"]
        c2 = (gate(f) * c if forget else c) + gate(i) * np.tanh(g)
        return gate(o) * np.tanh(c2), c2
    return lstm_step


sigmoid = lambda x: 1 / (1 + np.exp(-x))
WRONG = [
    (1, lambda e, t, r=0.05: bool(np.linalg.norm(np.asarray(e) - t, axis=-1).min() <= r),
     ["whole episode", "final fifth"]),
    (1, lambda e, t, r=0.05: bool(np.linalg.norm(np.asarray(e)[-1] - t) <= r), ["last step only"]),
    (1, lambda e, t, r=0.05: bool(np.linalg.norm(_fifth(e) - t, axis=-1).min() < r), ["strict <"]),
    (2, _kinematics(lambda q: q[..., 1], lambda q: q[..., 0] + q[..., 1]), ["swapped the joint angles"]),
    (2, _kinematics(lambda q: q[..., 0], lambda q: q[..., 1]), ["q1 + q2, not q2"]),
    (2, _kinematics(lambda q: q[..., 0], lambda q: q[..., 0] + q[..., 1], transpose=True), ["Jacobian is transposed"]),
    (3, _backward_step(bvb=False), ["lacks the term B^T V_xx B"]),
    (3, _backward_step(mu_identity=True), ["regularised Q_uu with mu I", "regularises V_xx"]),
    (3, _backward_step(K_sign=+1), ["K has the wrong sign"]),
    (4, _conv(pad=False), ["did not pad", "k // 2"]),
    (4, _conv(channel_first=True), ["(channel, dy, dx)"]),
    (4, _conv(stride_used=False), ["ignored the stride"]),
    (5, _loss(lambda r: anp.mean(anp.sum(r ** 2, axis=1))), ["1/T", "sums over frames, it does not average"]),
    (5, _loss(lambda r: anp.sum(anp.abs(r))), ["without squaring"]),
    (5, _loss(lambda r: anp.sum(r[:, 0] ** 2)), ["first torque only"]),
    (6, _inner(sign=+1), ["UP the gradient"]),
    (6, _inner(everything=True), ["updated every parameter"]),
    (6, _inner(step=lambda alpha: alpha ** 2), ["alpha^2"]),
    (6, _inner(step=lambda alpha: 1.0), ["lacks alpha"]),
    (7, _meta(second_order=False), ["equals the first-order one"]),
    (7, _meta(adapt=False), ["gradient at w", "ADAPTED"]),
    (8, _context(frame=0), ["FIRST image"]),
    (8, _context(axis=0), ["frame axis"]),
    (9, _wald, ["Wald"]),
    (9, lambda s, n, z=1.96: student_copy(9)(s, n), ["z = 1.96 whatever z is given"]),
    (10, _lstm(np.tanh), ["sigmoids"]),
    (10, _lstm(sigmoid, forget=False), ["forget gate"]),
    (1, lambda e, t, r=0.05: bool(np.linalg.norm(_fifth(e) - t, axis=-1).max() <= r), ["EVERY step"]),
    (1, lambda e, t, r=0.05: bool(np.linalg.norm(np.asarray(e)[len(e) - len(e) // 5:] - t, axis=-1).min() <= r),
     ["raised ValueError", "T // 5 is 0", "max(1, T // 5)"]),
    (2, lambda q, l1, l2: _kinematics(lambda q: q[..., 0], lambda q: q[..., 0] + q[..., 1])(q, l1, l2)[::-1],
     ["returned (J, p)"]),
    (3, _backward_step(closed_value=True), ["Q_xx - Q_ux^T Q_uu^-1 Q_ux", "mu = 0.5"]),
    (3, _backward_step(use_mu=False), ["ignores mu"]),
    (5, _loss(lambda r: anp.sum(anp.mean(r ** 2, axis=1))), ["a mean over them halves it"]),
    (7, _meta(reduce=np.mean), ["a mean over the demo's points"]),
    (8, _context(transpose=True), ["rows and columns are swapped"]),
    (10, _lstm(sigmoid, order="igfo"), ["TensorFlow's order i, j, f, o"]),
    (10, _lstm(sigmoid, order="gifo"), ["you read them as g, i, f, o"]),
    (10, _lstm(sigmoid, forget_bias=1.0), ["forget_bias=1.0"]),
]


# Wrong answers that a single case, check or message of a checker is there to catch: each was found by a
# mutation audit of the checkers (that case dropped, that check loosened, let it pass or lose its words).

def _short_value_x(Vx, Vxx, A, B, lx, lu, lxx, luu, lux, mu):
    """V_x in its short form Q_x + K^T Q_u (right only when mu = 0), V_xx in the full one."""
    Qx, Qu = lx + A.T @ Vx, lu + B.T @ Vx
    Qxx, Quu, Qux = lxx + A.T @ Vxx @ A, luu + B.T @ Vxx @ B, lux + B.T @ Vxx @ A
    k, K = -np.linalg.solve(Quu + mu * B.T @ B, Qu), -np.linalg.solve(Quu + mu * B.T @ B, Qux + mu * B.T @ A)
    return k, K, Qx + K.T @ Qu, Qxx + K.T @ Quu @ K + K.T @ Qux + Qux.T @ K


def _residual_in_place(params, demo):
    images, states, actions = demo
    actions -= forward(params, images, states)            # the residual, written into the demo's actions
    return anp.sum(actions ** 2)


def _inner_by_prefix(first_only=False, stop_gradient=False, with_gradients=False):
    def inner_update(params, demo, loss_fn, alpha, only=None):
        g = grad(loss_fn)(params, demo)
        g = {k: getval(v) for k, v in g.items()} if stop_gradient else g
        adapt = lambda k: only is None or k.startswith(only[0] if first_only else tuple(only))
        new = {k: v - alpha * g[k] if adapt(k) else v for k, v in params.items()}
        return {**new, **{"grad_" + k: v for k, v in g.items()}} if with_gradients else new
    return inner_update


def _meta_residual_reversed(w, alpha, adapt_demo, eval_demo):
    """The inner step right, the outer gradient written with the residual y - w' x: the opposite sign."""
    (xa, ya), (xe, ye) = adapt_demo, eval_demo
    w2 = w - alpha * 2 * np.sum(xa * (w * xa - ya))
    first = 2 * np.sum(xe * (ye - w2 * xe))
    return float(first * (1 - 2 * alpha * np.sum(xa ** 2))), float(first)


def _wilson_unguarded(successes, trials, z=1.96):
    p, n = successes / trials, trials
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def _lstm_in_place(w_h, xw, h, c):
    i, f, g, o = np.split(xw + h @ w_h, 4, axis=-1)
    c *= sigmoid(f)                                        # the cell state, updated in the caller's array
    c += sigmoid(i) * np.tanh(g)
    return sigmoid(o) * np.tanh(c), c


WRONG += [
    (1, lambda e, t, r=0.05: bool(np.linalg.norm(np.asarray(e)[-(len(e) // 5):] - t, axis=-1).min() <= r),
     ["T // 5 is 0", "on a 3-step episode"]),              # right for T = 1 (e[-0:] is its one step), not T = 3
    (1, lambda e, t, r=0.05: bool(np.linalg.norm(np.asarray(e)[int(0.8 * len(e)):] - t, axis=-1).min() <= r),
     ["final fifth is too long", "of 23 steps it is the last T // 5 = 4"]),   # 5 of 23 steps; right for T = 50
    # other distances than the straight line: right on every case off the diagonal (a wrong-answer audit)
    (1, lambda e, t, r=0.05: bool(np.abs(np.asarray(e)[-max(1, len(e) // 5):] - t).max(-1).min() <= r),
     ["largest coordinate difference", "0.06 m from the target at step 18, diagonally"]),
    (1, lambda e, t, r=0.05: bool(np.abs(np.asarray(e)[-max(1, len(e) // 5):] - t).sum(-1).min() <= r),
     ["you add the coordinate differences", "0.045 m from the target at step 18, diagonally"]),
    (1, lambda e, t, r=0.05: bool(np.abs(np.asarray(e)[-max(1, len(e) // 5):, 0] - t[0]).min() <= r),
     ["you measure one coordinate only"]),
    (2, _kinematics(lambda q: q[0], lambda q: q[0] + q[1]),
     ["on a batch of 5 poses", "has shape (2, 2); expected (5, 2) (axis 0: 2 instead of 5); q has leading axes: use "
      "q[..., 0] and q[..., 1]"]),
    (2, _kinematics(lambda q: q[..., 0], lambda q: q[..., 0] + q[..., 1], transpose=True),
     ["your Jacobian J[x, q2] is", "it is the transpose of the expected value"]),
    (3, _backward_step(K_sign=+1), ["(on the arm's sizes: n = 4 states, m = 2 controls, mu = 0.0: your K[0, 0] is",
                                    "it is the expected value with the opposite sign"]),
    (3, _short_value_x, ["V_x", "mu = 0.5"]),              # Vx the mistake's, Vxx right: named on Vx alone
    (5, _residual_in_place, ["changed its argument `demo` in place"]),
    (6, _inner_by_prefix(first_only=True), ["you adapted only the keys starting with the first prefix of `only`",
                                            "on one step of alpha = 0.3 on the keys starting with 'layer0_w' or "
                                            "'layer1_b'", "params['layer1_b']"]),
    (6, _inner_by_prefix(stop_gradient=True), ["first-order one", "MAML's meta-gradient through your update"]),
    (6, _inner_by_prefix(with_gradients=True), ["keys that were not asked for: ['grad_layer0_w'"]),
    (6, lambda params, demo, loss_fn, alpha, only=None: {       # the part of a name before "_" is no prefix
        k: v - alpha * grad(loss_fn)(params, demo)[k] if only is None or k.split("_")[0] in only or k in only else v
        for k, v in params.items()}, ["holds key PREFIXES, not names or name parts: ('layer0_',)"]),
    (7, _meta_residual_reversed, ["(the opposite sign)"]),
    (8, lambda images, demo_images: np.concatenate([images, np.broadcast_to(demo_images[-1], images.shape)], -1),
     ["on a batch of 2 tasks", "demo_images[..., -1:, :, :, :]"]),
    (8, _context(axis=-2), ["image's width", "(column: 12 instead of 6; channel: 3 instead of 6)"]),
    (8, lambda images, demo_images: np.concatenate([images, np.broadcast_to(                  # one leading axis
        demo_images[:, -1:] if demo_images.ndim == 5 else demo_images[-1:], images.shape)], -1),
     ["two leading axes", "any number of leading axes"]),
    (9, _wilson_unguarded, ["raised ZeroDivisionError", "on 0 trials", "(0.0, 1.0)"]),
    (10, _lstm_in_place, ["changed its argument `c` in place"]),
    (10, _lstm(lambda x: sigmoid(np.clip(x, -10, 10))), ["large gate inputs (saturated gates)"]),
]


@pytest.mark.parametrize("number, function, words", WRONG, ids=[f"{n}-{i}" for i, (n, _, _) in enumerate(WRONG)])
def test_checker_names_the_mistake(number, function, words):
    text = message(number, function)
    for word in words:
        assert word in text, text


def test_at_least_two_different_mistakes_per_exercise():
    for number in EXERCISES:
        assert len({id(f) for n, f, _ in WRONG if n == number}) >= 2


# ----- functions that raise, return the wrong shape, or change their inputs -----

def _wrong_shape(number):
    """The reference, its result mangled into the wrong shape: one value too many or an extra axis."""
    def mangle(result):
        if isinstance(result, dict):
            return list(result.values())
        if isinstance(result, tuple):
            return result[:1]
        if isinstance(result, (bool, np.bool_)):
            return np.array([result, result])
        return np.asarray(result)[None]
    return lambda *args: mangle(student_copy(number)(*args))


@pytest.mark.parametrize("number", sorted(EXERCISES))
def test_functions_that_raise_or_return_the_wrong_shape_are_reported(number):
    def raises(*args):
        raise ZeroDivisionError("division by zero")
    assert f"your {EXERCISES[number].name} raised ZeroDivisionError: division by zero on " in message(number, raises)
    text = message(number, _wrong_shape(number))
    assert any(w in text for w in ("has shape", "expected a tuple of", "expected True or False", "expected a dict",
                                   "expected a single number")), text
    stub = lambda *args: (_ for _ in ()).throw(NotImplementedError)
    assert message(number, stub) == f"{EXERCISES[number].name} is not written yet (it raises NotImplementedError)"


def test_a_function_that_changes_its_input_is_told_so():
    def imitation_loss(params, demo):
        params["out_b"] += 1.0
        return student_copy(5)(params, demo)
    assert "changed its argument `params` in place" in message(5, imitation_loss)
    assert "expected a function" in message(5, 3.0)


def test_a_near_miss_shows_the_digits_that_differ_and_no_relation_that_is_not_there():
    text = message(9, lambda s, n, z=1.96: tuple(v * (1 + 2e-6) for v in student_copy(9)(s, n, z)))
    got, want = re.search(r"is (\S+); expected (\S+) ", text).groups()
    assert got != want and "relative difference of 2.0e-06" in text and "times the expected" not in text, text
    in_float32 = lambda *a: tuple(v.astype(np.float32) for v in student_copy(10)(*(x.astype(np.float32) for x in a)))
    text = message(10, in_float32)                         # a 1 x 1 array is its own transpose
    assert "transpose" not in text and "relative difference" in text, text
    symmetric, out = np.array([[2.0, 1.0], [1.0, 3.0]]), Out("array", "your M")
    assert "transpose" not in compare(symmetric + 1e-3, symmetric, out).message
    assert "transpose" in compare(np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([[1.0, 3.0], [2.0, 4.0]]), out).message


def test_a_result_passes_only_as_a_number_of_the_right_kind_within_the_relative_tolerance():
    """The tolerance is relative (rtol 1e-6): a small number is not "close" to one twice its size because
    both are near 0; True is not the number 1, nor a complex array its real part."""
    number, array = Out("number", "your loss"), Out("array", "your K")
    assert compare(2e-8 * (1 + 1e-7), 2e-8, number) is None
    assert compare(1e-8, 2e-8, number).message.startswith("your loss is 1e-08; expected 2e-08")
    assert compare(True, 1.0, number).message == "your loss is True; expected a single number"
    assert compare(np.array([1.0 + 1.0j, 2.0]), np.array([1.0, 2.0]), array).message.startswith("your K is an array")


def test_a_hint_about_raising_is_not_added_to_a_wrong_value():
    """A case's hint about an error ("autograd cannot differentiate ...") is not given for a wrong
    value that no mistake explains: here an update right in value whose derivative is 1.5 times too
    large in its gradient's part (g - getval(g) is 0, its derivative that of g)."""
    def inner_update(params, demo, loss_fn, alpha, only=None):
        g = grad(loss_fn)(params, demo)
        adapt = lambda k: only is None or k.startswith(tuple(only))
        return {k: v - alpha * (g[k] + 0.5 * (g[k] - getval(g[k]))) if adapt(k) else v for k, v in params.items()}
    text = message(6, inner_update)
    assert text.startswith("on MAML's meta-gradient through your update") and "autograd cannot" not in text, text


def _scaled(value, part, factor):
    """The result with the floats of its part `part` (a tuple index; None: all of it) times `factor`."""
    if part is not None:
        return tuple(_scaled(v, None, factor) if i == part else v for i, v in enumerate(value))
    if isinstance(value, dict):
        return {k: _scaled(v, None, factor) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return (value * factor).astype(value.dtype) if value.dtype.kind == "f" else value
    return value * factor


@pytest.mark.parametrize("number, part", [(2, 0), (2, 1), (3, 0), (3, 1), (3, 2), (3, 3), (4, None), (5, None),
                                          (6, None), (7, 0), (7, 1), (8, None), (9, 0), (9, 1), (10, 0), (10, 1)])
def test_every_part_of_every_result_is_held_to_the_tolerance(number, part):
    """The right answer with one part 1 + 1e-5 times too large is refused on the first case it shows on
    (exercise 8's first float case; exercise 5's first loss, not only its gradient), that part and the
    relative difference named: a tolerance loosened on any one part's Out would let it pass."""
    right, checker = student_copy(number), CHECKERS[number]
    text = message(number, lambda *args: _scaled(right(*args), part, 1 + 1e-5))
    first = next(c for c in checker.cases() if number != 8 or c.args[0].dtype.kind == "f")
    assert text.startswith(f"on {first.label}, ") and "relative difference of 1.0e-05" in text, text
    assert part is None or re.search(re.escape(checker.out.parts[part].what) + r"(\[| is)", text), text


def test_exercise_8_keeps_a_float_dtype_as_well_as_an_integer_one():
    widen = lambda images, demo_images: student_copy(8)(images, demo_images).astype(np.float64)
    floats_only = lambda images, demo_images: (widen if images.dtype.kind == "f" else student_copy(8))(images, demo_images)
    assert "has dtype float64; expected float32, the inputs' own dtype" in message(8, floats_only)
    assert "has dtype float64; expected uint8" in message(8, widen)


def test_a_loss_autograd_cannot_differentiate_is_told_so():
    def imitation_loss(params, demo):        # right value, plain NumPy: grad fails
        images, states, actions = demo
        return float(np.sum((np.asarray(forward(params, images, states)) - actions) ** 2))
    assert "autograd cannot differentiate your loss" in message(5, imitation_loss)


def test_the_step_is_checked_against_ilqg_backward_pass_on_one_step():
    rng = np.random.default_rng(0)
    n, m = 4, 2
    spd = lambda k: (lambda M: M @ M.T + np.eye(k))(rng.normal(size=(k, k)))
    Vx, Vxx, A, B = rng.normal(size=n), spd(n), rng.normal(size=(n, n)), rng.normal(size=(n, m))
    lx, lu, lxx, luu, lux = rng.normal(size=n), rng.normal(size=m), spd(n), spd(m), rng.normal(size=(m, n))
    k, K, _, _ = reference(3)(Vx, Vxx, A, B, lx, lu, lxx, luu, lux, 0.3)
    k1, K1, _ = ilqg.backward_pass(A[None], B[None], np.stack([lx, Vx]), lu[None], np.stack([lxx, Vxx]),
                                   luu[None], lux[None], 0.3)
    np.testing.assert_allclose(k, k1[0], rtol=1e-10)
    np.testing.assert_allclose(K, K1[0], rtol=1e-10)


# ----- the command line -----

WRONG_1 = RIGHT_1.replace("e[-max(1, len(e) // 5):]", "e")


def test_cli_check_exit_statuses(tmp_path, capsys):
    (tmp_path / "right.py").write_text(RIGHT_1)
    (tmp_path / "wrong.py").write_text(WRONG_1)
    (tmp_path / "raises.py").write_text("def is_success(e, t, r=0.05):\n    return 1 / 0\n")
    (tmp_path / "broken.py").write_text("def is_success(:\n")
    assert main(["check", "1", "--file", str(tmp_path / "right.py")]) == 0
    assert capsys.readouterr().out == "exercise 1 (Sec. IV, the success criterion): correct\n"
    assert main(["check", "1", "--file", str(tmp_path / "wrong.py")]) == 1
    assert capsys.readouterr().out.startswith("exercise 1: not yet: you judge the whole episode")
    assert main(["check", "1", "--file", str(tmp_path / "raises.py")]) == 1
    assert "raised ZeroDivisionError" in capsys.readouterr().out
    (tmp_path / "stub.py").write_text("import numpy as np\n\n" + EXERCISES[1].stub)
    assert main(["check", "1", "--file", str(tmp_path / "stub.py")]) == 1
    assert capsys.readouterr().out == "exercise 1: not written: is_success raises NotImplementedError, as the stub does\n"
    for number, file, words in [(1, "missing.py", "no such file"),
                                (5, "right.py", "defines no function imitation_loss"),
                                (1, "broken.py", "could not load broken.py: SyntaxError"),
                                (12, "right.py", "there is no exercise 12")]:
        assert main(["check", str(number), "--file", str(tmp_path / file)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err, err
    assert main(["list"]) == 0
    assert "def imitation_loss(params, demo)" in capsys.readouterr().out


def test_cli_grade_survives_wrong_raising_looping_and_broken_submissions(tmp_path, capsys):
    (tmp_path / "alice.py").write_text(RIGHT_1 + RIGHT_9)
    (tmp_path / "bob.py").write_text(WRONG_1 + "\ndef imitation_loss(params, demo):\n    raise RuntimeError('oops')\n")
    (tmp_path / "carol.py").write_text("def is_success(e, t, r=0.05):\n    while True:\n        pass\n" + RIGHT_9)
    (tmp_path / "dave.py").write_text("def is_success(:\n")
    (tmp_path / "erin.py").write_text(RIGHT_9 + "raise RuntimeError('oops at import')\n" + RIGHT_1)
    (tmp_path / "frank.py").write_text(RIGHT_1 + "while True:\n    pass\n")
    assert main(["grade", str(tmp_path), "--timeout", "3", "--jobs", "4"]) == 0
    lines = capsys.readouterr().out.splitlines()
    verdict = lambda who, n: next(line.split(None, 2)[2] for line in lines if line.split()[:2] == [who, str(n)])
    assert verdict("alice.py", 1) == "correct" and verdict("alice.py", 9) == "correct"
    assert verdict("alice.py", 5) == "missing"
    assert verdict("bob.py", 1).startswith("not yet: you judge the whole episode")
    assert verdict("bob.py", 5) == "not yet: your imitation_loss raised RuntimeError: oops on a 5-frame demo"
    assert verdict("carol.py", 1) == "timed out after 3 s (an endless loop?)"
    assert verdict("carol.py", 9) == "correct"                     # graded after the loop was killed
    assert "could not load dave.py: SyntaxError" in next(line for line in lines if line.startswith("dave.py"))
    assert verdict("erin.py", 9) == "correct"                      # defined before the file raised: graded
    assert verdict("erin.py", 1) == ("missing (erin.py raised RuntimeError: oops at import as it loaded, after "
                                     "defining wilson_interval)")
    assert ("frank.py   -  timed out after 3 s (an endless loop?) while loading (if it only loads slowly, raise "
            "--timeout)") in lines
    totals = [line.split(None, 2)[2] for line in lines if line.split()[1] == "total"]
    assert totals == ["2/10 correct, 2 attempted", "0/10 correct, 2 attempted", "1/10 correct, 2 attempted",
                      "0/10 correct, 0 attempted", "1/10 correct, 1 attempted", "0/10 correct, 0 attempted"]
    assert main(["grade", str(tmp_path / "nobody")]) == 2
    assert main(["--grade", str(tmp_path)]) == 2                   # one way to grade: a pointer to it
    assert "use python -m oneshot.exercises grade" in capsys.readouterr().err


# ----- the notebooks -----

def notebook_cells():
    """(notebook, cell) for every cell of the exercise notebooks."""
    return [(path.name, cell) for path in sorted(NOTEBOOKS.glob("*.ipynb"))
            for cell in json.loads(path.read_text())["cells"]]


def test_notebooks_follow_the_convention():
    names = sorted(p.name for p in NOTEBOOKS.glob("*.ipynb"))
    assert names == ["01_world_and_expert.ipynb", "02_network_and_maml.ipynb", "03_baselines.ipynb"]
    for name in names:
        nb = json.loads((NOTEBOOKS / name).read_text())
        assert nb["nbformat"] == 4 and nb["cells"][0]["cell_type"] == "markdown"
        assert "Section" in "".join(nb["cells"][0]["source"])
    cells = notebook_cells()
    assert len({c["id"] for _, c in cells}) == len(cells)
    tagged = {}
    for name, cell in cells:
        if cell["cell_type"] == "code":
            assert cell["outputs"] == [] and cell["execution_count"] is None, f"{name}: clear the outputs"
        for tag in cell["metadata"].get("tags", []):
            tagged.setdefault(int(tag.removeprefix("exercise-")), []).append("".join(cell["source"]))
    assert sorted(tagged) == sorted(EXERCISES) and all(len(v) == 1 for v in tagged.values())
    for number, [source] in tagged.items():
        assert source == EXERCISES[number].stub.rstrip("\n")    # the stub, no solution
    sources = ["".join(c["source"]) for _, c in cells]
    for number, e in EXERCISES.items():
        assert f"check({number}, {e.name})" in sources


@pytest.mark.parametrize("filled", [False, True], ids=["stubs", "solutions"])
def test_notebooks_run_as_stubs_and_with_the_solutions_filled_in(filled, capsys):
    for path in sorted(NOTEBOOKS.glob("*.ipynb")):
        namespace = {"__name__": "__main__"}
        for cell in json.loads(path.read_text())["cells"]:
            tags = [t for t in cell["metadata"].get("tags", []) if t.startswith("exercise-")]
            source = "".join(cell["source"])
            if tags and filled:
                number = int(tags[0].removeprefix("exercise-"))
                source = solution_source(number)
            if cell["cell_type"] == "code":
                exec(compile(source, f"<{path.name}>", "exec"), namespace)
    verdicts = [line for line in capsys.readouterr().out.splitlines() if line.startswith("exercise ")]
    assert len(verdicts) == 10
    assert all(line.endswith(": correct") if filled else "not written yet" in line for line in verdicts)
