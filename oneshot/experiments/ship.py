"""A finished run of a sweep, shipped as a pretrained policy (`oneshot/pretrained/`): the run's own
checkpoint, with the paths of its datasets made those a user's `python -m oneshot.experiments fig2
--profile P --data-only` collects, instead of the machine's that trained it.

    python -m oneshot.experiments ship --profile ablation --line L --seed S --out oneshot/pretrained/F.npz

The shipped file is reproduced by running that line and seed again (`fig2 --profile P --lines L --seeds S`,
the same numbers to float32 rounding) and shipping it the same way.
"""
import dataclasses
import os

from oneshot.experiments.fig2 import PROFILES, data_paths, plan, run_config, run_context
from oneshot.experiments.rows import ROW_FILE
from oneshot.tools import cli
from oneshot.training import checkpoint, run_folder

SPLITS = {"train": "train_data", "validation": "validation_data", "test": "test_data"}


class NotShippable(ValueError):
    """The run asked for is not in the profile, has not finished, or was trained otherwise."""


def finished_run(cfg, line, seed, work_dir):
    """The RunSpec and run folder of `line`'s run with `seed` at the sweep `cfg`'s largest size, checked
    finished (its row written). Raises NotShippable naming what is missing and the command that makes it."""
    runs = [r for r in plan(cfg) if r.method == line and r.seed == seed]
    if not runs:
        raise NotShippable(f"the {cfg.name} profile has no run of line {line!r} with seed {seed} (its lines: "
                           f"{', '.join(cfg.methods)}; its seeds: {', '.join(map(str, cfg.seeds))})")
    spec = max(runs, key=lambda r: r.size)
    folder = os.path.join(work_dir, spec.run_id)
    make = (f"python -m oneshot.experiments fig2 --profile {cfg.name} --lines {line} --seeds {seed} --work {work_dir}"
            + ("" if len(cfg.sizes) == 1 else f" (that command trains the line at each of the profile's "
                                               f"{len(cfg.sizes)} sizes; ship takes the largest)"))
    if not os.path.isfile(os.path.join(folder, ROW_FILE)):
        raise NotShippable(f"{folder} holds no finished run; make it with: {make}")
    if not os.path.isfile(os.path.join(folder, "checkpoint.npz")):
        raise NotShippable(f"{folder} holds a finished run without its checkpoint.npz; move that folder aside and "
                           f"make it again with: {make}")
    return spec, folder


def ship(cfg, line, seed, work_dir, data_dir, out):
    """Write the finished run of `line` and `seed` (`finished_run`) to `out`, its dataset paths made
    data_dir/<the sweep's file name> (relative if data_dir is). Checks that the checkpoint is the run's
    last and was trained with the line's configuration for that run (but for its data's folder and the
    fields a resume may change). Returns the run's spec."""
    spec, folder = finished_run(cfg, line, seed, work_dir)
    cli.not_an_input(out, [work_dir], "--out", "the sweep's work folder (its runs must stay as trained)")
    cli.replaces_only(out, checkpoint.is_checkpoint, "--out", "a policy")
    ckpt = checkpoint.load(os.path.join(folder, "checkpoint.npz"))
    trained = ckpt["config"]
    expected = run_config(spec, run_context(cfg, os.path.dirname(trained.train_data)))
    # what a resume may change, but not the step size: a line of the ablation is an lr change
    as_run = dataclasses.replace(trained, **{n: getattr(expected, n) for n in run_folder.RESUMABLE if n != "lr"})
    wrong = [f"{f.name} {getattr(as_run, f.name)!r}, not {getattr(expected, f.name)!r}"
             for f in dataclasses.fields(expected) if getattr(as_run, f.name) != getattr(expected, f.name)]
    if ckpt["iteration"] != spec.iterations:
        wrong.append(f"iteration {ckpt['iteration']} of {spec.iterations}")
    if ckpt["ln_offsets_drawn"]:
        wrong.append("began with random layer-norm offsets (saved before they started at zero)")
    if wrong:
        raise NotShippable(f"{folder}/checkpoint.npz is not {spec.run_id} as this code trains it ({'; '.join(wrong)}): "
                           f"move that folder aside and run it again")
    names = {split: os.path.basename(path) for split, path in data_paths(cfg, data_dir).items()}
    shipped = dataclasses.replace(trained, **{field: os.path.join(data_dir, names[split])
                                             for split, field in SPLITS.items()})
    checkpoint.save(out, ckpt["params"], ckpt["adam"], ckpt["iteration"], ckpt["rng"], shipped, ckpt["network"],
                    ema=ckpt["ema"], world=ckpt["world"], seconds=ckpt["seconds"])
    return spec


def add_ship_command(commands):
    """`python -m oneshot.experiments ship`'s parser, added to `commands` (argparse subparsers)."""
    h = commands.add_parser("ship", help="copy a finished run of a profile's line as a pretrained policy, its "
                                         "datasets' paths made those `fig2 --profile P --data-only` collects")
    h.add_argument("--profile", choices=sorted(PROFILES), required=True, help="the sweep that trained it")
    h.add_argument("--line", required=True, help="the line, e.g. mil-released+widths-flat")
    h.add_argument("--seed", type=int, required=True, help="the run's training seed")
    h.add_argument("--work", default=os.path.join("runs", "fig2"), help="the runs' work folders (default: runs/fig2)")
    h.add_argument("--data", default="data/fig2", help="where the shipped policy's datasets are looked for "
                                                       "(default: data/fig2)")
    h.add_argument("--out", type=cli.writable_file, required=True, help="the policy file, e.g. oneshot/pretrained/F.npz")
    return h


def run_ship_command(args, parser):
    """Ship as `args` say; a run that cannot be shipped is a one-line error (exit 2). Returns 0."""
    try:
        spec = ship(PROFILES[args.profile], args.line, args.seed, args.work, args.data, args.out)
    except NotShippable as e:
        parser.error(str(e))
    print(f"{args.out}: {spec.run_id} of the {args.profile} profile; its datasets are looked for in {args.data} "
          f"(python -m oneshot.experiments fig2 --profile {args.profile} --data {args.data} --data-only)")
    return 0
