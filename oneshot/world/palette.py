"""Colours, and so tasks: a task is "reach the object of colour c" (paper Section IV).

Meta-learning needs many tasks: MIL meta-trained its simulated reaching on 750 to 1650 colours, while
the default palette here has 36. So there are two palettes, chosen by `PaletteConfig.mode`. Each has
three splits of colours (`split_colours`): meta-training colours, validation colours for every choice
(hyperparameters, iterations, early stopping, ablations), and test colours that no choice has seen,
scored once per trained policy. Validation and test colours are of the held-out hues:

- "hues" (the default, and the shipped policy's): 48 fully saturated hues, 7.5 degrees apart. Every
  4th hue (0, 30, ..., 330 degrees) is held out: 36 meta-training colours and 12 validation colours,
  each 7.5 degrees of hue from the nearest training colour. The 24 test colours are the fully saturated
  hues half-way between each held-out hue and its two training neighbours (3.75 and 26.25 degrees past
  each multiple of 30): of the palette's kind, but, the 7.5-degree wheel being full, 3.75 degrees from a
  training colour, nearer than the validation colours are.
- "grid": hue x saturation x value. 72 hues 5 degrees apart x saturations (1.0, 0.75, 0.5) x values
  (1.0, 0.8, 0.6) = 648 colours. The held-out hues are again every 30 degrees (0, 30, ..., 330, the
  same 12 hues as "hues" mode), with all 9 of their saturation/value variants: 108 held-out colours.
  A guard band (`guard` = 1 hue) either side of each held-out hue belongs to NEITHER split, so every
  held-out colour is at least 10 degrees of hue from every training colour. That leaves 36 training
  hues x 9 = 324 meta-training colours (and 216 unused guard colours). The 108 colours of the held-out
  hues are the validation colours; the 48 test colours are the held-out hues at saturations (0.875,
  0.625) x values (0.9, 0.7), between the validation colours' levels: 10 degrees of hue from every
  training colour, as the validation colours are, and distinct from every validation colour.

Minimum distances, RGB 0-255, Euclidean, over every pair (`tests/test_palette.py` checks them):

                                                   grid    hues
    any validation colour to any training colour   12.0    31.0   (grid: hues 10 deg apart, sat 0.5, val 0.6)
    any test colour to any training colour         26.9    16.0   (grid: 10 deg apart as validation; hues: 3.75)
    any test colour to any validation colour       27.7    15.0   (grid: the same hue, a level apart; hues: 3.75)
    any two training colours                        6.0    32.0   (grid: hues 5 deg apart, sat 0.5, val 0.6)
    training colours that can share a scene        56.8   185.7   (>= 60 deg apart in hue)
    any colour to the black background              153     255
    any colour to the white arm                     127     255   (grid: pale yellow, 255 255 128)

The small margins are all at the dull corner (saturation 0.5, value 0.6: chroma 0.3), where 5 degrees
of hue moves one channel by about 6 units. The centre pixel of a disc keeps its exact colour at 32x32
(`oneshot.world.render` antialiases only the rim), so even these are visible to the network. Other levels buy
little: values (1.0, 0.85, 0.7) raise the held-out margin to 14, saturations (1.0, 0.8, 0.55) with
those values to 16 (and the training minimum to 8), so the grid keeps its evenly spaced levels.

Both modes: validation and test colours never appear in meta-training, not even as distractors (a
scene's distractors come from its target's split), so at meta-test the policy meets colours it has never
seen; within one scene any two objects differ in HUE by at least `min_separation_deg` (60), so
distractors are clearly different colours even at low saturation.

Colour indices are plain ints 0 .. n_colours(cfg) - 1. The grid's come first, hue-major: index = hue *
per_hue + variant, with variant = saturation level * len(values) + value level; then the test colours,
held-out hue by held-out hue, `test_colours` each. In "hues" mode per_hue is 1, so an index below 48 is
its hue, and every colour has the index it had before the test split existed.
"""
import colorsys
from dataclasses import dataclass

