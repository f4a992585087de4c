"""The random policy, a baseline of paper Section IV: Gaussian torques of a fixed standard deviation,
ignoring everything. Not trained by gradient: of `TrainConfig.random_stds`, the std that scores best in
one-shot trials is kept (`fit`), as the paper reports the best.
"""
import numpy as np

from oneshot.maml import imitation
from oneshot.methods.base import INNER_LOOP_FIELDS, Method


def random_policy(std, rng):
    """Gaussian torques: a function (image, state, scene) -> action (1, 2) ~ N(0, std^2), network units
    (std in units of the torque bound: std = 1 is the bound itself). rng: np.random.Generator."""
    return lambda image, state, scene: std * rng.standard_normal((1, 2))


class RandomPolicy(Method):
    """Gaussian torques; its one parameter is the torque std (units of the torque bound)."""

    name = "random"
    learns = False
    has_network = False
    ignores = (*INNER_LOOP_FIELDS, "lstm_units")

    def init_params(self, net_cfg, rng):
        return {"std": np.array([self.cfg.random_stds[0]], np.float32)}

    def parameter_count(self, net_cfg):
        return 1

    def fit(self, params, dataset, trials, seed):
        """The best std of cfg.random_stds by one-shot success on `dataset` (`trials` per colour, scenes
        and torques from `seed`). Returns ({"std": (1,)}, {std: success rate})."""
        scores = {}
        for std in self.cfg.random_stds:
            condition = self.conditioner({"std": np.array([std], np.float32)}, seed=seed)
            scores[std] = imitation.one_shot_success(condition, dataset, trials, seed=seed, progress=False)["rate"]
        best = max(self.cfg.random_stds, key=lambda s: scores[s])
        return {"std": np.array([best], np.float32)}, scores

    def conditioner(self, params, seed=0):
        rng = np.random.default_rng(seed)
        return lambda demo: random_policy(float(params["std"][0]), rng)

    def notes(self, params):
        return {"std": round(float(params["std"][0]), 6)}
