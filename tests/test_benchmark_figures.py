"""What `python -m oneshot.benchmark` computes its figures from, in this process, with the work and the
clock faked: each fake piece of work says how long it took (`Clock`), so medians, warm-ups, rates and
which runs were profiled are checked against values worked out by hand. (tests/test_benchmark.py runs
the real benchmark in its own process.) BLAS threads are recorded, never set, here."""
import cProfile
import dataclasses
import json
import pstats
from types import SimpleNamespace

import numpy as np
import pytest

from oneshot import methods
from oneshot.benchmark import __main__ as benchmark, breakdown, expert, maml, peers, privileged
from oneshot.data import datasets
from oneshot.maml import imitation, inner, shards
from oneshot.policy import affine, conv, layers, network, norm
from oneshot.tools import cli
from oneshot.training.config import PROFILES
from oneshot.training.scoring import wilson_interval
from oneshot.world import palette
from oneshot.world.reach import ReachWorld, WorldConfig


class Pool:
    """A fake pool of shard processes: says when it is closed."""

    def __init__(self, events):
        self.events = events
        events.append(("pool",))

    def close(self):
        self.events.append(("close",))


class Clock:
    """A fake `time.perf_counter`: it moves only when fake work says it took `seconds`."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now

    def take(self, seconds):
        self.now += seconds


@pytest.fixture
def threads(monkeypatch):
    """BLAS's threads as the benchmark sets them: recorded in threads["now"], not set."""
    state = {"now": None}
    monkeypatch.setattr(maml.host, "blas_threads", lambda n: state.update(now=n))
    monkeypatch.setattr(maml.host, "tune_malloc", lambda: None)
    return state


@pytest.mark.parametrize("blas_threads, expected_threads, ceiling_cores, percent",
                         [(None, 1, 3, 50.0), (2, 2, 4, 150.0)])
def test_maml_reports_the_median_after_two_warm_ups_against_a_ceiling_on_its_cores(
        monkeypatch, threads, blas_threads, expected_threads, ceiling_cores, percent):
    """Five meta-iterations of 0.9, 0.7 (warm-ups), 0.1, 0.5 and 0.25 s: 0.25 s per iteration (the median
    of the last three). The ceiling is the median of two products, timed before the pool starts and after
    it closes, on min(cores, shards x BLAS threads) threads: 3 shards of 1 thread on 4 cores use 3, of
    2 threads 4 (not 6); the iterations run on the BLAS threads asked for. Above 100% of the ceiling
    (150%), the figure says the cores were shared; at 50% it does not."""
    clock, events, durations = Clock(), [], [0.9, 0.7, 0.1, 0.5, 0.25]
    method = methods.of(dataclasses.replace(PROFILES["smoke"], shards=3))

    def meta_gradient(self, params, adapt, evaluate, pool):
        assert isinstance(pool, Pool) and adapt[0].shape == (2, 20, 32, 32, 3) and evaluate[2].shape == (2, 20, 2)
        events.append(("iteration", threads["now"]))
        clock.take(durations.pop(0))
    flops = method.meta_gradient_flops(method.network_config(32), 20, 2)
    rate = flops / 1e9 / 0.25                                  # GFLOP/s of the timed iterations
    ceilings = [0.8 * rate * 100 / percent, 1.2 * rate * 100 / percent]   # median: rate * 100 / percent
    monkeypatch.setattr(type(method), "meta_gradient", meta_gradient)
    monkeypatch.setattr(type(method), "make_pool", lambda self: Pool(events))
    monkeypatch.setattr(maml, "sgemm_rate", lambda: events.append(("ceiling", threads["now"])) or ceilings.pop(0))
    monkeypatch.setattr(maml, "time", SimpleNamespace(perf_counter=clock))
    monkeypatch.setattr(maml, "os", SimpleNamespace(cpu_count=lambda: 4))
    result = maml.bench_meta_iteration(3, "smoke", blas_threads=blas_threads, shards=3)
    assert events == [("ceiling", ceiling_cores), ("pool",), *[("iteration", expected_threads)] * 5,
                      ("close",), ("ceiling", ceiling_cores)]
    assert (result["seconds_per_iteration"], result["shards"], result["blas_threads"], result["ceiling_cores"]) == \
           (0.25, 3, expected_threads, ceiling_cores)
    assert result["gflop_per_iteration"] == round(flops / 1e9, 2)
    assert result["gflop_per_second"] == pytest.approx(rate, abs=0.05)
    assert result["ceiling_gflop_per_second"] == pytest.approx(rate * 100 / percent, abs=0.05)
    assert result["percent_of_ceiling"] == pytest.approx(percent, abs=0.05)
    assert ("warning" in result) == (percent > 100)
    if percent > 100:
        assert "before and after" in result["warning"]