import numpy as np

from oneshot.tools.checks import whole_number

SPLITS = ("train", "validation", "test")
LEGACY_SPLITS = {"heldout": "validation"}   # what older datasets and checkpoints call a split
MODES = ("hues", "grid")

# The defaults each mode gives the fields left at None (see PaletteConfig).
_DEFAULTS = {
    "hues": {"size": 48, "heldout_every": 4, "saturations": (1.0,), "values": (1.0,), "guard": 0,
             "test_colours": ((-3.75, 1.0, 1.0), (3.75, 1.0, 1.0))},
    "grid": {"size": 72, "heldout_every": 6, "saturations": (1.0, 0.75, 0.5), "values": (1.0, 0.8, 0.6),
             "guard": 1, "test_colours": ((0.0, 0.875, 0.9), (0.0, 0.875, 0.7), (0.0, 0.625, 0.9),
                                          (0.0, 0.625, 0.7))},
}


@dataclass(frozen=True)
class PaletteConfig:
    """The colours. Fields left at None take their mode's default (_DEFAULTS), so PaletteConfig() is
    the 48-hue palette and PaletteConfig(mode="grid") the 648-colour grid; the saved config (and so a
    dataset's metadata) holds the resolved numbers. Build a grid with PaletteConfig(mode="grid"), not
    dataclasses.replace(PaletteConfig(), mode="grid"), which keeps the hues palette's numbers."""
    size: int = None                  # hues around the wheel, 360 / size degrees apart (48; grid 72)
    heldout_every: int = None         # every n-th hue is held out, with all its variants (4; grid 6)
    min_separation_deg: float = 60.0  # minimum hue difference between objects of one scene
    mode: str = "hues"                # "hues" or "grid" (the module docstring)
    saturations: tuple = None         # saturation levels of every hue ((1.0,); grid (1.0, 0.75, 0.5))
    values: tuple = None              # value (brightness) levels ((1.0,); grid (1.0, 0.8, 0.6))
    guard: int = None                 # hues either side of a held-out hue used by neither split (0; grid 1)
    test_colours: tuple = None        # (hue offset deg, saturation, value) of the test colours at each held-out hue

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"unknown palette mode {self.mode!r}; use one of {MODES}")
        for name, default in _DEFAULTS[self.mode].items():
            if getattr(self, name) is None:
                object.__setattr__(self, name, default)
        for name in ("saturations", "values"):     # tuples of floats, also when read back from JSON lists
            levels = tuple(float(x) for x in getattr(self, name))
            if not levels or not all(0 < x <= 1 for x in levels):
                raise ValueError(f"palette {name} must be a non-empty sequence in (0, 1]; got {levels}")
            object.__setattr__(self, name, levels)
        for name in ("size", "heldout_every", "guard"):       # plain ints, as JSON saves them
            object.__setattr__(self, name, whole_number(f"palette {name}", getattr(self, name), "pass a whole number"))
        if self.size < 1 or self.heldout_every < 1 or self.guard < 0:
            raise ValueError(f"palette needs whole numbers size >= 1, heldout_every >= 1 and guard >= 0; "
                             f"got {self.size!r}, {self.heldout_every!r}, {self.guard!r}")
        triples = tuple(tuple(float(x) for x in t) for t in self.test_colours)
        step = 360.0 / self.size
        if not triples or not all(len(t) == 3 and abs(t[0]) < step and 0 < t[1] <= 1 and 0 < t[2] <= 1 for t in triples) \
                or {(0.0, s, v) for s in self.saturations for v in self.values} & set(triples):
            raise ValueError(f"palette test_colours must be (hue offset deg, saturation, value) triples, the offset "
                             f"under one hue step ({step:g} deg) and the levels in (0, 1], none of them a validation "
                             f"colour; got {self.test_colours}")
        object.__setattr__(self, "test_colours", triples)
        if self.guard > 0 and not np.any(hue_steps_to_heldout(self) > self.guard):
            raise ValueError(f"guard {self.guard} leaves no training hue between held-out hues "
                             f"{self.heldout_every} apart; lower guard or raise heldout_every")


