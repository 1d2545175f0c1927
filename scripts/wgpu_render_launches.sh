#!/usr/bin/env bash
# Kernel launches, readbacks and seconds of one `nia-infer render --backend wgpu` with warm
# caches: a first
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
source scripts/launch_count_setup.sh "${1:-}"; shift
repo=$(pwd)
args=()
for a in "$@"; do # paths relative to the repository
  if [ -e "$repo/$a" ]; then args+=("$repo/$a"); else args+=("$a"); fi
done
# One render into OUT/NAME, run in OUT (cubecl reads cubecl.toml there).
render() {
  (cd "$out" && "$bin" render --backend wgpu --out "$out/$1" "${args[@]}" > "$1.json" 2> "$1.err") \
    || { echo "nia-infer render failed: $out/$1.err" >&2; exit 1; }
}
rm -f "$out/cubecl.toml"
render warm
start=$(date +%s.%N)
render timed
end=$(date +%s.%N)
printf '[profiling.logger]\nlevel = "minimal"\nfile = "%s/launches.log"\n' "$out" > "$out/cubecl.toml"
rm -f "$out/launches.log"
render logged
rm -f "$out/cubecl.toml"
python3 - "$out" "$start" "$end" <<'PY'
import json, sys
out, wall = sys.argv[1], float(sys.argv[3]) - float(sys.argv[2])
report = json.load(open(f"{out}/timed/render.json"))
launches = sum(1 for _ in open(f"{out}/launches.log"))
images = report["images"]
print(f"chunk {report['chunk']} rays: {launches} kernel launches (whole process), "
      f"command wall {wall:.1f} s, encoding {report['encode_seconds']:.1f} s "
      f"({report.get('encode_readbacks', '-')} readbacks)")
print("| view | rays | network points | readbacks | seconds |\n|---|---:|---:|---:|---:|")
for im in images:
    print(f"| {im['target_view']} | {im['rays']} | {im['point_evaluations']} | "
          f"{im.get('readbacks', '-')} | {im['seconds']:.2f} |")
PY
