"""The summary of a sweep's rows (per method and size, over seeds), the numbers of Figure 2 of the paper
(its picture: `figure.plot`).

    summary = summarise(rows, config, command)        # what summary.json holds
    pooled = pool_evaluations(results, names)         # one recipe's seeds, from evaluate's --json files
"""
import dataclasses
import json
import math
import os

import numpy as np

from oneshot.tools.files import atomic_write, loads_json, open_read
from oneshot.experiments import stats


def _groups(rows):
    """{(method, size): [rows]}, each group one configuration with distinct seeds (else ValueError)."""
    groups = {}
    for row in rows:
        groups.setdefault((row["method"], row["size"]), []).append(row)
    for (method, size), group in groups.items():
        check_point(method, size, group, "summarise one configuration per size")
    return groups


def check_point(method, size, group, fix):
    """Raise ValueError unless the rows `group` of `method` at `size` are one configuration (colours,
    demos, iterations) with distinct seeds; `fix` says what to do instead."""
    shapes = {(r["colours"], r["demos_per_colour"], r["iterations"]) for r in group}
    if len(shapes) > 1:
        raise ValueError(f"{method} at size {size} mixes runs of (colours, demos, iterations) {sorted(shapes)}; {fix}")
    seeds = [r["seed"] for r in group]
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"{method} at size {size} has seed(s) repeated: {sorted(seeds)}; {fix}")


def summarise(rows, config=None, command=None, pairs=()):
    """Per method and size: the runs (seeds), their mean success rate with its 95% interval over seeds
    and scored colours (`stats.interval`), the pooled successes / trials, and the lowest and highest
    rate over seeds; and for each (a, b) of `pairs`, at each size both have, the difference a - b with
    its interval paired over the colours (`stats.difference_interval`).

    -> {"methods": {method: [{"size", "colours", "demos_per_colour", "runs", "seeds", "successes",
    "trials", "mean_rate", "ci_low", "ci_high", "min_rate", "max_rate"}, ... by size]}, "differences":
    [{"a", "b", "size", "difference", "ci_low", "ci_high"}], "interval": stats.METHOD, "runs": n,
    "config": asdict(config), "command": command} (the last two when given).
    """
    groups = _groups(rows)
    methods = {}
    for (method, size), group in sorted(groups.items()):
        group = sorted(group, key=lambda r: r["seed"])
        mean, lo, hi = stats.interval(*stats.counts(group))
        rates = [r["successes"] / r["trials"] for r in group]
        methods.setdefault(method, []).append({
            "size": size, "colours": group[0]["colours"], "demos_per_colour": group[0]["demos_per_colour"],
            "runs": len(group), "seeds": [r["seed"] for r in group], "successes": sum(r["successes"] for r in group),
            "trials": sum(r["trials"] for r in group), "mean_rate": mean, "ci_low": lo, "ci_high": hi,
            "min_rate": min(rates), "max_rate": max(rates)})
    differences = []
    for a, b in pairs:
        for size in sorted({s for m, s in groups if m == a} & {s for m, s in groups if m == b}):
            d, lo, hi = stats.difference_interval(stats.counts(groups[a, size]), stats.counts(groups[b, size]))
            differences.append({"a": a, "b": b, "size": size, "difference": d, "ci_low": lo, "ci_high": hi})
    summary = {"methods": methods, "differences": differences, "interval": stats.METHOD, "runs": len(rows)}
    if config is not None:
        summary["config"] = dataclasses.asdict(config)
    if command is not None:
        summary["command"] = command
    return summary


def compare(mine, theirs):
    """A reproduction check: for every point (method, size) in both sets of rows, the difference of mean
    rates mine - theirs with its interval (seeds of each resampled, colours paired) and whether it holds 0.
    -> [{"method", "size", "mine", "theirs", "difference", "ci_low", "ci_high", "agree"}]."""
    a, b = _groups(mine), _groups(theirs)
    out = []
    for key in sorted(set(a) & set(b)):
        ours, others = stats.counts(a[key]), stats.counts(b[key])
        if ours[0].shape[1] != others[0].shape[1]:              # scored on other colours: compare totals only
            ours, others = (tuple(x.sum(1, keepdims=True) for x in p) for p in (ours, others))
        d, lo, hi = stats.difference_interval(ours, others)
        out.append({"method": key[0], "size": key[1], "mine": stats.mean_rate(*ours), "theirs": stats.mean_rate(*others),
                    "difference": d, "ci_low": lo, "ci_high": hi, "agree": lo <= 0 <= hi})
    return out


SCORED = ("validation", "test")        # the splits an evaluate result scores (its "train" is a contrast)
POOLED = ("split", "dataset", "colours", "trials_per_colour", "eval_seed", "method", "recipe")  # must agree


