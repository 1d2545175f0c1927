#!/usr/bin/env python3
"""How far the SMPL alignment moved each evaluated fit towards the true body.

    python3 scripts/alignment_error.py EVAL_DIR FLAWED_SET TRUE_SET

EVAL_DIR is an `nia-infer eval --smpl-alignment on` output on FLAWED_SET (its metrics.json lists
each image's correction); TRUE_SET is the same generator seed written without the fit error
(`nia-train synth ... --capture none`, or the same flaws without `smpl-fit`), whose
vertices/ are the bodies the images show. Prints, per (subject, source frame), the mean vertex
error of the fit as stored and as aligned, then the means over frames (metres).
"""
import json
import sys
from pathlib import Path

import numpy as np


def vertices(root: Path, subject: str, frame: int) -> np.ndarray:
    folder = root / subject / "vertices"
    for name in (f"{frame}.npy", f"{frame:06d}.npy"):
        if (folder / name).is_file():
            return np.load(folder / name).astype(np.float64)
    sys.exit(f"{folder}: no vertices file for frame {frame}")


def rotation(axis_angle: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(axis_angle)
    if theta < 1e-12:
        return np.eye(3)
    k = axis_angle / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx


def main() -> None:
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    eval_dir, flawed, truth = (Path(a) for a in sys.argv[1:])
    metrics = json.loads((eval_dir / "metrics.json").read_text())
    seen = {}
    for image in metrics["images"]:
        a = image.get("smpl_alignment")
        if a is None:
            sys.exit(f"{eval_dir}/metrics.json: image without smpl_alignment (run with --smpl-alignment on)")
        key = (image["subject"], image["reference_frame"])
        if key in seen:
            continue
        fit = vertices(flawed, *key)
        true = vertices(truth, *key)
        r = rotation(np.array(a["rotation"]))
        c = np.array(a["centre_m"])
        t = np.array(a["translation_m"])
        aligned = (fit - c) @ r.T + c + t
        before = np.linalg.norm(fit - true, axis=1).mean()
        after = np.linalg.norm(aligned - true, axis=1).mean()
        # What a rigid motion can reach at best: the mean translation between fit and truth.
        oracle = np.linalg.norm(fit + (true - fit).mean(axis=0) - true, axis=1).mean()
        seen[key] = (before, after, oracle, np.linalg.norm(t), a["rotation_deg"])
    print("| subject | frame | fit error (cm) | aligned (cm) | mean-shift oracle (cm) | |t| (cm) | rotation (deg) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for (subject, frame), (b, a, o, t, deg) in sorted(seen.items()):
        print(f"| {subject} | {frame} | {100 * b:.2f} | {100 * a:.2f} | {100 * o:.2f} | {100 * t:.2f} | {deg:.2f} |")
    v = np.array(list(seen.values()))
    print(f"| mean | {len(seen)} frames | {100 * v[:, 0].mean():.2f} | {100 * v[:, 1].mean():.2f} | "
          f"{100 * v[:, 2].mean():.2f} | {100 * v[:, 3].mean():.2f} | {v[:, 4].mean():.2f} |")


if __name__ == "__main__":
    main()
