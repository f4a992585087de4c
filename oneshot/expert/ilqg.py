"""iLQG (iterative LQR with the robust schedule of Tassa, Erez & Todorov, IROS 2012), in NumPy.

The expert of paper Section IV: it plans on a model (`oneshot.world.arm`) and returns a time-varying
feedback controller u_t = u_bar_t + K_t (x_t - x_bar_t) that `oneshot.expert.controller` runs in Pymunk.

The problem: minimise  sum_t l(x_t, u_t) + l_f(x_T)  subject to  x_{t+1} = f(x_t, u_t).

Each iteration:
  1. linearise f and quadratise l along the current trajectory (x_bar, u_bar);
  2. backward pass: the Riccati recursion gives the open-loop step k_t and the gains K_t; the
     regulariser mu is added to V_xx (Tassa et al. eq. 10) and raised when Q_uu is not positive definite;
  3. forward pass: roll out u = u_bar + alpha k + K (x - x_bar) for alpha = 1, 0.5, ... (backtracking),
     accept the first alpha whose actual cost reduction is a fair fraction of the expected one;
  4. lower mu on success, raise it on failure (the quadratic schedule of Tassa et al., Sec. II-F);
     stop when the expected reduction of a full step, the step itself, or the actual reduction of a
     (nearly) full step is tiny.

`dynamics` and `cost` are small objects with these vectorised methods (N = T steps at once):
    dynamics.step(x (n,), u (m,)) -> (n,)                              one step of one trajectory
    dynamics.derivatives(x (T, n), u (T, m)) -> (A (T, n, n), B (T, n, m))
    cost.total(x (T+1, n), u (T, m)) -> float                          total cost of a trajectory
    cost.derivatives(x (T+1, n), u (T, m)) -> (lx (T+1, n), lu (T, m), lxx (T+1, n, n), luu (T, m, m), lux (T, m, n))
"""
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ILQGConfig:
    """iLQG's stopping rules, regularisation schedule and line search (Tassa et al. 2012, Sec. II-F)."""
    max_iterations: int = 100
    tol_cost: float = 1e-4       # stop when a full step is expected to lower the cost by less than this fraction
    tol_grad: float = 1e-4       # stop when the open-loop step is this small (relative to u)
    mu_init: float = 1e-3        # regularisation of V_xx (Tassa et al. eq. 10)
    mu_min: float = 1e-6         # the smallest non-zero mu: lowering it further sets it to 0
    mu_max: float = 1e10         # raising mu past this ends the solve, not converged
    mu_factor: float = 1.6       # delta_0 of Tassa et al.
    alphas: tuple = tuple(10.0 ** np.linspace(0, -3, 11))   # backtracking line search
    min_reduction_ratio: float = 0.0   # accept when actual / expected reduction > this


@dataclass
class ILQGResult:
    """x: (T+1, n) nominal states, u: (T, m) nominal controls, K: (T, m, n) feedback gains."""
    x: np.ndarray
    u: np.ndarray
    K: np.ndarray
    cost: float
    iterations: int
    converged: bool
    cost_history: list = field(default_factory=list)


def rollout(x0, u_bar, dynamics, x_bar=None, k=None, K=None, alpha=1.0):
    """One rollout. x0: (n,), u_bar: (T, m) -> x (T+1, n), u (T, m).

    Without gains, the open-loop rollout of u_bar; with x_bar (T+1, n), k (T, m), K (T, m, n), the
    closed loop u_t = u_bar_t + alpha k_t + K_t (x_t - x_bar_t) of the forward pass.
    """
    T, m = u_bar.shape
    x, u = np.empty((T + 1, len(x0))), np.empty((T, m))
    x[0] = x0
    for t in range(T):
        u[t] = u_bar[t] if k is None else u_bar[t] + alpha * k[t] + K[t] @ (x[t] - x_bar[t])
        x[t + 1] = dynamics.step(x[t], u[t])
    return x, u


def _inverse_pd(M):
    """Inverse of a symmetric matrix, or None if it is not positive definite.

    2x2 (the arm's case) in closed form: np.linalg on a 2x2 costs ~10 us a call, which made the
    backward pass 3x slower than the rest of an iteration.
    """
    if M.shape == (2, 2):
        det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
        if M[0, 0] <= 0 or det <= 0:
            return None
        return np.array([[M[1, 1], -M[0, 1]], [-M[1, 0], M[0, 0]]]) / det
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        return None
    return np.linalg.inv(M)


