#!/usr/bin/env bash
# Issue 37 end to end, as a user would run it: a fresh synthetic set of the quickstart's shape
# (seed 31, not used in development; 4 people, 6 frames, 6 cameras, 128x128) with OpenPose
# keypoints (2 px noise, 10 % dropped, 2 % outliers); every person's true params/ and vertices/
# removed; `nia-train prepare` on every person into one root; configs/own_capture.toml trained
# STEPS steps on that root and, for comparison, on the true root; `nia-infer eval` of each
# model on the held-out person (CoreView_4). Nothing was tuned on this seed.
#   cargo build --workspace --all-features --bins
#   scripts/own_capture_train.sh            # SEED=31 STEPS=1000 OUT=/tmp/nia_own_capture_train
# A real capture's flaws: CAPTURE=zju_like (SYNTH_FLAGS for single flaws, as scripts/fit_eval.sh).
# The second root is then the flawed set as generated, whose params/ hold the simulated fit
# (a dataset's own fit, EasyMocap-like), and the fits are compared with the same seed
# generated clean. EXTRA="--set k=v ..." adds settings to both trainings.
set -euo pipefail
cd "$(dirname "$0")/.."
SEED=${SEED:-31}
STEPS=${STEPS:-1000}
OUT=${OUT:-/tmp/nia_own_capture_train}
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/debug}
CAPTURE=${CAPTURE:-none}
rm -rf "$OUT" && mkdir -p "$OUT"
# shellcheck disable=SC2086 # SYNTH_FLAGS is a list of flags
"$BIN/nia-train" synth --out "$OUT/true" --subjects 4 --frames 6 --cameras 6 --size 128 \
  --seed "$SEED" --keypoints --keypoint-noise-px 2 --keypoint-drop 0.1 \
  --capture "$CAPTURE" ${SYNTH_FLAGS:-} >/dev/null
TRUTH="$OUT/true"
if [ "$CAPTURE" != none ]; then
  TRUTH="$OUT/clean"
  "$BIN/nia-train" synth --out "$TRUTH" --subjects 4 --frames 6 --cameras 6 --size 128 \
    --seed "$SEED" >/dev/null
fi
for subject in "$OUT"/true/CoreView_*; do
  name=$(basename "$subject")
  # The capture as a user has it: images, masks, keypoints, cameras; no params/ or vertices/.
  mkdir -p "$OUT/capture/$name"
  for x in "$subject"/*; do
    case "$(basename "$x")" in params | vertices) ;; *) cp -r "$x" "$OUT/capture/$name/" ;; esac
  done
  echo "== prepare $name =="
  "$BIN/nia-train" prepare --input "$OUT/capture/$name" --smpl "$OUT/true/body_model.npz" \
    --out "$OUT/fitted" --truth "$TRUTH/$name" | grep -E "fit time|against"
done
for root in fitted true; do
  # shellcheck disable=SC2086 # EXTRA is a list of flags
  "$BIN/nia-train" --config configs/own_capture.toml --set "data.root=$OUT/$root" \
    --set "data.smpl_model=$OUT/true/body_model.npz" --set "train.steps=$STEPS" \
    --set "optim.decay_steps=$STEPS" ${EXTRA:-} --out "$OUT/run_$root" >"$OUT/train_$root.log" 2>&1
  "$BIN/nia-infer" export --checkpoint "$OUT/run_$root" --out "$OUT/$root.nia" >/dev/null
  "$BIN/nia-infer" eval --model "$OUT/$root.nia" --out "$OUT/eval_$root" --no-pictures \
    >"$OUT/eval_$root.log" 2>&1
  # The summary is the last line of the eval's output (JSON).
  summary=$(tail -n 1 "$OUT/eval_$root.log")
  label=$root
  if [ "$root" = true ] && [ "$CAPTURE" != none ]; then label="set's own (simulated)"; fi
  echo "== trained on the $label SMPL, held-out person: $(grep -o '"psnr":[0-9.]*' <<<"$summary")" \
    "$(grep -o '"ssim":[0-9.]*' <<<"$summary")"
done
