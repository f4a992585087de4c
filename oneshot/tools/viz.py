"""Pictures: film strips (PNG) and animations (GIF) of episodes, with Pillow only.

A frame is what the policy sees, (H, W, 3) uint8 (32x32 by default). Pictures show it `scale` times
larger, each pixel a block, and mark what a person needs to read it, on the enlarged copy only (the
policy's frames are never changed): the target disc with a dashed white ring (white is no disc's
colour, the palette's colours are all saturated, and the dashes tell the ring from the white arm), the
arm's base with a white square and its hand (the end effector) with a small white circle.
Positions are in frame pixels, as `oneshot.world.render.world_to_pixels` gives them; `episode_marks`
computes them all for recorded episodes. Every function here takes arrays and returns new PIL images;
only the `save_*` functions write files.
"""
import io
import os

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from oneshot.tools.files import atomic_write
from oneshot.world import arm, palette, render

BACKGROUND = (40, 40, 40)      # between tiles and behind text
TEXT = (235, 235, 235)
MARK = (255, 255, 255)         # the target ring, the base and the hand
BASE_HALF_WIDTH = 1.2          # the base's square: half its side, frame pixels
HAND_RADIUS = 1.2              # the hand's circle, frame pixels (a disc's radius is 1.8 at 32x32)


def font(size=14):
    """Pillow's default font at `size` pixels (Pillow >= 10.1 with FreeType), else its small bitmap font."""
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError, ImportError):      # older Pillow (no size argument) or no FreeType
        return ImageFont.load_default()


