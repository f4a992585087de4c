"""Figure 2 of the paper (Section IV): one-shot success against the size of the meta-training dataset,
one line per method. A *run* is one line (a method and its configuration: `oneshot.experiments.lines`)
trained on one dataset size (colours x demos per colour) with one seed, then scored on the same trials
of the scored split (the test colours for a figure, the validation colours for a search or an
ablation). A profile (`SweepConfig`, `PROFILES`) names the sizes, lines and seeds; `run_one` does one
run; the command is `python -m oneshot.experiments fig2` (`oneshot/experiments/__main__.py`), the
machinery `sweep`.
"""
import dataclasses
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass

import numpy as np

from oneshot.data import collection, datasets
from oneshot.maml import imitation
from oneshot import methods
from oneshot.tools import files, host
from oneshot.training import checkpoint, run_data, run_folder, scoring
from oneshot.world import palette
from oneshot.training.config import PROFILES as PROFILES_TRAIN
from oneshot.expert.controller import ExpertConfig
from oneshot.world.palette import PaletteConfig
from oneshot.experiments.lines import ABLATION, FIGURE, FIRST_FIGURE, LINES, LONGER, SEARCH
from oneshot.experiments.rows import RunSpec, read_rows
from oneshot.world.reach import WorldConfig


def load_results(folder):
    """The results of a Figure 2 sweep in `folder` (e.g. results/fig2_paper): (rows of runs.csv,
    summary.json as a dict). A summary.json that is not JSON, or not a summary (an object whose config,
    if any, is an object naming its lines in a list), raises ValueError naming the file."""
    path = os.path.join(folder, "summary.json")
    fix = "restore it (git checkout), or run the sweep's fig2 command again to write it"
    with files.open_read(path, "r") as f:
        try:
            summary = files.loads_json(f.read())
        except ValueError as e:
            raise ValueError(f"{path} is not JSON ({e}); {fix}") from None
    config = (summary.get("config") or {}) if isinstance(summary, dict) else None     # none recorded: {}
    whole = lambda x: isinstance(x, int) and not isinstance(x, bool)
    if (not isinstance(config, dict) or not isinstance(config.get("methods", []), list)
            or not isinstance(config.get("seeds", []), list) or not all(map(whole, config.get("seeds", [])))
            or not isinstance(config.get("sizes", []), list)
            or not all(isinstance(s, list) and len(s) == 2 and all(map(whole, s)) for s in config.get("sizes", []))):
        raise ValueError(f"{path} is not a Figure 2 summary (a JSON object whose config names its lines, and its "
                         f"sizes and seeds as lists of [colours, demos] and of whole numbers); {fix}")
    return read_rows(os.path.join(folder, "runs.csv")), summary


CONTINUED = "CONTINUED"   # in a LONGER run's folder: the run id it continued (`_continue_shorter`)


