#!/usr/bin/env bash
# The SMPL fitter against the generator's truth (issue 37): a fresh synthetic subject (seed 31,
# not used in development), 3 and 6 views, OpenPose BODY_25 keypoints with 2 px noise, 10 %
# dropped (and the generator's 2 % outliers); `nia-train prepare --truth` prints MPJPE, mean
# vertex error and fitting time per frame. Run from the repository root after building:
#   cargo build --workspace --all-features --bins
#   scripts/fit_eval.sh                      # SEED=31 FRAMES=30 SIZE=512 OUT=/tmp/nia_fit_eval
set -euo pipefail
SEED=${SEED:-31}
FRAMES=${FRAMES:-30}
SIZE=${SIZE:-512}
OUT=${OUT:-/tmp/nia_fit_eval}
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/debug/nia-train}
mkdir -p "$OUT"
for VIEWS in ${VIEWS:-3 6}; do
  GEN="$OUT/gen_s${SEED}_c${VIEWS}"
  rm -rf "$GEN" "$OUT/input_c${VIEWS}"
  "$BIN" synth --out "$GEN" --subjects 1 --frames "$FRAMES" --cameras "$VIEWS" --size "$SIZE" \
    --seed "$SEED" --keypoints --keypoint-noise-px 2 --keypoint-drop 0.1 >/dev/null
  # The capture as a user has it: everything but the true params/ and vertices/.
  IN="$OUT/input_c${VIEWS}/CoreView_1"
  mkdir -p "$IN"
  for x in "$GEN"/CoreView_1/*; do
    case "$(basename "$x")" in params | vertices) ;; *) ln -s "$(realpath "$x")" "$IN/" ;; esac
  done
  echo "== $VIEWS views, seed $SEED, $FRAMES frames, ${SIZE}x${SIZE} =="
  "$BIN" prepare --input "$IN" --smpl "$GEN/body_model.npz" --out "$OUT/fitted_c${VIEWS}" \
    --truth "$GEN/CoreView_1" --overwrite
done
