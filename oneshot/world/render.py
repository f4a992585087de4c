"""Top-down RGB images of the arena, drawn with Pillow (what the policy sees; paper Section IV).

Drawn at `supersample` times the output size and shrunk with a box filter (area averaging): an
antialiased image in which a small disc keeps its own colour at its centre. The discs are drawn
over the arm, so the colour of the target is never hidden; the arm's pose is also in the state.
"""
import numpy as np
from PIL import Image, ImageDraw

BACKGROUND = (0, 0, 0)
ARM_COLOUR = (255, 255, 255)


def world_to_pixels(points, arena_half_width, size):
    """Map world points (..., 2) in metres (y up) to pixel coordinates (..., 2) (y down)."""
    points = np.asarray(points, dtype=float)
    scale = size / (2 * arena_half_width)
    return np.stack([(points[..., 0] + arena_half_width) * scale,
                     (arena_half_width - points[..., 1]) * scale], axis=-1)


def render(joints, positions, colours, *, arena_half_width, size=32, object_radius=0.025,
           arm_width=0.012, supersample=4):
    """Render one frame.

    joints: (3, 2) base, elbow, end effector, metres; positions: (n, 2) object centres, metres;
    colours: (n, 3) uint8 RGB. Returns (size, size, 3) uint8.
    """
    big = size * supersample
    image = Image.new("RGB", (big, big), BACKGROUND)
    draw = ImageDraw.Draw(image)
    scale = big / (2 * arena_half_width)
    pj = world_to_pixels(joints, arena_half_width, big)
    draw.line([tuple(p) for p in pj], fill=ARM_COLOUR, width=max(1, round(arm_width * scale)))
    r = object_radius * scale
    for (px, py), c in zip(world_to_pixels(positions, arena_half_width, big), colours):
        draw.ellipse([px - r, py - r, px + r, py + r], fill=tuple(int(v) for v in c))
    return np.array(image.resize((size, size), Image.BOX))     # a writable copy (asarray: read-only)
