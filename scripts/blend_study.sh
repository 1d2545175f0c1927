#!/usr/bin/env bash
# The blend study of docs/results.md ("The learned blend under each flaw"): the main command's
# recipe (configs/quickstart.toml) trained on generator seed 0's people (4, 8 cameras) with
# one capture flaw at a time, as the full model (e) and as the simple average (c), then each
# model evaluated with scripts/robustness.sh on sets of other people with the same flaw.
#
#   scripts/blend_study.sh
#
# Environment:
#   FLAWS     training-data flaws, robustness.sh's spelling (default: "none mask=1 colour=1
#             calibration=1 geometry=1 smpl-fit=1 zju_like")
#   VARIANTS  "e c" (default): e = the config's model, c = model.variant = "simple_average"
#   TSEEDS    training seeds (default "0")
#   SETS      generator seeds of the evaluation sets (default "21": the tuning set)
#   CAMERAS   cameras of the evaluation sets' ring (default 8)
#   SETTINGS  extra `--set KEY=VALUE` words for every training (default none), and TAG a name
#             for them in the run and model names (default "base")
#   FLAGS     robustness.sh's eval flag sets (default "" = the model's own render settings)
#   CONFIG    the training config (default configs/quickstart.toml)
#   BIN       folder holding nia-train and nia-infer (default the dev profile's)
#   RUNS, MODELS, DATA  where runs, .nia files and data go (default runs/blend, models/blend,
#             data/blend); everything already there is reused, so the script resumes.
set -euo pipefail

FLAWS=${FLAWS:-"none mask=1 colour=1 calibration=1 geometry=1 smpl-fit=1 zju_like"}
VARIANTS=${VARIANTS:-"e c"}
TSEEDS=${TSEEDS:-0}
SETS=${SETS:-21}
CAMERAS=${CAMERAS:-8}
SETTINGS=${SETTINGS:-}
TAG=${TAG:-base}
FLAGS=${FLAGS:-}
CONFIG=${CONFIG:-configs/quickstart.toml}
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/debug}
RUNS=${RUNS:-runs/blend}
MODELS=${MODELS:-models/blend}
DATA=${DATA:-data/blend}
mkdir -p "$RUNS" "$MODELS" "$DATA"

# `--set` words of the training data for one FLAWS entry: "mask=1" -> synth.mask_level=1.
data_sets() {
  local out=() part key preset=none
  IFS=',' read -ra parts <<< "$1"
  # A single flaw is that flaw alone: the preset is "none" unless the entry names zju_like
  # (the config's own preset would otherwise add every other flaw).
  for part in "${parts[@]}"; do [ "$part" = zju_like ] && preset=zju_like; done
  out+=(--set "synth.capture=\"$preset\"")
  for part in "${parts[@]}"; do
    case "$part" in
      none|zju_like) ;;
      *=*) key=${part%%=*}; out+=(--set "synth.${key//-/_}_level=${part##*=}") ;;
      *) echo "unknown flaw \`$part\`" >&2; exit 2 ;;
    esac
  done
  printf '%s\n' "${out[@]}"
}

for flaw in $FLAWS; do
  name=${flaw//[=,]/_}
  mapfile -t synth < <(data_sets "$flaw")
  for variant in $VARIANTS; do
    case "$variant" in
      e) variant_set=() ;;
      c) variant_set=(--set 'model.variant="simple_average"') ;;
      *) echo "unknown variant \`$variant\`" >&2; exit 2 ;;
    esac
    for tseed in $TSEEDS; do
      run="$RUNS/${TAG}_${name}_${variant}_t${tseed}"
      model="$MODELS/${TAG}_${name}_${variant}_t${tseed}.nia"
      if [ ! -f "$model" ]; then
        # shellcheck disable=SC2086
        "$BIN/nia-train" --config "$CONFIG" --out "$run" --overwrite \
          --set "data.root=\"$DATA/train_s0_c8_$name\"" "${synth[@]}" "${variant_set[@]}" \
          --set synth.seed=0 --set synth.subjects=4 --set synth.test_fraction=0.25 \
          --set train.seed="$tseed" --set train.evaluate_at_end=false \
          --set train.validate_every=1000000 $SETTINGS > "$run.log" 2>&1
        "$BIN/nia-infer" export --checkpoint "$run" --out "$model" > /dev/null
      fi
      SEEDS="$SETS" CAMERAS="$CAMERAS" FLAWS="$flaw" FLAGS="$FLAGS" DATA="$DATA" BIN="$BIN" \
        scripts/robustness.sh "$model" | tail -n +3
    done
  done
done
