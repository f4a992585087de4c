"""Checkers of exercises 4 and 5: the im2col convolution of the policy's layers (Section IV) and the
imitation loss, eq. (2) (Section III). Each compares with the package's own function."""
import autograd.numpy as anp
import numpy as np
from autograd import grad

from oneshot.maml import imitation
from oneshot.policy import layers, reference
from oneshot.exercises.checking import Case, Checker, Mistake
from oneshot.exercises.compare import Out
from oneshot.policy.network import NetworkConfig, forward, init_params

# ----------------------------------------------------------------------------------------------------
# 4. im2col convolution: layers.conv2d (= reference.conv2d_reference, tested)
# ----------------------------------------------------------------------------------------------------


def _conv_cases():
    rng = np.random.default_rng(4)
    cases = []
    for label, (n, h, w, c_in), k, c_out, stride in [
        ("2 images 8x8x3, 3x3 filters, 4 outputs, stride 2 (the policy's layers, smaller)", (2, 8, 8, 3), 3, 4, 2),
        ("one 7x9x2 image (odd sides, not square), 3x3 filters, stride 2", (1, 7, 9, 2), 3, 3, 2),
        ("one 5x6x2 image, 3x3 filters, stride 1", (1, 5, 6, 2), 3, 2, 1),
        ("2 images 4x4x3, 1x1 filters, stride 1", (2, 4, 4, 3), 1, 2, 1),
        ("one 9x9x1 image, 5x5 filters, stride 2", (1, 9, 9, 1), 5, 2, 2),
        ("one 10x10x2 image, 3x3 filters, stride 3", (1, 10, 10, 2), 3, 2, 3),
        ("3 images 32x32x3, 3x3 filters, 40 outputs, stride 2 (the policy's first layer)", (3, 32, 32, 3), 3, 40, 2),
    ]:
        args = (rng.normal(size=(n, h, w, c_in)), rng.normal(size=(k, k, c_in, c_out)), rng.normal(size=c_out), stride)
        p = k // 2
        facts = {"k": k, "p": p, "s": stride, "H": h, "W": w,
                 "Ho": (h + 2 * p - k) // stride + 1, "Wo": (w + 2 * p - k) // stride + 1}
        cases.append(Case(label, args, facts))
    return cases


def _wrong_conv(pad=lambda p: (p, p), use_stride=True, order=(0, 1, 2), flip=False, bias=True, swap_hw=False):
    def conv2d(x, w, b, stride):
        stride = stride if use_stride else 1
        n, h, width, c_in = x.shape
        k, c_out = w.shape[0], w.shape[-1]
        before, after = pad(k // 2)
        x = np.pad(x, ((0, 0), (before, after), (before, after), (0, 0)))
        h_out, w_out = (x.shape[1] - k) // stride + 1, (x.shape[2] - k) // stride + 1
        w = w[::-1, ::-1] if flip else w
        patches = np.stack([x[:, stride * i: stride * i + k, stride * j: stride * j + k, :]
                            for i in range(h_out) for j in range(w_out)], axis=1)   # (N, P, k, k, C_in)
        cols = patches.transpose((0, 1) + tuple(2 + a for a in order)).reshape(n * h_out * w_out, -1)
        y = cols @ w.reshape(-1, c_out) + (b if bias else 0)
        return y.reshape((n, w_out, h_out, c_out) if swap_hw else (n, h_out, w_out, c_out))
    return conv2d


CONV = Checker(
    expected=layers.conv2d, cases=_conv_cases, package=(layers.conv2d, reference.conv2d_reference),
    out=Out("array", "your output", ("image", "row", "column", "channel")),
    mistakes=(
        Mistake("you did not pad: 'same' convolution pads k // 2 = {p} zeros on every side, so {H}x{W} images "
                "give {Ho}x{Wo} outputs at stride {s}", _wrong_conv(pad=lambda p: (0, 0))),
        Mistake("you padded only at the bottom and the right: pad k // 2 = {p} zeros on EVERY side",
                _wrong_conv(pad=lambda p: (0, 2 * p))),
        Mistake("you ignored the stride: patches start every stride = {s} pixels, so {H}x{W} images give "
                "{Ho}x{Wo} outputs", _wrong_conv(use_stride=False)),
        Mistake("your patches are flattened in (channel, dy, dx) order; w.reshape(k * k * C_in, C_out) is in "
                "(dy, dx, channel) order: flatten the (k, k, C_in) patch as it is", _wrong_conv(order=(2, 0, 1))),
        Mistake("your patches are flattened in (dx, dy, channel) order: the patch's rows (dy) come first, as "
                "in w's first axis", _wrong_conv(order=(1, 0, 2))),
        Mistake("you flipped the filter (a true convolution): MIL's layers, like TensorFlow's, are "
                "cross-correlations, y[i, j] = sum w[dy, dx] x[i + dy, j + dx]", _wrong_conv(flip=True)),
        Mistake("you left out the bias b", _wrong_conv(bias=False)),
        Mistake("your output's rows and columns are swapped: it is (N, H_out, W_out, C_out), row i before "
                "column j", _wrong_conv(swap_hw=True)),
    ))

# ----------------------------------------------------------------------------------------------------
# 5. The imitation loss, eq. (2): imitation.imitation_loss
# ----------------------------------------------------------------------------------------------------

_POLICY = NetworkConfig(image_size=8, channels=(4,), hidden=(8,))     # the policy, small: fast to check


def _demo(rng, params, T, perfect=False):
    images, states = rng.uniform(0, 1, (T, 8, 8, 3)), rng.normal(size=(T, 6))
    actions = forward(params, images, states) if perfect else rng.normal(size=(T, 2))
    return images, states, actions


def _gradient(fn, params, demo):
    return grad(fn)(params, demo)


def _loss_cases():
    rng = np.random.default_rng(5)
    params = init_params(_POLICY, rng, np.float64)
    params = {k: v + rng.normal(0, 0.3, v.shape) if k.endswith("_b") else v for k, v in params.items()}
    return [Case("a 5-frame demo", (params, _demo(rng, params, 5)), {"T": 5}),
            Case("a 12-frame demo", (params, _demo(rng, params, 12)), {"T": 12}),
            Case("a 1-frame demo", (params, _demo(rng, params, 1)), {"T": 1}),
            Case("a 4-frame demo whose actions are the policy's own", (params, _demo(rng, params, 4, True)), {"T": 4}),
            Case("autograd's gradient of your loss on a 6-frame demo", (params, _demo(rng, params, 6)), {"T": 6},
                 call=_gradient, out=Out("dict", "grad(your loss)"),
                 hint="autograd cannot differentiate your loss: write it with autograd.numpy "
                      "(import autograd.numpy as np), without np.array(...) or float(...) on its values",
                 hint_only_on_error=True)]


def _wrong_loss(combine):
    def imitation_loss(params, demo):
        images, states, actions = demo
        return combine(forward(params, images, states) - actions)
    return imitation_loss


LOSS = Checker(
    expected=imitation.imitation_loss, cases=_loss_cases, out=Out("number", "your loss"),
    package=(imitation.imitation_loss,),
    mistakes=(
        Mistake("your loss is 1/T of the expected value: eq. (2) sums over frames, it does not average "
                "(T = {T})", _wrong_loss(lambda r: anp.sum(r ** 2) / len(r))),
        Mistake("your loss is 1/(2T) of the expected value: you averaged over frames and torques; eq. (2) sums "
                "over frames, and the squared norm sums over the 2 torques", _wrong_loss(lambda r: anp.mean(r ** 2))),
        Mistake("your loss is half the expected value: eq. (2) has no 1/2, and its squared norm sums over the "
                "2 torques (a mean over them halves it)",
                _wrong_loss(lambda r: 0.5 * anp.sum(r ** 2))),
        Mistake("you sum |pi(o_t) - u_t| without squaring: eq. (2) sums SQUARED errors",
                _wrong_loss(lambda r: anp.sum(anp.abs(r)))),
        Mistake("you sum the residuals pi(o_t) - u_t without squaring them: eq. (2) sums SQUARED errors",
                _wrong_loss(anp.sum)),
        Mistake("you sum the norms || pi(o_t) - u_t || without squaring them: eq. (2) squares each frame's norm",
                _wrong_loss(lambda r: anp.sum(anp.sqrt(anp.sum(r ** 2, axis=-1))))),
        Mistake("your loss is the square root of the expected one: np.linalg.norm(...) is not squared; eq. (2) "
                "is a sum of squares", _wrong_loss(lambda r: anp.sqrt(anp.sum(r ** 2)))),
        Mistake("you sum over the first torque only: the squared norm || . ||^2 runs over both torques "
                "(shoulder and elbow)", _wrong_loss(lambda r: anp.sum(r[:, 0] ** 2))),
        Mistake("you sum over the second torque only: the squared norm || . ||^2 runs over both torques "
                "(shoulder and elbow)", _wrong_loss(lambda r: anp.sum(r[:, 1] ** 2))),
        Mistake("you sum over the first frame only: eq. (2) sums over all T = {T} frames",
                _wrong_loss(lambda r: anp.sum(r[0] ** 2))),
    ))

CHECKERS = {4: CONV, 5: LOSS}
