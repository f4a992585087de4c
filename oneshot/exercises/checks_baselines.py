"""Checkers of exercises 8-10 (the experiments, paper Section IV): the contextual baseline's input,
the Wilson interval of a success rate, one LSTM step. Each compares with the package's own function."""
import itertools

import numpy as np

from oneshot.methods import contextual, lstm
from oneshot.training import scoring
from oneshot.exercises.checking import Case, Checker, Mistake
from oneshot.exercises.compare import Out

# ----------------------------------------------------------------------------------------------------
# 8. The contextual baseline's input: contextual.contextual_images
# ----------------------------------------------------------------------------------------------------


def _package_contextual_input(images, demo_images):
    return contextual.contextual_images(images, demo_images[..., -1, :, :, :])


def _context_cases():
    rng = np.random.default_rng(8)
    image = lambda *shape: rng.integers(0, 256, shape, dtype=np.uint8)
    floats = lambda *shape: rng.uniform(0, 1, shape).astype(np.float32)
    return [Case("5 frames of 6x6 uint8 images and a 7-frame demo", (image(5, 6, 6, 3), image(7, 6, 6, 3))),
            Case("a batch of 2 tasks: images (2, 4, 6, 6, 3), demos (2, 5, 6, 6, 3)",
                 (image(2, 4, 6, 6, 3), image(2, 5, 6, 6, 3)),
                 hint="with a leading task axis, take every task's final demo frame, demo_images[..., -1:, :, :, :]"),
            Case("one float32 frame of 5x7 (not square) and a 3-frame demo",
                 (floats(1, 5, 7, 3), floats(3, 5, 7, 3))),
            Case("two leading axes, 3 x 2 tasks: images (3, 2, 4, 6, 6, 3), demos (3, 2, 5, 6, 6, 3)",
                 (image(3, 2, 4, 6, 6, 3), image(3, 2, 5, 6, 6, 3)),
                 hint="any number of leading axes: demo_images[..., -1:, :, :, :] takes every task's final frame")]


def _wrong_context(frame=-1, axis=-1, context_first=False, own_frames=False, new_axis=False, transposed=False):
    def contextual_input(images, demo_images):
        source = images if own_frames else demo_images
        final = source[..., frame:frame + 1 or None, :, :, :]
        final = np.broadcast_to(np.swapaxes(final, -2, -3) if transposed else final, images.shape)
        if new_axis:
            return np.stack([images, final], axis=-1)
        return np.concatenate([final, images] if context_first else [images, final], axis=axis)
    return contextual_input


CONTEXT = Checker(
    expected=_package_contextual_input, cases=_context_cases, package=(contextual.contextual_images,),
    out=Out("array", "your input", ("frame", "row", "column", "channel"), keep_dtype=True),
    mistakes=(
        Mistake("you stacked the demo's FIRST image: the context is its FINAL image, demo_images[..., -1, :, :, :], "
                "where the arm has reached the target", _wrong_context(frame=0)),
        Mistake("you stacked on the frame axis: stack on the last axis (the channels), which makes 6 channels",
                _wrong_context(axis=-4)),
        Mistake("you stacked along the image's width: stack on the last axis (the channels), which makes 6 channels",
                _wrong_context(axis=-2)),
        Mistake("you stacked along the image's height: stack on the last axis (the channels), which makes "
                "6 channels", _wrong_context(axis=-3)),
        Mistake("np.stack added a new axis: concatenate along the channel axis, (..., T, H, W, 3 + 3)",
                _wrong_context(new_axis=True)),
        Mistake("you put the demo's image first: channels 0-2 are the current frame, 3-5 the demo's final image",
                _wrong_context(context_first=True)),
        Mistake("you stacked the last of `images` (the policy's own frames): the context is the demo's final "
                "image, from demo_images", _wrong_context(own_frames=True)),
        Mistake("your demo image's rows and columns are swapped: it keeps its (H, W) layout, as `images` does",
                _wrong_context(transposed=True)),
    ))

# ----------------------------------------------------------------------------------------------------
# 9. The Wilson interval: scoring.wilson_interval
# ----------------------------------------------------------------------------------------------------


def _wilson_cases():
    return [Case("439 successes of 480 trials", (439, 480)),
            Case("7 successes of 120 trials, z = 2.576 (99%)", (7, 120, 2.576)),
            Case("0 successes of 10 trials", (0, 10)),
            Case("10 successes of 10 trials", (10, 10)),
            Case("1 success of 1 trial", (1, 1)),
            Case("0 trials", (0, 0), hint="with no trials, the interval is (0.0, 1.0): nothing is known")]


