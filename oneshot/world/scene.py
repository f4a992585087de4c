"""A scene: what one episode of a task starts from (paper Section IV): a target disc of the task's colour
and distractor discs of other colours of the same split, at reachable positions apart from each other.

    scene = sample_scene(target_colour, rng, world_config)      # a random scene of the task
    scene = check_scene(scene, world_config)                    # a given one, checked and copied

`oneshot.world.reach.ReachWorld.reset` samples one, or takes one as its "scene" option.
"""
from dataclasses import dataclass

import numpy as np

from oneshot.tools.checks import whole_number
from oneshot.world import palette


@dataclass(frozen=True)
class Scene:
    """One arrangement: colours (n,) palette indices, positions (n, 2) metres, target index."""
    colours: np.ndarray
    positions: np.ndarray
    target: int = 0

    @property
    def target_colour(self):
        return int(self.colours[self.target])

    @property
    def target_position(self):
        return self.positions[self.target]


def check_scene(scene, cfg):
    """A copy of `scene` (so that writing into the caller's arrays cannot move the world's discs), if it is
    a `Scene` the world can show: colours (n,) integer palette indices, positions (n, 2) finite metres
    inside the arena, an int target index; else a ValueError naming the reset option and the fix."""
    fix = "build one with oneshot.world.scene.Scene(colours, positions, target), or sample_scene"
    if not isinstance(scene, Scene):
        raise ValueError(f"reset option 'scene' must be a oneshot.world.scene.Scene; got {type(scene).__name__}; {fix}")
    colours, positions = np.asarray(scene.colours), np.asarray(scene.positions)
    if colours.dtype.kind not in "iu":
        raise ValueError(f"reset option 'scene': colours must be integer palette indices; got {colours.dtype} "
                         f"{colours.tolist()}; pass np.array(colours, dtype=int)")
    a = cfg.arena_half_width
    if positions.dtype.kind not in "iuf" or not np.all(np.abs(positions) <= a):     # False for NaN too
        raise ValueError(f"reset option 'scene': positions must be finite metres inside the arena [-{a}, {a}]^2; "
                         f"got {positions.tolist()}; replace the NaN, inf or outside positions")
    target = whole_number("reset option 'scene': target", scene.target, "pass the index of the target object")
    if colours.ndim != 1 or positions.shape != (len(colours), 2):
        raise ValueError(f"scene needs colours (n,) and positions (n, 2); "
                         f"got {colours.shape} and {positions.shape}")
    if not 0 <= target < len(colours):
        raise ValueError(f"scene target index {target} is out of range for {len(colours)} objects")
    n = palette.n_colours(cfg.palette)
    if colours.min() < 0 or colours.max() >= n:
        raise ValueError(f"scene colours must be palette indices in [0, {n}); got {colours}")
    return Scene(colours.copy(), positions.astype(np.result_type(positions, float)), target)


def sample_positions(n, rng, cfg):
    """n reachable object positions, pairwise more than cfg.min_separation apart. -> (n, 2) metres."""
    for _ in range(10000):
        r = np.sqrt(rng.uniform(cfg.min_object_radius ** 2, cfg.max_object_radius ** 2, n))
        a = rng.uniform(-np.pi, np.pi, n)
        p = np.stack([r * np.cos(a), r * np.sin(a)], -1)
        d = np.linalg.norm(p[:, None] - p[None], axis=-1) + np.eye(n) * 1e9
        if d.min() > cfg.min_separation:
            return p
    raise ValueError(f"could not place {n} objects {cfg.min_separation} m apart; "
                     f"lower n_objects or min_separation")


def sample_scene(target_colour, rng, cfg):
    """A random scene for the task `target_colour` (a palette index of cfg.split)."""
    colours = palette.sample_scene_colours(target_colour, cfg.n_objects, cfg.split, rng, cfg.palette)
    positions = sample_positions(cfg.n_objects, rng, cfg)
    order = rng.permutation(cfg.n_objects)          # the target is not always object 0
    return Scene(colours=colours[order], positions=positions, target=int(np.argmin(order)))
