"""The exercises as a student sees them: for each, the function to write, its signature and its
docstring (the stub in the notebooks is `Exercise.stub`), in the paper's order, and the notebook of
`notebooks/exercises/` that holds it."""
from dataclasses import replace

from oneshot.exercises.checking import Exercise

_EXERCISES = [
    Exercise(1, "is_success", "Sec. IV, the success criterion", "IV",
             "end_effector, target, success_radius=0.05", """
Did the arm reach the target? Paper Section IV: a trial succeeds when the end effector comes
within `success_radius` of the target (the straight-line distance) at some step of the final fifth
of the episode.

end_effector: (T, 2) end-effector positions after each of the T steps, metres.
target: (2,) the target's centre, metres. success_radius: metres (0.05 in the paper).
The final fifth of T steps is the last max(1, T // 5) of them (10 of 50; 1 of 3).
Returns True or False.
"""),
    Exercise(2, "kinematics", "Sec. IV, forward kinematics and its Jacobian", "IV", "q, l1, l2", """
Forward kinematics of the 2-link arm, and its Jacobian (`oneshot.world.arm`).

q: (..., 2) joint angles, radians: q1 = q[..., 0] the shoulder angle from the +x axis, q2 =
q[..., 1] the elbow angle relative to link 1. l1, l2: the link lengths, metres.
Returns (p, J): p (..., 2) the end effector's (x, y) in metres, the base at the origin;
J (..., 2, 2) = dp/dq, rows (x, y), columns (q1, q2): J[..., i, j] = d p_i / d q_j.
"""),
    Exercise(3, "backward_step", "Sec. IV, one iLQG backward-pass step", "IV",
             "Vx, Vxx, A, B, lx, lu, lxx, luu, lux, mu", """
One step of iLQG's backward pass: the Q-terms, the gains, and the value function one step back
(Tassa, Erez & Todorov 2012, eqs. 10-11; `oneshot.expert.ilqg.backward_pass` does every step).

Vx (n,), Vxx (n, n): the value function's gradient and Hessian at time t + 1.
A (n, n), B (n, m): the dynamics linearised at time t, dx_{t+1} = A dx_t + B du_t.
lx (n,), lu (m,), lxx (n, n), luu (m, m), lux (m, n): the cost's derivatives at time t.
mu >= 0: the regulariser. It is added to Vxx (Vxx + mu I) where Q_uu and Q_ux are formed
for the gains k, K. The value update (Tassa et al. eq. 11) uses those gains with the plain,
unregularised Q-terms: V_x = Q_x + K^T Q_uu k + K^T Q_u + Q_ux^T k, and
V_xx = Q_xx + K^T Q_uu K + K^T Q_ux + Q_ux^T K.
Returns (k (m,), K (m, n), Vx (n,), Vxx (n, n)): the open-loop step, the feedback gains,
and the value function's gradient and Hessian at time t.
"""),
    Exercise(4, "conv2d", "Sec. IV, im2col convolution", "IV", "x, w, b, stride", """
'Same'-padded strided 2-D convolution (cross-correlation, as in TensorFlow and MIL), by im2col.

x: (N, H, W, C_in) images; w: (k, k, C_in, C_out) filters, k odd; b: (C_out,); stride: int.
Pad x with k // 2 zeros on every side; every output pixel (i, j) is the k x k patch whose
top-left corner is at (stride * i, stride * j) of the padded image, flattened in (dy, dx, c)
order into one row of a matrix (im2col), times w reshaped to (k * k * C_in, C_out), plus b.
Returns (N, H_out, W_out, C_out), H_out = (H + 2 * (k // 2) - k) // stride + 1, W_out likewise.
"""),
    Exercise(5, "imitation_loss", "eq. 2, the imitation loss", "III", "params, demo", """
Paper eq. (2), the behavioural-cloning loss of one demonstration:

    L(theta, d) = sum_t || pi_theta(o_t) - u_t ||^2

params: the policy's parameters, a dict of arrays. demo: (images (T, H, W, 3) float in
[0, 1], states (T, 6), actions (T, 2)), in network units. The policy's actions for all T
frames at once: oneshot.policy.network.forward(params, images, states), (T, 2).
Returns a scalar. Write it with autograd.numpy: MAML differentiates it.
"""),
    Exercise(6, "inner_update", "eq. 1, the inner update", "II", "params, demo, loss_fn, alpha, only=None", """
Paper eq. (1), one step: adapt the parameters to one demonstration by gradient descent,

    theta' = theta - alpha * grad_theta L(theta, demo)

params: dict name -> array (do not modify it). demo: whatever loss_fn takes.
loss_fn(params, demo) -> scalar. alpha: the step size, a float.
only: None (every parameter adapts) or a tuple of key PREFIXES, e.g. ("conv0",): only the
parameters whose names start with one of them adapt; the others keep their values.
Returns a new dict with every key of params. Use autograd.grad, and keep the update
differentiable: MAML's meta-gradient differentiates through it.
"""),
    Exercise(7, "meta_gradients", "Sec. II, the second- and first-order meta-gradient", "II",
             "w, alpha, adapt_demo, eval_demo", """
MAML's meta-gradient on a toy problem, exactly: second order, and first order.

The model is a line through the origin, y = w x, with one parameter w (a float); the loss of
a demo d = (x (T,), y (T,)) is eq. (2)'s summed squared error, L(w, d) = sum_t (w x_t - y_t)^2.
MAML adapts on adapt_demo with one step of eq. (1), w' = w - alpha dL(w, adapt_demo)/dw,
and scores w' on eval_demo: the meta-objective is L(w', eval_demo).
Returns (second_order, first_order), two floats: the derivative of the meta-objective with
respect to w, exactly (through the inner step), and first-order MAML's approximation of it
(the inner step's Jacobian dw'/dw taken as 1). Work them out by hand: no autograd needed.
"""),
    Exercise(8, "contextual_input", "Sec. IV, the contextual baseline's input", "IV", "images, demo_images", """
The contextual baseline's input (paper Section IV): the demonstration's FINAL image, stacked
on every frame the policy sees as 3 more channels.

images: (..., T, H, W, 3) the frames the policy acts on. demo_images: (..., T_demo, H, W, 3)
the demonstration's frames, with the same leading axes (e.g. one per task). Keep the dtype.
Returns (..., T, H, W, 6): channels 0-2 the frame, channels 3-5 the demo's final image.
"""),
    Exercise(9, "wilson_interval", "Sec. IV, the Wilson interval", "IV", "successes, trials, z=1.96", """
The Wilson score interval of a success rate: how `python -m oneshot.evaluate` reports its
95% intervals. successes, trials: ints, 0 <= successes <= trials; z: the normal quantile.
With p = successes / trials and n = trials:

    centre = (p + z^2 / (2 n)) / (1 + z^2 / n)
    half   = z * sqrt(p (1 - p) / n + z^2 / (4 n^2)) / (1 + z^2 / n)

Returns (lo, hi) = (centre - half, centre + half) clipped to [0, 1]; (0.0, 1.0) when trials == 0.
"""),
    Exercise(10, "lstm_step", "Sec. IV, one step of the LSTM baseline", "IV", "w_h, xw, h, c", """
One step of the LSTM baseline's recurrent cell (with a forget gate).

w_h: (U, 4U) the recurrent weights. xw: (B, 4U) the input's share of the gates, x W_x + b.
h, c: (B, U) the hidden and cell states.

    z = xw + h w_h, cut along its last axis into four blocks of U: i, f, g, o (in that order)
    c' = s(f) * c + s(i) * tanh(g),    h' = s(o) * tanh(c'),    s(x) = 1 / (1 + exp(-x))

Returns (h', c'), each (B, U).
"""),
]

NOTEBOOKS = {"01_world_and_expert.ipynb": (1, 2, 3), "02_network_and_maml.ipynb": (4, 5, 6, 7),
             "03_baselines.ipynb": (8, 9, 10)}       # in notebooks/exercises/, each cell tagged exercise-N
EXERCISES = {e.number: replace(e, notebook=next(nb for nb, ns in NOTEBOOKS.items() if e.number in ns))
             for e in _EXERCISES}
