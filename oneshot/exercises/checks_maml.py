"""Checkers of exercises 6 and 7 (MAML, paper Section II): the inner update, eq. (1), on a subset of
the parameters, and the second- and first-order meta-gradients on a toy problem. Each compares with
the package's own functions (`inner.inner_update`, `inner.meta_gradient`)."""
import autograd.numpy as anp
import numpy as np
from autograd import grad
from autograd.tracer import getval

from oneshot.maml import inner
from oneshot.exercises.checking import Case, Checker, Mistake
from oneshot.exercises.compare import Out

# ----------------------------------------------------------------------------------------------------
# 6. The inner update, eq. (1), one step on the parameters `only` names: inner.inner_update
# ----------------------------------------------------------------------------------------------------


def toy_loss(params, demo):
    """The summed squared error of a 3-5-2 tanh network: the stand-in for eq. (2) in exercise 6."""
    x, y = demo
    hidden = anp.tanh(x @ params["layer0_w"] + params["layer0_b"])
    return anp.sum((hidden @ params["layer1_w"] + params["layer1_b"] - y) ** 2)


def _package_inner_update(params, demo, loss_fn, alpha, only=None):
    return inner.inner_update(params, demo, loss_fn, alpha, steps=1, only=only)


def _through(eval_demo):
    """How a case differentiates through an update: grad of L(theta'; eval_demo) with respect to theta."""
    def call(fn, params, demo, loss_fn, alpha, only):
        return grad(lambda theta: loss_fn(fn(theta, demo, loss_fn, alpha, only), eval_demo))(params)
    return call


def _inner_cases():
    # loss_fn is `toy_loss`, of this module: a function of oneshot.maml (imitation_loss, say) would be one
    # of the package's answers, and both the grader and `check` would flag an honest student who calls it.
    rng = np.random.default_rng(6)
    params = {"layer0_w": rng.normal(0, 0.7, (3, 5)), "layer0_b": rng.normal(0, 0.1, 5),
              "layer1_w": rng.normal(0, 0.7, (5, 2)), "layer1_b": rng.normal(0, 0.1, 2)}
    demo = lambda: (rng.normal(size=(6, 3)), rng.normal(size=(6, 2)))
    cases = []
    for alpha, only in [(0.1, ("layer1",)), (0.05, None), (0.3, ("layer0_w", "layer1_b")), (0.0, None),
                        (0.2, ("layer0_",)), (0.15, ("layer",))]:        # prefixes that are no part of a name
        words = "every parameter" if only is None else f"the keys starting with {' or '.join(map(repr, only))}"
        fixed = [k for k in params if only is not None and not k.startswith(only)]
        cases.append(Case(f"one step of alpha = {alpha} on {words}", (params, demo(), toy_loss, alpha, only),
                          {"alpha": alpha, "only": only, "fixed": fixed}))
    cases.append(Case("MAML's meta-gradient through your update (alpha = 0.1 on the keys starting with 'layer1')",
                      (params, demo(), toy_loss, 0.1, ("layer1",)), call=_through(demo()),
                      out=Out("dict", "d L(your theta') / d theta"),
                      hint="autograd cannot differentiate through your update: keep it in autograd's terms "
                           "(theta - alpha * g, no np.array(...) or float(...) on the values)",
                      hint_only_on_error=True))
    return cases


def _prefixed(key, only):
    return only is None or key.startswith(tuple(only))


def _wrong_inner(sign=-1, step=lambda alpha: alpha, adapts=_prefixed, cut=False, keep_fixed=True):
    def inner_update(params, demo, loss_fn, alpha, only=None):
        g = grad(loss_fn)(params, demo)
        g = {k: getval(v) for k, v in g.items()} if cut else g
        return {k: v + sign * step(alpha) * g[k] if adapts(k, only) else v for k, v in params.items()
                if keep_fixed or adapts(k, only)}
    return inner_update


INNER = Checker(
    expected=_package_inner_update, cases=_inner_cases, out=Out("dict", "your adapted params"),
    package=(inner.inner_update,),
    mistakes=(
        Mistake("you stepped UP the gradient (theta + alpha * grad): eq. (1) subtracts it, theta - alpha * grad",
                _wrong_inner(sign=+1)),
        Mistake("you updated every parameter: with only = {only}, only the keys starting with one of those "
                "prefixes adapt; {fixed} must keep their values", _wrong_inner(adapts=lambda key, only: True)),
        Mistake("`only` holds key PREFIXES: {only} selects every key that starts with one of them "
                "(key.startswith(tuple(only))), not only the keys equal to one",
                _wrong_inner(adapts=lambda key, only: only is None or key in only)),
        Mistake("`only` holds key PREFIXES, not names or name parts: {only} selects every key that starts with "
                "one of them (key.startswith(tuple(only)))",
                _wrong_inner(adapts=lambda key, only: only is None or key in only or key.split("_")[0] in only)),
        Mistake("you adapted only the keys starting with the first prefix of `only`: {only} selects every key "
                "that starts with any of them (key.startswith(tuple(only)))",
                _wrong_inner(adapts=lambda key, only: only is None or key.startswith(only[0]))),
        Mistake("your step is alpha^2 * grad: eq. (1) steps by alpha * grad (alpha = {alpha})",
                _wrong_inner(step=lambda alpha: alpha ** 2)),
        Mistake("your step lacks alpha: eq. (1) is theta - alpha * grad (alpha = {alpha})",
                _wrong_inner(step=lambda alpha: 1.0)),
        Mistake("you returned only the adapted parameters: return every key of params, those not adapted "
                "unchanged", _wrong_inner(keep_fixed=False)),
        Mistake("the meta-gradient through your update is the first-order one: autograd lost track of how the "
                "inner gradient depends on theta (np.array(...), .astype or getval cut it); MAML needs the "
                "second-order term", _wrong_inner(cut=True)),
    ))

