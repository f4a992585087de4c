"""One-shot success rate of a meta-trained policy: `python -m oneshot.evaluate CHECKPOINT --help`.

Paper Section IV's protocol: for each held-out colour, take ONE demonstration of it, adapt (eq. 1),
and run the adapted policy in new scenes of that colour (new positions, new distractors); success is
the end effector within 0.05 m of the target over the final fifth of the episode. Reported with a
95% Wilson score interval, and on meta-training colours for contrast.
"""
import argparse
import dataclasses
import json
import os
from oneshot.data import datasets
from oneshot.maml import imitation
from oneshot import methods
from oneshot.tools import cli, files
from oneshot.training import checkpoint, fit_check
from oneshot.world import palette
from oneshot.world.palette import PaletteConfig
from oneshot.training.scoring import adaptation_gain, colour_breakdown, wilson_interval


def main(argv=None):
    p = cli.Parser(prog="python -m oneshot.evaluate", description=__doc__,
                   formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", help="a checkpoint written by `python -m oneshot.train`")
    p.add_argument("--heldout", default="data/heldout.npz", help="held-out demonstrations (.npz; '' to skip)")
    p.add_argument("--train", default="data/train.npz",
                   help="meta-training demonstrations, for the contrast (.npz; '' to skip)")
    p.add_argument("--trials", type=cli.positive_int, default=10,
                   help="trials per colour (default 10: 120 held-out trials)")
    p.add_argument("--seed", type=cli.non_negative_int, default=0, help="seed of the trial scenes")
    p.add_argument("--unadapted", action="store_true",
                   help="also run the policy without adaptation on the held-out colours (does adapting help?)")
    p.add_argument("--raw", action="store_true",
                   help="act with the parameters Adam trained, not their moving average (runs with --ema)")
    p.add_argument("--alpha", type=cli.finite_non_negative_float, default=None,
                   help="meta-test with this inner step size instead of the one the checkpoint was trained with")
    p.add_argument("--inner-steps", type=cli.non_negative_int, default=None,
                   help="meta-test with this many inner steps instead of the trained number")
    p.add_argument("--method", choices=list(methods.REGISTRY), default=None,
                   help="the method the checkpoint must have been trained with (default: whatever it was)")
    p.add_argument("--any-palette", action="store_true",
                   help="allow datasets of another palette than the policy was trained with (a transfer test, "
                        "e.g. a grid-trained policy on the default hues)")
    p.add_argument("--json", type=cli.writable_file, default=None,
                   help="also write the results to this JSON file (checked before evaluating)")
    args = p.parse_args(argv)
    splits = [(name, path) for name, path in (("heldout", args.heldout), ("train", args.train)) if path]
    if not splits:
        p.error("--heldout and --train are both '': nothing to evaluate")
    ckpt = checkpoint.load(args.checkpoint)
    params, cfg = checkpoint.policy_params(ckpt, args.raw), ckpt["config"]
    if args.method is not None and args.method != cfg.method:      # the checkpoint is not what was asked for
        p.error(f"{args.checkpoint} holds a {cfg.method!r} policy, not {args.method!r}; train one with "
                f"`python -m oneshot.train --method {args.method}`")
    cfg = dataclasses.replace(cfg, **{k: v for k, v in (("alpha", args.alpha), ("inner_steps", args.inner_steps))
                                      if v is not None})
    try:
        method = methods.of(cfg)
    except ValueError as e:
        p.error(f"{e} (--alpha >= 0, --inner-steps >= 0)")
    if args.unadapted and not method.adapts:
        p.error(f"--unadapted compares a policy before and after eq. (1); {cfg.method!r} does not adapt")
    # Every dataset is found and checked before the first trial (not the second after the first's).
    for name, path in splits:
        if not os.path.exists(path):
            split, flag, demos, seed = (("heldout", "--heldout", cfg.heldout_demos, 1) if name == "heldout" else
                                        ("train", "--train", cfg.train_demos, 0))
            tasks = len(palette.split_colours(split, PaletteConfig(mode=cfg.palette)))
            make = (f"make it with `python -m oneshot.collect --out {path} --split {split} --tasks {tasks} "
                    f"--demos {demos} --seed {seed} --noise {cfg.demo_noise}"
                    f"{' --palette ' + cfg.palette if cfg.palette != 'hues' else ''}`")
            raise FileNotFoundError(f"no {name} dataset at {path!r} ({flag}); {make}"
                                    f"{'' if name == 'heldout' else ', or skip it with --train ' + repr('')}")
    loaded = {name: datasets.load(path) for name, path in splits}
    for name, path in splits:                # images, horizon, state, torques (and palette) as trained on
        fit_check.check_data(ckpt, loaded[name]["metadata"], args.checkpoint, path, palette=not args.any_palette)
    results = {}
    for name, dataset in loaded.items():
        condition = method.conditioner(params, seed=args.seed)
        r = imitation.one_shot_success(condition, dataset, args.trials, args.seed)
        r["ci95"] = lo, hi = wilson_interval(r["successes"], r["trials"])
        print(f"{name} colours: one-shot success {r['rate']:.3f} ({r['successes']}/{r['trials']}), "
              f"95% CI [{lo:.3f}, {hi:.3f}]; failures: {r['failures']['near_miss']} near misses (closest "
              f"to the target, but not within reach), {r['failures']['wrong_object']} at a distractor")
        results[name] = r
        if name == "heldout":
            print(f"heldout colours, by colour: {colour_breakdown(r, args.trials, dataset['metadata'])}")
        if name == "heldout" and method.adapts:
            g = adaptation_gain(params, dataset, method.conditioner(params))
            print(f"heldout colours: eq. (2) loss on a second demo {g['before']:.3f} before adapting on "
                  f"one demo, {g['after']:.3f} after ({g['pairs']} pairs)")
            results["adaptation_gain"] = g
        if args.unadapted and name == "heldout":
            u = imitation.one_shot_success(method.unadapted(params), dataset, args.trials,
                                           args.seed)
            u["ci95"] = lo, hi = wilson_interval(u["successes"], u["trials"])
            print(f"heldout colours, unadapted policy: success {u['rate']:.3f} ({u['successes']}/{u['trials']}), "
                  f"95% CI [{lo:.3f}, {hi:.3f}]")
            results["heldout_unadapted"] = u
    if args.json:
        written = {k: dict(v, per_colour={str(c): x for c, x in v["per_colour"].items()})
                   if "per_colour" in v else v for k, v in results.items()}
        with files.atomic_write(args.json) as f:             # never half a file
            f.write(json.dumps(written, indent=1).encode())
    return results


if __name__ == "__main__":
    cli.run(main)
