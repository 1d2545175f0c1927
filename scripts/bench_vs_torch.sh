#!/usr/bin/env bash
# Side-by-side timing of the NIA forward and training step: the eager PyTorch + spconv
# reference and `nia-infer bench`, back to back on this machine, at the same dimensions, with
# per-stage ratios (nia-rs / PyTorch; below 1 is faster).
#
#   scripts/bench_vs_torch.sh [--reps N] [--backend flex|ndarray|wgpu] [--rays R] [--samples S]
#                             [--views N] [--size PX] [--threads T]
#
# The reference is ../shared/reference/nia_torch.py (override: NIA_TORCH_REF) run with the
# Python of a venv holding torch and spconv (NIA_TORCH_PYTHON, default /tmp/refenv/bin/python):
#   python3 -m venv /tmp/refenv && /tmp/refenv/bin/pip install torch spconv numpy   # ~5 GB
# Without it only nia-rs is timed, and the script says so. Both sides are pinned to --threads
# threads (PyTorch's intra-op pool; RAYON_NUM_THREADS for nia-rs). The machine is noisy: read
# the ratios, and rerun before trusting a small one.
set -euo pipefail
cd "$(dirname "$0")/.."

reps=1 backend=flex rays=1024 samples=64 views=3 size=512 threads=2
while [ $# -gt 0 ]; do
  case "$1" in
    --reps) reps=$2; shift 2 ;;
    --backend) backend=$2; shift 2 ;;
    --rays) rays=$2; shift 2 ;;
    --samples) samples=$2; shift 2 ;;
    --views) views=$2; shift 2 ;;
    --size) size=$2; shift 2 ;;
    --threads) threads=$2; shift 2 ;;
    -h|--help) sed -n '2,15p' "$0"; exit 0 ;;
    *) echo "unknown argument: $1 (see --help)" >&2; exit 2 ;;
  esac
done

ref_script=${NIA_TORCH_REF:-../shared/reference/nia_torch.py}
ref_python=${NIA_TORCH_PYTHON:-/tmp/refenv/bin/python}
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$PWD/target}
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT

# One build of the whole workspace (the profile and features the tests use).
cargo build --quiet --workspace --all-features
nia_infer=$CARGO_TARGET_DIR/debug/nia-infer

dims=(--rays "$rays" --samples "$samples" --views "$views" --size "$size" --reps "$reps")
if [ -f "$ref_script" ] && [ -x "$ref_python" ] && "$ref_python" -c 'import torch, spconv' 2>/dev/null; then
  echo "reference: $ref_python $ref_script ${dims[*]} --threads $threads" >&2
  OMP_NUM_THREADS=$threads "$ref_python" "$ref_script" "${dims[@]}" --threads "$threads" > "$out/torch.json"
else
  echo "reference not run: needs $ref_script and a Python with torch and spconv at $ref_python" >&2
  echo "  (python3 -m venv /tmp/refenv && /tmp/refenv/bin/pip install torch spconv numpy)" >&2
fi
echo "nia-rs: nia-infer bench --backend $backend ${dims[*]} (RAYON_NUM_THREADS=$threads)" >&2
RAYON_NUM_THREADS=$threads "$nia_infer" bench --backend "$backend" "${dims[@]}" | tail -n 1 > "$out/nia.json"

python3 - "$out" "$backend" <<'PY'
import json, os, platform, subprocess, sys
out, backend = sys.argv[1], sys.argv[2]
nia = json.load(open(os.path.join(out, "nia.json")))
ref_path = os.path.join(out, "torch.json")
ref = json.load(open(ref_path)) if os.path.exists(ref_path) else None
def cpu():
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"
commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True).stdout.strip()
print(f"machine: {cpu()}, {os.cpu_count()} cores; nia-rs commit {commit}{' (modified)' if dirty else ''}, backend {backend}, heap {nia.get('heap', '?')}")
print(f"dimensions: {nia['rays']} rays x {nia['samples']} samples, {nia['views']} views of {nia['size']}x{nia['size']}")
if ref:
    print(f"reference: PyTorch {ref['torch']} + spconv, {ref['threads']} threads")
print()
stages = dict(nia["stages_s"])
print("| stage | PyTorch + spconv (s) | nia-rs (s) | nia-rs / PyTorch |")
print("|---|---:|---:|---:|")
names = ["encoder", "body_volume", "sampling", "mlps", "blending", "compositing"]
for name in names:
    ours = stages.get(name)
    theirs = ref["stages_s"].get({"mlps": "nerf_mlps"}.get(name, name)) if ref else None
    ratio = f"{ours / theirs:.2f}x" if ours is not None and theirs else "-"
    fmt = lambda x: f"{x:.2f}" if x is not None else "-"
    print(f"| {name} | {fmt(theirs)} | {fmt(ours)} | {ratio} |")
for key, label in [("forward_s", "**forward**"), ("train_step_s", "**training step**")]:
    ours = nia[key]; theirs = ref[key] if ref else None
    ratio = f"**{ours / theirs:.2f}x**" if theirs else "-"
    print(f"| {label} | {theirs:.2f} | {ours:.2f} | {ratio} |" if theirs else f"| {label} | - | {ours:.2f} | - |")
PY
