"""Ceilings for the policy network (`python -m oneshot.benchmark privileged`): plain behavioural cloning
on all meta-training demos when the policy is GIVEN what one-shot imitation must infer (the target's
position, or its colour), scored on validation colours. If these are high, what remains hard is the
one-shot identification of the colour, i.e. meta-learning itself."""
import dataclasses

import numpy as np
from autograd import grad
from tqdm import tqdm

from oneshot.data import datasets
from oneshot.maml import imitation, optim
from oneshot.policy import network
from oneshot.world import palette
from oneshot.training.scoring import wilson_interval
from oneshot.world.reach import ReachWorld



def bench_privileged(given="colour", steps=3000, batch=16, trials=60, feature_points=False, seed=0,
                     train_data="data/train.npz", lr=1e-3):
    """Behavioural cloning with privileged inputs: the ceiling of the network, not a method.

    given="position": the target's position (m / 0.2) is appended to the robot state.
    given="colour":   the target colour's RGB in [0, 1] is appended to every pixel (3 more input
                      channels to the first convolution; MIL's contextual policy gets a demo image there).
    Trains the policy network (`oneshot.policy.network`) on all demos of `train_data` with Adam, `batch`
    demos per step, then runs it in `trials` new scenes of validation colours, seeded by `seed` as
    evaluate's trial scenes are (`imitation.trial_seed`).
    """
    if given not in ("position", "colour"):
        raise ValueError(f"given must be 'position' or 'colour'; got {given!r}")
    ds = datasets.load(train_data)
    if ds["metadata"].get("split") != "train":        # else it would be scored on the colours it trained on
        raise datasets.DatasetError(f"{train_data} holds {ds['metadata'].get('split')} colours, not meta-training "
                                    f"colours; name a train split's dataset with --train-data")
    world_cfg = datasets.world_config(ds["metadata"])
    max_torque = world_cfg.arm.max_torque
    rgb = palette.palette_rgb(world_cfg.palette).astype(np.float32) / 255     # (colours, 3)
    images, states, actions = imitation.prepare_demos(ds["images"], ds["states"], ds["actions"], max_torque)
    n, k, T = states.shape[:3]
    target = ds["positions"][np.arange(n)[:, None], np.arange(k), ds["target_index"].astype(int)]  # (N, K, 2)
    rng = np.random.default_rng(seed)
    net_cfg = network.NetworkConfig(image_size=images.shape[-2], feature_points=feature_points,
                                    state_dim=8 if given == "position" else 6)
    params = network.init_params(net_cfg, rng)
    if given == "colour":                                      # first convolution sees 6 channels
        w = params["conv0_w"]
        params["conv0_w"] = (rng.standard_normal((*w.shape[:2], 6, w.shape[3])) *
                             np.sqrt(2 / (9 * 6))).astype(np.float32)

    def inputs(im, st, tgt, colour):
        """im (B, H, W, 3), st (B, 6), tgt (B, 2) m, colour (B, 3) -> network inputs."""
        if given == "position":
            return im, np.concatenate([st, tgt / np.float32(0.2)], -1).astype(np.float32)
        return np.concatenate([im, np.broadcast_to(colour[:, None, None, :], im.shape)], -1), st

    def loss(p, im, st, act):
        return imitation.imitation_loss(p, (im, st, act)) / len(act)     # eq. (2), per frame

    def policy(im, st, scene):
        """The network given a trial scene's target position or colour (`imitation.rollout`)."""
        im, st = inputs(im, st, scene.target_position.astype(np.float32)[None], rgb[scene.target_colour][None])
        return network.forward(params, im, st)

    g, adam = grad(loss), optim.adam_init(params)
    colours = rgb[ds["task_colours"].astype(int)]
    for _ in tqdm(range(steps), desc=f"BC, {given} given"):
        ti, ki = rng.integers(n, size=batch), rng.integers(k, size=batch)
        im, st = inputs(images[ti, ki].reshape(-1, *images.shape[-3:]), states[ti, ki].reshape(-1, 6),
                        np.repeat(target[ti, ki], T, 0), np.repeat(colours[ti], T, 0))
        params, adam = optim.adam_step(params, g(params, im, st, actions[ti, ki].reshape(-1, 2)), adam, lr)
    world = ReachWorld(dataclasses.replace(world_cfg, split="validation"))
    wins = sum(imitation.rollout(policy, world, imitation.trial_seed(seed, 0, j))["success"]
               for j in tqdm(range(trials), desc="validation trials"))
    return {"given": given, "feature_points": feature_points, "steps": steps, "batch_demos": batch,
            "seed": seed, "validation_trials": trials, "validation_success": wins / trials,
            "ci95": wilson_interval(wins, trials)}
