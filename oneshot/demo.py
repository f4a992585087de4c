"""The demo: `python -m oneshot.demo [--out DIR]`.

Shows the reaching world of paper Section IV and its iLQG expert: for a few tasks (target colours),
one expert demonstration each, saved as a film strip (PNG) and an animation (GIF), with the success
of each by the paper's criterion.
"""
import argparse
import os

import numpy as np

from oneshot import expert, palette, viz
from oneshot.world import ReachWorld, WorldConfig


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m oneshot.demo", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default="demo_out", help="folder for the pictures (default: demo_out)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    rows, labels = [], []
    for split in ("train", "heldout"):
        world = ReachWorld(WorldConfig(split=split))
        colours = palette.split_colours(split)
        for i, colour in enumerate(np.random.default_rng(args.seed).choice(colours, 2, replace=False)):
            d = expert.demonstrate(world, seed=args.seed + 10 * len(rows) + i, options={"target_colour": int(colour)})
            dist = np.linalg.norm(d["end_effector"] - d["scene"].target_position, axis=1)
            print(f"expert, {split} colour {colour:2d}: final-fifth min distance {dist[-4:].min():.4f} m, "
                  f"success {d['success']}, iLQG iterations {d['ilqg_iterations']}")
            rows.append(d["images"])
            labels.append(f"{split} {colour}")
    strip = os.path.join(args.out, "expert_demos.png")
    viz.save_atomically(viz.filmstrip(rows, labels=labels), strip)
    viz.save_gif(rows[0], os.path.join(args.out, "expert_demo.gif"))
    print(f"wrote {strip} and {os.path.join(args.out, 'expert_demo.gif')}")


if __name__ == "__main__":
    main()
