#!/usr/bin/env bash
# Kernel launches and seconds of one `nia-infer render --backend wgpu` with warm caches: a first
# render fills cubecl's autotune cache (and the driver's shader cache), a second is timed (the
# seconds of each image from its render.json), a third runs with cubecl's profiling log on
# ("minimal": one line per kernel that runs) and counts the launches of the whole process
# (the scene's encoding included, the same for every chunk size). Launch counts do not depend
# on the device's speed, so Mesa's software Vulkan (lavapipe) counts them as a GPU would
# (docs/speed.md, "Fewer, larger calls").
#
#   scripts/wgpu_render_launches.sh OUT_DIR [nia-infer render arguments without --out/--backend]
#   NIA_INFER=path/to/nia-infer  (default: the dev build in $CARGO_TARGET_DIR or target/)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:?OUT_DIR}; shift
bin=${NIA_INFER:-${CARGO_TARGET_DIR:-target}/debug/nia-infer}
[ -x "$bin" ] || { echo "no nia-infer at $bin (build it or set NIA_INFER)" >&2; exit 1; }
bin=$(cd "$(dirname "$bin")" && pwd)/$(basename "$bin")
mkdir -p "$out"; out=$(cd "$out" && pwd)
repo=$(pwd)
args=()
for a in "$@"; do # paths relative to the repository
  if [ -e "$repo/$a" ]; then args+=("$repo/$a"); else args+=("$a"); fi
done
rm -f "$out/cubecl.toml"
(cd "$out" && "$bin" render --backend wgpu --out "$out/warm" "${args[@]}" > warm.json 2> warm.err) \
  || { echo "nia-infer render failed: $out/warm.err" >&2; exit 1; }
start=$(date +%s.%N)
(cd "$out" && "$bin" render --backend wgpu --out "$out/timed" "${args[@]}" > timed.json 2> timed.err) \
  || { echo "nia-infer render failed: $out/timed.err" >&2; exit 1; }
end=$(date +%s.%N)
printf '[profiling.logger]\nlevel = "minimal"\nfile = "%s/launches.log"\n' "$out" > "$out/cubecl.toml"
rm -f "$out/launches.log"
(cd "$out" && "$bin" render --backend wgpu --out "$out/logged" "${args[@]}" > logged.json 2> logged.err) \
  || { echo "nia-infer render failed: $out/logged.err" >&2; exit 1; }
rm -f "$out/cubecl.toml"
python3 - "$out" "$start" "$end" <<'PY'
import json, sys
out, wall = sys.argv[1], float(sys.argv[3]) - float(sys.argv[2])
report = json.load(open(f"{out}/timed/render.json"))
launches = sum(1 for _ in open(f"{out}/launches.log"))
images = report["images"]
print(f"chunk {report['chunk']} rays: {launches} kernel launches (whole process), "
      f"command wall {wall:.1f} s, encoding {report['encode_seconds']:.1f} s")
print("| view | rays | network points | seconds |\n|---|---:|---:|---:|")
for im in images:
    print(f"| {im['target_view']} | {im['rays']} | {im['point_evaluations']} | {im['seconds']:.2f} |")
PY
