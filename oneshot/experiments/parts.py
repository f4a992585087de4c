"""A part of a Figure 2 sweep (`fig2 --seeds S ... --lines L ... --sizes N ...`): the profile narrowed to
the chosen seeds, lines and sizes, and the suffix that names the part's summary and figure
(summary<suffix>.json, fig2<suffix>.png), so that a part never takes the whole figure's file names."""
import dataclasses
import hashlib


def narrow(cfg, seeds=None, lines=None, sizes=None):
    """(cfg narrowed to the chosen seeds, lines and sizes (None: all of the profile's), the file-name suffix
    ("" when every one is chosen), the part in words for the figure's title). sizes in demonstrations
    (colours x demos per colour). Raises ValueError naming the flag when a choice is not the profile's."""
    part, words = "", f"{len(cfg.seeds)} seed{'s' * (len(cfg.seeds) > 1)}"
    if seeds is not None:
        if set(seeds) - set(cfg.seeds) or len(set(seeds)) != len(seeds):
            raise ValueError(f"--seeds must be distinct seeds of the {cfg.name} profile, {list(cfg.seeds)}; "
                             f"got {list(seeds)}")
        if set(seeds) != set(cfg.seeds):
            chosen = sorted(seeds)
            part = "_seeds" + "-".join(map(str, chosen))
            words = f"seed{'s' * (len(chosen) > 1)} {', '.join(map(str, chosen))} of {len(cfg.seeds)}"
        cfg = dataclasses.replace(cfg, seeds=tuple(sorted(seeds)))
    if lines is not None:
        if set(lines) - set(cfg.methods) or len(set(lines)) != len(lines):
            raise ValueError(f"--lines must be distinct lines of the {cfg.name} profile ({', '.join(cfg.methods)}); "
                             f"got {' '.join(lines)}")
        if set(lines) != set(cfg.methods):
            chosen = [m for m in cfg.methods if m in lines]               # the profile's order
            part += "_" + lines_part(chosen)
            words += f", {', '.join(chosen)}"
            cfg = dataclasses.replace(cfg, methods=tuple(chosen))
    if sizes is not None:
        profile = {c * d: (c, d) for c, d in cfg.sizes}
        if set(sizes) - set(profile) or len(set(sizes)) != len(sizes):
            raise ValueError(f"--sizes must be distinct sizes of the {cfg.name} profile, in demonstrations "
                             f"({', '.join(map(str, sorted(profile)))}); got {' '.join(map(str, sizes))}")
        if set(sizes) != set(profile):
            chosen = sorted(sizes)
            part += "_sizes" + "-".join(map(str, chosen))
            words += f", {', '.join(map(str, chosen))} demonstrations"
            cfg = dataclasses.replace(cfg, sizes=tuple(profile[n] for n in chosen))
    return cfg, part, words


def lines_part(lines):
    """The part of a summary's file name that names `--lines`: the lines joined by "_", or for many lines
    (a file name must stay under the 255 bytes of most file systems) "<N>lines-<hash of the names>"."""
    named = "_".join(lines)
    return named if len(named) <= 100 else f"{len(lines)}lines-{hashlib.sha256(named.encode()).hexdigest()[:8]}"
