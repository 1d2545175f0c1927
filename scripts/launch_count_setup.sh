# Sourced by scripts/wgpu_launches.sh and scripts/wgpu_render_launches.sh, from the repository
# root, with the OUT_DIR argument: sets `bin` (the absolute path of nia-infer: $NIA_INFER, or
# the dev build in $CARGO_TARGET_DIR or target/) and `out` (OUT_DIR, created, absolute), since
# the counting runs happen inside OUT_DIR, where cubecl reads its cubecl.toml.
out=${1:?OUT_DIR}
bin=${NIA_INFER:-${CARGO_TARGET_DIR:-target}/debug/nia-infer}
[ -x "$bin" ] || { echo "no nia-infer at $bin (build it or set NIA_INFER)" >&2; exit 1; }
bin=$(cd "$(dirname "$bin")" && pwd)/$(basename "$bin")
mkdir -p "$out"; out=$(cd "$out" && pwd)
