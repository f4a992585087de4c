"""The demo: `python -m oneshot.demo [--out DIR] [--checkpoint PATH]`.

One-shot visual imitation, end to end (paper Sections III-IV):
  1. for every test colour (never seen in meta-training, nor by any choice made in developing the
     package: `oneshot.world.palette`) the iLQG expert records ONE demonstration;
  2. the meta-trained policy adapts to that demo by gradient descent (eq. 1; the default profile takes
     one step on its first convolution layer, docs/results.md);
  3. the adapted policy acts in new scenes of that colour (new positions, new distractors).
Prints the one-shot success rate (with a 95% interval) and the unadapted policy's for contrast, and
writes two pictures to DIR, the target ringed and the arm's base and hand marked in every frame:
  one_shot.png        for 4 test colours, the demo above the adapted policy's trial in a new scene,
                      each row labelled with the colour and the trial's outcome (a failure among them if
                      any trial failed);
  one_shot_trial.gif  one colour's demo, and the policy before and after adapting in the SAME new scene,
                      side by side (a scene where adapting made the difference, if there is one).

The policy is the pre-trained checkpoint shipped in `oneshot/pretrained/` (the default profile's
run in docs/results.md; reproduce it with `python -m oneshot.train --profile default`, seed 0), or
any checkpoint you pass.
"""
import argparse
import dataclasses
import os

import numpy as np
from tqdm import tqdm

from oneshot import methods
from oneshot.expert import controller
from oneshot.maml import imitation
from oneshot.tools import cli, host, viz
from oneshot.training import checkpoint, fit_check
from oneshot.world import palette
from oneshot.training.scoring import wilson_interval
from oneshot.world.reach import ReachWorld, WorldConfig, closest_object

PRETRAINED = os.path.join(os.path.dirname(__file__), "pretrained", "mil_default.npz")
SHOWN_COLOURS = 4           # test colours in the film strip, one trial each
SPLIT = "test"              # the colours the demo shows: never seen by training or by any choice
# The ways a trial fails, as `outcome` tells them apart.
NEAR_MISS, DISTRACTOR, ASTRAY = "missed: near miss", "missed: went to a distractor", "missed: near no disc"
LEFT = "missed: reached, then left"


def shown_trials(successes, n_shown=SHOWN_COLOURS):
    """Which trials the film strip shows: the first trial of each of the first `n_shown` colours, but
    at least one failed trial if any failed (the first failure, in its colour's row, or in the last row
    if its colour is not among them), so the picture does not show only the successes.

    successes: (colours, trials) bool. Returns n_shown (colour, trial) index pairs in colour order.
    """
    successes = np.asarray(successes, dtype=bool)
    shown = {i: 0 for i in range(min(n_shown, len(successes)))}
    failed = np.argwhere(~successes)                       # (failures, 2), in colour-major order
    if len(failed) and all(successes[i, j] for i, j in shown.items()):
        i, j = (int(v) for v in failed[0])
        if i not in shown:
            del shown[max(shown)]
        shown[i] = j
    return sorted(shown.items())


def contrast_trial(adapted, unadapted):
    """The trial the animation shows: the first where the policy reached the target after adapting and,
    before adapting, went to a distractor (or passed the target and left it: LEFT), else the first where
    adapting turned any miss into a success, else the first success after adapting, else the first
    trial. adapted, unadapted: (colours, trials) `outcome` strings of the same scenes. Returns (colour,
    trial) indices."""
    adapted, unadapted = np.asarray(adapted), np.asarray(unadapted)
    reached = adapted == "reached"
    elsewhere = np.isin(unadapted, (DISTRACTOR, LEFT))
    for candidates in (reached & elsewhere, reached & (unadapted != "reached"), reached):
        if candidates.any():
            return tuple(int(v) for v in np.argwhere(candidates)[0])
    return 0, 0


def outcome(trial, cfg=WorldConfig()):
    """A trial's caption: "reached" (paper Section IV success), or how it missed, judged like success on
    the final fifth of the episode (`oneshot.world.reach.closest_object`): NEAR_MISS if the hand came
    within half cfg.min_separation (0.06 m) of the target's centre, DISTRACTOR if of a distractor's, else
    ASTRAY (it stopped between or beyond the discs). Within that radius the hand is near one disc at most.
    But LEFT if the hand was ever within the success radius of the target (so, in a failed trial, before
    the final fifth, where one step within it is a success; the demo once
    said "went to a distractor" of an arm that came within 11 mm of its target and swung away).
    (`oneshot.maml.imitation.one_shot_success` counts failures by the closest disc alone, however far.)
    trial: {"success", "end_effector" (T, 2) m, "scene"}; cfg: the WorldConfig of the trial's world.
    """
    if trial["success"]:
        return "reached"
    scene = trial["scene"]
    if (np.linalg.norm(trial["end_effector"] - scene.positions[scene.target], axis=1) <= cfg.success_radius).any():
        return LEFT
    closest, distance = closest_object(trial["end_effector"], scene.positions)
    if distance > cfg.min_separation / 2:
        return ASTRAY
    return NEAR_MISS if closest == trial["scene"].target else DISTRACTOR


