#!/usr/bin/env bash
# Issue 37 end to end: a fresh synthetic set with OpenPose keypoints (seed 31, the quickstart's
# shape: 4 people, 6 frames, 6 cameras, 128x128, keypoints with 2 px noise and 10 % dropped),
# the true params/ and vertices/ removed, `nia-train prepare` on every subject into one root,
# then the clean quickstart config trained for STEPS steps on the fitted root and, for
# comparison, on the true one, each evaluated on its unseen subject at the end of training.
#   cargo build --workspace --all-features --bins
#   scripts/own_capture_train.sh            # SEED=31 STEPS=1000 OUT=/tmp/nia_own_capture
set -euo pipefail
cd "$(dirname "$0")/.."
SEED=${SEED:-31}
STEPS=${STEPS:-1000}
OUT=${OUT:-/tmp/nia_own_capture}
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/debug/nia-train}
rm -rf "$OUT" && mkdir -p "$OUT"
"$BIN" synth --out "$OUT/true" --subjects 4 --frames 6 --cameras 6 --size 128 --seed "$SEED" \
  --keypoints --keypoint-noise-px 2 --keypoint-drop 0.1 >/dev/null
mkdir -p "$OUT/fitted"
cp "$OUT/true/synth.json" "$OUT/true/body_model.npz" "$OUT/fitted/"
for subject in "$OUT"/true/CoreView_*; do
  name=$(basename "$subject")
  # The capture as a user has it: everything but the true params/ and vertices/.
  mkdir -p "$OUT/input/$name"
  for x in "$subject"/*; do
    case "$(basename "$x")" in params | vertices) ;; *) ln -s "$(realpath "$x")" "$OUT/input/$name/" ;; esac
  done
  echo "== prepare $name =="
  "$BIN" prepare --input "$OUT/input/$name" --smpl "$OUT/true/body_model.npz" --out "$OUT/fitted" \
    --truth "$subject" 2>&1 | tail -n 3
done
for root in fitted true; do
  "$BIN" --config configs/quickstart_clean.toml --set "data.root=$OUT/$root" \
    --set "train.steps=$STEPS" --set "optim.decay_steps=$STEPS" --out "$OUT/run_$root" \
    > "$OUT/train_$root.log" 2>&1 &
done
wait
for root in fitted true; do
  echo "== trained on the $root SMPL: $(grep -m1 -i 'unseen' "$OUT/train_$root.log" || tail -n 2 "$OUT/train_$root.log")"
done
