#!/usr/bin/env bash
# The robustness table of docs/robustness.md: exported models evaluated on synthetic sets with
# and without capture flaws (docs/data.md, "Capture flaws"). Prints one markdown row per
# (model, set, flags) with PSNR, SSIM, IBR-only and NeRF-only PSNR, the PSNR next to the
# outline and c0's share of the blend where a source sees.
#
#   scripts/robustness.sh MODEL.nia [MODEL.nia ...]
#
# Environment:
#   SEEDS    generator seeds of the sets (default "23 24": never used to choose a setting)
#   CAMERAS  cameras of the ring (default 8: no target view faces a source view)
#   FLAWS    sets per seed: none, zju_like, or one flaw as `<flag>=<level>` with the flag of
#            `nia-train synth` (default: "none zju_like smpl-fit=1 mask=1 geometry=1
#            calibration=1 colour=1 zju_like,smpl-fit=2")
#   FLAGS    `|`-separated nia-infer eval flag sets, each one row (default: "" = the model's)
#   TRUTH    a FLAWS entry (e.g. none) whose set of the same seed is also scored against
#            (`nia-infer eval --truth-data`): adds the PSNR / SSIM and the IBR-only PSNR against
#            the true image (default none: off). Meaningful for mask flaws alone.
#   DATA     where the sets are generated (default data/robustness; kept between runs)
#   BIN      folder holding nia-train and nia-infer (default the dev profile's)
set -euo pipefail

SEEDS=${SEEDS:-"23 24"}
CAMERAS=${CAMERAS:-8}
FLAWS=${FLAWS:-"none zju_like smpl-fit=1 mask=1 geometry=1 calibration=1 colour=1 zju_like,smpl-fit=2"}
FLAGS=${FLAGS:-""}
TRUTH=${TRUTH:-}
DATA=${DATA:-data/robustness}
BIN=${BIN:-${CARGO_TARGET_DIR:-target}/debug}
[ $# -ge 1 ] || { echo "usage: $0 MODEL.nia [MODEL.nia ...]" >&2; exit 2; }
for m in "$@"; do [ -f "$m" ] || { echo "$m: no such model file" >&2; exit 2; }; done

# The synth flags of one FLAWS entry: "zju_like,smpl-fit=2" -> --capture zju_like --smpl-fit-level 2.
synth_flags() {
  local out=() part
  IFS=',' read -ra parts <<< "$1"
  for part in "${parts[@]}"; do
    case "$part" in
      none) out+=(--capture none) ;;
      zju_like) out+=(--capture zju_like) ;;
      *=*) out+=("--${part%%=*}-level" "${part##*=}") ;;
      *) echo "unknown flaw \`$part\`" >&2; exit 2 ;;
    esac
  done
  echo "${out[@]}"
}

# The set of `seed` with the flaws of FLAWS entry $2, generated into $DATA once.
set_of() {
  local seed=$1 flaw=$2 dir="$DATA/s$1_c${CAMERAS}_${2//[=,]/_}"
  if [ ! -f "$dir/synth.json" ]; then
    # shellcheck disable=SC2046
    "$BIN/nia-train" synth --out "$dir" --subjects 8 --frames 6 --cameras "$CAMERAS" \
      --size 128 --seed "$seed" --supersample 2 $(synth_flags "$flaw") > /dev/null
  fi
  echo "$dir"
}

if [ -n "$TRUTH" ]; then
  echo "| model | seed | cameras | flaws | flags | PSNR | SSIM | IBR-only | NeRF-only | outline | c0 share | PSNR / SSIM (truth) | IBR-only (truth) |"
  echo "|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
else
  echo "| model | seed | cameras | flaws | flags | PSNR | SSIM | IBR-only | NeRF-only | outline | c0 share |"
  echo "|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|"
fi
for seed in $SEEDS; do
  truth_flags=()
  [ -z "$TRUTH" ] || truth_flags=(--truth-data "$(set_of "$seed" "$TRUTH")")
  for flaw in $FLAWS; do
    set_dir=$(set_of "$seed" "$flaw")
    for model in "$@"; do
      IFS='|' read -ra flag_sets <<< "${FLAGS:-}"
      [ ${#flag_sets[@]} -gt 0 ] || flag_sets=("")
      for flags in "${flag_sets[@]}"; do
        out=$(mktemp -d)
        # shellcheck disable=SC2086
        "$BIN/nia-infer" eval --model "$model" --data "$set_dir" --split test --out "$out" $flags "${truth_flags[@]}" \
          2> /dev/null | tail -n 1 |
          python3 -c '
import json, sys
d = json.load(sys.stdin); g = d["diagnostics"]
row = "| %s | %s | %s | %s | %s | %.2f | %.3f | %.2f | %.2f | %.2f | %.2f |" % (
    sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5] or "-", d["psnr"], d["ssim"],
    g["psnr_ibr"], g["psnr_nerf"], g["psnr_silhouette"], g["c0_weight_seen"])
if "psnr_truth" in g:
    row += " %.2f / %.3f | %.2f |" % (g["psnr_truth"], g["ssim_truth"], g["psnr_ibr_truth"])
print(row)
' "$(basename "$model")" "$seed" "$CAMERAS" "$flaw" "$flags"
        rm -rf "$out"
      done
    done
  done
done
