"""Section III on the real network: eq. (2), the batched meta-objective, and second-order MAML,
against independent references (per-task loops and finite differences)."""
import colorsys
import dataclasses
import types

import numpy as np
import pytest
from autograd import grad

from helpers import assert_batched_equals_loop
from oneshot import methods
from oneshot.expert import controller
from oneshot.maml import batched, imitation, inner
from oneshot.policy import network
from oneshot.maml.inner import InnerLoop
from oneshot.world import palette
from oneshot.world.reach import ReachWorld, WorldConfig

CFG = network.NetworkConfig(image_size=8, channels=(3, 4), hidden=(5, 5))


def _demos(rng, B=None, T=3, dtype=np.float64):
    lead = (T,) if B is None else (B, T)
    return (rng.random(lead + (8, 8, 3)).astype(dtype), rng.normal(size=lead + (6,)).astype(dtype),
            rng.normal(size=lead + (2,)).astype(dtype))


def test_imitation_loss_is_the_summed_squared_error_frame_by_frame(rng):
    params = network.init_params(CFG, rng, dtype=np.float64)
    images, states, actions = _demos(rng)
    expected = sum(np.sum((network.predict(params, images[t:t + 1], states[t:t + 1])[0] - actions[t]) ** 2)
                   for t in range(3))
    assert imitation.imitation_loss(params, (images, states, actions)) == pytest.approx(expected, rel=1e-12)


def test_batched_meta_objective_equals_the_per_task_loop(rng):
    params = network.init_params(CFG, rng, dtype=np.float64)
    adapt, evaluate = _demos(rng, B=3), _demos(rng, B=3)
    for first_order in (False, True):
        assert_batched_equals_loop(params, adapt, evaluate, imitation.imitation_loss, 0.01, 2, first_order=first_order)


def test_adapting_only_the_convolutions_leaves_the_rest_and_matches_the_loop(rng):
    params = network.init_params(CFG, rng, dtype=np.float64)
    adapt, evaluate = _demos(rng, B=3), _demos(rng, B=3)
    adapted = imitation.adapt(params, tuple(a[0] for a in adapt), 0.05, 2, only=("conv",))
    for k in params:
        assert (np.array_equal(adapted[k], params[k])) != k.startswith("conv"), k
    # batched (non-adapted parameters shared across tasks) == per-task loop, value and gradient
    (v1, _), _ = assert_batched_equals_loop(params, adapt, evaluate, imitation.imitation_loss, 0.05, 2,
                                            only=("conv",))
    # and it is a different objective from adapting everything
    tasks = [(tuple(a[b] for a in adapt), tuple(e[b] for e in evaluate)) for b in range(3)]
    v_all, _ = inner.meta_gradient(params, tasks, imitation.imitation_loss, 0.05, 2)
    assert v_all != pytest.approx(v1, rel=1e-6)
    with pytest.raises(ValueError, match="no parameter starts with"):
        imitation.adapt(params, tuple(a[0] for a in adapt), 0.05, 1, only=("nothing",))


def test_second_order_meta_gradient_matches_finite_differences(rng):
    params = network.init_params(CFG, rng, dtype=np.float64)
    adapt, evaluate = _demos(rng, B=2), _demos(rng, B=2)
    alpha, steps = 0.05, 3          # a large step so second-order terms matter

    def f(p):
        return batched.meta_objective_batched(p, adapt, evaluate, imitation.imitation_loss, InnerLoop(alpha, steps))

    _, g = batched.meta_gradient_batched(params, adapt, evaluate, imitation.imitation_loss, InnerLoop(alpha, steps))
    _, g_first = batched.meta_gradient_batched(params, adapt, evaluate, imitation.imitation_loss, InnerLoop(alpha, steps, True))
    eps = 1e-5
    for _ in range(3):
        d = {k: rng.normal(size=v.shape) for k, v in params.items()}
        fd = (f({k: params[k] + eps * d[k] for k in params}) - f({k: params[k] - eps * d[k] for k in params})) / (2 * eps)
        analytic = sum(np.sum(g[k] * d[k]) for k in params)
        first = sum(np.sum(g_first[k] * d[k]) for k in params)
        assert analytic == pytest.approx(fd, rel=1e-6)
        assert abs(first - fd) > 1e-4 * abs(fd)       # the first-order shortcut is measurably different