def backward_pass(A, B, lx, lu, lxx, luu, lux, mu):
    """Riccati recursion of iLQR with V_xx regularised by mu (Tassa et al. eqs. 10-11).

    Returns (k (T, m), K (T, m, n), dV (2,)) with the expected reduction alpha dV[0] + alpha^2 dV[1],
    or None when some Q_uu is not positive definite (then mu must grow).
    """
    T, n, m = B.shape
    k, K = np.empty((T, m)), np.empty((T, m, n))
    Vx, Vxx = lx[T], lxx[T]
    dV1 = dV2 = 0.0
    # The regularisation terms mu B^T B and mu B^T A, for all t at once (fewer calls in the loop).
    BtB, BtA = mu * np.einsum("tki,tkj->tij", B, B), mu * np.einsum("tki,tkj->tij", B, A)
    for t in range(T - 1, -1, -1):
        At, Bt = A[t], B[t]
        AtT, BtT = At.T, Bt.T
        Qx = lx[t] + AtT @ Vx
        Qu = lu[t] + BtT @ Vx
        VA = Vxx @ At
        Qxx = lxx[t] + AtT @ VA
        Quu = luu[t] + BtT @ (Vxx @ Bt)
        Qux = lux[t] + BtT @ VA
        # Regularised Q_uu, Q_ux give the gains (eq. 10); the value update below uses the plain ones
        # (eq. 11), or a large mu would drive V_xx indefinite.
        Quu_inv = _inverse_pd(Quu + BtB[t])
        if Quu_inv is None:
            return None
        kt, Kt = -Quu_inv @ Qu, -Quu_inv @ (Qux + BtA[t])
        k[t], K[t] = kt, Kt
        KtQuu = Kt.T @ Quu
        Quuk = Quu @ kt
        dV1 += kt @ Qu
        dV2 += 0.5 * kt @ Quuk
        Vx = Qx + Kt.T @ (Quuk + Qu) + Qux.T @ kt
        M = Kt.T @ Qux
        Vxx = Qxx + KtQuu @ Kt + M + M.T
    dV = np.array([dV1, dV2])
    return k, K, dV


def solve(x0, u_init, dynamics, cost, cfg=ILQGConfig()):
    """Run iLQG from the control sequence u_init (T, m) at state x0 (n,). Returns an ILQGResult."""
    x0, u = np.asarray(x0, float), np.array(u_init, float)
    x, _ = rollout(x0, u, dynamics)
    J = float(cost.total(x, u))
    if not np.isfinite(J):
        raise ValueError("the initial rollout has a non-finite cost; start from smaller controls")
    mu, dmu = cfg.mu_init, 1.0
    history, converged, K = [J], False, None
    for it in range(1, cfg.max_iterations + 1):
        # 1. Linearise and quadratise along the trajectory.
        A, B = dynamics.derivatives(x[:-1], u)
        lx, lu, lxx, luu, lux = cost.derivatives(x, u)
        # 2. Backward pass, raising mu until Q_uu is positive definite.
        while True:
            back = backward_pass(A, B, lx, lu, lxx, luu, lux, mu)
            if back is not None:
                break
            dmu = max(cfg.mu_factor, dmu * cfg.mu_factor)
            mu = max(cfg.mu_min, mu * dmu)
            if mu > cfg.mu_max:
                return ILQGResult(x, u, K if K is not None else np.zeros(u.shape + x0.shape), J, it, False, history)
        k, K, dV = back
        # Converged when the full step is tiny, or promises to lower the cost by a tiny fraction.
        if (np.mean(np.max(np.abs(k) / (np.abs(u) + 1), axis=1)) < cfg.tol_grad
                or -(dV[0] + dV[1]) < cfg.tol_cost * J):
            converged = True
            break
        # 3. Forward pass: backtracking line search, take the first acceptable step.
        for alpha in cfg.alphas:
            x_new, u_new = rollout(x0, u, dynamics, x, k, K, alpha)
            J_new = float(cost.total(x_new, u_new))
            expected = -(alpha * dV[0] + alpha ** 2 * dV[1])
            if np.isfinite(J_new) and expected > 0 and J - J_new > cfg.min_reduction_ratio * expected:
                break
        else:
            alpha = None
        if alpha is not None:
            small_step = alpha >= 0.5 and J - J_new < cfg.tol_cost * J_new
            x, u, J = x_new, u_new, J_new
            history.append(J)
            # 4a. Success: lower mu.
            dmu = min(1 / cfg.mu_factor, dmu / cfg.mu_factor)
            mu = mu * dmu if mu * dmu > cfg.mu_min else 0.0
            if small_step:          # a (nearly) full step that barely helped: at the optimum
                converged = True
                break
        else:
            # 4b. Failure: raise mu.
            dmu = max(cfg.mu_factor, dmu * cfg.mu_factor)
            mu = max(cfg.mu_min, mu * dmu)
            if mu > cfg.mu_max:
                break
    return ILQGResult(x, u, K, J, it, converged, history)
