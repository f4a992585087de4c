"""The demo: `python -m oneshot.demo [--out DIR] [--checkpoint PATH]`.

One-shot visual imitation, end to end (paper Sections III-IV):
  1. for every held-out colour (never seen in meta-training) the iLQG expert records ONE demonstration;
  2. the meta-trained policy adapts to that demo by gradient descent (eq. 1; the default profile takes
     one step on its first convolution layer, docs/results.md);
  3. the adapted policy acts in new scenes of that colour (new positions, new distractors).
Prints the one-shot success rate (with a 95% interval) and the unadapted policy's for contrast, and
writes pictures to DIR: the demo and the adapted policy side by side (PNG), and one trial (GIF).

The policy is the pre-trained checkpoint shipped in `oneshot/pretrained/` (the default profile's
run in docs/results.md; reproduce it with `python -m oneshot.train --profile default`, seed 0), or
any checkpoint you pass.
"""
import argparse
import os

from oneshot import checkpoint, expert, imitation, palette, viz
from oneshot.config import inner_only
from oneshot.evaluate import wilson_interval
from oneshot.world import ReachWorld, WorldConfig

PRETRAINED = os.path.join(os.path.dirname(__file__), "pretrained", "mil_default.npz")


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m oneshot.demo", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="demo_out", help="folder for the pictures (default: demo_out)")
    p.add_argument("--checkpoint", default=PRETRAINED, help="meta-trained policy (default: the shipped one)")
    p.add_argument("--trials", type=int, default=3, help="new scenes per held-out colour (default 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the demos and trial scenes")
    args = p.parse_args(argv)
    ckpt = checkpoint.load(args.checkpoint) if os.path.exists(args.checkpoint) else None
    # Demos like the ones the policy was meta-trained on (with the same DART noise, if any).
    expert_cfg = expert.ExpertConfig(action_noise=ckpt["config"].demo_noise if ckpt else 0.0)

    # 1. One expert demonstration per held-out colour.
    world = ReachWorld(WorldConfig(split="heldout"))
    colours = palette.split_colours("heldout")
    print(f"1. The iLQG expert records ONE demonstration for each of the {len(colours)} held-out colours")
    demos = {}
    for i, colour in enumerate(colours):
        d = expert.demonstrate(world, seed=args.seed * 1000 + i, options={"target_colour": int(colour)},
                               cfg=expert_cfg)
        demos[int(colour)] = d
    print(f"   expert success: {sum(d['success'] for d in demos.values())}/{len(demos)}")

    if ckpt is None:
        print(f"no meta-trained policy at {args.checkpoint}; train one with "
              f"`python -m oneshot.train --profile default --run runs/default` and pass "
              f"--checkpoint runs/default/checkpoint.npz")
        viz.save_atomically(viz.filmstrip([d["images"] for d in list(demos.values())[:4]]),
                            os.path.join(args.out, "expert_demos.png"))
        return None
    params, cfg = checkpoint.policy_params(ckpt), ckpt["config"]
    max_torque = world.config.arm.max_torque

    # 2-3. Adapt on the one demo, act in new scenes; the unadapted policy for contrast.
    print(f"2. Adapt the meta-trained policy ({ckpt['iteration']} meta-iterations) to each demo: "
          f"{cfg.inner_steps} gradient step(s) of size "
          f"{'meta-learnt per element' if cfg.learn_alpha else cfg.alpha} on {cfg.inner_params} parameters (eq. 1)")
    print(f"3. Run it in {args.trials} new scenes per colour (new positions, new distractors)")
    wins = base_wins = 0
    rows, labels, gif = [], [], None
    for i, (colour, d) in enumerate(demos.items()):
        demo = imitation.prepare_demos(d["images"], d["states"], d["actions"], max_torque)
        adapted = imitation.adapt(params, demo, cfg.alpha, cfg.inner_steps, inner_only(cfg))
        for j in range(args.trials):
            seed = imitation.trial_seed(args.seed, i, j)       # trial scenes, seeded as in `oneshot.evaluate`
            r = imitation.rollout(adapted, world, seed, colour)
            wins += r["success"]
            base_wins += imitation.rollout(params, world, seed, colour)["success"]
            if j == 0 and len(rows) < 8:
                rows += [d["images"], r["images"]]
                labels += [f"demo {colour}", f"policy {'ok' if r['success'] else 'miss'}"]
                gif = r["images"] if gif is None and r["success"] else gif
    n = len(demos) * args.trials
    lo, hi = wilson_interval(wins, n)
    print(f"\none-shot success on held-out colours: {wins}/{n} = {wins / n:.2f} (95% CI {lo:.2f}-{hi:.2f})")
    print(f"the same policy without adaptation:   {base_wins}/{n} = {base_wins / n:.2f}")
    strip = os.path.join(args.out, "one_shot.png")
    viz.save_atomically(viz.filmstrip(rows, labels=labels), strip)
    print(f"wrote {strip} (each demo above the adapted policy's trial in a new scene)")
    if gif is not None:
        viz.save_gif(gif, os.path.join(args.out, "one_shot_trial.gif"))
        print(f"wrote {os.path.join(args.out, 'one_shot_trial.gif')}")
    return {"successes": wins, "trials": n, "unadapted_successes": base_wins}


if __name__ == "__main__":
    main()