def test_first_order_meta_gradient_is_the_plain_gradient_at_the_adapted_parameters(rng):
    params = network.init_params(CFG, rng, dtype=np.float64)
    adapt, evaluate = _demos(rng, B=2), _demos(rng, B=2)
    _, g = batched.meta_gradient_batched(params, adapt, evaluate, imitation.imitation_loss, InnerLoop(0.05, 3, True))
    expected = {k: 0.0 for k in params}
    for b in range(2):
        p = params
        for _ in range(3):                            # eq. (1) written out by hand
            gb = grad(imitation.imitation_loss)(p, tuple(a[b] for a in adapt))
            p = {k: p[k] - 0.05 * gb[k] for k in p}
        ge = grad(imitation.imitation_loss)(p, tuple(e[b] for e in evaluate))
        expected = {k: expected[k] + ge[k] / 2 for k in params}
    for k in params:
        np.testing.assert_allclose(g[k], expected[k], rtol=1e-9, atol=1e-12)


def test_adaptation_lowers_the_loss_and_alpha_zero_changes_nothing(rng):
    params = network.init_params(network.NetworkConfig(), rng)          # the real float32 network
    images = rng.random((20, 32, 32, 3), dtype=np.float32)
    demo = (images, rng.normal(size=(20, 6)).astype(np.float32), rng.normal(size=(20, 2)).astype(np.float32))
    before = imitation.imitation_loss(params, demo)
    after = imitation.imitation_loss(imitation.adapt(params, demo, alpha=0.001, steps=3), demo)
    assert after < before
    same = imitation.adapt(params, demo, alpha=0.0, steps=3)
    assert all(np.array_equal(same[k], params[k]) for k in params)
    adapted = imitation.adapt(params, demo, 0.001, 3)
    assert all(adapted[k].dtype == np.float32 for k in adapted)
    with pytest.raises(TypeError):           # no default step: a policy adapts as it was meta-trained
        imitation.adapt(params, demo)


def test_batched_meta_gradient_keeps_float32(rng):
    params = network.init_params(CFG, rng)
    adapt, evaluate = _demos(rng, B=2, dtype=np.float32), _demos(rng, B=2, dtype=np.float32)
    value, g = batched.meta_gradient_batched(params, adapt, evaluate, imitation.imitation_loss, InnerLoop(0.001, 3))
    assert np.asarray(value).dtype == np.float32
    assert all(v.dtype == np.float32 for v in g.values())


def test_prepare_demos_scales_and_rejects_mismatched_shapes(rng):
    images = rng.integers(0, 256, (2, 20, 32, 32, 3), dtype=np.uint8)
    states, actions = np.ones((2, 20, 6), np.float32), np.full((2, 20, 2), 0.5, np.float32)
    im, st, ac = imitation.prepare_demos(images, states, actions, max_torque=0.5)
    assert im.dtype == np.float32 and im.max() <= 1.0
    np.testing.assert_allclose(st[0, 0], 1 / imitation.STATE_SCALE)
    np.testing.assert_allclose(ac, 1.0)
    with pytest.raises(ValueError, match="actions must be"):
        imitation.prepare_demos(images, states, actions[:, :-1], 0.5)
    for torque in (0, -0.5, np.inf, "0.5", True):               # 0 made infinite actions, with a warning
        with pytest.raises(ValueError, match="max_torque must be (a finite number|the arm's torque bound in N m > 0)"):
            imitation.prepare_demos(images, states, actions, torque)
    with pytest.raises(ValueError, match=r"images must be \(..., T, H, W, 3\) uint8, a demo's frames; got \(32, 32, 3\)"):
        imitation.prepare_demos(images[0, 0], states[0, 0], actions[0, 0], 0.5)
    with pytest.raises(ValueError, match="images_to_float expects uint8 images; got dtype int64"):   # lists: int64
        imitation.prepare_demos(images[0].tolist(), states[0].tolist(), actions[0].tolist(), 0.5)


