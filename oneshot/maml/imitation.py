"""One-shot imitation (paper Section III): behavioural cloning as MAML's task loss, and meta-test.

Meta-training (Section III-A): a task is one target colour; its data are demonstrations. For each
task of a meta-batch, adapt on one demo with eq. (1) and score the adapted policy with eq. (2) on a
second demo of the same task. Meta-test (Section III-B): given ONE demo of a new colour, adapt, then
run the adapted policy in the world, in a new scene (new positions) with the same target colour.

Units: the network sees images in [0, 1], states divided by STATE_SCALE and predicts torques divided
by the torque bound, so every input and output is of order one.
"""
import numbers

import autograd.numpy as anp
import numpy as np
from tqdm import tqdm

from oneshot.maml import inner
from oneshot.data.datasets import world_config
from oneshot.policy import inputs
from oneshot.tools.checks import real_number, whole_number
from oneshot.policy.network import STRIDE, forward, images_to_float
from oneshot.world.palette import hue_distance_deg
from oneshot.world.reach import ReachWorld, closest_object, is_success, observation_state

# joint angles (rad), joint velocities (rad/s), end effector (m) -> order one
STATE_SCALE = np.array([np.pi, np.pi, 10.0, 10.0, 0.2, 0.2], np.float32)


def prepare_demos(images, states, actions, max_torque):
    """Dataset arrays -> network units. images (..., T, H, W, 3) uint8, states (..., T, 6),
    actions (..., T, 2) N m -> (images float32 in [0, 1], states / STATE_SCALE, actions / max_torque)."""
    fix = "the arm's torque bound in N m > 0 (the dataset's world: ArmConfig.max_torque, 0.5 by default)"
    if real_number("max_torque", max_torque, f"pass {fix}") <= 0:
        raise ValueError(f"max_torque must be {fix}; got {max_torque!r}")
    images, states, actions = np.asarray(images), np.asarray(states), np.asarray(actions)
    if images.ndim < 4:
        raise ValueError(f"images must be (..., T, H, W, 3) uint8, a demo's frames; got {images.shape}")
    for name, a, last in (("states", states, 6), ("actions", actions, 2)):
        if a.shape[-1] != last or a.shape[:-1] != images.shape[:-3]:
            raise ValueError(f"{name} must be {images.shape[:-3] + (last,)} to match images "
                             f"{images.shape}; got {a.shape}")
    return (images_to_float(images), (states / STATE_SCALE).astype(np.float32),
            (actions / np.float32(max_torque)).astype(np.float32))


def imitation_loss(params, demo):
    """Paper eq. (2): the behavioural-cloning loss, summed over the demo's frames.

        L(theta, d) = sum_t || pi_theta(o_t) - u_t ||^2

    demo: (images (T, H, W, 3) float32, states (T, 6), actions (T, 2)), in network units.
    With a leading task axis on the demo and the params (MAML's batched meta-objective), the sum also
    runs over tasks, which gives each task's own gradient with respect to its own parameter copy.
    """
    images, states, actions = demo
    residual = forward(params, images, states) - actions
    return anp.sum(residual * residual)


def sample_meta_batch(demos, rng, meta_batch=5):
    """A meta-batch: `meta_batch` tasks, and for each two different demos (adapt, evaluate).

    demos: (images (N, K, T, H, W, 3), states (N, K, T, 6), actions (N, K, T, 2)) in network units.
    Returns (adapt, evaluate), each a tuple of arrays with a leading task axis of size meta_batch.
    """
    n, k = demos[0].shape[:2]
    tasks = rng.choice(n, meta_batch, replace=meta_batch > n)
    pairs = np.array([rng.choice(k, 2, replace=False) for _ in tasks])
    adapt = tuple(a[tasks, pairs[:, 0]] for a in demos)
    evaluate = tuple(a[tasks, pairs[:, 1]] for a in demos)
    return adapt, evaluate


class PolicyDiverged(ValueError):
    """A policy's torques are NaN or inf: its checkpoint diverged (bad input, so a ValueError)."""


def adapt(params, demo, alpha, steps, **options):
    """One-shot adaptation (eq. 1 with eq. 2 as its loss) to a single demo (images, states, actions) in
    network units: `inner.inner_update`, whose options (first_order, only, ...) pass through. The step
    and its count have no default: a policy adapts as it was meta-trained (a checkpoint's method knows
    how: `methods.of(cfg).conditioner(params)`), and the paper's 3 steps of 0.001 on every parameter
    took the shipped policy, trained with 1 step of 0.3 on its first convolution, from 20/24 trials to 2/24
    (12 validation colours x 2, seed 0). The demo
    is checked first (`inputs.check_adapt_demo`): camera images in 0..255, say, would make a step 255 times
    too large and a policy that fails without saying why."""
    return inner.inner_update(params, inputs.check_adapt_demo(params, demo, STRIDE), imitation_loss, alpha, steps,
                              **options)