def _wrong_wilson(wald=False, short_half=False, centre_p=False, fixed_z=None):
    def wilson_interval(successes, trials, z=1.96):
        if trials == 0:
            return 0.0, 1.0
        z, p, n = z if fixed_z is None else fixed_z, successes / trials, trials
        if wald:
            half = z * np.sqrt(p * (1 - p) / n)
            return max(0.0, p - half), min(1.0, p + half)
        centre = p if centre_p else (p + z * z / (2 * n)) / (1 + z * z / n)
        half = z * np.sqrt(p * (1 - p) / n + (0 if short_half else z * z / (4 * n * n))) / (1 + z * z / n)
        return max(0.0, centre - half), min(1.0, centre + half)
    return wilson_interval


WILSON = Checker(
    expected=scoring.wilson_interval, cases=_wilson_cases, package=(scoring.wilson_interval,),
    out=Out("tuple", parts=(Out("number", "your lower bound"), Out("number", "your upper bound"))),
    mistakes=(
        Mistake("yours is the Wald interval p +- z sqrt(p (1 - p) / n): Wilson's centre is pulled towards 1/2 "
                "and its half-width has the extra z^2 / (4 n^2)", _wrong_wilson(wald=True)),
        Mistake("your half-width lacks the term z^2 / (4 n^2) under the square root", _wrong_wilson(short_half=True)),
        Mistake("your centre is p: Wilson's is (p + z^2 / (2 n)) / (1 + z^2 / n)", _wrong_wilson(centre_p=True)),
        Mistake("you used z = 1.96 whatever z is given: use the argument z", _wrong_wilson(fixed_z=1.96)),
    ))

# ----------------------------------------------------------------------------------------------------
# 10. One LSTM step: lstm.lstm_step
# ----------------------------------------------------------------------------------------------------


def _lstm_cases():
    rng = np.random.default_rng(10)

    def step(B, U, scale):
        return (rng.normal(0, 0.5, (U, 4 * U)), rng.normal(0, scale, (B, 4 * U)), rng.normal(0, 0.5, (B, U)),
                rng.normal(0, 1.0, (B, U)))
    return [Case("a batch of 3, 4 units", step(3, 4, 1.0)),
            Case("a batch of 1, 1 unit", step(1, 1, 1.0)),
            Case("a batch of 2, 3 units, large gate inputs (saturated gates)", step(2, 3, 15.0))]


def _wrong_lstm(order="ifgo", gate=lambda x: 1 / (1 + np.exp(-x)), forget=True, squash_cell=True, swap=False,
                forget_bias=0.0):
    def lstm_step(w_h, xw, h, c):
        blocks = dict(zip(order, np.split(xw + h @ w_h, 4, axis=-1)))
        c_next = (gate(blocks["f"] + forget_bias) * c if forget else c) + gate(blocks["i"]) * np.tanh(blocks["g"])
        h_next = gate(blocks["o"]) * (np.tanh(c_next) if squash_cell else c_next)
        return (c_next, h_next) if swap else (h_next, c_next)
    return lstm_step


def _order_mistake(order):
    """Reading z's four blocks in `order` (e.g. "igfo", TensorFlow's i, j, f, o) instead of i, f, g, o."""
    swapped = [a for a, b in zip(order, "ifgo") if a != b]
    words = f"you swapped {swapped[1]} and {swapped[0]}" if len(swapped) == 2 else f"you read them as {', '.join(order)}"
    tensorflow = ": TensorFlow's order i, j, f, o, with j for g" if order == "igfo" else ""
    return Mistake(f"your gate blocks are in the wrong order: z splits into i, f, g, o, in that order ({words}"
                   f"{tensorflow})", _wrong_lstm(order=order))


_state = lambda what: Out("array", what, ("batch", "unit"))
LSTM = Checker(
    expected=lstm.lstm_step, cases=_lstm_cases, out=Out("tuple", parts=(_state("your h'"), _state("your c'"))),
    package=(lstm.lstm_step,),
    mistakes=(
        *(_order_mistake("".join(order)) for order in itertools.permutations("ifgo") if order != tuple("ifgo")),
        Mistake("your forget gate has a bias of +1 added (TensorFlow's forget_bias=1.0): here c' = s(f) * c + "
                "s(i) * tanh(g), with no added bias", _wrong_lstm(forget_bias=1.0)),
        Mistake("your gates use tanh: the gates i, f, o are sigmoids s(x) = 1 / (1 + exp(-x)); only g and the "
                "cell's output use tanh", _wrong_lstm(gate=np.tanh)),
        Mistake("your cell keeps all of c: the forget gate scales it, c' = s(f) * c + s(i) * tanh(g)",
                _wrong_lstm(forget=False)),
        Mistake("your h' lacks the tanh: h' = s(o) * tanh(c')", _wrong_lstm(squash_cell=False)),
        Mistake("you returned (c', h'): the order is (h', c')", _wrong_lstm(swap=True)),
    ))

CHECKERS = {8: CONTEXT, 9: WILSON, 10: LSTM}