def film_strip(cfg, pairs):
    """The demo's film strip: for each (demo, trial) pair a row for the demonstration and, unless the trial
    is None, a row for the adapted policy's trial; each row labelled with the target colour's name and
    (trials) the outcome, the target ringed and the arm's base and hand marked in every frame
    (`viz.episode_marks`). cfg: the WorldConfig. Returns a PIL image."""
    rgb = palette.palette_rgb(cfg.palette)
    episodes, labels, swatches = [], [], []
    for demo, trial in pairs:
        colour = demo["scene"].target_colour
        name = palette.colour_name(colour, cfg.palette)
        for episode, what in ((demo, "demonstration"), (trial, "adapted, new scene")):
            if episode is not None:
                episodes.append(episode)
                labels.append(f"{name}\n{what}" + (f"\n{outcome(episode, cfg)}" if episode is trial else ""))
                swatches.append(rgb[colour])
    return viz.filmstrip([e["images"] for e in episodes], labels=labels, swatches=swatches,
                         group=2 if any(trial is not None for _, trial in pairs) else 1,
                         **viz.episode_marks(episodes, cfg))


def animation(cfg, demo, adapted, unadapted):
    """The demo's animation: the demonstration, and the policy before and after adapting in one new scene,
    side by side, the targets ringed and the arm's base and hand marked. cfg: the WorldConfig. Returns
    T PIL images."""
    name = palette.colour_name(demo["scene"].target_colour, cfg.palette)
    titles = [f"demonstration\n{name}", f"before adapting\n{outcome(unadapted, cfg)}",
              f"after adapting\n{outcome(adapted, cfg)}"]
    episodes = [demo, unadapted, adapted]          # the same new scene before and after adapting
    return viz.side_by_side([e["images"] for e in episodes], titles, **viz.episode_marks(episodes, cfg))


