#!/usr/bin/env python3
"""A dataset root whose subjects take some views' cameras from another root (docs/robustness.md,
"What is left at level 1"): the images, masks and SMPL are links to FLAWED's, and each subject's
annots.npy is FLAWED's with the cameras of VIEWS (0-based, comma-separated) taken from OTHER's
annots.npy for the same subject. With OTHER the same generator seed and flaws but
`--calibration-level 0`, the views in VIEWS get their true cameras and the rest keep the
calibration error.

    scripts/swap_cameras.py FLAWED OTHER OUT VIEWS
    scripts/swap_cameras.py data/robustness/s23_c8_zju_like \
        data/robustness/s23_c8_zju_like_calibration_0 /tmp/s23_inputs_true 0,3,5
"""
import os
import sys

import numpy as np


def main() -> None:
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    flawed, other, out = sys.argv[1], sys.argv[2], sys.argv[3]
    views = [int(v) for v in sys.argv[4].split(",")]
    os.makedirs(out)
    for name in sorted(os.listdir(flawed)):
        src = os.path.join(flawed, name)
        if name.startswith("."):
            continue  # caches of the readers: rebuilt for the new root
        if not (name.startswith("CoreView_") and os.path.isdir(src)):
            os.symlink(os.path.realpath(src), os.path.join(out, name))
            continue
        os.makedirs(os.path.join(out, name))
        for entry in os.listdir(src):
            if entry != "annots.npy":
                os.symlink(os.path.realpath(os.path.join(src, entry)), os.path.join(out, name, entry))
        annots = np.load(os.path.join(src, "annots.npy"), allow_pickle=True).item()
        theirs = np.load(os.path.join(other, name, "annots.npy"), allow_pickle=True).item()
        for key in annots["cams"]:
            count = len(annots["cams"][key])
            if len(theirs["cams"][key]) != count:
                sys.exit(f"{other}/{name}/annots.npy: cams.{key} has {len(theirs['cams'][key])} "
                         f"cameras, {src}/annots.npy has {count}")
            for v in views:
                if not 0 <= v < count:
                    sys.exit(f"view {v}: {src}/annots.npy has cameras 0..{count - 1}")
                annots["cams"][key][v] = theirs["cams"][key][v]
        np.save(os.path.join(out, name, "annots.npy"), annots, allow_pickle=True)


if __name__ == "__main__":
    main()