def test_sample_meta_batch_pairs_two_different_demos_of_one_task(rng):
    N, K = 4, 3
    ids = np.arange(N * K, dtype=np.float32).reshape(N, K, 1, 1, 1, 1) * np.ones((1, 1, 2, 8, 8, 3), np.float32)
    demos = (ids, np.zeros((N, K, 2, 6), np.float32), np.zeros((N, K, 2, 2), np.float32))
    adapt, evaluate = imitation.sample_meta_batch(demos, rng, 3)
    a, e = adapt[0][:, 0, 0, 0, 0].astype(int), evaluate[0][:, 0, 0, 0, 0].astype(int)
    assert np.all(a // K == e // K) and np.all(a != e)          # same task, different demo
    assert len(set((a // K).tolist())) == 3                      # distinct tasks in the meta-batch


def test_learnt_step_sizes_batched_equals_the_per_task_loop(rng):
    params = network.init_params(CFG, rng, dtype=np.float64)
    params = {**params, **inner.init_step_sizes(params, 0.05, only=("conv0_",))}
    params[inner.STEP_PREFIX + "conv0_w"] = params[inner.STEP_PREFIX + "conv0_w"] * rng.uniform(0, 2, params["conv0_w"].shape)
    adapt, evaluate = _demos(rng, B=3), _demos(rng, B=3)
    _, (_, g2) = assert_batched_equals_loop(params, adapt, evaluate, imitation.imitation_loss, 0.0, 1,
                                            only=("conv0_",))
    assert np.abs(g2[inner.STEP_PREFIX + "conv0_w"]).max() > 0


def test_trial_seeds_are_distinct_and_the_ones_evaluation_always_used():
    """Every (seed, task, trial) of the documented range gets its own scene, and the seed is the formula
    evaluation used before `trial_seed` existed, so the shipped policy's meta-test scenes are unchanged."""
    seeds, tasks, trials = range(3), range(100), range(1000)
    got = np.array([[[imitation.trial_seed(s, i, j) for j in trials] for i in tasks] for s in seeds])
    s, i, j = np.meshgrid(seeds, tasks, trials, indexing="ij")
    np.testing.assert_array_equal(got, 1_000_003 + s * 100_000 + i * 1000 + j)
    assert len(np.unique(got)) == got.size == 300_000
    # far seeds stay apart from each other's trials too: the last trial of seed s, the first of seed s + 1
    for s in (0, 7, 12_345):
        assert imitation.trial_seed(s, 99, 999) < imitation.trial_seed(s + 1, 0, 0)


def test_trial_seeds_are_distinct_for_any_number_of_colours_and_trials_and_the_test_splits_are_its_own():
    """No hidden limit: 108 grid colours (or 10^6 trials) get seeds too, distinct from each other, from the
    seeds of the first 100 x 1000, and across splits; the test split never shares a seed with another."""
    splits = ("train", "validation", "test")
    seeds = {(split, s, i, j): imitation.trial_seed(s, i, j, split)
             for split in splits for s in (0, 1, 3) for i in (0, 7, 99, 100, 107, 5000) for j in (0, 9, 999, 1000, 10 ** 6)}
    assert len(set(seeds.values())) == len(seeds) - sum(1 for (split, s, i, j) in seeds     # train and validation
                                                        if split == "train" and i < 100 and j < 1000)   # share old seeds
    test = {v for k, v in seeds.items() if k[0] == "test"}
    assert not test & {v for k, v in seeds.items() if k[0] != "test"}
    assert min(test) >= 2 ** 64 > 2 ** 63 > max(imitation.trial_seed(s, 99, 999) for s in (0, 1, 3))
    assert imitation.trial_seed(0, 3, 4, "validation") == imitation.trial_seed(0, 3, 4) == 1_000_003 + 3004


@pytest.mark.parametrize("seed, task, trial, split", [(-1, 0, 0, "test"), (0, -1, 0, "validation"),
                                                      (0, 0, -1, "train"), (0, 0.5, 0, "test"), (0, 0, 0, "heldout")])
def test_trial_seed_refuses_what_is_not_a_count_or_a_split(seed, task, trial, split):
    with pytest.raises(ValueError, match="non-negative int|splits"):
        imitation.trial_seed(seed, task, trial, split)


@pytest.mark.parametrize("trials", [0, -1, 1.5, True])
def test_one_shot_success_refuses_a_count_of_trials_that_is_not_one_or_more(trials):
    with pytest.raises(ValueError, match=f"trials_per_colour must be an int( >= 1)?; got {trials!r}"):
        imitation.one_shot_success(lambda demo: None, {"metadata": {}}, trials)


@pytest.mark.parametrize("colour, message", [(4.7, "must be an int"), ("4", "must be an int"), (True, "must be an int")])
def test_rollout_lets_the_world_check_the_target_colour(colour, message):
    """Not int(colour): 4.7 and "4" were episodes of colour 4, and True was called colour 1."""
    world = ReachWorld(WorldConfig(split="validation"))
    with pytest.raises(ValueError, match=message):
        imitation.rollout(lambda image, state, scene: np.zeros((1, 2)), world, 0, colour)


def test_methods_of_asks_for_a_config_not_a_name():
    with pytest.raises(ValueError, match=r"methods.of takes a TrainConfig, e.g. TrainConfig\(method='mil'\)"):
        methods.of("mil")


def test_the_other_colour_demo_is_the_colour_farthest_in_hue():
    # `evaluate --other-colour-demo` conditions each task's trials on the demos of the task whose hue is
    # farthest from its own: checked against the hue distances computed here, in a shuffled order
    cfg = palette.PaletteConfig(mode="grid")
    colours = np.random.default_rng(0).permutation(palette.split_colours("test", cfg))
    chosen = imitation.farthest_hue_tasks(colours, cfg)
    hue = [colorsys.rgb_to_hsv(*(palette.palette_rgb(cfg)[c] / 255.0))[0] * 360 for c in colours]
    apart = lambda a, b: min(abs(a - b), 360 - abs(a - b))
    for i, j in enumerate(chosen):
        assert j != i and apart(hue[i], hue[j]) == pytest.approx(max(apart(hue[i], h) for h in hue), abs=1.0)
    assert all(apart(hue[i], hue[j]) > 90 for i, j in enumerate(chosen))                 # all far: above 90 deg
    assert len(set(chosen.tolist())) > len(colours) // 2       # ties broken across the opposite hue's colours
    one_hue = [c for c in colours if palette.colour_hue(c, cfg) == palette.colour_hue(colours[0], cfg)]
    assert len(one_hue) > 1 and all(j != i for i, j in enumerate(imitation.farthest_hue_tasks(one_hue, cfg)))
    with pytest.raises(ValueError, match="another task needs 2 tasks or more; got 1"):
        imitation.farthest_hue_tasks(colours[:1], cfg)


def _one_colour_dataset(k=1, T=20, split="validation"):
    world = WorldConfig(split=split)
    meta = {"split": split, "world": dataclasses.asdict(world)}
    colour = int(palette.split_colours(split)[0])
    return {"metadata": meta, "images": np.zeros((1, k, T, 32, 32, 3), np.uint8),
            "states": np.zeros((1, k, T, 6), np.float32), "actions": np.zeros((1, k, T, 2), np.float32),
            "task_colours": np.array([colour]), "seeds": np.zeros((1, k), np.int64)}


def test_failures_next_to_the_target_count_as_near_misses_not_as_a_distractor(monkeypatch):
    """Two failed trials that end 0.08 m from the target (the distractors 0.3 m away): both near misses."""
    positions = np.array([[0.2, 0.0], [-0.2, 0.1], [0.0, 0.3]])         # the target is object 0

    def rollout(policy, world, seed, colour):
        ee = np.tile(positions[0] + [0.0, 0.08], (20, 1))
        return {"success": False, "end_effector": ee, "scene": types.SimpleNamespace(target=0, positions=positions)}
    monkeypatch.setattr(imitation, "rollout", rollout)
    r = imitation.one_shot_success(lambda demo: None, _one_colour_dataset(), 2, progress=False)
    assert r["successes"] == 0 and r["failures"] == {"near_miss": 2, "wrong_object": 0}


def test_a_rollouts_policy_sees_what_prepare_demos_makes_of_a_recorded_demo_and_its_torques_are_scaled():
    """At meta-test the policy gets the units it was trained on: in the same scene, its first observation is
    prepare_demos' first frame of the expert's recorded demonstration (image in [0, 1], state / STATE_SCALE),
    and its action, in units of the torque bound, reaches the world multiplied by it (N m)."""
    world = ReachWorld(WorldConfig(split="validation"))
    demo = controller.demonstrate(world, seed=4)
    images, states, _ = imitation.prepare_demos(demo["images"], demo["states"], demo["actions"],
                                                world.config.arm.max_torque)
    seen, applied, step = [], [], world.step

    def policy(image, state, scene):
        seen.append((image, state))
        return np.array([[0.5, -1.0]])
    world.step = lambda action: applied.append(action) or step(action)
    imitation.rollout(policy, world, 4)
    np.testing.assert_array_equal(seen[0][0], images[:1])
    np.testing.assert_allclose(seen[0][1], states[:1], rtol=1e-6)
    np.testing.assert_allclose(applied[0], [0.5 * world.config.arm.max_torque, -world.config.arm.max_torque])


@pytest.mark.parametrize("split", ["train", "validation", "test"])
def test_each_trial_acts_in_the_scene_of_its_trial_seed_for_the_datasets_split(monkeypatch, split):
    """Trial j of task i runs in the scene trial_seed(seed, i, j, split) of the dataset's own split: the
    test split's scenes are its own (no choice made on validation scenes has seen one)."""
    played = []
    monkeypatch.setattr(imitation, "rollout", lambda policy, world, seed, colour: played.append(seed) or
                        {"success": True, "end_effector": None, "scene": None})
    imitation.one_shot_success(lambda demo: None, _one_colour_dataset(k=2, T=2, split=split), 3, seed=2, progress=False)
    assert played == [imitation.trial_seed(2, 0, j, split) for j in range(3)]