def per_hue(cfg=PaletteConfig()):
    """Colours per hue: len(saturations) * len(values) (1 in "hues" mode, 9 in the default grid)."""
    return len(cfg.saturations) * len(cfg.values)


def saved_config(fields):
    """A PaletteConfig from its saved fields (a checkpoint's or a dataset's metadata, `asdict` of one).
    Files written between commits 87055e1 and 18fc823 name the test colours `test_levels`, (saturation,
    value) pairs at each held-out hue itself: those are the test colours (0, saturation, value), and they
    are read as such (the same colours, in the same order)."""
    fields = dict(fields)
    if "test_levels" in fields and "test_colours" not in fields:
        fields["test_colours"] = tuple((0.0, *level) for level in fields.pop("test_levels"))
    return PaletteConfig(**fields)


def n_grid(cfg=PaletteConfig()):
    """How many colours the hue x level grid has (48; the default grid 648): the train and validation
    colours (and guard colours) have indices below it, the test colours from it on."""
    return cfg.size * per_hue(cfg)


def heldout_hues(cfg=PaletteConfig()):
    """(k,) int: the held-out hue columns, whose colours are the validation and test colours."""
    return np.flatnonzero(hue_steps_to_heldout(cfg) == 0)


def n_colours(cfg=PaletteConfig()):
    """How many colours the palette has (72; the default grid 696). Indices run 0 .. n_colours - 1."""
    return n_grid(cfg) + len(heldout_hues(cfg)) * len(cfg.test_colours)


