"""Methods as objects (oneshot/methods/): every method of the registry goes through the whole package
(train -> checkpoint -> resume -> evaluate) behind the one interface, a new method needs nothing but
its own module and a registry line, nothing outside the methods' modules tests a method's name, and
eq. (1) is one inner loop: training's inner update and meta-test's give the same adapted parameters
for every option."""
import dataclasses
import inspect
import json
import pathlib
import re

import numpy as np
import pytest

import oneshot
from oneshot import evaluate, methods
from oneshot.benchmark.maml import timed_config
from oneshot.maml import batched, imitation, inner
from oneshot.maml.inner import InnerLoop
from oneshot.methods.base import Method
from oneshot.policy import network
from oneshot.experiments.lines import LINES
from oneshot.training import checkpoint, config, run_folder


@pytest.fixture
def smoke(tiny_datasets):
    train_path, validation_path = tiny_datasets
    return dataclasses.replace(config.PROFILES["smoke"], train_data=train_path, validation_data=validation_path,
                               iterations=6, checkpoint_every=100, eval_trials=1)


def _same(p, q):
    return set(p) == set(q) and all(np.array_equal(p[k], q[k]) for k in p)


@pytest.mark.parametrize("name", list(methods.REGISTRY))
def test_every_method_of_the_registry_trains_checkpoints_resumes_and_evaluates(name, smoke, tmp_path):
    cfg = dataclasses.replace(smoke, method=name, lstm_units=4, random_stds=(0.25, 1.0))
    whole = run_folder.train(cfg, tmp_path / "whole", progress=False)
    run_folder.train(cfg, tmp_path / "split", progress=False, stop_after=2)          # "killed" at iteration 2
    resumed = run_folder.train(cfg, tmp_path / "split", resume=True, progress=False)
    assert _same(whole, resumed), name                                             # resume is exact
    ckpt = checkpoint.load(tmp_path / "split" / "checkpoint.npz")
    assert ckpt["config"] == cfg and _same(ckpt["params"], whole)
    method = methods.of(cfg)
    assert ckpt["iteration"] == cfg.iterations and (ckpt["ema"] is None) == (not method.learns or cfg.ema == 0)
    results = evaluate.main([str(tmp_path / "split" / "checkpoint.npz"), "--validation", cfg.validation_data, "--train", "",
                             "--trials", "2"] + (["--unadapted"] if method.adapts else []))
    assert results["validation"]["trials"] == 4 and 0 <= results["validation"]["successes"] <= 4
    assert ("validation_unadapted" in results) == ("adaptation_gain" in results) == method.adapts


class Imitator(Method):
    """A method the package has never seen: behavioural cloning that ignores the demonstration."""

    name = "imitator"

    def meta_gradient(self, params, adapt, evaluate, pool=None):
        return batched.value_and_grads(lambda p, e: imitation.imitation_loss(p, e) / len(e[0]), params, evaluate)

    def meta_gradient_flops(self, net_cfg, T, tasks):
        return tasks * 3 * network.count_flops(net_cfg, T)

    def conditioner(self, params, seed=0):
        return lambda demo: params


def test_a_new_method_needs_only_its_module_and_a_registry_line(smoke, tmp_path, monkeypatch):
    monkeypatch.setitem(methods.REGISTRY, "imitator", Imitator)
    cfg = dataclasses.replace(smoke, method="imitator")
    params = run_folder.train(cfg, tmp_path / "run", progress=False)
    ckpt = checkpoint.load(tmp_path / "run" / "checkpoint.npz")
    assert _same(ckpt["params"], params) and ckpt["config"].method == "imitator"
    results = evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--validation", cfg.validation_data, "--train", "",
                             "--trials", "1", "--method", "imitator"])
    assert results["validation"]["trials"] == 2 and "adaptation_gain" not in results
    with pytest.raises(SystemExit):                                   # it does not adapt: no unadapted policy
        evaluate.main([str(tmp_path / "run" / "checkpoint.npz"), "--validation", cfg.validation_data, "--unadapted"])


def test_nothing_outside_the_methods_modules_tests_a_methods_name():
    """Code asks the method object; it never branches on `cfg.method == "..."` (or `!=`, `in (...)`)."""
    package = pathlib.Path(oneshot.__file__).parent
    pattern = re.compile(r"""\.method\s*(==|!=|\bin\b|\bnot in\b)\s*[("'\[]""")
    found = [f"{path.relative_to(package)}:{n}: {line.strip()}"
             for path in package.rglob("*.py") if "methods" not in path.relative_to(package).parts
             for n, line in enumerate(path.read_text().splitlines(), 1) if pattern.search(line)]
    assert not found, "tests of a method's name outside oneshot/methods/:\n" + "\n".join(found)
    assert pattern.search('if cfg.method == "mil":') and pattern.search("cfg.method in ('lstm', 'x')")  # it can fail


# ----- one inner loop -----------------------------------------------------------------------------

