"""One-shot success rate of a meta-trained policy: `python -m oneshot.evaluate CHECKPOINT --help`.

Paper Section IV's protocol: for each colour of a held-out split (validation or test), take ONE demonstration of it, adapt (eq. 1),
and run the adapted policy in new scenes of that colour (new positions, new distractors); success is
the end effector within 0.05 m of the target over the final fifth of the episode. Reported with a
95% Wilson score interval, and on meta-training colours for contrast.
"""
import math

from oneshot.data import datasets
from oneshot.maml import imitation
from oneshot.world import palette


def wilson_interval(successes, trials, z=1.96):
    """95% Wilson score interval (lo, hi) for a success rate. It always holds the observed rate; at no
    or all successes rounding put its end one ulp inside it (wilson_interval(6, 6)[1] was
    0.9999999999999999), so the ends are held to the rate."""
    if trials == 0:
        return 0.0, 1.0
    p = successes / trials
    centre = (p + z * z / (2 * trials)) / (1 + z * z / trials)
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / (1 + z * z / trials)
    return min(p, max(0.0, centre - half)), max(p, min(1.0, centre + half))


def colour_breakdown(result, trials_per_colour, metadata):
    """One line of per-colour successes, e.g. "hue 0 deg 10/10; hue 30 deg 8/10; ...", in colour order:
    which new colours are hard (on the default palette, the hues half-way between the primaries and
    secondaries; docs/results.md, "Which colours fail")."""
    cfg = datasets.world_config(metadata).palette
    return "; ".join(f"{palette.colour_name(c, cfg)} {round(rate * trials_per_colour)}/{trials_per_colour}"
                     for c, rate in sorted(result["per_colour"].items()))


def adaptation_gain(params, dataset, condition, pairs=5):
    """Does adapting on one demo help on ANOTHER demo of the same colour? (Cheap, and far less noisy
    than rollouts.) For each task and j < pairs: adapt on demo j, score eq. (2) on demo j + 1.

    condition(demo) -> adapted parameters: a method's conditioner (`methods.of(cfg).conditioner(params)`).

    Returns {"before": mean loss of the unadapted policy on demo j + 1, "after": the same after
    adapting on demo j, "pairs": how many (demo, demo) pairs were scored}.
    """
    n, k = dataset["images"].shape[:2]
    pairs = min(pairs, k - 1)
    if pairs < 1:
        raise ValueError(f"adaptation_gain needs >= 2 demos per task; the dataset has {k}")
    world_cfg = datasets.world_config(dataset["metadata"])
    demos = imitation.prepare_demos(dataset["images"][:, :pairs + 1], dataset["states"][:, :pairs + 1],
                                    dataset["actions"][:, :pairs + 1], world_cfg.arm.max_torque)
    before, after = [], []
    for i in range(n):
        for j in range(pairs):
            adapt_demo, eval_demo = (tuple(a[i, j] for a in demos), tuple(a[i, j + 1] for a in demos))
            before.append(float(imitation.imitation_loss(params, eval_demo)))
            after.append(float(imitation.imitation_loss(condition(adapt_demo), eval_demo)))
    return {"before": sum(before) / len(before), "after": sum(after) / len(after), "pairs": len(before)}