def act(policy, obs, max_torque, scene=None):
    """The policy's torques (2,) N m for one observation of the world.

    policy: a parameter dict (the network acts: `forward(params, image, state)`), or a function
    policy(image (1, H, W, 3), state (1, 6), scene) -> (1, 2) in network units (the baselines, or a
    network given more than it sees: `benchmark privileged`). scene: the episode's Scene, for it.
    """
    image = images_to_float(obs["image"])[None]
    state = (observation_state(obs) / STATE_SCALE)[None]
    action = policy(image, state, scene) if callable(policy) else forward(policy, image, state)
    action = np.asarray(action)[0].astype(np.float64) * max_torque
    if not np.all(np.isfinite(action)):
        raise PolicyDiverged(f"the policy's torques are {action} (not finite): its parameters, or the ones "
                             f"adapting to a demo made, overflow; use an earlier checkpoint (or a smaller --alpha)")
    return action


def rollout(policy, world, seed, target_colour=None):
    """Run a policy (as in `act`) for one episode in a new scene of `target_colour` (None: a random
    colour of the world's split, drawn from `seed`).

    Returns {"success": bool, "images": (T, H, W, 3) uint8, "end_effector": (T, 2), "scene": Scene}.
    """
    options = {} if target_colour is None else {"target_colour": target_colour}   # the world checks it
    obs, info = world.reset(seed=seed, options=options)
    images, ee = [], []
    for _ in range(world.config.horizon):
        images.append(obs["image"])
        obs, _, _, _, info = world.step(act(policy, obs, world.config.arm.max_torque, info["scene"]))
        ee.append(obs["end_effector"])
    return {"success": is_success(ee, info["target_position"], world.config.success_radius),
            "images": np.stack(images), "end_effector": np.stack(ee), "scene": info["scene"]}


def one_shot_trial(params, demo, world, seed, target_colour, alpha, steps, **options):
    """Meta-test (Section III-B): adapt on ONE demo (network units; `adapt`), then act in a new scene."""
    return rollout(adapt(params, demo, alpha, steps, **options), world, seed, target_colour)


TRIAL_SEED_OFFSET = 1_000_003   # trial scenes never reuse a dataset's scene seeds (those are 63-bit hashes)
SPLIT_TAGS = {"train": 1, "validation": 2, "test": 3}


def trial_seed(seed, task, trial, split="validation"):
    """The scene seed of trial `trial` of task `task` at meta-test, scored on colours of `split`: the one
    function that makes them (evaluate, demo, training's validation checks, the experiments).

    Distinct for every (split, seed, task, trial) of non-negative ints, and from every dataset's scene
    seeds. The test split's seeds are its own, so that no choice made on validation scenes has seen a
    test scene; training and validation colours keep the seeds every number before the test split was
    measured with (TRIAL_SEED_OFFSET + seed 100000 + task 1000 + trial, for task < 100 and trial < 1000).
    """
    for name, n in (("seed", seed), ("task", task), ("trial", trial)):
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 0:
            raise ValueError(f"trial seeds need a non-negative int {name}; got {n!r}")
    if split not in SPLIT_TAGS:
        raise ValueError(f"trial seeds are for the splits {', '.join(SPLIT_TAGS)}; got {split!r}")
    if split != "test" and task < 100 and trial < 1000 and seed < 2 ** 40:
        return TRIAL_SEED_OFFSET + seed * 100_000 + task * 1000 + trial
    # Above 2^64 (beyond the numbers above and every 63-bit dataset seed), an injective pairing.
    return 2 ** 64 + _pair(SPLIT_TAGS[split], _pair(_pair(int(seed), int(task)), int(trial)))


def _pair(a, b):
    """Cantor's pairing: a different non-negative int for every pair of non-negative ints."""
    return (a + b) * (a + b + 1) // 2 + b