def test_maml_times_a_peer_on_every_core_without_our_shard_processes(monkeypatch, threads):
    """--peer: the peer's meta-gradient runs (no pool of ours is started) and the ceiling is read on all
    4 cores, the peer's threads; the result says one process and no BLAS threads of ours. A baseline has
    no peer (its meta-gradient is not MIL's) and is refused before any work."""
    clock, events, durations = Clock(), [], [0.9, 0.7, 0.2]

    def step(params, adapt, evaluate):
        events.append("peer")
        clock.take(durations.pop(0))
    monkeypatch.setattr(maml.peers, "meta_gradient", lambda peer, net_cfg, inner: events.append(peer) or step)
    monkeypatch.setattr(type(methods.of(PROFILES["smoke"])), "make_pool", lambda self: pytest.fail("a pool"))
    monkeypatch.setattr(maml, "sgemm_rate", lambda: events.append(threads["now"]) or 10.0)
    monkeypatch.setattr(maml, "time", SimpleNamespace(perf_counter=clock))
    monkeypatch.setattr(maml, "os", SimpleNamespace(cpu_count=lambda: 4))
    result = maml.bench_meta_iteration(1, "smoke", peer="torch")
    assert events == ["torch", 4, "peer", "peer", "peer", 4]
    assert (result["peer"], result["shards"], result["blas_threads"], result["ceiling_cores"]) == ("torch", 1, None, 4)
    assert result["seconds_per_iteration"] == 0.2
    with pytest.raises(ValueError, match="--peer times MIL's meta-gradient, not a baseline's"):
        maml.bench_meta_iteration(1, "smoke", peer="torch", method="lstm")
    assert events == ["torch", 4, "peer", "peer", "peer", 4]           # no peer built, no ceiling timed


def test_the_ceiling_is_the_median_products_rate(monkeypatch):
    """sgemm_rate: 2 n^3 operations per (n, n) @ (n, n) product, at the median of its timings (here 0.5,
    0.1 and 0.2 s: 0.2 s)."""
    ticks = iter([0.0, 0.5, 10.0, 10.1, 20.0, 20.2])
    monkeypatch.setattr(maml, "time", SimpleNamespace(perf_counter=lambda: next(ticks)))
    assert maml.sgemm_rate(n=8, repeats=3) == pytest.approx(2 * 8 ** 3 / 0.2 / 1e9)


def test_breakdown_counts_a_callees_time_in_its_own_group_only():
    """A function's cProfile time, less what its callees of a group took: here `middle` (2 ms of its own)
    calls `leaf` twice (3 ms each), under an ungrouped `outer`: 2 ms and 6 ms, not 8 and 6."""
    clock = Clock()

    def leaf():
        clock.take(0.003)

    def middle():
        clock.take(0.002)
        leaf()
        leaf()

    def outer():
        clock.take(0.001)
        middle()
    profiler = cProfile.Profile(clock)
    profiler.enable()
    outer()
    profiler.disable()
    keys = {breakdown._code_key(middle): "conv_products", breakdown._code_key(leaf): "im2col_col2im"}
    ms = breakdown._grouped_ms(pstats.Stats(profiler).stats, keys)
    assert ms == pytest.approx({"conv_products": 2.0, "transposed_products": 0.0, "im2col_col2im": 6.0,
                                "other_layer_primitives": 0.0})