def _count(value, low=0, high=math.inf):
    """value as an int in [low, high] (not a bool, not a float), else ValueError."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ValueError(value)
    return value


def _evaluation(result, name):
    """One evaluate --json result as a row: its policy, split and per-colour success counts, every count
    checked against its totals. ValueError names the file and what is wrong."""
    scored = [s for s in SCORED if s in result] if isinstance(result, dict) else []
    if len(scored) > 1:
        raise ValueError(f"{name} scores {' and '.join(scored)}: pool results of one split")
    try:
        policy, r = result["policy"], result[scored[0]]
        per_trial = _count(policy["trials_per_colour"], 1)
        rates = r["per_colour"]
        if not isinstance(rates, dict) or not rates:
            raise ValueError(rates)
        colours = sorted(rates, key=int)
        counts = {}
        for c in colours:
            won = float(rates[c]) * per_trial
            if not 0 <= won <= per_trial or abs(won - round(won)) > 1e-6:
                raise ValueError(c)
            counts[c] = round(won)
        row = {"file": name, "split": scored[0], "colours": colours, "per_colour": counts,
               "successes": _count(r["successes"]), "trials": _count(r["trials"], 1),
               "checkpoint": str(policy["checkpoint"]), "training_seed": _count(policy["training_seed"]),
               "trials_per_colour": per_trial, "eval_seed": _count(policy["eval_seed"]),
               "method": str(policy["method"]), "dataset": str(policy["dataset"]),
               "recipe": json.dumps(policy["recipe"], sort_keys=True)}
    except (AttributeError, IndexError, KeyError, OverflowError, TypeError, ValueError):
        raise ValueError(f"{name} is not one split's result of `python -m oneshot.evaluate CKPT --split S --json "
                         f"FILE` (this version's, which records its policy, with rates of whole trials); run that "
                         f"command again") from None
    if sum(counts.values()) != row["successes"] or row["trials"] != per_trial * len(colours):
        raise ValueError(f"{name}: its per-colour rates ({sum(counts.values())} successes in {per_trial} trials x "
                         f"{len(colours)} colours) disagree with its totals ({row['successes']}/{row['trials']}); "
                         f"run evaluate again")
    return row


def read_evaluations(paths):
    """The results that `python -m oneshot.evaluate CHECKPOINT --json FILE` wrote, one file per path; a
    missing file, or one that is not JSON, raises an error naming it and what to give instead."""
    results = []
    for path in paths:
        if not os.path.isfile(path):
            raise FileNotFoundError(f"no file {path}; name the JSON files of `python -m oneshot.evaluate CHECKPOINT "
                                    f"--json FILE`, one per training seed")
        with open_read(path, "r") as f:
            try:
                results.append(loads_json(f.read()))
            except ValueError as e:
                raise ValueError(f"{path} is not JSON ({e}); name evaluate's --json files") from None
    return results


def _differing(rows, key):
    """What differs in `key` between the rows, for a message: the recipe's entries that differ (the
    recipe is long, and its first entries are the same), or each file's value."""
    if key == "recipe":
        recipes = [json.loads(row[key]) for row in rows]
        names = sorted(k for k in set().union(*recipes) if len({json.dumps(r.get(k)) for r in recipes}) > 1)
        return "; ".join(f"{row['file']}: " + ", ".join(f"{k}={r.get(k)!r}" for k in names)
                         for row, r in zip(rows, recipes))
    return "; ".join(f"{row['file']}: {str(row[key])[:80]}" for row in rows)


def pool_evaluations(results, names):
    """The mean over training seeds of one recipe's policies, each scored by `python -m oneshot.evaluate
    CKPT --split S --json FILE` on the same split, colours and scenes, with its 95% interval over seeds
    and colours (`stats.interval`): how a training profile is reported (Section IV's success rates),
    not one lucky run.

    results: the JSON of each file (at least two); names: the files, for messages. ValueError if a file
    is not evaluate's, or its counts disagree with its totals, or the results do not pool: another split,
    dataset, colours, trials, trial scenes, method or recipe (the training config but its seed and data
    paths, evaluate's --raw, --alpha, --inner-steps, --demo-scenes and --other-colour-demo), or a training
    seed twice.
    -> {"split", "dataset", "colours", "trials_per_colour", "eval_seed", "method", "policies": [{"file",
    "checkpoint", "training_seed", "successes", "trials", "rate"}], "successes", "trials", "mean_rate",
    "ci_low", "ci_high", "min_rate", "max_rate", "interval": stats.METHOD}.
    """
    if len(results) < 2:
        raise ValueError(f"{len(results)} result given: the mean over seeds needs the results of two or more "
                         f"training seeds (one policy's own interval is the one evaluate printed)")
    rows = [_evaluation(result, name) for result, name in zip(results, names)]
    for key in POOLED:
        values = {str(row[key]) for row in rows}
        if len(values) > 1:
            raise ValueError(f"these results differ in {key} ({_differing(rows, key)}): pool one recipe's policies "
                             f"scored on the same split, colours and scenes (evaluate's --split, --trials and --seed; "
                             f"the recipe: the training config, --alpha, --inner-steps, --raw, --demo-scenes and "
                             f"--other-colour-demo)")
    by_seed = {}
    for row in rows:
        by_seed.setdefault(row["training_seed"], []).append(row["file"])
    twice = {seed: paths for seed, paths in by_seed.items() if len(paths) > 1}
    if twice:
        raise ValueError(f"training seed(s) repeated: {twice}; pool one result per trained policy")
    rows.sort(key=lambda row: row["training_seed"])
    colours = rows[0]["colours"]
    successes = np.array([[row["per_colour"][c] for c in colours] for row in rows], np.int64)
    mean, lo, hi = stats.interval(successes, np.full_like(successes, rows[0]["trials_per_colour"]))
    rates = [row["successes"] / row["trials"] for row in rows]
    first = rows[0]
    return {**{k: first[k] for k in ("split", "dataset", "trials_per_colour", "eval_seed", "method")},
            "colours": len(colours),
            "policies": [{k: row[k] for k in ("file", "checkpoint", "training_seed", "successes", "trials")}
                         | {"rate": row["successes"] / row["trials"]} for row in rows],
            "successes": sum(row["successes"] for row in rows), "trials": sum(row["trials"] for row in rows),
            "mean_rate": mean, "ci_low": lo, "ci_high": hi, "min_rate": min(rates), "max_rate": max(rates),
            "interval": stats.METHOD}


def write_summary(summary, path):
    """summary.json, atomically."""
    with atomic_write(path) as f:
        f.write((json.dumps(summary, indent=1) + "\n").encode("utf-8"))
