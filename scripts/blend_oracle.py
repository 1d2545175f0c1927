#!/usr/bin/env python3
"""How far any trust between c0 and the source views could lift the blend over the views alone.

The blend's colour is c0's weight w0 times c0 plus (1 - w0) times the views' composite (the
IBR-only composite, F_B's view weights renormalised without c0). Whatever F_B learns about whom
to trust, as long as c0 and the views' weights among themselves stay as they are, its result is
`a c0 + (1 - a) IBR` for some a per point. This script takes an evaluation's pictures
(`nia-infer eval`'s `pictures/*_parts.png`: c0 | IBR-only | prediction | truth | opacity) and
scores, against the truth, over each image's box of truth or opacity (about the protocol's
`mask_at_box` crop):

- c0 alone, IBR-only, the prediction;
- the best single a per image (a in 0, 0.1, ..., 1);
- the best a per square patch of 16, 8 and 4 pixels, and per pixel: an oracle that knows the
  truth, so an upper bound, loose at small patches (per pixel it fits the noise).

It prints the mean PSNR over the images (dB, as eval averages) and each bound minus IBR-only.
The pictures are 8-bit, so the figures sit a little off eval's; compare them with each other.

    python3 scripts/blend_oracle.py EVAL_OUT [EVAL_OUT ...]
"""
import glob
import os
import sys

import numpy as np
from PIL import Image

GAP = 2  # black pixels between the panels (nia-eval's pictures::side_by_side)
PANELS = 5
ALPHAS = np.linspace(0.0, 1.0, 11)
PATCHES = (16, 8, 4, 1)


def psnr(a, b):
    return 10.0 * np.log10(1.0 / max(float(np.mean((a - b) ** 2)), 1e-10))


def panels(path):
    """The five panels of one parts picture, floats in [0, 1]."""
    im = np.asarray(Image.open(path).convert("RGB"), dtype=np.float64) / 255.0
    h, w, _ = im.shape
    width = (w - GAP * (PANELS - 1)) / PANELS
    if width != int(width) or int(width) < 1:
        sys.exit(f"{path}: width {w} is not {PANELS} panels with {GAP}-pixel gaps")
    width = int(width)
    return [im[:, i * (width + GAP): i * (width + GAP) + width] for i in range(PANELS)]


def best_mix(c0, ibr, gt, patch):
    """The composite with the best a per square patch of `patch` pixels."""
    out = np.empty_like(gt)
    h, w, _ = gt.shape
    for y in range(0, h, patch):
        for x in range(0, w, patch):
            s = (slice(y, y + patch), slice(x, x + patch))
            errors = [np.sum((a * c0[s] + (1 - a) * ibr[s] - gt[s]) ** 2) for a in ALPHAS]
            a = ALPHAS[int(np.argmin(errors))]
            out[s] = a * c0[s] + (1 - a) * ibr[s]
    return out


def scores(path):
    c0, ibr, pred, gt, opacity = panels(path)
    inside = (gt.max(axis=-1) > 0) | (opacity.mean(axis=-1) > 0.02)
    ys, xs = np.nonzero(inside)
    if len(ys) == 0:
        return None
    box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    c0, ibr, pred, gt = (x[box] for x in (c0, ibr, pred, gt))
    row = {"c0": psnr(c0, gt), "IBR-only": psnr(ibr, gt), "prediction": psnr(pred, gt)}
    row["best a per image"] = max(psnr(a * c0 + (1 - a) * ibr, gt) for a in ALPHAS)
    for patch in PATCHES:
        mix = best_mix(c0, ibr, gt, patch)
        row[f"per {patch} px" if patch > 1 else "per pixel"] = psnr(mix, gt)
    return row


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for out in sys.argv[1:]:
        files = sorted(glob.glob(os.path.join(out, "pictures", "*_parts.png")))
        if not files:
            sys.exit(f"{out}: no pictures/*_parts.png (run nia-infer eval without --no-pictures)")
        rows = [r for r in map(scores, files) if r is not None]
        if not rows:
            sys.exit(f"{out}: every picture is empty (no truth and no opacity)")
        mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]}
        ibr = mean["IBR-only"]
        print(f"{out} ({len(rows)} images)")
        for k, v in mean.items():
            extra = "" if k == "IBR-only" else f"  ({v - ibr:+.2f} over IBR-only)"
            print(f"  {k:>18}: {v:6.2f}{extra}")


if __name__ == "__main__":
    main()