def test_a_breakdown_whose_parts_outran_the_plain_runs_says_its_remainder_is_not_measured(monkeypatch):
    """Under load the parts, timed under cProfile, can take longer than the plain runs: the remainder
    (autograd's Python) came out at -29.4 ms with no word. It is kept as measured, and "note" says why."""
    host = breakdown.host
    monkeypatch.setattr(host, "blas_threads", lambda n=None: None)      # this process's BLAS stays as it is
    monkeypatch.setattr(breakdown, "_grouped_ms", lambda stats, keys: dict.fromkeys(
        [*breakdown.GROUPS, "other_layer_primitives"], 1e6))          # a million ms each: far past the wall time
    result = breakdown.bench_breakdown(1, "smoke", rollouts=1, inner_steps=1)
    assert result["autograd_python_ms"] < 0 and "not measured here" in result["note"]
    monkeypatch.setattr(breakdown, "_grouped_ms", lambda stats, keys: dict.fromkeys(
        [*breakdown.GROUPS, "other_layer_primitives"], 0.0))
    assert "note" not in breakdown.bench_breakdown(1, "smoke", rollouts=1, inner_steps=1)


def test_breakdown_groups_the_networks_functions_as_its_docstring_says():
    """The module docstring's table: the products, their transposes, im2col/col2im; bias, ReLU and its mask,
    concatenation, layer norm and eq. (1)'s step are the other layer primitives."""
    groups = breakdown._function_groups()
    named = {"conv_products": [conv.conv, affine.matmul],
             "transposed_products": [conv.conv_dx, conv.conv_dw, affine.matmul_dx, affine.matmul_dw],
             "im2col_col2im": [conv.im2col, conv.col2im],
             "other_layer_primitives": [affine.add_bias, layers.relu, layers.mask, layers.concat_last,
                                        norm.normalise, norm.normalise_dx, inner.descend]}
    for group, functions in named.items():
        for f in functions:
            assert groups[breakdown._code_key(f)] == group, f


def test_breakdown_times_the_training_processs_frames_plain_and_profiled_in_turn(monkeypatch, threads):
    """After two warm-ups, plain runs (30, 10, 20 ms: part_ms 20) alternate with profiled ones, whose
    groups are the medians over the profiled runs; autograd's Python is the rest of the part's time. With
    3 shards, the training process's part is the last block of frames: 7 of 20 (bounds 0, 6, 13, 20)."""
    clock, seen, profiling = Clock(), [], []
    durations = [1.0, 1.0, 0.030, 0.5, 0.010, 0.5, 0.020, 0.5]
    groups = [dict(zip(breakdown.GROUPS, v), other_layer_primitives=o) for *v, o in
              [(1, 2, 3, 4), (5, 6, 7, 8), (3, 2, 1, 0)]]

    class Profile:              # a fake: from Python 3.12, sys.getprofile() is None under cProfile
        def enable(self):
            profiling.append(self)

        def disable(self):
            profiling.remove(self)

    def part(params, adapt, evaluate, settings):
        seen.append((adapt[0].shape[:2], evaluate[2].shape[:2], bool(profiling)))
        clock.take(durations.pop(0))
    monkeypatch.setattr(breakdown, "cProfile", SimpleNamespace(Profile=Profile))
    monkeypatch.setattr(breakdown, "pstats", SimpleNamespace(Stats=lambda profiler: SimpleNamespace(stats={})))
    monkeypatch.setattr(breakdown, "shards", SimpleNamespace(split_frames=shards.split_frames, part=part))
    monkeypatch.setattr(breakdown, "_grouped_ms", lambda stats, keys: groups.pop(0))
    monkeypatch.setattr(breakdown, "time", SimpleNamespace(perf_counter=clock))
    monkeypatch.setattr(breakdown, "_exchanges", lambda method, *args: {"exchanged": method.shards})
    monkeypatch.setattr(breakdown, "_rollouts", lambda *args: {})
    result = breakdown.bench_breakdown(3, "smoke", shards=3)
    assert seen == [((2, 7), (2, 7), profiled) for profiled in (False, False, False, True, False, True, False, True)]
    assert (result["tasks"], result["frames"], result["part_ms"], result["exchanged"]) == (2, 7, 20.0, 3)
    assert [result[k + "_ms"] for k in [*breakdown.GROUPS, "other_layer_primitives"]] == [3, 2, 3, 4]
    assert result["autograd_python_ms"] == 20.0 - (3 + 2 + 3 + 4)


