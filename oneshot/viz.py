"""Pictures: film strips (PNG) and animations (GIF) of episodes, with Pillow only."""
import os

import numpy as np
from PIL import Image, ImageDraw

from oneshot.data import atomic_write


def filmstrip(rows, every=2, scale=4, labels=None, gap=2):
    """Tile episodes into one picture, one row each.

    rows: list of (T, H, W, 3) uint8 frame stacks (equal H, W); every: keep every n-th frame (the last
    is always kept); labels: optional text per row, drawn at its left. Returns a PIL image.
    """
    strips = []
    for frames in rows:
        idx = sorted(set(range(0, len(frames), every)) | {len(frames) - 1})
        tiles = [np.pad(frames[i], ((gap, gap), (gap, gap), (0, 0)), constant_values=40) for i in idx]
        strips.append(np.concatenate(tiles, axis=1))
    width = max(s.shape[1] for s in strips)
    strips = [np.pad(s, ((0, 0), (0, width - s.shape[1]), (0, 0))) for s in strips]
    image = Image.fromarray(np.concatenate(strips, axis=0))
    image = image.resize((image.width * scale, image.height * scale), Image.NEAREST)
    if labels:
        margin = 9 * max(len(label) for label in labels) + 8
        canvas = Image.new("RGB", (image.width + margin, image.height), (40, 40, 40))
        canvas.paste(image, (margin, 0))
        draw = ImageDraw.Draw(canvas)
        row_h = image.height / len(labels)
        for r, label in enumerate(labels):
            draw.text((4, r * row_h + row_h / 2 - 5), label, fill=(255, 255, 255))
        image = canvas
    return image


def save_atomically(image, path, **kwargs):
    """Save a PIL image via a temporary file and a rename, so no half-written picture is left."""
    with atomic_write(path) as f:
        image.save(f, format=os.path.splitext(path)[1][1:].upper().replace("JPG", "JPEG"), **kwargs)


def save_gif(frames, path, scale=6, ms_per_frame=100):
    """An animated GIF of frames (T, H, W, 3) uint8."""
    images = [Image.fromarray(f).resize((f.shape[1] * scale, f.shape[0] * scale), Image.NEAREST) for f in frames]
    save_atomically(images[0], path, save_all=True, append_images=images[1:], duration=ms_per_frame, loop=0)