@dataclass(frozen=True)
class SweepConfig:
    """A Figure 2 sweep: every line x size x seed, each run scored on the `score` split's colours (the test
    colours for a figure; the validation colours for a search that chooses). The defaults are the "paper"
    profile's but for its lines (`lines.FIGURE`): 5 sizes from 192 to 5184 demonstrations (27x), 3 seeds,
    10000 meta-iterations per run."""
    name: str = "paper"
    sizes: tuple = ((24, 8), (36, 12), (72, 12), (144, 16), (324, 16))  # (colours, demos per colour)
    methods: tuple = FIRST_FIGURE         # lines of LINES
    seeds: tuple = (0, 1, 2)
    iterations: int = 10000                # meta-iterations per run (a LONGER line: its own): as the shipped policy
    trials: int = 5                        # trials per scored colour (5 x 48 test colours: 240 trials)
    palette_mode: str = "grid"             # oneshot.world.palette.PaletteConfig(mode=...): enough colours for 324
    eval_seed: int = 0                     # seed of the trial scenes: the same scenes for every run
    data: tuple = (324, 16)                # (colours, demos) collected once; every size is its first part
    validation: tuple = (12, 10)           # validation (colours, demos): the random policy's std is chosen there
    test: tuple = (48, 10)                 # test (colours, demos): each trial adapts on one of the demos
    score: str = "test"                    # the split runs are scored on: "test", or "validation" to choose
    eval_every: int = 0                    # each run's validation checks during training (0: none), its curve

    def __post_init__(self):
        if not self.sizes or len({c * d for c, d in self.sizes}) != len(self.sizes):
            raise ValueError(f"sizes must be distinct (colours, demos) pairs with distinct products "
                             f"(one point per size on the figure); got {self.sizes}")
        if not self.methods or set(self.methods) - set(LINES) or len(set(self.methods)) != len(self.methods):
            raise ValueError(f"methods must be distinct names from {', '.join(LINES)}; got {self.methods}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds must be distinct; got {self.seeds}")
        if self.trials < 1:
            raise ValueError(f"trials (per scored colour) must be >= 1; got {self.trials}")
        if self.score not in ("validation", "test"):
            raise ValueError(f"score must be 'validation' or 'test'; got {self.score!r}")
        for line in (m for m in self.methods if m in LONGER):     # in the profile's order: one message
            shorter, iterations = LONGER[line]
            if LINES[line] != LINES[shorter] or LINES[line].lr_schedule != "constant" or iterations <= self.iterations:
                raise ValueError(f"{line} continues {shorter} to {iterations} iterations: it needs {shorter}'s "
                                 f"configuration, a constant step size (a schedule depends on the iterations) "
                                 f"and more than the profile's {self.iterations} iterations")
        for c, d in self.sizes:                # checks the pair's types and signs
            RunSpec(self.methods[0], c, d, self.seeds[0], self.iterations)
            if c > self.data[0] or d > self.data[1]:
                raise ValueError(f"size ({c}, {d}) is larger than the collected data {self.data}")
        palette_cfg = PaletteConfig(mode=self.palette_mode)
        for split, (c, d) in self.splits().items():
            available = len(palette.split_colours(split, palette_cfg))
            if not 1 <= c <= available or d < 2:
                raise ValueError(f"{split} data of {c} colours x {d} demos: the {self.palette_mode} palette has "
                                 f"{available} {split} colours; need 1..{available} colours and >= 2 demos")

    def splits(self):
        """{split: (colours, demos)} the sweep collects: meta-training, validation and test."""
        return {"train": self.data, "validation": self.validation, "test": self.test}


PROFILES = {
    "quick": SweepConfig(name="quick", sizes=((24, 8), (72, 12), (324, 16)), seeds=(0,), iterations=3000),
    "paper": SweepConfig(methods=FIGURE),
    # The first figure (mil-all as its every-parameter line), scored on 12 validation colours x 10 trials
    # before the test split existed: results/fig2_paper-validation.
    "paper-validation": SweepConfig(name="paper-validation", score="validation", trials=10),
    "search": SweepConfig(name="search", sizes=((72, 12),), seeds=(0,), iterations=3000, score="validation",
                          methods=SEARCH),
    "ablation": SweepConfig(name="ablation", sizes=((144, 16),), seeds=(0, 1), score="validation", methods=ABLATION,
                            validation=(36, 10), eval_every=2000),
    # The workshop paper's LSTM (2048 units) once, at the figure's largest size, on its test colours:
    # does the baseline's width change the conclusion? (Compare with `paper`'s lstm at 5184.)
    "lstm-2048": SweepConfig(name="lstm-2048", sizes=((324, 16),), methods=("lstm-2048",), seeds=(0,)),
    # Figure 2's 2,304-demonstration point for its two MIL lines with seeds 3 and 4 added (5 seeds): the
    # every-parameter line's seeds disagree there (one of three memorised its scenes). Seeds 0-2 are the
    # paper profile's runs (the same run ids: a paper sweep's work folders are reused).
    "paper-2304": SweepConfig(name="paper-2304", sizes=((144, 16),), methods=FIGURE[:2], seeds=(0, 1, 2, 3, 4)),
    "tiny": SweepConfig(name="tiny", sizes=((3, 3), (3, 4)), seeds=(0, 1), iterations=2, trials=2,  # tests
                        data=(3, 4), validation=(2, 2), test=(2, 2)),
}


def plan(cfg):
    """Every line x size x seed of `cfg`, as a list of RunSpec: seed by seed (so the first pass draws the
    whole figure once), within a seed the smaller datasets first, then the lines in the profile's order."""
    runs = [RunSpec(m, c, d, s, iterations(cfg, m)) for m in cfg.methods for c, d in cfg.sizes for s in cfg.seeds]
    return sorted(runs, key=lambda r: (r.seed, r.size, cfg.methods.index(r.method)))


def iterations(cfg, line):
    """The meta-iterations of `line`'s runs in the sweep `cfg`: the profile's, or a LONGER line's own."""
    return LONGER[line][1] if line in LONGER else cfg.iterations