def test_breakdown_times_the_exchanges_after_two_warm_ups(monkeypatch):
    """The whole meta-iteration on its processes, plain and profiled in turn after two warm-ups (one of
    each, 1 s and 0.9 s inside 9 exchanges: counted in neither). Plain: 80 and 60 ms (iteration_ms 70);
    profiled: 3 exchanges of 4 ms, then 5 of 3.6 ms (exchange_ms 15, 4 per iteration). The pool is closed."""
    clock, events = Clock(), []
    work = [(1.0, 3, 0.1), (1.0, 9, 0.1), (0.050, 3, 0.010), (0.0, 3, 0.004), (0.030, 3, 0.010), (0.0, 5, 0.0036)]

    def exchange():
        clock.take(exchange.seconds)

    def meta_gradient(params, adapt, evaluate, pool):
        assert isinstance(pool, Pool) and adapt[0].shape == (2, 20, 32, 32, 3)
        compute, count, exchange.seconds = work.pop(0)
        clock.take(compute)
        for _ in range(count):
            exchange()
    method = SimpleNamespace(cfg=SimpleNamespace(meta_batch=2), make_pool=lambda: Pool(events),
                             meta_gradient=meta_gradient)
    monkeypatch.setattr(breakdown, "EXCHANGE", [exchange])
    monkeypatch.setattr(breakdown, "time", SimpleNamespace(perf_counter=clock))
    monkeypatch.setattr(breakdown, "cProfile", SimpleNamespace(Profile=lambda: cProfile.Profile(clock)))
    result = breakdown._exchanges(method, {}, np.random.default_rng(0), 20, 32, 2)
    assert result == {"iteration_ms": 70.0, "exchange_ms": 15.0, "exchanges_per_iteration": 4}
    assert events == [("pool",), ("close",)]


@pytest.mark.parametrize("adapts, run_s", [(True, 60.0), (False, 36.0)])
def test_breakdown_prices_a_figure_2_runs_rollouts(monkeypatch, adapts, run_s):
    """Adapting to a demo takes 50 ms, a forward pass 2 ms, a rollout of 20 steps 0.1 s (5 ms a step). A
    Figure 2 run scores 240 trials (5 on each of 48 test colours), MIL's twice (adapted and not), each
    adapted once: (2 x 240 x 20 x 5 + 240 x 50) ms = 60 s; a baseline's once: 36 s."""
    clock, rolled = Clock(), []

    def policy(image, state, scene):
        assert image.shape == (1, 32, 32, 3) and state.shape == (1, 6) and scene is None
        clock.take(0.002)

    def condition(demo):
        assert [a.shape for a in demo] == [(20, 32, 32, 3), (20, 6), (20, 2)]
        clock.take(0.050)
        return policy

    def rollout(p, world, seed):
        assert p is policy and world.config.horizon == 20
        rolled.append(seed)
        clock.take(0.1)
    method = SimpleNamespace(adapts=adapts, conditioner=lambda params: condition)
    demos = maml.synthetic_demos(np.random.default_rng(0), 2, 20, 32)
    monkeypatch.setattr(breakdown, "time", SimpleNamespace(perf_counter=clock))
    monkeypatch.setattr(breakdown.imitation, "rollout", rollout)
    result = breakdown._rollouts(method, {}, SimpleNamespace(image_size=32), demos, 2)
    assert result == {"rollout_step_ms": 5.0, "rollout_forward_ms": 2.0, "adapt_one_demo_ms": 50.0,
                      "figure2_run_rollouts_s": run_s}
    assert rolled == [0, 1]


def test_the_expert_benchmark_plans_each_seeded_scene_of_both_splits(monkeypatch):
    """Scene i is seeded seed + i, of validation colours when i % 4 == 0, else of training colours; iLQG
    plans to its target and the expert runs in it. Plans of 5, 1, 3, 2 and 4 s: median 3 s, 90th
    percentile 4.6 s (between the 4th and 5th sorted values, 0.6 of the way); 4 successes of 5."""
    clock, planned, demonstrated = Clock(), [], []
    durations, outcomes = [5.0, 1.0, 3.0, 2.0, 4.0], [True, False, True, True, True]

    def plan(state, target, arm, horizon):
        planned.append(tuple(target))
        clock.take(durations[len(planned) - 1])
        return SimpleNamespace(iterations=10 * len(planned))

    def demonstrate(world, seed):
        demonstrated.append((world.config.split, seed))
        return {"success": outcomes[len(demonstrated) - 1]}
    monkeypatch.setattr(expert.controller, "plan", plan)
    monkeypatch.setattr(expert.controller, "demonstrate", demonstrate)
    monkeypatch.setattr(expert, "time", SimpleNamespace(perf_counter=clock))
    result = expert.bench_expert(scenes=5, seed=7)
    splits = ["validation", "train", "train", "train", "validation"]
    assert demonstrated == list(zip(splits, range(7, 12)))
    assert planned == [tuple(ReachWorld(WorldConfig(split=s)).reset(seed=7 + i)[1]["target_position"])
                       for i, s in enumerate(splits)]
    assert result == {"scenes": 5, "expert_successes": 4, "expert_success_rate": 0.8, "ilqg_solve_s_median": 3.0,
                      "ilqg_solve_s_p90": pytest.approx(4.6), "ilqg_iterations_median": 30.0}


