"""The folders of Figure 2's sweeps as a command meets them before any run: may this sweep write to a
results folder (`results/fig2_<profile>/`; `check_results_folder`: one profile's results to a folder),
may its points be compared with the results there (`check_comparable`, `fig2 --compare`), do the
runs of its work folder continue with these datasets (`check_work_data`), are the datasets in its
data folder the ones it collects (`check_data`), and does a results folder hold its whole sweep
(`check_finished`, before `summarise`)?
"""
import dataclasses
import os

from oneshot.data import datasets
from oneshot.experiments.fig2 import collected_with, data_paths, plan, run_config, run_context
from oneshot.experiments.rows import read_rows, row_id
from oneshot.tools import files
from oneshot.training import checkpoint, run_data


def check_results_folder(cfg, folder):
    """Raise ValueError if the results folder `folder` holds another sweep's results: runs.csv rows that
    are not runs of the profile `cfg` (the whole profile, not a part of it), or a summary of another
    profile. A folder holds one profile's results: its summary and figure would otherwise replace
    another's, and `summarise` would pool both. (Its own rows scored otherwise, as the
    `quick` results were before the test split, are run again and replaced: `sweep`.)"""
    ids = {r.run_id for r in plan(cfg)}
    foreign = [row_id(row) for row in read_rows(os.path.join(folder, "runs.csv")) if row_id(row) not in ids]
    names = {_summary_config(os.path.join(folder, name)).get("name")
             for name in (os.listdir(folder) if os.path.isdir(folder) else [])
             if name.startswith("summary") and name.endswith(".json")} - {cfg.name, None}
    if foreign or names:
        what = (f"runs that are not the {cfg.name} profile's (e.g. {foreign[0]})" if foreign
                else f"a summary of the {sorted(names)[0]} profile")
        raise ValueError(f"{folder} holds another sweep's results ({what}); name another folder for --out (the "
                         f"default is results/fig2_{cfg.name})")


def check_comparable(cfg, folder, rows):
    """Raise ValueError unless the results in `folder` (its runs.csv `rows`) can be compared point by
    point with the sweep `cfg` (`--compare`), before any run: they share a point (line and size), and
    were scored on the same split (its summary's "score"; a summary from before the test split, with none,
    scored the validation colours)."""
    points = {(r.method, r.size) for r in plan(cfg)}
    if not any((row["method"], row["size"]) in points for row in rows):
        raise ValueError(f"{folder} holds no point of this sweep (no runs.csv rows of its lines and sizes); name "
                         f"the results of the same profile, e.g. results/fig2_{cfg.name}")
    config = _summary_config(os.path.join(folder, "summary.json"))
    score = config.get("score", "validation") if config else None
    if score is not None and score != cfg.score:
        raise ValueError(f"{folder} was scored on the {score} colours and this sweep scores the {cfg.score} colours: "
                         f"their points do not compare; name results scored on the {cfg.score} colours")


def check_work_data(runs, work_dir, context, done=()):
    """Raise ValueError, before any data is collected or run started, if a run of `runs` (but those in
    `done`) has a checkpoint in work_dir trained on other datasets than `context`'s: a sweep resumed with
    another --data, each of whose runs would fail to resume one by one. A damaged checkpoint is left to
    its run, which names it."""
    for spec in runs:
        path = os.path.join(work_dir, spec.run_id, "checkpoint.npz")
        if spec.run_id in done or not os.path.isfile(path):
            continue
        try:
            stored = checkpoint.load(path)["config"]
        except checkpoint.CheckpointError:
            continue
        expected = run_config(spec, context)
        for name in ("train_data", "validation_data", "test_data"):
            was, now = getattr(stored, name), getattr(expected, name)
            if was == now:
                continue
            if os.path.dirname(was) != os.path.dirname(now):
                raise ValueError(f"{path} was trained on {was}, not on {os.path.dirname(now)}'s: pass "
                                 f"--data {os.path.dirname(was)}, as its sweep did, or another --work")
            raise ValueError(f"{path} was trained on {was}, not {now}: it is another sweep's run; "   # same folder
                             f"name another --work")


def check_data(cfg, data_dir):
    """Raise ValueError (one line: the file, what differs, the fix) unless each dataset in `data_dir` is
    what the sweep `cfg` collects there (`fig2.collected_with`; `run_data.check`: split, palette, seed,
    noise, colours x demos; and the world, e.g. the image size), read from its metadata only: a damaged
    or wrong file is named once, before any is collected or any run starts, not by each run that loads
    it. A missing file is not checked: the sweep collects it."""
    again = "move it away (this command then collects it again), or name another --data"
    world, expert = collected_with(cfg)
    as_collected = dataclasses.replace(run_config(plan(cfg)[0], run_context(cfg, data_dir)),
                                       demo_noise=expert.action_noise)
    for split, path in data_paths(cfg, data_dir).items():
        if not os.path.exists(path):
            continue
        try:
            metadata = datasets.read_metadata(path)
        except datasets.DatasetError as e:              # its fix: collect it as this sweep does
            raise datasets.DatasetError(f"{str(e).removesuffix('; ' + datasets.FIX)}; {again}") from None
        run_data.check(as_collected, split, metadata, path, "this sweep's", "another --data")
        held = dataclasses.replace(datasets.world_config(metadata, repr(path)), split=world.split)
        differ = [f"{f.name} {getattr(held, f.name)!r}, not {getattr(world, f.name)!r}"
                  for f in dataclasses.fields(world) if getattr(held, f.name) != getattr(world, f.name)]
        if differ:
            raise run_data.DataMismatch(f"{path} was collected in another world than this sweep's: "
                                        f"{'; '.join(differ)}; {again}")


def check_finished(folder, rows, summary):
    """Raise ValueError unless `rows` (folder's runs.csv) hold every run of the sweep its summary records:
    config's methods x sizes x seeds, checked by `load_results` (none recorded: nothing to check)."""
    config = summary.get("config") or {}
    have = {(r["method"], r["size"], r["seed"]) for r in rows}
    wanted = [(m, c * d, s) for m in config.get("methods", ()) for c, d in config.get("sizes", ())
              for s in config.get("seeds", ())]
    missing = [run for run in wanted if run not in have]
    if missing:
        raise ValueError(f"{os.path.join(folder, 'runs.csv')} lacks {len(missing)} of its sweep's {len(wanted)} "
                         f"runs ({missing[0][0]} at {missing[0][1]} demos, seed {missing[0][2]}"
                         f"{', ...' * (len(missing) > 1)}): summarise redoes a finished sweep's summary; finish "
                         f"the sweep first ({summary.get('command') or 'run its fig2 command again'})")


def _summary_config(path):
    """The config a summary file records (a dict; {} if it records none or cannot be read)."""
    try:
        with files.open_read(path, "r") as f:
            summary = files.loads_json(f.read())
    except (ValueError, OSError):
        return {}
    config = summary.get("config") if isinstance(summary, dict) else None
    return {k: v for k, v in config.items() if k != "name" or isinstance(v, str)} if isinstance(config, dict) else {}
