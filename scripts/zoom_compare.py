#!/usr/bin/env python3
"""Zoom on the torso of one evaluated image under several models, to compare fine detail.

    python3 scripts/zoom_compare.py docs/surface_zoom.png CoreView_4_frame0000_view01 \
        runs/A/evaluation runs/B/evaluation

For each folder: the IBR-only composite and the prediction of `STEM_parts.png`; then the ground
truth (from the first folder). 6x, nearest neighbour, so every pixel shows. Needs Pillow.
"""

import sys

from PIL import Image

TILE, SEP = 128, 2  # nia-infer's parts tiles: C0, IBR-only, prediction, ground truth, opacity
BOX = (44, 14, 84, 70)  # the torso of the quickstart's 128-px images
SCALE, GAP = 6, 6


def tile(path, index):
    im = Image.open(path).convert("RGB")
    x = index * (TILE + SEP)
    return im.crop((x + BOX[0], BOX[1], x + BOX[2], BOX[3]))


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    out, stem, folders = sys.argv[1], sys.argv[2], sys.argv[3:]
    crops = []
    for folder in folders:
        parts = f"{folder}/{stem}_parts.png"
        crops += [tile(parts, 1), tile(parts, 2)]
    crops.append(tile(f"{folders[0]}/{stem}_parts.png", 3))
    w, h = (BOX[2] - BOX[0]) * SCALE, (BOX[3] - BOX[1]) * SCALE
    fig = Image.new("RGB", (len(crops) * (w + GAP) - GAP, h), (40, 40, 40))
    for i, c in enumerate(crops):
        fig.paste(c.resize((w, h), Image.NEAREST), (i * (w + GAP), 0))
    fig.save(out)


if __name__ == "__main__":
    main()