def farthest_hue_tasks(task_colours, palette_cfg):
    """For each task, another task whose colour's hue is farthest from its own: task_colours (n,)
    palette indices, n >= 2 -> (n,) task indices, never the task itself. Of tasks equally far (in the
    grid palette every colour of the opposite hue), the first after it in the tasks' cyclic order, so
    that the tasks of one hue are shown different colours' demonstrations."""
    colours = np.asarray(task_colours)
    n = len(colours)
    if n < 2:
        raise ValueError(f"another task needs 2 tasks or more; got {n}")
    distance = hue_distance_deg(colours[:, None], colours[None, :], palette_cfg)
    np.fill_diagonal(distance, -1.0)                      # another task, even if every hue is the same
    after = (np.arange(n)[None, :] - np.arange(n)[:, None]) % n          # how far task j comes after task i
    farthest = distance == distance.max(axis=1, keepdims=True)
    return np.argmin(np.where(farthest, after, n), axis=1)


def one_shot_success(condition, dataset, trials_per_colour=10, seed=0, progress=True, demo_scenes=False,
                     other_colour_demo=False):
    """Meta-test over a dataset (Section III-B, scored as in Section IV): for each task (colour) of
    `dataset`, `trials_per_colour` trials; trial j conditions the policy on demo j % K of that task
    and runs it in a fresh scene of that colour (`trial_seed`).

    demo_scenes: run trial j instead in the recorded scene of the task's demo (j + 1) % k, k = min(K,
    trials_per_colour): another of the demos the trials adapt on (the same positions and colours). On meta-training data this asks whether a
    policy has learnt the task or memorised its training scenes (docs/results.md, section 10).

    other_colour_demo: condition trial j of task i on demo j of the task whose hue is farthest from
    task i's (`farthest_hue_tasks`), and still score it on task i's target: the control for what the
    demonstration carries. A policy that reads the colour from the demonstration should now fail (it
    looks for a disc of another colour: it reaches the target about as often as it would by picking a
    disc at random); one that knows the scene without the demonstration should not.

    condition(demo) -> policy: what one demonstration (network units) makes of the policy, e.g.
    `lambda demo: adapt(params, demo, alpha, steps, only=only)` for MIL (eq. 1), `lambda demo: params` for
    the unadapted policy, a baseline's conditioned policy (`methods.of(cfg).conditioner(params)`).
    Returns {"successes", "trials", "rate", "per_colour": {colour: rate}, "failures": {"near_miss": n,
    "wrong_object": m}}: a failed trial is a near miss when the end effector's closest object over the
    final fifth was the target, else it went to a distractor.
    """
    if whole_number("trials_per_colour", trials_per_colour, "pass a count >= 1") < 1:
        raise ValueError(f"trials_per_colour must be an int >= 1; got {trials_per_colour!r}")
    meta = dataset["metadata"]
    world_cfg = world_config(meta)
    world = ReachWorld(world_cfg)
    n, k = dataset["images"].shape[:2]
    shown = (farthest_hue_tasks(dataset["task_colours"], world_cfg.palette) if other_colour_demo else
             np.arange(n))                                # the task whose demos condition each task's trials
    if demo_scenes and not 2 <= trials_per_colour <= k:   # else a trial replays another, or its own demo's scene
        raise ValueError(f"demo scenes need 2 <= trials per colour <= the {k} demos per colour of the "
                         f"{meta['split']} dataset; got {trials_per_colour}")
    k = min(k, trials_per_colour)                     # only these demos are used: convert just them
    scene_seed = ((lambda i, j: int(dataset["seeds"][i, (j + 1) % k])) if demo_scenes else
                  (lambda i, j: trial_seed(seed, i, j, meta["split"])))
    demos = prepare_demos(dataset["images"][:, :k], dataset["states"][:, :k], dataset["actions"][:, :k],
                          world_cfg.arm.max_torque)
    wins, per_colour, failures = 0, {}, {"near_miss": 0, "wrong_object": 0}
    bar = tqdm(total=n * trials_per_colour, desc=f"one-shot trials ({meta['split']})", disable=not progress)
    # A diverged policy overflows: `act` raises PolicyDiverged, so numpy's warnings would only add noise.
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            for i in range(n):
                colour, won = int(dataset["task_colours"][i]), 0
                for j in range(trials_per_colour):
                    policy = condition(tuple(a[shown[i], j % k] for a in demos))
                    trial = rollout(policy, world, scene_seed(i, j), colour)
                    won += trial["success"]
                    if not trial["success"]:
                        closest, _ = closest_object(trial["end_effector"], trial["scene"].positions)
                        failures["near_miss" if closest == trial["scene"].target else "wrong_object"] += 1
                    bar.update()
                per_colour[colour] = won / trials_per_colour
                wins += won
    except BaseException:
        bar.leave = False                         # wipe the half-drawn bar: the error is the line left
        raise
    finally:
        bar.close()
    trials = n * trials_per_colour
    return {"successes": wins, "trials": trials, "rate": wins / trials, "per_colour": per_colour,
            "failures": failures}
