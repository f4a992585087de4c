"""Reference solutions of the exercises, for teachers: each written as a student would, from the
docstring alone (not by calling the package's function it is checked against). `reference(n)` in
`oneshot.exercises` returns them; the tests run every checker on them."""
import autograd.numpy as anp
import numpy as np
from autograd import grad

from oneshot.policy.network import forward


def is_success(end_effector, target, success_radius=0.05):                                   # 1
    end_effector = np.asarray(end_effector, float)
    final = end_effector[-max(1, len(end_effector) // 5):]                 # the final fifth: (T // 5, 2)
    distance = np.sqrt(np.sum((final - np.asarray(target)) ** 2, axis=-1))  # metres, one per step
    return bool(distance.min() <= success_radius)


def kinematics(q, l1, l2):                                                                   # 2
    q = np.asarray(q, float)
    a1, a12 = q[..., 0], q[..., 0] + q[..., 1]                 # link 1's angle, link 2's angle (from +x)
    p = np.stack([l1 * np.cos(a1) + l2 * np.cos(a12), l1 * np.sin(a1) + l2 * np.sin(a12)], axis=-1)
    dx = np.stack([-l1 * np.sin(a1) - l2 * np.sin(a12), -l2 * np.sin(a12)], axis=-1)   # dx/dq1, dx/dq2
    dy = np.stack([l1 * np.cos(a1) + l2 * np.cos(a12), l2 * np.cos(a12)], axis=-1)     # dy/dq1, dy/dq2
    return p, np.stack([dx, dy], axis=-2)                                                 # (..., 2), (..., 2, 2)


def backward_step(Vx, Vxx, A, B, lx, lu, lxx, luu, lux, mu):                                # 3
    Qx, Qu = lx + A.T @ Vx, lu + B.T @ Vx
    Qxx, Quu, Qux = lxx + A.T @ Vxx @ A, luu + B.T @ Vxx @ B, lux + B.T @ Vxx @ A
    V_reg = Vxx + mu * np.eye(len(Vx))                          # regularised V_xx, for the gains only
    Quu_reg, Qux_reg = luu + B.T @ V_reg @ B, lux + B.T @ V_reg @ A
    k = -np.linalg.solve(Quu_reg, Qu)
    K = -np.linalg.solve(Quu_reg, Qux_reg)
    Vx_t = Qx + K.T @ Quu @ k + K.T @ Qu + Qux.T @ k             # the plain Q-terms (eq. 11)
    Vxx_t = Qxx + K.T @ Quu @ K + K.T @ Qux + Qux.T @ K
    return k, K, Vx_t, Vxx_t


def conv2d(x, w, b, stride):                                                                 # 4
    n, h, width, c_in = x.shape
    k, c_out = w.shape[0], w.shape[-1]
    p = k // 2
    h_out, w_out = (h + 2 * p - k) // stride + 1, (width + 2 * p - k) // stride + 1
    x_pad = np.pad(x, ((0, 0), (p, p), (p, p), (0, 0)))                   # (N, H + 2p, W + 2p, C_in)
    rows = [x_pad[:, stride * i: stride * i + k, stride * j: stride * j + k, :].reshape(n, k * k * c_in)
            for i in range(h_out) for j in range(w_out)]                    # each (N, k * k * C_in)
    cols = np.stack(rows, axis=1).reshape(n * h_out * w_out, k * k * c_in)  # im2col: one row per pixel
    y = cols @ w.reshape(k * k * c_in, c_out) + b                          # (N * H_out * W_out, C_out)
    return y.reshape(n, h_out, w_out, c_out)


def imitation_loss(params, demo):                                                            # 5
    images, states, actions = demo
    residual = forward(params, images, states) - actions                 # (T, 2)
    return anp.sum(residual ** 2)                                          # sum over frames and torques


def inner_update(params, demo, loss_fn, alpha, only=None):                                   # 6
    g = grad(loss_fn)(params, demo)                                        # dict: dL/dtheta for every key
    adapts = lambda key: only is None or key.startswith(tuple(only))
    return {key: value - alpha * g[key] if adapts(key) else value for key, value in params.items()}


def meta_gradients(w, alpha, adapt_demo, eval_demo):                                         # 7
    (xa, ya), (xe, ye) = adapt_demo, eval_demo
    w_adapted = w - alpha * 2 * np.sum(xa * (w * xa - ya))                # eq. (1): w' = w - alpha L'(w; adapt)
    first_order = 2 * np.sum(xe * (w_adapted * xe - ye))                  # L'(w'; eval), dw'/dw taken as 1
    second_order = first_order * (1 - alpha * 2 * np.sum(xa * xa))        # dw'/dw = 1 - alpha L''(w; adapt)
    return float(second_order), float(first_order)


def contextual_input(images, demo_images):                                                   # 8
    final = demo_images[..., -1:, :, :, :]                                 # (..., 1, H, W, 3)
    return np.concatenate([images, np.broadcast_to(final, images.shape)], axis=-1)   # (..., T, H, W, 6)


def wilson_interval(successes, trials, z=1.96):                                              # 9
    if trials == 0:
        return 0.0, 1.0
    p, n = successes / trials, trials
    centre = (p + z ** 2 / (2 * n)) / (1 + z ** 2 / n)
    half = z * np.sqrt(p * (1 - p) / n + z ** 2 / (4 * n ** 2)) / (1 + z ** 2 / n)
    return max(0.0, centre - half), min(1.0, centre + half)


def lstm_step(w_h, xw, h, c):                                                                # 10
    sigmoid = lambda x: 1 / (1 + np.exp(-x))
    i, f, g, o = np.split(xw + h @ w_h, 4, axis=-1)                        # four (B, U) blocks
    c_next = sigmoid(f) * c + sigmoid(i) * np.tanh(g)
    return sigmoid(o) * np.tanh(c_next), c_next


SOLUTIONS = {1: is_success, 2: kinematics, 3: backward_step, 4: conv2d, 5: imitation_loss, 6: inner_update,
             7: meta_gradients, 8: contextual_input, 9: wilson_interval, 10: lstm_step}
