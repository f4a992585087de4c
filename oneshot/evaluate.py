"""One-shot success rate of a meta-trained policy: `python -m oneshot.evaluate CHECKPOINT --help`.

Paper Section IV's protocol: for each colour of a held-out split, take ONE demonstration of it, adapt
(eq. 1), and run the adapted policy in new scenes of that colour (new positions, new distractors);
success is the end effector within 0.05 m of the target over the final fifth of the episode. Reported
with a 95% Wilson score interval, and on meta-training colours for contrast.

    python -m oneshot.evaluate CHECKPOINT                  # the validation colours: for every choice
    python -m oneshot.evaluate CHECKPOINT --split test     # the test colours: once, to report

The datasets are the checkpoint's own (the paths its run recorded) unless a flag names others; if any
is missing, one message names them all and the commands that make them.
"""
import argparse
import dataclasses
import json
import sys

from oneshot import methods
from oneshot.data import datasets
from oneshot.maml import imitation
from oneshot.tools import cli, files, host
from oneshot.training import checkpoint, fit_check, run_data
from oneshot.training.scoring import adaptation_gain, colour_breakdown, wilson_interval

FLAGS = {"train": "--train", "validation": "--validation", "test": "--test"}
FLAGGED = ("demo_scenes", "other_colour_demo")      # options recorded in the recipe when set: never pooled with plain


