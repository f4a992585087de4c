"""Checkers of exercises 1-3 (the world and the expert, paper Section IV): the success criterion,
the arm's kinematics, one iLQG backward-pass step. Each compares with the package's own function."""
import numpy as np

from oneshot.expert import ilqg
from oneshot.world import arm, reach
from oneshot.exercises.checking import Case, Checker, Mistake
from oneshot.exercises.compare import Out

# ----------------------------------------------------------------------------------------------------
# 1. The success criterion: reach.is_success
# ----------------------------------------------------------------------------------------------------


def _episode(T, near, distance, rng, target=(0.1, 0.05), far=0.3):
    """(T, 2) end-effector positions: `distance` m from the target at the steps in `near`, `far` m elsewhere."""
    angles = rng.uniform(0, 2 * np.pi, T)
    radius = np.full(T, far)
    radius[list(near)] = distance
    return np.asarray(target) + radius[:, None] * np.stack([np.cos(angles), np.sin(angles)], -1), np.asarray(target)


def _success_cases():
    rng = np.random.default_rng(1)
    cases = []
    for label, T, near, d, radius in [
        ("a 50-step episode that passes 0.02 m from the target at step 5, then stays 0.3 m away", 50, [5], 0.02, 0.05),
        ("a 50-step episode 0.03 m from the target at step 42 only (in the final fifth, not the last step)",
         50, [42], 0.03, 0.05),
        ("a 50-step episode exactly 0.0625 m from the target at step 47, radius 0.0625", 50, [47], 0.0625, 0.0625),
        ("a 50-step episode 0.01 m from the target at its last step only", 50, [49], 0.01, 0.05),
        ("a 50-step episode 0.08 m from the target at step 45, radius 0.1", 50, [45], 0.08, 0.1),
        ("a 50-step episode whose closest approach is 0.15 m, at step 48", 50, [48], 0.15, 0.05),
        ("a 23-step episode near the target at step 18 only (the final fifth is steps 19-22)", 23, [18], 0.01, 0.05),
        ("a 3-step episode near the target at step 0 only (the final fifth is the last step)", 3, [0], 0.01, 0.05),
        ("a 1-step episode near the target", 1, [0], 0.01, 0.05),
        ("a 20-step episode near the target for the whole final fifth", 20, range(16, 20), 0.04, 0.05),
    ]:
        positions, target = _episode(T, near, d, rng)
        if d == radius:     # on the circle exactly, in binary fractions: every way of computing the distance agrees
            target, positions[near[0]] = np.array([0.25, 0.125]), [0.25 + d, 0.125]
        hint = f"for T = {T} steps, T // 5 is 0: the final fifth is the last max(1, T // 5) steps" if T < 5 else ""
        cases.append(Case(label, (positions, target, radius), {"T": T, "w": max(1, T // 5), "r": radius}, hint=hint))
    positions, target = _episode(20, range(16, 19), 0.01, rng, far=0.08)      # the mean 0.0275, the largest 0.08
    cases.append(Case("a 20-step episode 0.01 m from the target at steps 16-18, 0.08 m at every other step",
                      (positions, target, 0.05), {"T": 20, "w": 4, "r": 0.05}))
    for d, words in ((0.06, "a near miss"), (0.045, "a success")):   # diagonal: only the straight line agrees
        positions, target = _episode(20, [], d, rng)
        positions[18] = target + d * np.sqrt(0.5)
        cases.append(Case(f"a 20-step episode {d} m from the target at step 18, diagonally (45 degrees): "
                          f"{words} for radius 0.05", (positions, target, 0.05), {"T": 20, "w": 4, "r": 0.05}))
    return cases


def _judge(window, squared=False, mean=False, strict=False, fixed=None, every=False, distance=None):
    def is_success(end_effector, target, success_radius=0.05):
        e = np.asarray(end_effector)
        d = np.sum((window(e) - target) ** 2, -1) if squared else np.linalg.norm(window(e) - target, axis=-1)
        d = d if distance is None else distance(np.abs(window(e) - target))
        d = d.mean() if mean else d.max() if every else d.min()
        r = success_radius if fixed is None else fixed
        return bool(d < r if strict else d <= r)
    return is_success


_fifth = lambda e: e[-max(1, len(e) // 5):]
SUCCESS = Checker(
    expected=reach.is_success, cases=_success_cases, out=Out("bool", "your answer"), package=(reach.is_success,),
    mistakes=(
        Mistake("you judge the whole episode: success is judged on its final fifth only (the last {w} of "
                "{T} steps), so passing the target early and leaving does not count", _judge(lambda e: e)),
        Mistake("you judge the last step only: the arm succeeds if it is within the radius at ANY step of "
                "the final fifth (the last {w} of {T} steps)", _judge(lambda e: e[-1:])),
        Mistake("you judge the first fifth: success is judged on the FINAL fifth (the last {w} of {T} steps)",
                _judge(lambda e: e[:max(1, len(e) // 5)])),
        Mistake("you compare with a strict <: a distance exactly equal to the radius counts as success "
                "(min distance <= radius)", _judge(_fifth, strict=True)),
        Mistake("you ignore success_radius (here {r} m): compare with the radius you are given, not 0.05",
                _judge(_fifth, fixed=0.05)),
        Mistake("for T = {T} steps, T // 5 is 0 and end_effector[-0:] is the WHOLE episode: the final fifth "
                "is the last max(1, T // 5) steps", _judge(lambda e: e[-(len(e) // 5):])),
        Mistake("your final fifth is too long: of {T} steps it is the last T // 5 = {w} (rounded down)",
                _judge(lambda e: e[-int(np.ceil(len(e) / 5)):])),
        Mistake("you compare the SQUARED distance with the radius: compare the distance in metres (or its "
                "square with radius ** 2)", _judge(_fifth, squared=True)),
        Mistake("you average the distance over the final fifth: one step within the radius is enough "
                "(the minimum distance)", _judge(_fifth, mean=True)),
        Mistake("you require EVERY step of the final fifth to be within the radius: one step within it is "
                "enough (the minimum distance)", _judge(_fifth, every=True)),
        Mistake("you measure the largest coordinate difference (a square around the target): the distance is "
                "the straight line, np.linalg.norm of the difference", _judge(_fifth, distance=lambda a: a.max(-1))),
        Mistake("you add the coordinate differences: the distance is the straight line, np.linalg.norm of "
                "the difference", _judge(_fifth, distance=lambda a: a.sum(-1))),
        Mistake("you measure one coordinate only: the distance is the straight line in the plane, "
                "np.linalg.norm of the (x, y) difference", _judge(_fifth, distance=lambda a: a[..., 0])),
    ))

# ----------------------------------------------------------------------------------------------------
# 2. Forward kinematics and its Jacobian: arm.forward_kinematics, arm.end_effector_jacobian
# ----------------------------------------------------------------------------------------------------


def _package_kinematics(q, l1, l2):
    cfg = arm.ArmConfig(l1=l1, l2=l2)
    return arm.forward_kinematics(np.asarray(q, float), cfg), arm.end_effector_jacobian(np.asarray(q, float), cfg)


def _kinematics_cases():
    rng = np.random.default_rng(2)
    return [Case("one pose q = (0.3, 1.1), l1 = 0.1, l2 = 0.11", (np.array([0.3, 1.1]), 0.1, 0.11)),
            Case("one pose q = (1.2, -0.4), l1 = 0.3, l2 = 0.7", (np.array([1.2, -0.4]), 0.3, 0.7)),
            Case("a batch of 5 poses, q (5, 2)", (rng.uniform(-np.pi, np.pi, (5, 2)), 0.1, 0.11),
                 hint="q has leading axes: use q[..., 0] and q[..., 1]"),
            Case("a (3, 4) grid of poses, q (3, 4, 2)", (rng.uniform(-np.pi, np.pi, (3, 4, 2)), 0.2, 0.15),
                 hint="q has leading axes: use q[..., 0] and q[..., 1]"),
            Case("the straight arm q = (0, 0)", (np.zeros(2), 0.1, 0.11))]


def _wrong_kinematics(link1=lambda q1, q2: q1, link2=lambda q1, q2: q1 + q2, swap_lengths=False,
                      transpose=False, short_column=False, trig=(np.cos, np.sin), jacobian_sign=1):
    def kinematics(q, l1, l2):
        if swap_lengths:
            l1, l2 = l2, l1
        q = np.asarray(q, float)
        cfg = arm.ArmConfig(l1=l1, l2=l2)
        a1, a2 = link1(q[..., 0], q[..., 1]), link2(q[..., 0], q[..., 1])
        cx, sy = trig
        p = np.stack([l1 * cx(a1) + l2 * cx(a2), l1 * sy(a1) + l2 * sy(a2)], -1)
        J = jacobian_sign * arm.end_effector_jacobian(np.stack([a1, a2 - a1], -1), cfg)
        if short_column:
            J[..., :, 0] = np.stack([-l1 * np.sin(a1), l1 * np.cos(a1)], -1)
        return p, np.swapaxes(J, -1, -2) if transpose else J
    return kinematics


KINEMATICS = Checker(
    expected=_package_kinematics, cases=_kinematics_cases, package=(arm.forward_kinematics, arm.end_effector_jacobian),
    out=Out("tuple", parts=(Out("array", "your position p", ("coordinate",), (("x", "y"),)),
                            Out("array", "your Jacobian J", ("row", "column"), (("x", "y"), ("q1", "q2"))))),
    mistakes=(
        Mistake("you swapped the joint angles: link 1 points at angle q1 = q[..., 0], link 2 at q1 + q2",
                _wrong_kinematics(link1=lambda q1, q2: q2)),
        Mistake("link 2's angle from the x axis is q1 + q2, not q2: the elbow angle q2 is relative to link 1",
                _wrong_kinematics(link2=lambda q1, q2: q2)),
        Mistake("you swapped the link lengths: l1 is link 1, from the shoulder to the elbow",
                _wrong_kinematics(swap_lengths=True)),
        Mistake("you swapped sin and cos: angles are measured from the +x axis, so x = l1 cos q1 + "
                "l2 cos(q1 + q2)", _wrong_kinematics(trig=(np.sin, np.cos))),
        Mistake("your Jacobian is transposed: its rows are (x, y) and its columns (q1, q2), "
                "J[..., i, j] = d p_i / d q_j", _wrong_kinematics(transpose=True)),
        Mistake("your column d p / d q1 lacks link 2's terms: turning the shoulder moves both links "
                "(d x / d q1 = -l1 sin q1 - l2 sin(q1 + q2))", _wrong_kinematics(short_column=True)),
        Mistake("your Jacobian has the wrong sign: d cos(a)/da = -sin(a) and d sin(a)/da = +cos(a)",
                _wrong_kinematics(jacobian_sign=-1)),
        Mistake("you returned (J, p): the order is (p, J), the position first",
                lambda q, l1, l2: _package_kinematics(q, l1, l2)[::-1]),
    ))

# ----------------------------------------------------------------------------------------------------
# 3. One iLQG backward-pass step: ilqg.backward_pass
# ----------------------------------------------------------------------------------------------------


def _package_step(Vx, Vxx, A, B, lx, lu, lxx, luu, lux, mu):
    """The step as `ilqg.backward_pass` computes it, on a two-step problem whose step 1 is this one.

    backward_pass returns the gains but not the value function, so step 0 is a probe that reveals it:
    with A0 = 0, B0 = I (n controls), lu0 = 0, luu0 = c I and lux0 = I, its gains are
    K0 = -((c + mu) I + Vxx_t)^-1 and k0 = K0 Vx_t, so Vxx_t = -K0^-1 - (c + mu) I and Vx_t = K0^-1 k0.
    Step 1 gets n - m extra controls that nothing depends on (zero columns of B, unit cost): its gains
    are this step's, padded with zero rows, and its value function is unchanged.
    """
    n, m = B.shape
    As, Bs = np.stack([np.zeros((n, n)), A]), np.stack([np.eye(n), np.hstack([B, np.zeros((n, n - m))])])
    lus = np.stack([np.zeros(n), np.concatenate([lu, np.zeros(n - m)])])
    luu1 = np.eye(n)
    luu1[:m, :m] = luu
    luxs = np.stack([np.eye(n), np.vstack([lux, np.zeros((n - m, n))])])
    for c in 10.0 ** np.arange(13):          # the smallest c that makes step 0's Q_uu positive definite
        back = ilqg.backward_pass(As, Bs, np.stack([np.zeros(n), lx, Vx]), lus,
                                  np.stack([np.zeros((n, n)), lxx, Vxx]), np.stack([c * np.eye(n), luu1]), luxs, mu)
        if back is not None:
            break
    k, K, _ = back
    K0_inv = np.linalg.inv(K[0])
    return k[1, :m], K[1, :m], K0_inv @ k[0], -K0_inv - (c + mu) * np.eye(n)


def _step_cases():
    rng = np.random.default_rng(3)

    def problem(n, m, mu):
        spd = lambda size, s: (lambda M: M @ M.T + s * np.eye(size))(rng.normal(0, 0.5, (size, size)))
        return (rng.normal(size=n), spd(n, 1.0), np.eye(n) + rng.normal(0, 0.2, (n, n)), rng.normal(0, 0.7, (n, m)),
                rng.normal(size=n), rng.normal(size=m), spd(n, 0.5), spd(m, 0.5), rng.normal(0, 0.3, (m, n)), mu)
    return [Case(f"{words}: n = {n} states, m = {m} controls, mu = {mu}", problem(n, m, mu), {"mu": mu})
            for words, n, m, mu in [("the arm's sizes", 4, 2, 0.0), ("the arm's sizes", 4, 2, 0.5),
                                    ("another problem", 3, 1, 0.2), ("another problem", 2, 2, 0.0)]]


def _wrong_step(no_BVB=False, mu_on_quu=False, plain_qux=False, regularised_value=False, K_sign=1, k_sign=1,
                A_not_transposed=False, no_lux=False, short_value=False, closed_value=False, no_mu=False):
    def backward_step(Vx, Vxx, A, B, lx, lu, lxx, luu, lux, mu):
        mu = 0.0 if no_mu else mu
        At = A if A_not_transposed else A.T
        Qx, Qu = lx + At @ Vx, lu + B.T @ Vx
        Qxx, Qux = lxx + At @ Vxx @ At.T, (0 if no_lux else lux) + B.T @ Vxx @ At.T
        Quu = luu + (0 if no_BVB else B.T @ Vxx @ B)
        Quu_r = Quu + (mu * np.eye(len(lu)) if mu_on_quu else mu * B.T @ B)
        Qux_r = Qux + (0 if plain_qux or mu_on_quu else mu * B.T @ At.T)
        k, K = -k_sign * np.linalg.solve(Quu_r, Qu), -K_sign * np.linalg.solve(Quu_r, Qux_r)
        if regularised_value:
            Quu, Qux = Quu_r, Qux_r
        if short_value:
            return k, K, Qx + K.T @ Qu, Qxx - K.T @ Quu @ K
        if closed_value:
            return k, K, Qx - Qux.T @ np.linalg.solve(Quu, Qu), Qxx - Qux.T @ np.linalg.solve(Quu, Qux)
        return k, K, Qx + K.T @ Quu @ k + K.T @ Qu + Qux.T @ k, Qxx + K.T @ Quu @ K + K.T @ Qux + Qux.T @ K
    return backward_step


_vector = lambda what, axis: Out("array", what, (axis,))
BACKWARD_STEP = Checker(
    expected=_package_step, cases=_step_cases, package=(ilqg.backward_pass,),
    out=Out("tuple", parts=(_vector("your k", "control"), Out("array", "your K", ("control", "state")),
                            _vector("your Vx", "state"), Out("array", "your Vxx", ("state", "state")))),
    mistakes=(
        Mistake("your Q_uu lacks the term B^T V_xx B: Q_uu = l_uu + B^T V_xx B", _wrong_step(no_BVB=True)),
        Mistake("you regularised Q_uu with mu I; this iLQG regularises V_xx (Tassa et al. eq. 10), which "
                "adds mu B^T B to Q_uu and mu B^T A to Q_ux", _wrong_step(mu_on_quu=True)),
        Mistake("your Q_ux for the gains lacks mu B^T A: regularising V_xx changes both Q_uu and Q_ux",
                _wrong_step(plain_qux=True)),
        Mistake("your value update uses the regularised Q_uu and Q_ux: the gains use them, but V_x and V_xx "
                "use the plain ones (Tassa et al. eq. 11), or a large mu would make V_xx wrong",
                _wrong_step(regularised_value=True)),
        Mistake("your K has the wrong sign: K = -Q_uu^-1 Q_ux", _wrong_step(K_sign=-1)),
        Mistake("your k has the wrong sign: k = -Q_uu^-1 Q_u", _wrong_step(k_sign=-1)),
        Mistake("you used A where A^T belongs: Q_x = l_x + A^T V_x, Q_xx = l_xx + A^T V_xx A, "
                "Q_ux = l_ux + B^T V_xx A", _wrong_step(A_not_transposed=True)),
        Mistake("your Q_ux lacks l_ux: Q_ux = l_ux + B^T V_xx A", _wrong_step(no_lux=True)),
        Mistake("your V_x = Q_x + K^T Q_u and V_xx = Q_xx - K^T Q_uu K hold only when mu = 0: with mu = {mu} use "
                "V_x = Q_x + K^T Q_uu k + K^T Q_u + Q_ux^T k and V_xx = Q_xx + K^T Q_uu K + K^T Q_ux + Q_ux^T K",
                _wrong_step(short_value=True)),
        Mistake("your V_x = Q_x - Q_ux^T Q_uu^-1 Q_u and V_xx = Q_xx - Q_ux^T Q_uu^-1 Q_ux hold only when mu = 0: "
                "with mu = {mu} the gains k, K come from the regularised Q-terms, so write the value update with "
                "them: V_x = Q_x + K^T Q_uu k + K^T Q_u + Q_ux^T k, V_xx = Q_xx + K^T Q_uu K + K^T Q_ux + Q_ux^T K",
                _wrong_step(closed_value=True)),
        Mistake("your step ignores mu (here {mu}): the gains use V_xx + mu I, i.e. Q_uu + mu B^T B and "
                "Q_ux + mu B^T A", _wrong_step(no_mu=True)),
    ))

CHECKERS = {1: SUCCESS, 2: KINEMATICS, 3: BACKWARD_STEP}
