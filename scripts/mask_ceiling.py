#!/usr/bin/env python3
"""What a perfect renderer scores under the evaluation protocol when the masks are flawed.

The protocol (NHP's, which nia-infer eval follows) sets the ground truth to black outside the
dataset's person mask. With segmentation flaws (holes, a lost hand, ragged outlines) the
ground truth itself is wrong there, and even the true image scores below infinity. This script
compares, on the target views of the test subjects of a synthetic set, the true image (the image masked with the
exact mask of the clean set of the same seed) with the image masked by the flawed set's mask,
over the person's bounding box grown by 8 px (about the protocol's `mask_at_box`), and prints
the mean per-image PSNR: the ceiling a renderer cannot pass on that set.

    python3 scripts/mask_ceiling.py CLEAN_SET FLAWED_SET

Both sets must come from `nia-train synth` with the same spec except the mask flaw (the images
are then the same; with other flaws the images differ and the figure means nothing).
"""
import glob
import json
import os
import sys

import numpy as np
from PIL import Image


def split(root):
    """The test subjects' folders and the target cameras' folders of a synthetic set."""
    path = os.path.join(root, "synth.json")
    with open(path) as f:
        d = json.load(f)
    for key in ("test_subjects", "target_views"):
        if not isinstance(d.get(key), list) or not d[key]:
            raise SystemExit(f"{path}: `{key}`: expected a non-empty list")
    subjects = [f"CoreView_{n}" for n in d["test_subjects"]]
    cameras = [f"Camera_B{v + 1}" for v in d["target_views"]]
    return subjects, cameras


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    clean, flawed = sys.argv[1:]
    psnrs = []
    subjects, cameras = split(flawed)
    for subject in subjects:
        paths = [p for c in cameras for p in glob.glob(os.path.join(clean, subject, c, "*.jpg"))]
        for path in sorted(paths):
            cam, name = path.split(os.sep)[-2:]
            mask_name = name.replace(".jpg", ".png")
            image = np.asarray(Image.open(path), dtype=np.float32) / 255.0
            exact = np.asarray(Image.open(os.path.join(clean, subject, "mask", cam, mask_name))) > 0
            flaw = np.asarray(Image.open(os.path.join(flawed, subject, "mask", cam, mask_name))) > 0
            ys, xs = np.nonzero(exact)
            box = np.zeros_like(exact)
            box[max(ys.min() - 8, 0) : ys.max() + 9, max(xs.min() - 8, 0) : xs.max() + 9] = True
            err = (image * exact[..., None] - image * flaw[..., None])[box]
            mse = float(np.mean(err**2))
            psnrs.append(10 * np.log10(1.0 / max(mse, 1e-10)))
    if not psnrs:
        raise SystemExit(f"{clean}: no images of the test subjects")
    print(f"{len(psnrs)} images: ceiling PSNR {np.mean(psnrs):.2f} dB (mean over images)")


if __name__ == "__main__":
    main()