def marked_frame(frame, scale=4, target=None, radius=3.0, dashes=12, hand=None, base=None):
    """One frame enlarged, with the target ringed and the arm's base and hand marked.

    frame: (H, W, 3) uint8; target: (x, y) in frame pixels, or None for no ring; radius: the ring's
    radius in frame pixels; hand, base: (x, y) in frame pixels, or None (or NaN) for no mark. Returns a
    PIL image of W scale x H scale pixels, each frame pixel a scale x scale block, with a white ring of
    `dashes` dashes around scale * target, a white square on the base and a white circle on the hand.
    """
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"a frame must be (H, W, 3) uint8; got {frame.shape} {frame.dtype}")
    tile = Image.fromarray(np.repeat(np.repeat(frame, scale, axis=0), scale, axis=1))
    draw, width = ImageDraw.Draw(tile), max(1, scale // 2)
    if base is not None and np.all(np.isfinite(base)):
        x, y, r = base[0] * scale, base[1] * scale, BASE_HALF_WIDTH * scale
        draw.rectangle([x - r, y - r, x + r, y + r], fill=MARK)
    if hand is not None and np.all(np.isfinite(hand)):
        x, y, r = hand[0] * scale, hand[1] * scale, HAND_RADIUS * scale
        draw.ellipse([x - r, y - r, x + r, y + r], outline=MARK, width=width)
    if target is not None:
        x, y, r = target[0] * scale, target[1] * scale, radius * scale
        step = 360 / dashes
        for k in range(dashes):                    # dash k spans angles [k step, (k + 1/2) step], clockwise
            draw.arc([x - r, y - r, x + r, y + r], k * step, (k + 0.5) * step, fill=MARK, width=width)
    return tile


def episode_marks(episodes, cfg):
    """What pictures mark in recorded episodes, as keyword arguments of `filmstrip` and `side_by_side`.

    episodes: dicts with "scene" (`oneshot.world.scene.Scene`) and "states" (T, 6) (an expert demo:
    `oneshot.world.reach.observation_state` of each frame) or "end_effector" (T, 2) m after each step (a
    policy's rollout); cfg: the WorldConfig they were recorded in. Returns {"targets": each episode's
    target centre (x, y), "hands": each episode's (T, 2) hand in every frame, "base": (x, y), "radius":
    the ring's radius, twice a disc's}, all in frame pixels. Frame t shows the arm before step t, so a
    rollout's hand in frame t is its end effector after step t - 1, and in frame 0 the start pose's (left
    unmarked, NaN, when cfg.start_noise moved the start pose).
    """
    def pixels(points):
        return render.world_to_pixels(points, cfg.arena_half_width, cfg.image_size)

    hands = []
    for episode in episodes:
        if "states" in episode:           # observation_state: angles (2,), velocities (2,), end effector (2,)
            hands.append(pixels(np.asarray(episode["states"])[:, 4:6]))
        else:
            start = (arm.forward_kinematics(np.array(cfg.arm.q0), cfg.arm) if cfg.start_noise == 0
                     else np.full(2, np.nan))
            hands.append(pixels(np.concatenate([start[None], np.asarray(episode["end_effector"])[:-1]])))
    return {"targets": [pixels(e["scene"].target_position) for e in episodes], "hands": hands,
            "base": pixels(np.zeros(2)), "radius": ring_radius(cfg)}


def ring_radius(cfg):
    """The target ring's radius in frame pixels: twice a disc's (cfg.object_radius), for the WorldConfig cfg."""
    return 2 * cfg.object_radius * cfg.image_size / (2 * cfg.arena_half_width)


def _text_size(draw, text, typeface):
    left, top, right, bottom = draw.multiline_textbbox((0, 0), text, font=typeface)
    return right, bottom


def filmstrip(rows, every=2, scale=4, labels=None, gap=6, targets=None, radius=3.0, swatches=None,
              group=1, font_size=18, hands=None, base=None):
    """Tile episodes into one picture: a row per episode, a column per kept time step.

    rows: R frame stacks (T, H, W, 3) uint8 (equal H, W); every: keep every n-th frame (the last is
    always kept), numbered "t = 0", "t = 2", ... above the first row; labels: R strings ("\\n" breaks
    lines), drawn at each row's left; swatches: R RGB colours, each a small disc before its label;
    targets: R target positions (x, y) in frame pixels (or None: no ring in that row), ringed in every
    frame (`marked_frame`, ring radius `radius` frame pixels); hands: R (T, 2) hand positions, one per
    frame, in frame pixels (or None), and base: the arm's base (x, y), marked in every frame
    (`episode_marks` gives targets, hands, base and radius); group: rows per group, groups set apart
    by an extra 2 gap pixels. Returns a PIL image of width margin + gap + C (W scale + gap) and height
    header + gap + R (H scale + gap) + 2 gap (number of groups - 1), where C is the longest row's
    column count and the margin fits the widest label (0 without labels).
    """
    if not rows:
        raise ValueError("filmstrip needs at least one row of frames")
    for name, per_row in (("labels", labels), ("targets", targets), ("swatches", swatches), ("hands", hands)):
        if per_row is not None and len(per_row) != len(rows):
            raise ValueError(f"filmstrip got {len(rows)} rows but {len(per_row)} {name}")
    h, w = rows[0].shape[1:3]
    columns = [sorted(set(range(0, len(frames), every)) | {len(frames) - 1}) for frames in rows]
    widest = max(columns, key=len)
    typeface = font(font_size)
    measure = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    dot = font_size if swatches is not None else 0       # swatch diameter, pixels
    margin = 0
    if labels is not None:
        margin = max(_text_size(measure, label, typeface)[0] for label in labels) + dot + (dot and gap) + 2 * gap
    header = _text_size(measure, "t = 0", typeface)[1] + 2 * gap
    tile_w, tile_h = w * scale + gap, h * scale + gap
    n_groups = -(-len(rows) // group)
    canvas = Image.new("RGB", (margin + gap + len(widest) * tile_w,
                               header + gap + len(rows) * tile_h + 2 * gap * (n_groups - 1)), BACKGROUND)
    draw = ImageDraw.Draw(canvas)
    for c, t in enumerate(widest):                         # time steps above the first row
        draw.text((margin + gap + c * tile_w + w * scale / 2, header), f"t = {t}", fill=TEXT,
                  font=typeface, anchor="md")
    for r, frames in enumerate(rows):
        top = header + gap + r * tile_h + 2 * gap * (r // group)
        target = None if targets is None else targets[r]
        for c, t in enumerate(columns[r]):
            hand = None if hands is None or hands[r] is None else hands[r][t]
            canvas.paste(marked_frame(frames[t], scale, target, radius, hand=hand, base=base),
                         (margin + gap + c * tile_w, top))
        if labels is not None:
            text_w, text_h = _text_size(draw, labels[r], typeface)
            middle = top + h * scale / 2
            if swatches is not None:
                draw.ellipse([gap, middle - dot / 2, gap + dot, middle + dot / 2],
                             fill=tuple(int(v) for v in swatches[r]))
            draw.multiline_text((gap + dot + (dot and gap), middle - text_h / 2), labels[r], fill=TEXT,
                                font=typeface, spacing=4)
    return canvas


def side_by_side(episodes, titles, targets=None, radius=3.0, scale=6, gap=6, font_size=14, hands=None, base=None):
    """Frames of an animation playing episodes side by side: a titled panel per episode, the time step
    below.

    episodes: P frame stacks (T, H, W, 3) uint8 of equal shape; titles: P strings ("\\n" breaks lines);
    targets: P target positions (x, y) in frame pixels (or None), ringed in every frame; hands: P (T, 2)
    hand positions and base: (x, y), marked as in `filmstrip` (`episode_marks` gives them). Returns T PIL
    images, each gap + P (W scale + gap) wide and header + H scale + footer high.
    """
    shapes = {np.shape(e) for e in episodes}
    if len(shapes) != 1:
        raise ValueError(f"side_by_side needs frame stacks of one shape (T, H, W, 3); got {sorted(shapes)}")
    for name, per_panel in (("titles", titles), ("targets", targets), ("hands", hands)):
        if per_panel is not None and len(per_panel) != len(episodes):
            raise ValueError(f"side_by_side got {len(episodes)} episodes but {len(per_panel)} {name}")
    n_steps, h, w = np.shape(episodes[0])[:3]
    typeface = font(font_size)
    measure = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    header = max(_text_size(measure, title, typeface)[1] for title in titles) + 2 * gap
    footer = _text_size(measure, "t = 0", typeface)[1] + 2 * gap
    panel = w * scale + gap
    images = []
    for t in range(n_steps):
        canvas = Image.new("RGB", (gap + len(episodes) * panel, header + h * scale + footer), BACKGROUND)
        draw = ImageDraw.Draw(canvas)
        for p, frames in enumerate(episodes):
            x = gap + p * panel
            draw.multiline_text((x + w * scale / 2, header - gap), titles[p], fill=TEXT, font=typeface,
                                anchor="md", align="center", spacing=4)
            hand = None if hands is None or hands[p] is None else hands[p][t]
            canvas.paste(marked_frame(frames[t], scale, None if targets is None else targets[p], radius,
                                      hand=hand, base=base), (x, header))
        draw.text((canvas.width / 2, header + h * scale + gap), f"t = {t} of {n_steps - 1}", fill=TEXT,
                  font=typeface, anchor="ma")
        images.append(canvas)
    return images


RINGS = (("train", 1.0, "outer: meta-training"), ("validation", 0.81, "middle: validation"),
         ("test", 0.64, "inner: test"))    # each split's ring, its radius a fraction of the wheel's


def hue_wheel(cfg=palette.PaletteConfig(), size=360):
    """The colour splits around the hue wheel (the hues palette, one colour per hue; Section IV's tasks):
    each colour a disc of its own RGB at its hue angle (0 deg to the right, counter-clockwise), the
    meta-training colours on the outer ring, the validation colours on the middle one, the test colours
    on the inner one, named in the centre. Returns a (size, size) RGB PIL image."""
    if cfg.mode != "hues":
        raise ValueError(f"hue_wheel draws the hues palette, one colour per hue; got mode {cfg.mode!r}, which has "
                         f"several per hue: pass PaletteConfig(mode='hues')")
    image = Image.new("RGB", (size, size), BACKGROUND)
    draw, rgb = ImageDraw.Draw(image), palette.palette_rgb(cfg)
    centre, outer, disc = size / 2, 0.44 * size, 0.025 * size
    for split, fraction, _ in RINGS:
        for i in palette.split_colours(split, cfg):
            angle = np.deg2rad(palette.colour_hue_deg(i, cfg))
            x, y = centre + fraction * outer * np.cos(angle), centre - fraction * outer * np.sin(angle)
            draw.ellipse([x - disc, y - disc, x + disc, y + disc], fill=tuple(int(c) for c in rgb[i]))
    typeface = font(max(9, size // 34))
    for row, (split, _, words) in enumerate(RINGS):
        text = f"{words} ({len(palette.split_colours(split, cfg))})"
        width, height = _text_size(draw, text, typeface)
        draw.text((centre - width / 2, centre + (row - 1.5) * 1.3 * height), text, fill=TEXT, font=typeface)
    return image


def encoded(image, path, **kwargs):
    """A PIL image's bytes in the format of `path`'s extension (.png, .gif, .jpg)."""
    out = io.BytesIO()
    image.save(out, format=os.path.splitext(path)[1][1:].upper().replace("JPG", "JPEG"), **kwargs)
    return out.getvalue()


def gif_encoded(images, ms_per_frame=150, hold_last_ms=1500):
    """An animated GIF's bytes, of PIL images (e.g. `side_by_side`'s), looping; the last one stays up
    `hold_last_ms` so the outcome can be seen."""
    durations = [ms_per_frame] * (len(images) - 1) + [hold_last_ms]
    return encoded(images[0], "animation.gif", save_all=True, append_images=images[1:], duration=durations, loop=0)


def save_atomically(image, path, **kwargs):
    """Save a PIL image via a temporary file and a rename, so no half-written picture is left."""
    save_together({path: encoded(image, path, **kwargs)})


def save_gif(images, path, ms_per_frame=150, hold_last_ms=1500):
    """An animated GIF of PIL images (`gif_encoded`), saved atomically."""
    save_together({path: gif_encoded(images, ms_per_frame, hold_last_ms)})


def save_together(encodings):
    """Write {path: bytes} (`encoded`, `gif_encoded`), each file atomically: pictures encoded before any
    is written, so an interruption while encoding leaves every file as it was."""
    for path, data in encodings.items():
        with atomic_write(path) as f:
            f.write(data)
