#!/usr/bin/env bash
# The SMPL fitter against the generator's truth (issue 37): a fresh synthetic subject (seed 31,
# not used in development), 3 and 6 views, OpenPose BODY_25 keypoints with 2 px noise, 10 %
# dropped (and the generator's 2 % outliers); `nia-train prepare --truth` prints MPJPE, mean
# vertex error and fitting time per frame. Run from the repository root after building:
#   cargo build --workspace --all-features --bins
#   scripts/fit_eval.sh                      # SEED=31 FRAMES=30 SIZE=512 OUT=/tmp/nia_fit_eval
# A real capture's flaws (docs/own-capture.md, "A real capture's flaws"): CAPTURE=zju_like,
# and SYNTH_FLAGS for single flaws, e.g. SYNTH_FLAGS="--smpl-fit-level 0 --colour-level 0
# --calibration-level 0 --geometry-level 0" keeps the masks' flaws only. The truth is then the
# same seed generated clean (the same people and poses), since a flawed set's params/ hold the
# simulated fit. FIT_CONFIG=FILE passes `--fit-config FILE` to prepare.
set -euo pipefail
SEED=${SEED:-31}
FRAMES=${FRAMES:-30}
SIZE=${SIZE:-512}
OUT=${OUT:-/tmp/nia_fit_eval}
CAPTURE=${CAPTURE:-none}
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/debug/nia-train}
mkdir -p "$OUT"
FIT_ARGS=()
if [ -n "${FIT_CONFIG:-}" ]; then FIT_ARGS=(--fit-config "$FIT_CONFIG"); fi
for VIEWS in ${VIEWS:-3 6}; do
  GEN="$OUT/gen_s${SEED}_c${VIEWS}"
  TRUTH="$GEN"
  rm -rf "$GEN" "$OUT/input_c${VIEWS}"
  # shellcheck disable=SC2086 # SYNTH_FLAGS is a list of flags
  "$BIN" synth --out "$GEN" --subjects 1 --frames "$FRAMES" --cameras "$VIEWS" --size "$SIZE" \
    --seed "$SEED" --keypoints --keypoint-noise-px 2 --keypoint-drop 0.1 \
    --capture "$CAPTURE" ${SYNTH_FLAGS:-} >/dev/null
  if [ "$CAPTURE" != none ]; then
    TRUTH="$OUT/truth_s${SEED}_c${VIEWS}"
    rm -rf "$TRUTH"
    "$BIN" synth --out "$TRUTH" --subjects 1 --frames "$FRAMES" --cameras "$VIEWS" \
      --size "$SIZE" --seed "$SEED" >/dev/null
  fi
  # The capture as a user has it: everything but the true params/ and vertices/.
  IN="$OUT/input_c${VIEWS}/CoreView_1"
  mkdir -p "$IN"
  for x in "$GEN"/CoreView_1/*; do
    case "$(basename "$x")" in params | vertices) ;; *) ln -s "$(realpath "$x")" "$IN/" ;; esac
  done
  echo "== $VIEWS views, seed $SEED, $FRAMES frames, ${SIZE}x${SIZE}, capture $CAPTURE ${SYNTH_FLAGS:-} =="
  "$BIN" prepare --input "$IN" --smpl "$GEN/body_model.npz" --out "$OUT/fitted_c${VIEWS}" \
    --truth "$TRUTH/CoreView_1" --overwrite "${FIT_ARGS[@]}"
done