def colour_hue(i, cfg=PaletteConfig()):
    """The hue column (0 .. size - 1) of palette index i (broadcasts): its own, or a test colour's held-out
    hue (the test colour lies `test_colours` degrees from it). Its angle is 360 hue / size deg."""
    i, grid = np.asarray(i), n_grid(cfg)
    test = heldout_hues(cfg)[np.maximum(i - grid, 0) // len(cfg.test_colours) % len(heldout_hues(cfg))]
    return np.where(i < grid, i // per_hue(cfg), test)


def colour_hue_deg(i, cfg=PaletteConfig()):
    """The hue angle in degrees, [0, 360), of palette index i (broadcasts)."""
    i = np.asarray(i)
    offsets = np.array([t[0] for t in cfg.test_colours])[np.maximum(i - n_grid(cfg), 0) % len(cfg.test_colours)]
    return (colour_hue(i, cfg) * 360.0 / cfg.size + np.where(i < n_grid(cfg), 0.0, offsets)) % 360.0


def colour_levels(i, cfg=PaletteConfig()):
    """(saturation, value) of palette index i (broadcasts): two floats, or two arrays of i's shape."""
    i, grid = np.asarray(i), n_grid(cfg)
    test = np.array(cfg.test_colours)[np.maximum(i - grid, 0) % len(cfg.test_colours)]    # (..., 3)
    s, v = np.divmod(i % per_hue(cfg), len(cfg.values))                                    # level indices
    return (np.where(i < grid, np.array(cfg.saturations)[s], test[..., 1])[()],
            np.where(i < grid, np.array(cfg.values)[v], test[..., 2])[()])


def palette_rgb(cfg=PaletteConfig()):
    """All palette colours. Returns (n_colours, 3) uint8; row i is hue colour_hue_deg(i) at saturation
    and value colour_levels(i)."""
    # Hues and levels of all colours at once, then colorsys colour by colour: 0.35 ms for the grid,
    # where calling the helpers once per colour took 23 ms (and every ReachWorld builds this).
    i = np.arange(n_colours(cfg))
    hue, (s, v) = colour_hue_deg(i, cfg) / 360.0, colour_levels(i, cfg)
    rgb = [colorsys.hsv_to_rgb(*hsv) for hsv in zip(hue.tolist(), s.tolist(), v.tolist())]
    return np.round(np.array(rgb) * 255).astype(np.uint8)


def hue_steps_to_heldout(cfg=PaletteConfig()):
    """(size,) int: how many hue steps each hue is from the nearest held-out hue, around the wheel
    (0: held out; 1 .. guard: the guard band, in neither split; more: a training hue)."""
    hues = np.arange(cfg.size)
    held = hues[hues % cfg.heldout_every == 0]
    k = np.abs(hues[:, None] - held[None]) % cfg.size           # (size, held-out hues)
    return np.minimum(k, cfg.size - k).min(axis=1)


def split_colours(split, cfg=PaletteConfig()):
    """Palette indices of a split: "train", "validation" or "test" -> (n,) int, sorted."""
    if split not in SPLITS:
        raise ValueError(f"unknown colour split {split!r}; use one of {', '.join(SPLITS)}")
    if split == "test":
        return np.arange(n_grid(cfg), n_colours(cfg))
    idx = np.arange(n_grid(cfg))
    steps = hue_steps_to_heldout(cfg)[colour_hue(idx, cfg)]
    return idx[steps == 0] if split == "validation" else idx[steps > cfg.guard]


def hue_distance_deg(i, j, cfg=PaletteConfig()):
    """Angular distance in degrees between the hues of palette indices i and j (broadcasts)."""
    k = np.abs(colour_hue_deg(i, cfg) - colour_hue_deg(j, cfg)) % 360.0
    return np.minimum(k, 360.0 - k)


def colour_name(i, cfg=PaletteConfig()):
    """A short name for pictures and tables: "hue 30 deg"; in grid mode "hue 30 deg, sat 0.75, val 0.8"."""
    whole_number("colour", i, f"name a palette index in [0, {n_colours(cfg)})")
    if not 0 <= i < n_colours(cfg):
        raise ValueError(f"colour {i!r} is not a palette index (an int in [0, {n_colours(cfg)}))")
    name = f"hue {float(colour_hue_deg(i, cfg)):g} deg"
    if cfg.mode == "hues":
        return name
    s, v = colour_levels(i, cfg)
    return f"{name}, sat {s:g}, val {v:g}"


def check_colour(colour, split, cfg=PaletteConfig(), name="colour"):
    """Raise ValueError unless `colour` is a palette index belonging to `split`: a Python or NumPy int, not
    a bool (which NumPy reads as 0 or 1) nor a float. name: what the message calls it."""
    whole_number(name, colour, f"choose one of oneshot.world.palette.split_colours({split!r})")
    allowed = split_colours(split, cfg)
    if colour not in allowed:
        shown = allowed.tolist() if len(allowed) <= 48 else f"split_colours({split!r}, cfg) ({len(allowed)})"
        raise ValueError(f"colour {colour!r} is not a {split!r} colour; choose a palette index from {shown}")


def sample_scene_colours(target, n_objects, split, rng, cfg=PaletteConfig()):
    """Colours of one scene: the target first, then distractors from the same split.

    target: palette index; returns (n_objects,) int with pairwise hue distance >= min_separation_deg.
    """
    check_colour(target, split, cfg, name="target_colour")
    chosen = [int(target)]
    candidates = split_colours(split, cfg)
    for _ in range(n_objects - 1):
        far = hue_distance_deg(candidates[:, None], np.array(chosen)[None], cfg) >= cfg.min_separation_deg
        ok = candidates[far.all(axis=1)]      # (n,): colours far enough in hue from every one chosen
        if not len(ok):
            raise ValueError(f"cannot find {n_objects} colours {cfg.min_separation_deg} degrees apart "
                             f"in the {split!r} split; lower min_separation_deg or n_objects")
        chosen.append(int(rng.choice(ok)))
    return np.array(chosen)