def data_paths(cfg, data_dir):
    """{split: dataset path} of a sweep: named by what they hold, so profiles that collect the same data
    share it."""
    folder = os.path.abspath(data_dir)
    return {split: os.path.join(folder, run_data.file_name(cfg.palette_mode, split, c, d))
            for split, (c, d) in cfg.splits().items()}


def collected_with(cfg):
    """(WorldConfig, ExpertConfig) a sweep collects its datasets with: its palette, the world's other
    settings at their defaults (the split is each dataset's), the default profile's DART noise."""
    return (WorldConfig(palette=PaletteConfig(mode=cfg.palette_mode)),
            ExpertConfig(action_noise=PROFILES_TRAIN["default"].demo_noise))


def ensure_data(cfg, data_dir, workers=None, progress=True):
    """Collect the sweep's datasets if missing (all cores; DART noise 0.1 N m as the default profile's):
    the first `cfg.data` colours x demos of the palette's meta-training split, every run training on the
    first part of it; `cfg.validation` of its validation colours and `cfg.test` of its test colours."""
    world_cfg, expert_cfg = collected_with(cfg)
    for split, path in data_paths(cfg, data_dir).items():
        c, d = cfg.splits()[split]
        if not os.path.exists(path):
            print(f"collecting {path}: {c} {split} colours x {d} demos", file=sys.stderr)
            with collection.unwritten(path):
                data = collection.collect(c, d, split, run_data.SEEDS[split], workers, world_cfg, expert_cfg, progress)
            datasets.save(data, path)


def run_context(cfg, data_dir="data/fig2"):
    """The small picklable dict every run_fn receives besides its spec and folder: what all runs of the
    sweep share. Paths are absolute (workers may start elsewhere)."""
    paths = data_paths(cfg, data_dir)
    return {"profile": cfg.name, "trials": cfg.trials, "iterations": cfg.iterations,
            "palette_mode": cfg.palette_mode, "eval_seed": cfg.eval_seed, "score": cfg.score, "eval_every": cfg.eval_every,
            "train_data": paths["train"], "validation_data": paths["validation"], "test_data": paths["test"],
            "demos": {split: d for split, (c, d) in cfg.splits().items()}}


# ----------------------------------------------------------------------------------------------------
# One run: train one method on one dataset size with one seed, then score it on the scored split
# ----------------------------------------------------------------------------------------------------

def run_config(spec, context):
    """The TrainConfig of one run: its line's configuration on the first `spec.colours` colours x
    `spec.demos` demos of the sweep's meta-training data, one process (the sweep runs several)."""
    demos = context["demos"]
    return dataclasses.replace(
        LINES[spec.method],
        train_data=context["train_data"], validation_data=context["validation_data"], test_data=context["test_data"],
        train_demos=demos["train"], validation_demos=demos["validation"], test_demos=demos["test"],
        palette=context["palette_mode"], tasks=spec.colours, demos=spec.demos, seed=spec.seed,
        iterations=spec.iterations, shards=1, eval_every=context.get("eval_every", 0), eval_trials=2,
        checkpoint_every=250, log_every=50)


def final_meta_loss(log_path, last=500):
    """The median meta-loss (eq. (2) after the inner step, on the training tasks; a baseline's training
    loss) of the last `last` iterations a run's log.jsonl records: does the line fit its own training
    tasks? None if it records none (the random policy)."""
    with files.open_read(log_path, "r") as f:
        records = [json.loads(line) for line in f if line.strip()]
    losses = [(r["iteration"], r["meta_loss"]) for r in records if "meta_loss" in r]
    if not losses:
        return None
    end = losses[-1][0]
    return float(np.median([loss for i, loss in losses if i > end - last]))