def test_collect_benchmark_rounds_demos_up_to_whole_colours(monkeypatch):
    """100 demos over the 36 training colours: 3 per colour, 108 demos, collected in 12.5 s: 8.6 a
    second; workers None is every core."""
    clock, asked = Clock(), {}

    def collect(tasks, per_task, split, seed, workers, progress):
        asked.update(tasks=tasks, per_task=per_task, split=split, workers=workers)
        clock.take(12.5)
        return {"metadata": {"expert_success_rate": 0.99}}
    monkeypatch.setattr(expert.collection, "collect", collect)
    monkeypatch.setattr(expert, "time", SimpleNamespace(perf_counter=clock))
    monkeypatch.setattr(expert, "os", SimpleNamespace(cpu_count=lambda: 6))
    assert expert.bench_collect(100) == {"demos": 108, "workers": 6, "seconds": 12.5, "demos_per_second": 8.6,
                                         "expert_success_rate": 0.99}
    assert asked == {"tasks": 36, "per_task": 3, "split": "train", "workers": None}


@pytest.mark.parametrize("workers, expected", [(["--workers", "8"], 2), (["--workers", "1"], 1), ([], 2)])
def test_benchmark_collect_checks_the_memory_of_what_it_collects_on_at_most_the_cores(
        monkeypatch, capsys, workers, expected):
    """`benchmark collect --demos 100` checks the memory of 3 demos of each of the 36 colours (108, not
    72) before it starts, and runs on at most the 2 cores; the result names the peak memory of this
    process and of its workers, each in its place."""
    asked, world = {}, WorldConfig()
    monkeypatch.setattr(benchmark, "bench_collect", lambda demos, workers: asked.update(demos=demos, workers=workers)
                        or {})
    monkeypatch.setattr(benchmark.cli, "check_memory", lambda need, what, fix: asked.update(need=need, what=what))
    monkeypatch.setattr(benchmark, "os", SimpleNamespace(cpu_count=lambda: 2))
    monkeypatch.setattr(benchmark.host, "peak_memory_mb", lambda: (12.34, 56.78))
    benchmark.main(["collect", "--demos", "100", *workers])
    result = json.loads(capsys.readouterr().out)
    assert asked == {"demos": 100, "workers": expected, "what": "100 demos",
                     "need": cli.dataset_bytes(36, 3, world.horizon, world.image_size, world.n_objects)}
    assert (result["peak_memory_mb"], result["peak_worker_memory_mb"]) == (12.3, 56.8)


def test_benchmark_maml_refuses_a_missing_peer_and_a_peers_breakdown_before_any_work(monkeypatch, capsys):
    """A peer that cannot be imported is named with what to install, as --peer's error; --peer with
    --breakdown is refused (a peer times whole meta-iterations). Neither benchmark starts."""
    ran = []
    monkeypatch.setattr(peers, "available", lambda peer: False)
    monkeypatch.setattr(benchmark, "bench_meta_iteration", lambda *args, **kw: ran.append(args) or {})
    monkeypatch.setattr(benchmark, "bench_breakdown", lambda *args, **kw: ran.append(args) or {})
    for argv, message in ((["--peer", "torch"], "argument --peer: PyTorch is not installed"),
                          (["--peer", "jax", "--breakdown"], "--peer times whole meta-iterations; drop --breakdown")):
        with pytest.raises(SystemExit) as exit_:
            benchmark.main(["maml", *argv])
        assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert ran == []