def main(argv=None):
    p = cli.Parser(prog="python -m oneshot.evaluate", description=__doc__,
                   formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", help="a checkpoint written by `python -m oneshot.train`")
    p.add_argument("--split", choices=("validation", "test"), default="validation",
                   help="the held-out colours scored: validation (default; for choices) or test (to report, once)")
    p.add_argument("--validation", default=None, help="validation demonstrations (.npz; default: the checkpoint's)")
    p.add_argument("--test", default=None, help="test demonstrations (.npz; default: the checkpoint's)")
    p.add_argument("--train", default=None,
                   help="meta-training demonstrations, for the contrast (.npz; default: the checkpoint's; '' to skip)")
    p.add_argument("--trials", type=cli.positive_int, default=10,
                   help="trials per colour (default 10: 120 trials on the 12 validation colours)")
    p.add_argument("--seed", type=cli.non_negative_int, default=0, help="seed of the trial scenes")
    p.add_argument("--demo-scenes", action="store_true",
                   help="act in the recorded scenes of the demonstrations (trial j adapts on demo j, acts in demo "
                        "(j + 1) mod min(demos, trials)'s scene), not in new ones: has the policy memorised its "
                        "meta-training scenes?")
    p.add_argument("--other-colour-demo", action="store_true",
                   help="the control for what the demonstration carries: condition each trial on a demonstration "
                        "of ANOTHER colour (the split's farthest in hue), scored on its own target; a policy that "
                        "reads the colour from the demonstration should now fail, one that knows the scene should not")
    p.add_argument("--unadapted", action="store_true",
                   help="also run the policy without adaptation, in the same scenes (does adapting help?)")
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
    p.add_argument("--no-progress", action="store_true",
                   help="no progress bar (e.g. when the output goes to a log file)")
    p.add_argument("--json", type=cli.writable_file, default=None,
                   help="also write the results to this JSON file (checked before evaluating; it replaces only an earlier "
                        "result of --json)")
    args = p.parse_args(argv)
    if getattr(args, args.split) == "":
        p.error(f"{FLAGS[args.split]} '' names no dataset, but the {args.split} colours are what this scores; "
                f"name their dataset, or drop the flag to use the checkpoint's")
    ckpt = checkpoint.load(args.checkpoint)
    params, cfg = checkpoint.policy_params(ckpt, args.raw), ckpt["config"]
    if args.method is not None and args.method != cfg.method:      # the checkpoint is not what was asked for
        p.error(f"{args.checkpoint} holds a {cfg.method!r} policy, not {args.method!r}; train one with "
                f"`python -m oneshot.train --method {args.method}`")
    # The datasets: the checkpoint's own, unless a flag names another (its collect command then writes there).
    cfg = dataclasses.replace(cfg, **{f"{split}_data": getattr(args, split) for split in FLAGS
                                      if getattr(args, split)})
    cfg = dataclasses.replace(cfg, **{k: v for k, v in (("alpha", args.alpha), ("inner_steps", args.inner_steps))
                                      if v is not None})
    try:
        method = methods.of(cfg)
    except ValueError as e:
        p.error(f"{e} (--alpha >= 0, --inner-steps >= 0)")
    try:                                        # a baseline's checkpoint has no eq. (1) to change
        method.refuse_ignored([k for k in ("alpha", "inner_steps") if getattr(args, k) is not None])
    except ValueError as e:
        p.error(str(e))
    if args.json:
        try:
            cli.not_an_input(args.json, [args.checkpoint] + [run_data.spec(cfg, split)[0] for split in FLAGS],
                             "--json", "a file this command reads")
            cli.replaces_only(args.json, lambda path: files.is_json_with(path, ("policy",)), "--json",
                              "a result of evaluate --json")         # an earlier result; not a README, a script
        except ValueError as e:
            p.error(f"argument {e}")
    if args.demo_scenes and args.trials < 2:
        p.error(f"--demo-scenes needs --trials >= 2 (trial j acts in another demo's scene); got {args.trials}")
    if args.unadapted and not method.adapts:
        p.error(f"--unadapted compares a policy before and after eq. (1); {cfg.method!r} does not adapt")
    splits = [args.split] + (["train"] if args.train != "" else [])
    # Every dataset is found and checked before the first trial; one message names all that are missing.
    gone = run_data.missing(cfg, splits, FLAGS)
    if gone:
        train_gone = "train" in splits and run_data.missing(cfg, ["train"]) is not None
        raise FileNotFoundError(gone + (", or skip the contrast with --train ''" if train_gone else ""))
    loaded = {split: datasets.load(run_data.spec(cfg, split)[0]) for split in splits}
    for split, dataset in loaded.items():    # its split; images, horizon, state, torques (and palette) as trained on
        path = run_data.spec(cfg, split)[0]
        if dataset["metadata"]["split"] != split:
            raise datasets.DatasetError(f"{path} holds {dataset['metadata']['split']} colours, not {split} colours; "
                                        f"name the {split} dataset with {FLAGS[split]}")
        fit_check.check_data(ckpt, dataset["metadata"], args.checkpoint, path, palette=not args.any_palette)
    notes = {}                               # a small file scores fewer colours than the numbers reported on its split
    for split, dataset in loaded.items():    # (counted in the dataset's own palette: --any-palette)
        mode = dataset["metadata"].get("world", {}).get("palette", {}).get("mode", cfg.palette)
        if split != "train":
            notes[split] = run_data.fewer_colours(dataclasses.replace(cfg, palette=mode), split,
                                                  len(dataset["task_colours"]), "this scored")
    if "train" in loaded:                    # the contrast: the colours and demos the run meta-trained on, no more
        loaded["train"] = run_data.subset(loaded["train"], cfg.tasks, cfg.demos)
    few = {split: len(d["task_colours"]) for split, d in loaded.items() if len(d["task_colours"]) < 2}
    if args.other_colour_demo and few:
        p.error(f"--other-colour-demo needs 2 colours or more in every scored split; "
                + ", ".join(f"the {split} split has {n}" for split, n in few.items())
                + (": skip the contrast with --train ''" if "train" in few else ""))
    if args.raw and ckpt["ema"] is None:
        print(f"note: {args.checkpoint} kept no moving average: its parameters are the raw ones, with or without "
              f"--raw", file=sys.stderr)
    host.blas_threads(1)       # small products: OpenBLAS's spinning threads only slow them (`oneshot.tools.host`)
    results = {}
    for split, dataset in loaded.items():
        condition = method.conditioner(params, seed=args.seed)
        r = imitation.one_shot_success(condition, dataset, args.trials, args.seed, demo_scenes=args.demo_scenes,
                                       other_colour_demo=args.other_colour_demo, progress=not args.no_progress)
        r["ci95"] = lo, hi = wilson_interval(r["successes"], r["trials"])
        shown = ", each shown a demonstration of another colour" if args.other_colour_demo else ""
        print(f"{split} colours{shown}: one-shot success {r['rate']:.3f} ({r['successes']}/{r['trials']}), "
              f"95% CI [{lo:.3f}, {hi:.3f}]; failures: {r['failures']['near_miss']} near misses (closest "
              f"to the target, but not within reach), {r['failures']['wrong_object']} at a distractor")
        if notes.get(split):
            print(notes[split])
        results[split] = r
        if args.unadapted:
            u = imitation.one_shot_success(method.unadapted(params), dataset, args.trials, args.seed,
                                           demo_scenes=args.demo_scenes, progress=not args.no_progress)
            u["ci95"] = lo, hi = wilson_interval(u["successes"], u["trials"])
            print(f"{split} colours, unadapted policy: success {u['rate']:.3f} ({u['successes']}/{u['trials']}), "
                  f"95% CI [{lo:.3f}, {hi:.3f}]")
            results[f"{split}_unadapted"] = u
        if split == "train":
            continue
        print(_wrapped(f"{split} colours, by colour:", colour_breakdown(r, args.trials, dataset["metadata"]).split("; ")))
        if method.adapts:
            g = adaptation_gain(params, dataset, method.conditioner(params))
            own = " of its own colour" if args.other_colour_demo else ""
            print(f"{split} colours: eq. (2) loss on a second demo {g['before']:.3f} before adapting on "
                  f"one demo{own}, {g['after']:.3f} after ({g['pairs']} pairs)")
            results["adaptation_gain"] = g
    if args.json:
        written = {k: dict(v, per_colour={str(c): x for c, x in v["per_colour"].items()})
                   if "per_colour" in v else v for k, v in results.items()}
        # what `python -m oneshot.experiments seeds` pools: one recipe (the config but its seed and data
        # paths, with this command's --alpha and --inner-steps, --raw, --demo-scenes and
        # --other-colour-demo), scored on one dataset and scenes
        recipe = {k: v for k, v in dataclasses.asdict(cfg).items() if k != "seed" and not k.endswith("_data")}
        written["policy"] = {"checkpoint": args.checkpoint, "training_seed": cfg.seed, "method": cfg.method,
                             "recipe": dict(recipe, raw=args.raw, **{k: True for k in FLAGGED if getattr(args, k)}),
                             "dataset": run_data.spec(cfg, args.split)[0], "trials_per_colour": args.trials,
                             "eval_seed": args.seed}
        with files.atomic_write(args.json) as f:             # never half a file
            f.write(json.dumps(written, indent=1).encode())
    return results


def _wrapped(head, items, width=100):
    """`head` and `items` joined by "; " on lines of at most `width` characters (unless one item is
    longer), each item whole, the continuation lines indented: 48 colours made one line of 2,000."""
    lines = [head]
    for k, item in enumerate(items):
        piece = item + (";" if k < len(items) - 1 else "")
        if len(lines[-1]) + 1 + len(piece) > width and lines[-1] != head:
            lines.append("  " + piece)
        else:
            lines[-1] += " " + piece
    return "\n".join(lines)


if __name__ == "__main__":
    cli.run(main)
