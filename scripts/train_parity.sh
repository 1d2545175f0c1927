#!/usr/bin/env bash
# Training on two or more backends, loss for loss, from the same weights: one step on `flex`
# writes a checkpoint, then each backend trains STEPS steps from it (`train.init_from`) with the
# same rays, samples and jitter (everything random comes from the run's seed and the step on the
# host), and the table gives every step's loss with its relative difference from the first
# backend's. Weights are initialised on the device by its own generator, so without the shared
# checkpoint two backends would start apart. On Mesa's software Vulkan (lavapipe) a wgpu run of
# 20 steps takes about five minutes (mostly shader compilation); its seconds mean nothing.
#
#   scripts/train_parity.sh OUT_DIR                       # flex, ndarray, wgpu; 20 steps
#   BACKENDS="flex wgpu" STEPS=50 scripts/train_parity.sh OUT_DIR [more nia-train flags]
#   NIA_TRAIN=path/to/nia-train  (default: the dev build in $CARGO_TARGET_DIR or target/)
#   CONFIG=configs/quickstart_clean.toml  (default; its data are generated when missing)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?OUT_DIR}
shift
bin=${NIA_TRAIN:-${CARGO_TARGET_DIR:-target}/debug/nia-train}
[ -x "$bin" ] || { echo "no nia-train at $bin (build it or set NIA_TRAIN)" >&2; exit 1; }
config=${CONFIG:-configs/quickstart_clean.toml}
backends=${BACKENDS:-flex ndarray wgpu}
steps=${STEPS:-20}
mkdir -p "$out"
out=$(cd "$out" && pwd)
common=(--config "$config" --set train.validate_every=0 --set train.evaluate_at_end=false
  --set train.rays_per_step=128 "$@")

rm -rf "$out/init"
"$bin" "${common[@]}" --backend flex --steps 1 --out "$out/init" --set train.checkpoint_every=1 \
  > "$out/init.log" 2>&1 || { echo "the initial step failed: $out/init.log" >&2; exit 1; }
init=$(ls -d "$out"/init/checkpoints/step_* | tail -n 1)
for backend in $backends; do
  rm -rf "${out:?}/$backend"
  SECONDS=0
  "$bin" "${common[@]}" --backend "$backend" --steps "$steps" --out "$out/$backend" \
    --set train.checkpoint_every=100000 --set "train.init_from=\"$init\"" \
    > "$out/$backend.log" 2>&1 || { echo "training on $backend failed: $out/$backend.log" >&2; exit 1; }
  echo "$backend: $steps steps in ${SECONDS} s" >&2
done

python3 - "$out" $backends <<'PY'
import json, sys
out, backends = sys.argv[1], sys.argv[2:]
def losses(backend):
    return {e["step"]: e["loss"] for e in map(json.loads, open(f"{out}/{backend}/metrics.jsonl"))
            if e.get("event") == "step"}
runs = {b: losses(b) for b in backends}
ref = backends[0]
steps = sorted(runs[ref])
for b in backends[1:]:
    if sorted(runs[b]) != steps:
        sys.exit(f"{b} logged steps {sorted(runs[b])}, {ref} logged {steps}")
print("| step | " + " | ".join(f"loss, {b}" for b in backends)
      + "".join(f" | {b} - {ref}, relative" for b in backends[1:]) + " |")
print("|---:|" + "---:|" * (2 * len(backends) - 1))
worst = {b: 0.0 for b in backends[1:]}
for s in steps:
    r = runs[ref][s]
    row = [f"{runs[b][s]:.6f}" for b in backends]
    for b in backends[1:]:
        d = (runs[b][s] - r) / r
        worst[b] = max(worst[b], abs(d))
        row.append(f"{d:+.1e}")
    print(f"| {s} | " + " | ".join(row) + " |")
for b, w in worst.items():
    print(f"largest |relative difference| of {b} from {ref}: {w:.1e}")
PY