# ----------------------------------------------------------------------------------------------------
# 7. Second- against first-order meta-gradient, y = w x: inner.meta_gradient
# ----------------------------------------------------------------------------------------------------


def line_loss(params, demo):
    """Eq. (2) for the line y = w x: sum_t (w x_t - y_t)^2."""
    x, y = demo
    return anp.sum((params["w"] * x - y) ** 2)


def _package_meta_gradients(w, alpha, adapt_demo, eval_demo):
    params, tasks = {"w": np.array(float(w))}, [(adapt_demo, eval_demo)]
    _, second = inner.meta_gradient(params, tasks, line_loss, alpha, 1)
    _, first = inner.meta_gradient(params, tasks, line_loss, alpha, 1, first_order=True)
    return float(second["w"]), float(first["w"])


def _meta_cases():
    rng = np.random.default_rng(7)

    def demo(T):
        x = rng.normal(size=T)
        return x, 1.5 * x + rng.normal(0, 0.3, T)
    cases = []
    for label, w, Ta, Te, alpha in [
            ("w = 0.5, alpha = 0.05, 4-point demos", 0.5, 4, 4, 0.05),
            ("w = 0.5, alpha = 0 (no adaptation)", 0.5, 4, 4, 0.0),
            ("w = 2.0, alpha = 1 / L''(w; adapt), a step that makes dw'/dw = 0", 2.0, 5, 5, None),
            ("w = -1.0, a 3-point adapt demo, a 7-point eval demo, alpha = 0.02", -1.0, 3, 7, 0.02),
            ("w = 0.0, alpha = 1.5 / L''(w; adapt), an overshooting step", 0.0, 4, 4, -1.5)]:
        adapt_demo, eval_demo = demo(Ta), demo(Te)
        curvature = 2 * np.sum(adapt_demo[0] ** 2)                  # L''(w; adapt)
        alpha = 1 / curvature if alpha is None else -alpha / curvature if alpha < 0 else alpha
        cases.append(Case(label, (w, alpha, adapt_demo, eval_demo),
                          {"alpha": f"{alpha:.4g}", "factor": f"{1 - alpha * curvature:.4g}", "H": f"{curvature:.4g}"}))
    return cases


def _wrong_meta(swap=False, same=False, adapted=True, factor=lambda a, h: 1 - a * h, two=2.0, score_on_adapt=False,
                inner_sign=-1, mean=False):
    def meta_gradients(w, alpha, adapt_demo, eval_demo):
        (xa, ya), (xe, ye) = adapt_demo, (adapt_demo if score_on_adapt else eval_demo)
        na, ne = (len(xa), len(xe)) if mean else (1, 1)
        w_adapted = w + inner_sign * alpha * two * np.sum(xa * (w * xa - ya)) / na if adapted else w
        first = two * np.sum(xe * (w_adapted * xe - ye)) / ne
        second = first if same else first * factor(alpha, two * np.sum(xa * xa) / na)
        return (float(first), float(second)) if swap else (float(second), float(first))
    return meta_gradients


META = Checker(
    expected=_package_meta_gradients, cases=_meta_cases, package=(inner.meta_gradient,),
    out=Out("tuple", parts=(Out("number", "your second-order meta-gradient"),
                            Out("number", "your first-order meta-gradient"))),
    mistakes=(
        Mistake("you returned (first_order, second_order): the order is (second_order, first_order)",
                _wrong_meta(swap=True)),
        Mistake("your second-order meta-gradient equals the first-order one: it has the extra factor "
                "dw'/dw = 1 - alpha L''(w; adapt) = {factor}", _wrong_meta(same=True)),
        Mistake("you took the eval loss's gradient at w: the meta-objective scores the ADAPTED "
                "w' = w - alpha L'(w; adapt)", _wrong_meta(adapted=False)),
        Mistake("you took the eval loss's gradient at w: the meta-objective scores the ADAPTED "
                "w' = w - alpha L'(w; adapt)", _wrong_meta(adapted=False, same=True)),
        Mistake("your dw'/dw has the wrong sign: w' = w - alpha L'(w), so dw'/dw = 1 - alpha L''(w; adapt) = {factor}",
                _wrong_meta(factor=lambda a, h: 1 + a * h)),
        Mistake("your L''(w; adapt) lacks the factor 2: d^2/dw^2 sum (w x - y)^2 = 2 sum x^2 = {H}",
                _wrong_meta(factor=lambda a, h: 1 - a * h / 2)),
        Mistake("your derivatives lack the factor 2: d/dw sum (w x - y)^2 = 2 sum x (w x - y)",
                _wrong_meta(two=1.0)),
        Mistake("you scored w' on the adapt demo: the meta-objective scores it on eval_demo",
                _wrong_meta(score_on_adapt=True)),
        Mistake("your inner step goes up the gradient: eq. (1) is w' = w - alpha L'(w; adapt)",
                _wrong_meta(inner_sign=+1)),
        Mistake("your loss is a mean over the demo's points: eq. (2) SUMS the squared errors, so L'(w) = "
                "2 sum x (w x - y) and L''(w; adapt) = 2 sum x^2 = {H}", _wrong_meta(mean=True)),
    ))

CHECKERS = {6: INNER, 7: META}
