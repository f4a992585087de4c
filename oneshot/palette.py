"""Colours, and so tasks: a task is "reach the object of colour c" (paper Section IV).

The palette is `size` fully saturated hues, evenly spaced around the colour wheel. Every
`heldout_every`-th hue is held out: it never appears in meta-training, not even as a distractor, so
at meta-test the policy meets a colour it has never seen. Within one scene, any two objects differ
in hue by at least `min_separation_deg`, so the colours are clearly distinguishable even at 32x32.
"""
import colorsys
from dataclasses import dataclass

import numpy as np

SPLITS = ("train", "heldout")


@dataclass(frozen=True)
class PaletteConfig:
    size: int = 48                   # hues, 7.5 degrees apart
    heldout_every: int = 4           # every 4th hue is held out: 36 training, 12 held-out colours
    min_separation_deg: float = 60.0  # minimum hue difference between objects of one scene


def palette_rgb(cfg=PaletteConfig()):
    """All palette colours. Returns (size, 3) uint8; row i is hue 360 i / size degrees."""
    rgb = [colorsys.hsv_to_rgb(i / cfg.size, 1.0, 1.0) for i in range(cfg.size)]
    return np.round(np.array(rgb) * 255).astype(np.uint8)


def split_colours(split, cfg=PaletteConfig()):
    """Palette indices of a split. split: "train" or "heldout" -> (n,) int, sorted."""
    if split not in SPLITS:
        raise ValueError(f"unknown colour split {split!r}; use one of {SPLITS}")
    idx = np.arange(cfg.size)
    heldout = idx % cfg.heldout_every == 0
    return idx[heldout] if split == "heldout" else idx[~heldout]


def hue_distance_deg(i, j, cfg=PaletteConfig()):
    """Angular distance in degrees between the hues of palette indices i and j (broadcasts)."""
    k = np.abs(np.asarray(i) - np.asarray(j)) % cfg.size
    return np.minimum(k, cfg.size - k) * 360.0 / cfg.size


def check_colour(colour, split, cfg=PaletteConfig()):
    """Raise ValueError unless `colour` is a palette index belonging to `split`."""
    allowed = split_colours(split, cfg)
    if not (np.issubdtype(type(colour), np.integer) or isinstance(colour, int)) or colour not in allowed:
        raise ValueError(f"colour {colour!r} is not a {split!r} colour; "
                         f"choose a palette index from {allowed.tolist()}")


def sample_scene_colours(target, n_objects, split, rng, cfg=PaletteConfig()):
    """Colours of one scene: the target first, then distractors from the same split.

    target: palette index; returns (n_objects,) int with pairwise hue distance >= min_separation_deg.
    """
    check_colour(target, split, cfg)
    chosen = [int(target)]
    candidates = split_colours(split, cfg)
    for _ in range(n_objects - 1):
        ok = [c for c in candidates if np.all(hue_distance_deg(c, chosen, cfg) >= cfg.min_separation_deg)]
        if not ok:
            raise ValueError(f"cannot find {n_objects} colours {cfg.min_separation_deg} degrees apart "
                             f"in the {split!r} split; lower min_separation_deg or n_objects")
        chosen.append(int(rng.choice(ok)))
    return np.array(chosen)