def main(argv=None):
    p = cli.Parser(prog="python -m oneshot.demo", description=__doc__,
                   formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=cli.writable_folder, default="demo_out",
                   help="folder for the pictures (default: demo_out; checked before the work)")
    p.add_argument("--checkpoint", default=None,
                   help="meta-trained policy (default: the shipped one; if that file is missing, the expert's "
                        "demos only)")
    p.add_argument("--trials", type=cli.positive_int, default=3, help="new scenes per test colour (default 3)")
    p.add_argument("--seed", type=cli.non_negative_int, default=0, help="seed of the demos and trial scenes")
    args = p.parse_args(argv)
    if args.checkpoint is not None:                  # a checkpoint asked for must be there
        ckpt = checkpoint.load(args.checkpoint)
    else:                                            # the shipped one may be missing: the demos alone
        args.checkpoint = PRETRAINED
        ckpt = checkpoint.load(PRETRAINED) if os.path.exists(PRETRAINED) else None
    for name in ("one_shot.png", "one_shot_trial.gif") if ckpt else ("expert_demos.png",):
        try:                                         # the pictures this run writes, checked before the work
            cli.writable_file(os.path.join(args.out, name))
        except argparse.ArgumentTypeError as e:
            p.error(f"argument --out: {e}")
    host.blas_threads(1)       # small products: OpenBLAS's spinning threads only slow them (`oneshot.tools.host`)
    if ckpt is not None and not methods.of(ckpt["config"]).adapts:
        raise ValueError(f"the demo shows a policy adapting to one demonstration (eq. 1); {args.checkpoint} holds "
                         f"a {ckpt['config'].method!r} policy, which does not adapt: score it with "
                         f"python -m oneshot.evaluate")
    # Demos like the ones the policy was meta-trained on (with the same DART noise, if any).
    expert_cfg = controller.ExpertConfig(action_noise=ckpt["config"].demo_noise if ckpt else 0.0)

    # 1. One expert demonstration per test colour, in the world the policy was trained in (its image
    # size, horizon, arm and palette; older checkpoints record only the image size and palette mode).
    world = ReachWorld(dataclasses.replace(fit_check.world_config(ckpt) if ckpt else WorldConfig(), split=SPLIT))
    colours = palette.split_colours(SPLIT, world.config.palette)
    print(f"1. The iLQG expert records ONE demonstration for each of the {len(colours)} {SPLIT} colours")
    demos = {}
    with tqdm(colours, desc="demonstrations", unit="demo", leave=False) as bar:   # closed, so wiped, on Ctrl-C
        for i, colour in enumerate(bar):
            d = controller.demonstrate(world, seed=args.seed * 1000 + i, options={"target_colour": int(colour)},
                                       cfg=expert_cfg)
            demos[int(colour)] = d
    print(f"   expert success: {sum(d['success'] for d in demos.values())}/{len(demos)}")

    if ckpt is None:
        print(f"no meta-trained policy at {args.checkpoint}; train one with "
              f"`python -m oneshot.train --profile default --run runs/default` and pass "
              f"--checkpoint runs/default/checkpoint.npz")
        viz.save_atomically(film_strip(world.config, [(d, None) for d in list(demos.values())[:SHOWN_COLOURS]]),
                            os.path.join(args.out, "expert_demos.png"))
        return None
    params, cfg = checkpoint.policy_params(ckpt), ckpt["config"]
    method = methods.of(cfg)
    max_torque = world.config.arm.max_torque

    # 2-3. Adapt on the one demo, act in new scenes; the unadapted policy for contrast.
    print(f"2. Adapt the meta-trained policy ({ckpt['iteration']} meta-iterations) to each demo: {method.describe()}")
    print(f"3. Run it in {args.trials} new scene{'s' * (args.trials != 1)} per colour (new positions, new distractors)")
    wins = base_wins = 0
    trials = {}                                            # (colour's position i, trial j) -> (adapted, unadapted)
    with tqdm(total=len(demos) * args.trials, desc="trials", unit="trial", leave=False) as bar:
        for i, (colour, d) in enumerate(demos.items()):
            demo = imitation.prepare_demos(d["images"], d["states"], d["actions"], max_torque)
            adapted = method.conditioner(params)(demo)
            for j in range(args.trials):
                seed = imitation.trial_seed(args.seed, i, j, SPLIT)     # trial scenes, seeded as evaluate's
                trials[i, j] = (imitation.rollout(adapted, world, seed, colour),
                                imitation.rollout(method.unadapted(params)(demo), world, seed, colour))  # unadapted
                wins += trials[i, j][0]["success"]
                base_wins += trials[i, j][1]["success"]
                bar.update(1)
    n = len(demos) * args.trials
    lo, hi = wilson_interval(wins, n)
    print(f"\none-shot success on {SPLIT} colours: {wins}/{n} = {wins / n:.2f} (95% CI {lo:.2f}-{hi:.2f})")
    print(f"the same policy without adaptation:   {base_wins}/{n} = {base_wins / n:.2f}")

    # 4. Pictures: a film strip of demos and adapted trials (a failure among them if there was one),
    #    and one scene played by the demo, the unadapted and the adapted policy.
    outcomes, unadapted_outcomes = (np.array([[outcome(trials[i, j][k], world.config)
                                               for j in range(args.trials)]
                                              for i in range(len(demos))]) for k in (0, 1))   # (colours, trials)
    shown = shown_trials(outcomes == "reached", SHOWN_COLOURS)
    strip, gif = os.path.join(args.out, "one_shot.png"), os.path.join(args.out, "one_shot_trial.gif")
    demo_list = list(demos.values())
    i, j = contrast_trial(outcomes, unadapted_outcomes)
    viz.save_together({                        # both drawn and encoded before either is written: a Ctrl-C
        strip: viz.encoded(film_strip(world.config, [(demo_list[a], trials[a, b][0]) for a, b in shown]), strip),
        gif: viz.gif_encoded(animation(world.config, demo_list[i], *trials[i, j]))})   # while drawing changes neither
    failures = sum(not trials[a, b][0]["success"] for a, b in shown)
    print(f"wrote {strip} (each demo above the adapted policy's trial in a new scene; "
          f"{len(shown) - failures} reached, {failures} missed)")
    name = palette.colour_name(list(demos)[i], world.config.palette)
    print(f"wrote {gif} ({name}, trial {j + 1} of {args.trials}: the demo, and the policy before and after "
          f"adapting in the same new scene)")
    return {"successes": wins, "trials": n, "unadapted_successes": base_wins}


if __name__ == "__main__":
    cli.run(main)