# Every option of eq. (1) (the fields of InnerLoop, which are inner_update's keyword options) and the
# values the test tries: a new option must be added here, or the first test below fails.
OPTIONS = {"alpha": [0.0, 0.05], "steps": [0, 2], "first_order": [False, True],
           "only": [None, ("conv0_",), ("fc", "out")], "frozen": [(), ("ln", "fc0")], "clip": [0.0, 0.05],
           "loss_scale": [1.0, 250.0]}


def test_inner_loop_carries_exactly_the_options_of_inner_update():
    keyword = [p.name for p in inspect.signature(inner.inner_update).parameters.values()
               if p.default is not inspect.Parameter.empty and p.kind is not inspect.Parameter.KEYWORD_ONLY]
    assert [f.name for f in dataclasses.fields(InnerLoop)] == keyword == list(OPTIONS)


@pytest.mark.parametrize("learnt", [False, True], ids=["alpha", "learnt step sizes"])
def test_training_and_meta_test_adapt_to_the_same_parameters_for_every_option(rng, learnt):
    """Training's inner update (`batched.adapt_batch`: a meta-batch at once, its own gradient route) and
    meta-test's (`imitation.adapt` on one demo, what `methods.MIL.conditioner` does) are eq. (1) once:
    for every combination of options, task b's adapted parameters are the same numbers."""
    net_cfg = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5,), bias_transform=2, feature_points=True,
                                    layer_norm=True)
    net = network.init_params(net_cfg, rng, np.float64)
    B, T = 3, 4
    demos = (rng.random((B, T, 8, 8, 3)), rng.normal(size=(B, T, 6)), rng.normal(size=(B, T, 2)))
    base = dict(alpha=0.05, steps=2, first_order=False, only=None, frozen=(), clip=0.0, loss_scale=1.0)
    combos = [dict(base, **{name: value}) for name, values in OPTIONS.items() for value in values]   # each value
    combos += [dict(base, frozen=("ln", "fc0"), clip=0.05, loss_scale=250.0, first_order=fo) for fo in (False, True)]
    for combo in combos:                                                               # ... and them together
        loop = InnerLoop(**combo)
        params = dict(net, **inner.init_step_sizes(net, 0.03, loop.only, loop.frozen)) if learnt else net
        trained = batched.adapt_batch(params, demos, imitation.imitation_loss, loop)
        for b in range(B):
            tested = imitation.adapt(params, tuple(a[b] for a in demos), **loop.options())
            assert trained.keys() == tested.keys(), loop
            for k in tested:
                np.testing.assert_allclose(trained[k][b] if np.ndim(trained[k]) > np.ndim(net[k]) else trained[k],
                                           tested[k], rtol=1e-10, atol=1e-12, err_msg=f"{loop} {k}")


def test_the_mil_method_trains_and_tests_with_the_inner_loop_of_its_config():
    cfg = dataclasses.replace(config.PROFILES["default"], inner_steps=2, alpha=0.1, first_order=True)
    assert methods.of(cfg).inner == InnerLoop(0.1, 2, True, ("conv0_",))
    with pytest.raises(ValueError, match="inner_params must be one of"):
        methods.of(dataclasses.replace(cfg, inner_params="fc9"))
    with pytest.raises(ValueError, match="alpha must be finite and >= 0"):
        InnerLoop(alpha=-1.0)
    assert json.dumps(InnerLoop(0.1, np.int64(2)).options()) == ('{"alpha": 0.1, "steps": 2, "first_order": false, '
                                                                 '"only": null, "frozen": [], "clip": 0.0, '
                                                                 '"loss_scale": 1.0}')
    released = methods.of(config.PROFILES["released"]).describe()     # what `train` prints first
    assert released.startswith("eq. (1): 1 step(s) of ") and "inner gradient clipped to +-20 " in released
    assert methods.of(cfg).describe().startswith("eq. (1): 2 step(s) of 0.1 on 1 x eq. (2)")
    assert "meta-learnt per element" in methods.of(dataclasses.replace(cfg, learn_alpha=True)).describe()
    assert "meta-learnt" not in methods.of(cfg).describe()
    assert all(methods.of(dataclasses.replace(cfg, method=name)).describe() == "" for name in methods.REGISTRY
               if name != "mil")


