"""Intervals for Figure 2 that include the variance between training seeds, not only the binomial one.

Every run of a point (one line, one data size) is scored on the same colours and scenes; the runs
differ in their training seed. Two sources of variation matter to a reader: another seed trains another
policy, and other colours would be easier or harder. So a point's 95% interval is a two-level
bootstrap: each replicate draws the seeds with replacement and, independently, the scored colours with
replacement (the same colours for every seed, as the runs share them), and takes the mean over the
drawn seeds of the success rate on the drawn colours. A difference between two lines is bootstrapped
the same way, paired over the colours (one colour draw for both lines) and with each line's seeds
drawn on their own: `difference_interval`.

    successes, trials = counts(rows)                     # (seeds, colours) arrays of a point's runs
    mean, lo, hi = interval(successes, trials)
"""
import json

import numpy as np

REPLICATES = 4000           # bootstrap replicates per interval
SEED = 0                    # the bootstrap's random seed: the same rows give the same interval
METHOD = (f"95% two-level bootstrap percentile interval: seeds and scored colours resampled with "
          f"replacement, {REPLICATES} replicates, seed {SEED}")


def counts(rows):
    """(successes, trials), each (seeds, colours) int arrays, of the runs of one point: the successes of
    each run on each scored colour (its notes' per_colour), in one colour order. Rows without per-colour
    counts (or with different colours) count as one colour each: then only the seeds are resampled."""
    colours = [json.loads(r["notes"]).get("per_colour") if isinstance(r.get("notes"), str) else None for r in rows]
    if colours and all(colours) and all(c.keys() == colours[0].keys() for c in colours):
        order = sorted(colours[0], key=int)
        successes = np.array([[c[k] for k in order] for c in colours], np.int64)
        per_colour = np.array([r["trials"] // len(order) for r in rows], np.int64)
        if np.all(per_colour * len(order) == [r["trials"] for r in rows]):
            return successes, np.repeat(per_colour[:, None], len(order), axis=1)
    return (np.array([[r["successes"]] for r in rows], np.int64), np.array([[r["trials"]] for r in rows], np.int64))


def _draws(rng, n_seeds, n_colours):
    """Replicate indices: seeds (REPLICATES, n_seeds), colours (REPLICATES, n_colours)."""
    return rng.integers(n_seeds, size=(REPLICATES, n_seeds)), rng.integers(n_colours, size=(REPLICATES, n_colours))


def _rates(successes, trials, seeds, colours):
    """(REPLICATES,) the mean over the drawn seeds of the success rate on the drawn colours."""
    won = successes[seeds[:, :, None], colours[:, None, :]].sum(-1)
    tried = trials[seeds[:, :, None], colours[:, None, :]].sum(-1)
    return (won / tried).mean(-1)


def mean_rate(successes, trials):
    """The point's rate: the mean over its seeds of each seed's success rate."""
    return float((successes.sum(1) / trials.sum(1)).mean())


def interval(successes, trials, level=0.95):
    """(mean rate, low, high): the mean over seeds and the two-level bootstrap interval (module docstring).
    successes, trials: (seeds, colours) counts of one point's runs."""
    successes, trials = np.asarray(successes), np.asarray(trials)
    if successes.shape != trials.shape or successes.ndim != 2 or not successes.size or np.any(trials < 1) \
            or np.any(successes < 0) or np.any(successes > trials):
        raise ValueError(f"need (seeds, colours) successes within trials >= 1; got {successes.shape} and {trials.shape}")
    rng = np.random.default_rng(SEED)
    rates = _rates(successes, trials, *_draws(rng, *successes.shape))
    lo, hi = np.quantile(rates, [(1 - level) / 2, (1 + level) / 2])
    return mean_rate(successes, trials), float(lo), float(hi)


def difference_interval(a, b, level=0.95):
    """(difference of mean rates a - b, low, high), paired over colours: a and b are (successes, trials)
    of two points scored on the same colours (the same columns), each with its own seeds."""
    (sa, ta), (sb, tb) = (tuple(np.asarray(x) for x in p) for p in (a, b))
    if sa.shape[1] != sb.shape[1]:
        raise ValueError(f"a paired difference needs the same colours; got {sa.shape[1]} and {sb.shape[1]}")
    rng = np.random.default_rng(SEED)
    seeds_a, colours = _draws(rng, sa.shape[0], sa.shape[1])
    seeds_b = rng.integers(sb.shape[0], size=(REPLICATES, sb.shape[0]))
    diffs = _rates(sa, ta, seeds_a, colours) - _rates(sb, tb, seeds_b, colours)
    lo, hi = np.quantile(diffs, [(1 - level) / 2, (1 + level) / 2])
    return mean_rate(sa, ta) - mean_rate(sb, tb), float(lo), float(hi)