def _continue_shorter(spec, run_dir, context):
    """For a LONGER line's run that has not started: copy the checkpoint and log of the shorter line's
    finished run (same size and seed, the profile's iterations, beside run_dir, trained with the config
    this sweep gives it) into run_dir, so that training continues it, and record its run id in
    run_dir/CONTINUED. Returns whether it did; if the shorter run has not finished (more workers than
    runs ahead of it), the longer one trains from its own start: the same numbers, at full cost."""
    if spec.method not in LONGER or "iterations" not in context:
        return False
    shorter = dataclasses.replace(spec, method=LONGER[spec.method][0], iterations=context["iterations"])
    source = os.path.join(os.path.dirname(os.path.abspath(run_dir)), shorter.run_id)
    path = os.path.join(source, "checkpoint.npz")
    if not os.path.exists(path):
        return False
    ckpt, expected = checkpoint.load(path), run_config(shorter, context)
    trained_as = dataclasses.replace(ckpt["config"], **{n: getattr(expected, n) for n in run_folder.RESUMABLE})
    if ckpt["iteration"] != shorter.iterations or trained_as != expected or ckpt["ln_offsets_drawn"]:
        return False
    with run_folder.lock_run(run_dir):
        for name in ("log.jsonl", "checkpoint.npz"):      # the checkpoint last: its presence means "resume"
            with files.open_read(os.path.join(source, name)) as f, \
                    files.atomic_write(os.path.join(run_dir, name)) as g:
                shutil.copyfileobj(f, g)
        with files.atomic_write(os.path.join(run_dir, CONTINUED)) as f:
            f.write(shorter.run_id.encode("utf-8"))
    return True


def _score(method, params, scored, spec, context):
    """One policy scored as a run is: (one_shot_success's result, notes: successes per colour and, for
    MIL, the unadapted policy's successes in the same scenes and eq. (2) on a second demo before and
    after adapting)."""
    score = lambda condition: imitation.one_shot_success(condition, scored, context["trials"], context["eval_seed"],
                                                         progress=False)
    r = score(method.conditioner(params, seed=[spec.seed, context["eval_seed"]]))
    notes = {"per_colour": {str(c): round(rate * context["trials"]) for c, rate in r["per_colour"].items()}}
    if method.adapts:                                                # the same scenes, without eq. (1)
        notes["unadapted_successes"] = score(method.unadapted(params))["successes"]
        gain = scoring.adaptation_gain(params, scored, method.conditioner(params))   # eq. (2) on a second demo
        notes.update(eq2_before=round(gain["before"], 4), eq2_after=round(gain["after"], 4))
    return r, notes


def run_one(spec, run_dir, context):
    """Train (or resume) one run in run_dir and score it on context["trials"] trials per colour of the
    scored split (`imitation.one_shot_success` with the sweep's eval seed: the same scenes for every run).
    Returns {"wall_seconds", "successes", "trials"} and, for the `notes` column, the successes per scored
    colour, for MIL the unadapted policy's successes in the same scenes and eq. (2) before and after
    adapting, and the same for the raw parameters when the policy acts with a moving average ("raw":
    what a run without one would score, since the average never feeds back into training), the
    training loss at the end (`final_meta_loss`, when the log records one), and what the method records of
    itself (the random policy: the torque std it chose on the validation colours; its torques are drawn
    from the run's own seed). wall_seconds: the meta-training time the checkpoint records (every sitting,
    a killed one too) plus the scoring; for a run begun before checkpoints recorded time, only this
    sitting's (notes: "wall": "this sitting")."""
    host.tune_malloc()
    host.blas_threads(1)                                   # several runs share the cores
    cfg = run_config(spec, context)
    t0 = time.perf_counter()
    resume = os.path.exists(os.path.join(run_dir, "checkpoint.npz")) or _continue_shorter(spec, run_dir, context)
    run_folder.train(cfg, run_dir, resume=resume, progress=False)
    ckpt = checkpoint.load(os.path.join(run_dir, "checkpoint.npz"))
    t_score = time.perf_counter()
    scored = run_data.load(cfg, context["score"])
    params = checkpoint.policy_params(ckpt)
    method = methods.of(cfg)
    r, notes = _score(method, params, scored, spec, context)
    if method.adapts and ckpt["ema"] is not None:      # the parameters Adam trained, without the moving average
        raw, raw_notes = _score(method, checkpoint.policy_params(ckpt, raw=True), scored, spec, context)
        notes["raw"] = {"successes": raw["successes"], **{k: v for k, v in raw_notes.items() if k != "per_colour"}}
    notes.update(method.notes(params))
    if os.path.exists(os.path.join(run_dir, CONTINUED)):          # its first iterations are another run's
        with files.open_read(os.path.join(run_dir, CONTINUED), "r") as f:
            notes["continued_from"] = f.read()
    end = final_meta_loss(os.path.join(run_dir, "log.jsonl"))
    if end is not None:
        notes["meta_loss_end"] = round(end, 4)
    if ckpt["seconds"] is None:
        spent, notes["wall"] = time.perf_counter() - t0, "this sitting"
    else:
        spent = ckpt["seconds"] + time.perf_counter() - t_score
    return {"wall_seconds": round(spent, 1), "successes": r["successes"], "trials": r["trials"], **notes}