def test_the_released_inner_loop_options_differentiate_to_second_order_and_do_what_they_say(rng):
    """Clip, frozen parameters and the loss scale, through the plain meta-objective: finite differences to
    second order; a clipped step moves no element by more than alpha x clip; a frozen parameter keeps
    its value; loss_scale s with step alpha is the step alpha s on the unscaled loss (without a clip)."""
    from autograd.test_util import check_grads
    net_cfg = network.NetworkConfig(image_size=8, channels=(2, 3), hidden=(4,), state_dim=6, layer_norm=True)
    params = {k: v + 0.05 * rng.normal(size=v.shape) for k, v in network.init_params(net_cfg, rng, np.float64).items()}
    demo = (rng.random((3, 8, 8, 3)), rng.normal(size=(3, 6)), rng.normal(size=(3, 2)))
    other = (rng.random((3, 8, 8, 3)), rng.normal(size=(3, 6)), rng.normal(size=(3, 2)))
    options = dict(alpha=0.01, steps=1, frozen=("ln",), clip=0.5, loss_scale=3.0)
    check_grads(lambda p: inner.meta_objective(p, [(demo, other)], imitation.imitation_loss, **options),
                modes=["rev"], order=2)(params)
    adapted = inner.inner_update(params, demo, imitation.imitation_loss, **options)
    moved = {k: np.abs(adapted[k] - params[k]).max() for k in params}
    assert all(moved[k] <= 0.01 * 0.5 + 1e-15 for k in params) and max(moved.values()) == pytest.approx(0.005)
    assert all(moved[k] == 0 for k in params if k.startswith("ln")) and moved["conv0_w"] > 0
    scaled = inner.inner_update(params, demo, imitation.imitation_loss, alpha=0.01, steps=1, loss_scale=3.0)
    plain = inner.inner_update(params, demo, imitation.imitation_loss, alpha=0.03, steps=1)
    for k in params:
        np.testing.assert_allclose(scaled[k], plain[k], rtol=1e-12, atol=1e-15)


def test_parameter_count_is_what_init_params_builds_for_every_profile_and_line():
    """Counted from the shapes, without allocating (train and benchmark refuse too large a network with
    it): every training profile, every Figure 2 line, and both with learnt step sizes (Meta-SGD)."""
    configs = list(config.PROFILES.values()) + list(LINES.values())
    configs += [dataclasses.replace(c, learn_alpha=True) for c in configs if c.method == "mil"]
    for cfg in configs:
        method = methods.of(cfg)
        net_cfg = method.network_config(32)
        built = method.init_params(net_cfg, np.random.default_rng(0))
        assert method.parameter_count(net_cfg) == sum(v.size for v in built.values()), cfg


def test_the_mil_methods_meta_test_adapts_with_its_configs_inner_loop(rng):
    """MIL.conditioner is eq. (1) as the config sets it (here 2 steps of 0.05 on the first convolution, not
    the paper's 3 of 0.001 on every parameter): the parameters training's inner update (`batched.adapt_batch`) makes
    from the same demo; its unadapted policy is the parameters themselves."""
    cfg = dataclasses.replace(config.PROFILES["smoke"], alpha=0.05, inner_steps=2, inner_params="conv0")
    method = methods.of(cfg)
    net_cfg = dataclasses.replace(method.network_config(8), channels=(3, 4), hidden=(5,))
    params = {k: v.astype(np.float64) for k, v in method.init_params(net_cfg, rng).items()}
    demo = (rng.random((3, 8, 8, 3)), rng.normal(size=(3, 6)), rng.normal(size=(3, 2)))
    adapted = method.conditioner(params)(demo)
    trained = batched.adapt_batch(params, tuple(a[None] for a in demo), imitation.imitation_loss,
                                  InnerLoop(alpha=0.05, steps=2, only=("conv0_",)))
    for k in params:
        np.testing.assert_allclose(adapted[k], trained[k][0] if k.startswith("conv0_") else trained[k],
                                   rtol=1e-10, atol=1e-12, err_msg=k)
    assert np.abs(adapted["conv0_w"] - params["conv0_w"]).max() > 1e-4 and np.array_equal(adapted["fc0_w"], params["fc0_w"])
    assert method.unadapted(params)(demo) is params


WIDE = {"hidden": (20000,), "inner_params": "all"}     # the adapted parameters' copies are most of a task


@pytest.mark.parametrize("timed, changes, measured_mb", [
    ("smoke", {}, 21.2), ("default", {}, 10.1), ("mil-released+widths-flat+3steps", {}, 27.7), ("lstm", {}, 8.0),
    ("smoke", dict(WIDE, inner_steps=1), 262), ("smoke", dict(WIDE, inner_steps=3), 381)])
def test_a_tasks_memory_estimate_holds_what_a_meta_iteration_was_measured_to_take(timed, changes, measured_mb):
    """task_bytes, which `train` and the benchmark check a meta-batch against before any work (a meta-batch
    of 1,000 had grown to 21 GB when the kernel killed it; so had one dense layer of 1,000,000 adapting,
    when the estimate left out each task's copies of the adapted parameters), is above the measured slope
    of peak memory per task and less than 2.5 times it. Measured on this machine's NumPy with `python -m
    oneshot.benchmark maml --shards 1 --iterations 2 --meta-batch N` (N = 4 and 16) and `--profile P` or
    `--line L`; the wide rows as the slope of one meta-gradient's peak resident memory (ru_maxrss) from
    meta-batch 1 to 3, each in its own process (the benchmark has no --hidden)."""
    method = methods.of(dataclasses.replace(timed_config(timed), **changes))
    estimate_mb = method.task_bytes(method.network_config(32), 20) / 2 ** 20
    assert measured_mb < estimate_mb < 2.5 * measured_mb, estimate_mb
