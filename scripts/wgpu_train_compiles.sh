#!/usr/bin/env bash
# Kernel compilations, time and readbacks per training step on wgpu: runs the quickstart config
# on the wgpu backend for STEPS steps with cubecl's compilation log on, and prints per step its
# seconds, the kernels compiled during it and its tensor reads (the log's `readbacks`: each one
# a wait for the device). Steps that keep compiling after the first few point at
# tensor shapes that change from step to step (docs/speed.md, "Training on a GPU").
#
#   scripts/wgpu_train_compiles.sh STEPS OUT_DIR [more nia-train arguments]
#   NIA_TRAIN=path/to/nia-train  (default: the dev build in $CARGO_TARGET_DIR or target/)
#
# For a cold start empty cubecl's autotune cache (~/.cache/cubecl) and the driver's shader cache
# (Mesa: ~/.cache/mesa_shader_cache) first. Writes cubecl.toml into the repository root while
# it runs (cubecl reads it from the working directory) and removes it after.
set -euo pipefail
cd "$(dirname "$0")/.."
steps=${1:?STEPS}; out=${2:?OUT_DIR}; shift 2
bin=${NIA_TRAIN:-${CARGO_TARGET_DIR:-target}/debug/nia-train}
[ -x "$bin" ] || { echo "no nia-train at $bin (build it or set NIA_TRAIN)" >&2; exit 1; }
[ -e cubecl.toml ] && { echo "cubecl.toml exists here already; not overwriting it" >&2; exit 1; }
mkdir -p "$out"; out=$(cd "$out" && pwd)
rm -f "$out/compile.log"
printf '[compilation.logger]\nlevel = "basic"\nfile = "%s/compile.log"\n' "$out" > cubecl.toml
trap 'rm -f cubecl.toml' EXIT
# Every second: the steps logged so far and the compilations so far.
( while true; do
    printf '%s %s %s\n' "$(date +%s.%N)" \
      "$(grep -c '"loss"' "$out/run/metrics.jsonl" 2>/dev/null || true)" \
      "$(grep -c . "$out/compile.log" 2>/dev/null || true)"
    sleep 1
  done ) > "$out/watch.txt" &
watcher=$!
start=$(date +%s.%N)
rc=0
"$bin" --config configs/quickstart.toml --set 'train.backend="wgpu"' --set train.steps="$steps" \
  --set train.validate_every=0 --set train.evaluate_at_end=false --set train.checkpoint_every=100000 \
  --out "$out/run" "$@" > "$out/train.log" 2>&1 || rc=$?
end=$(date +%s.%N)
kill $watcher 2>/dev/null || true
[ $rc = 0 ] || { echo "nia-train failed ($rc): $out/train.log" >&2; exit $rc; }
rays=256  # the quickstart's rays_per_step, unless set on the command line
for a in "$@"; do [[ $a == train.rays_per_step=* ]] && rays=${a#*=}; done
python3 - "$out" "$start" "$end" "$rays" <<'PY'
import json, sys
out, start, end, rays_per_step = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
steps = [json.loads(l) for l in open(f"{out}/run/metrics.jsonl") if '"loss"' in l]
# Compilations at the first second each step count was seen: what compiled during that step.
seen = {}
for line in open(f"{out}/watch.txt"):
    parts = line.split()
    if len(parts) == 3 and parts[1].isdigit() and parts[2].isdigit():
        seen.setdefault(int(parts[1]), int(parts[2]))
total = sum(1 for _ in open(f"{out}/compile.log"))
print(f"wall {end - start:.1f} s, {len(steps)} steps, {total} kernel compilations")
print("| step | seconds | compilations during it (1 s resolution) | readbacks |\n|---:|---:|---:|---:|")
for k, s in enumerate(steps):
    rays = s.get("rays_per_s") or 0
    secs = rays_per_step / rays if rays else float("nan")
    a, b = seen.get(k, 0), seen.get(k + 1, total)
    print(f"| {s['step']} | {secs:.1f} | {b - a} | {s.get('readbacks', '-')} |")
PY
