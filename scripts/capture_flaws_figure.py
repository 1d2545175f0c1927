#!/usr/bin/env python3
"""docs/capture_flaws.png: three cameras of one frame of the quickstart set, clean and flawed.

    S="nia-train synth --subjects 4 --frames 6 --cameras 6 --size 128 --seed 0 --supersample 2"
    $S --out /tmp/fig/clean
    $S --out /tmp/fig/geometry --geometry-level 1
    $S --out /tmp/fig/zju_like --capture zju_like
    python3 scripts/capture_flaws_figure.py /tmp/fig docs/capture_flaws.png

Rows: cameras B1, B3, B5 of CoreView_1, frame 2, cropped to the person. Columns (3x, nearest):
the clean image, the
image with the geometry flaw alone (hair volume, loose garments), the zju_like image, the clean
mask, the geometry flaw's mask over the clean one (red: the pixels hair and loose clothes add,
which the SMPL body does not explain), the zju_like mask. Needs Pillow and numpy.
"""

import sys
from pathlib import Path

import numpy as np
from PIL import Image

SUBJECT = "CoreView_1"
FRAME = 2
CAMERAS = (1, 3, 5)
SCALE = 3
MARGIN = 6  # pixels kept around the person (the union of the row's masks)
GAP = 4  # grey separator between tiles, pixels before scaling
GREY = (40, 40, 40)
ADDED = (230, 40, 40)  # mask pixels the geometry flaw adds
LOST = (40, 110, 230)  # mask pixels it removes (none expected: it only pushes outwards)


def image(root, camera):
    return np.asarray(Image.open(root / SUBJECT / f"Camera_B{camera}" / f"{FRAME:06}.jpg").convert("RGB"))


def mask(root, camera):
    m = np.asarray(Image.open(root / SUBJECT / "mask" / f"Camera_B{camera}" / f"{FRAME:06}.png").convert("L"))
    return m > 0


def grey(m):
    return np.repeat((m * 255).astype(np.uint8)[..., None], 3, axis=2)


def difference(clean, flawed):
    out = grey(clean & flawed)
    out[flawed & ~clean] = ADDED
    out[clean & ~flawed] = LOST
    return out


def grid_of(rows):
    """Tiles `rows[r][c]` on a grey background, each row as tall as its tallest tile."""
    widths = [max(row[c].shape[1] for row in rows) for c in range(len(rows[0]))]
    heights = [max(t.shape[0] for t in row) for row in rows]
    out = np.zeros((sum(heights) + GAP * (len(rows) - 1), sum(widths) + GAP * (len(widths) - 1), 3), np.uint8)
    out[:] = GREY
    y = 0
    for row, height in zip(rows, heights):
        x = 0
        for tile, width in zip(row, widths):
            out[y : y + tile.shape[0], x : x + tile.shape[1]] = tile
            x += width + GAP
        y += height + GAP
    return Image.fromarray(out)


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    root, out = Path(sys.argv[1]), Path(sys.argv[2])
    clean, geometry, zju = root / "clean", root / "geometry", root / "zju_like"
    rows = []
    for c in CAMERAS:
        union = mask(clean, c) | mask(geometry, c) | mask(zju, c)
        ys, xs = np.nonzero(union)
        h, w = union.shape
        y0, y1 = max(ys.min() - MARGIN, 0), min(ys.max() + MARGIN + 1, h)
        x0, x1 = max(xs.min() - MARGIN, 0), min(xs.max() + MARGIN + 1, w)
        tiles = [
            image(clean, c),
            image(geometry, c),
            image(zju, c),
            grey(mask(clean, c)),
            difference(mask(clean, c), mask(geometry, c)),
            grey(mask(zju, c)),
        ]
        rows.append([t[y0:y1, x0:x1] for t in tiles])
    grid = grid_of(rows)
    grid.resize((grid.width * SCALE, grid.height * SCALE), Image.NEAREST).save(out)


if __name__ == "__main__":
    main()
