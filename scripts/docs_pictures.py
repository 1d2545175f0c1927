#!/usr/bin/env python3
"""The evaluation pictures of docs/results.md from a run's evaluation folder.

    python3 scripts/docs_pictures.py runs/quickstart/evaluation docs/

writes `eval_grid.png` (the first three `*_grid.png` tiles stacked, 2x: source views,
prediction, ground truth, error) and `eval_parts.png` (the first image's `*_parts.png` and
`*_blend.png` side by side, the person's columns cropped, 3x: C0, IBR-only, prediction, ground
truth, opacity, then the blend weights of C0 and of each source view). Needs Pillow.
"""

import sys
from pathlib import Path

from PIL import Image

TILE = 128  # the quickstart's image size
SEP = 2  # separator between tiles in the written grids (nia-infer pictures)
GAP = 6  # separator in the README pictures
GREY = (40, 40, 40)


def stack(images, gap, vertical):
    w = max(i.width for i in images) if vertical else sum(i.width for i in images) + gap * (len(images) - 1)
    h = sum(i.height for i in images) + gap * (len(images) - 1) if vertical else max(i.height for i in images)
    out = Image.new("RGB", (w, h), GREY)
    at = 0
    for im in images:
        out.paste(im, (0, at) if vertical else (at, 0))
        at += (im.height if vertical else im.width) + gap
    return out


def tiles(path, count, x0, width):
    im = Image.open(path).convert("RGB")
    return [im.crop((i * (TILE + SEP) + x0, 0, i * (TILE + SEP) + x0 + width, im.height)) for i in range(count)]


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    folder, out = Path(sys.argv[1]), Path(sys.argv[2])
    grids = sorted(folder.glob("*_grid.png"))[:3]
    if not grids:
        sys.exit(f"{folder}: no *_grid.png (run nia-train or nia-infer eval first)")
    rows = [Image.open(g).convert("RGB") for g in grids]
    rows = [r.resize((r.width * 2, r.height * 2), Image.NEAREST) for r in rows]
    stack(rows, 2 * GAP, True).save(out / "eval_grid.png")

    stem = grids[0].name[: -len("_grid.png")]
    parts = folder / f"{stem}_parts.png"
    blend = folder / f"{stem}_blend.png"
    n_parts = (Image.open(parts).width + SEP) // (TILE + SEP)
    n_blend = (Image.open(blend).width + SEP) // (TILE + SEP)
    x0, width = 31, 66  # the person's columns of a 128-px tile
    crops = tiles(parts, n_parts, x0, width) + tiles(blend, n_blend, x0, width)
    crops = [c.resize((c.width * 3, c.height * 3), Image.NEAREST) for c in crops]
    stack(crops, GAP, False).save(out / "eval_parts.png")
    print(f"{out / 'eval_grid.png'}: {', '.join(g.name for g in grids)}")
    print(f"{out / 'eval_parts.png'}: {stem}")


if __name__ == "__main__":
    main()