def test_peers_are_named_and_their_pixel_positions_are_ours():
    """An unknown peer is refused with the known ones; `_positions` is spatial_soft_argmax's grid, row-major:
    for 2 rows of 3, x = -1, 0, 1 on each row and y = -1 on the first, 1 on the second."""
    with pytest.raises(ValueError, match=r"peer must be one of \['jax', 'torch'\]; got 'tf'"):
        peers.require("tf")
    xs, ys = peers._positions(2, 3)
    np.testing.assert_array_equal(xs, [-1, 0, 1, -1, 0, 1])
    np.testing.assert_array_equal(ys, [-1, -1, -1, 1, 1, 1])


@pytest.mark.parametrize("given", ["position", "colour"])
def test_privileged_gives_the_policy_its_demos_target_in_training_and_its_scenes_in_trials(
        monkeypatch, tiny_split_datasets, given):
    """Behavioural cloning is given, on every frame of each demo of a batch, that demo's target: its
    position / 0.2 after the 6 state values, or its colour's RGB in [0, 1] after the 3 channels of every
    pixel (read back from the dataset: the demo is found by its states or images). The trials, in new
    scenes of validation colours seeded by --seed (as evaluate's), give the scene's target. 2 of 3 trials
    won: 2/3."""
    path, seed, bc, trials = tiny_split_datasets["train"], 3, [], []
    ds = datasets.load(path)
    world_cfg = datasets.world_config(ds["metadata"])
    images, states, _ = imitation.prepare_demos(ds["images"], ds["states"], ds["actions"], world_cfg.arm.max_torque)
    rgb = palette.palette_rgb(world_cfg.palette) / 255

    def recorder(loss):
        return lambda params, im, st, act: bc.append((im, st)) or {k: np.zeros_like(v) for k, v in params.items()}

    def forward(params, im, st):
        trials[-1]["inputs"] = (im, st)
        return np.zeros((1, 2), np.float32)

    def rollout(policy, world, scene_seed):
        obs, info = world.reset(seed=scene_seed)
        trials.append({"split": world.config.split, "seed": scene_seed, "scene": info["scene"]})
        policy(imitation.images_to_float(obs["image"])[None], np.zeros((1, 6), np.float32), info["scene"])
        return {"success": len(trials) != 2}
    monkeypatch.setattr(privileged, "grad", recorder)
    monkeypatch.setattr(privileged.network, "forward", forward)
    monkeypatch.setattr(privileged.imitation, "rollout", rollout)
    result = privileged.bench_privileged(given, steps=2, batch=4, trials=3, seed=seed, train_data=path)
    n, k, T = states.shape[:3]
    assert len(bc) == 2
    for im, st in bc:
        assert im.shape == (4 * T, 32, 32, 6 if given == "colour" else 3)
        assert st.shape == (4 * T, 8 if given == "position" else 6)
        for b in range(4):
            frames = slice(b * T, (b + 1) * T)
            (i, j), = [(i, j) for i in range(n) for j in range(k) if np.array_equal(st[frames, :6], states[i, j])
                       and np.array_equal(im[frames, ..., :3], images[i, j])]
            if given == "position":
                target = ds["positions"][i, j, int(ds["target_index"][i, j])]
                np.testing.assert_allclose(st[frames, 6:], np.broadcast_to(target / 0.2, (T, 2)), rtol=1e-6)
            else:
                np.testing.assert_allclose(im[frames, ..., 3:], np.broadcast_to(rgb[int(ds["task_colours"][i])],
                                                                                (T, 32, 32, 3)), rtol=1e-6)
    assert [(t["split"], t["seed"]) for t in trials] == [("validation", imitation.trial_seed(seed, 0, j))
                                                         for j in range(3)]
    for t in trials:
        im, st = t["inputs"]
        if given == "position":
            np.testing.assert_allclose(st[0, 6:], t["scene"].target_position / 0.2, rtol=1e-6)
        else:
            np.testing.assert_allclose(im[0, ..., 3:], np.broadcast_to(rgb[t["scene"].target_colour], (32, 32, 3)),
                                       rtol=1e-6)
    assert (result["validation_trials"], result["validation_success"]) == (3, 2 / 3)
    assert result["ci95"] == wilson_interval(2, 3)


def test_privileged_names_what_it_can_be_given_before_loading_anything(tmp_path):
    """A typo in `given` (called from Python: the command's choices catch it there) is refused first,
    not as a missing dataset or a shape error several steps in."""
    with pytest.raises(ValueError, match="given must be 'position' or 'colour'; got 'target'"):
        privileged.bench_privileged("target", 1, train_data=str(tmp_path / "missing.npz"))
