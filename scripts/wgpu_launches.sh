#!/usr/bin/env bash
# Kernel launches of one steady forward (or training step) on wgpu, by kernel family: runs
# `nia-infer bench --backend wgpu --reps 1` and `--reps 2` with cubecl's profiling log on
# ("minimal": one line per kernel that runs) and prints the difference, which is what one more
# timed repetition launched. A first run without the log fills cubecl's autotune and throughput
# caches, so that neither logged run autotunes or probes the device. The counts do not depend on the device's speed, so they can be
# compared on Mesa's software Vulkan (lavapipe) as on a GPU: every launch costs a dispatch and
# burn's per-operation work on the host (docs/speed.md, "Kernel launches").
#
#   scripts/wgpu_launches.sh OUT_DIR [more nia-infer bench arguments, e.g. --rays 32 --no-train]
#   NIA_INFER=path/to/nia-infer  (default: the dev build in $CARGO_TARGET_DIR or target/)
#
# Writes cubecl.toml into OUT_DIR and runs the benches there (cubecl reads it from the working
# directory).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/launch_count_setup.sh "${1:-}"; shift
(cd "$out" && rm -f cubecl.toml && "$bin" bench --backend wgpu --reps 1 "$@" > bench_warm.json 2> bench_warm.err) \
  || { echo "nia-infer bench failed: $out/bench_warm.err" >&2; exit 1; }
for reps in 1 2; do
  rm -f "$out/launches_$reps.log"
  printf '[profiling.logger]\nlevel = "minimal"\nfile = "%s/launches_%s.log"\n' "$out" "$reps" \
    > "$out/cubecl.toml"
  (cd "$out" && "$bin" bench --backend wgpu --reps "$reps" "$@" > "bench_$reps.json" 2> "bench_$reps.err") \
    || { echo "nia-infer bench failed: $out/bench_$reps.err" >&2; exit 1; }
done
python3 - "$out" <<'PY'
import collections, sys
out = sys.argv[1]
def families(reps):
    c = collections.Counter()
    for line in open(f"{out}/launches_{reps}.log"):
        name = line.strip().removeprefix("Executing ")
        c[name.split(" | ")[0].split("_")[0]] += 1
    return c
one, two = families(1), families(2)
diff = {k: two[k] - one[k] for k in set(one) | set(two) if two[k] != one[k]}
print(f"kernel launches of one more repetition: {sum(diff.values())}")
print("| kernel family | launches |\n|---|---:|")
for k, v in sorted(diff.items(), key=lambda kv: -kv[1]):
    print(f"| {k} | {v} |")
PY
