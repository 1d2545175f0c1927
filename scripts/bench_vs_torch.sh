#!/usr/bin/env bash
# Side-by-side timing of the NIA forward and training step: the eager PyTorch + spconv
# reference and `nia-infer bench`, back to back on this machine, at the same dimensions, like for
# like: each heap setting runs on both sides (nia-rs / PyTorch; below 1 is faster).
#
#   scripts/bench_vs_torch.sh [--heap both|system|keep_freed] [--reps N] [--backend flex|ndarray|wgpu]
#                             [--rays R] [--samples S] [--views N] [--size PX] [--threads T]
#
# Heap settings (glibc): `system` is malloc as it comes (nia-rs: NIA_HEAP=system; PyTorch as
# installed); `keep_freed` is what nia-rs sets by default (mallopt: no mmap, no trimming), given
# to PyTorch as GLIBC_TUNABLES=glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=<2^62>.
# `both` (the default) runs system then keep_freed. Peak RSS of each process comes from
# /usr/bin/time -v. The CPU model and core count head the output.
#
# The reference is ../shared/reference/nia_torch.py (override: NIA_TORCH_REF) run with the
# Python of a venv holding torch and spconv (NIA_TORCH_PYTHON, default /tmp/refenv/bin/python):
#   python3 -m venv /tmp/refenv && /tmp/refenv/bin/pip install torch spconv numpy   # ~5 GB
# Without it only nia-rs is timed, and the script says so. Both sides are pinned to --threads
# threads (PyTorch's intra-op pool; RAYON_NUM_THREADS for nia-rs). The machine is noisy: read
# the ratios, and rerun before trusting a small one.
set -euo pipefail
cd "$(dirname "$0")/.."

reps=1 backend=flex rays=1024 samples=64 views=3 size=512 threads=2 heap=both
while [ $# -gt 0 ]; do
  case "$1" in
    --reps) reps=$2; shift 2 ;;
    --backend) backend=$2; shift 2 ;;
    --rays) rays=$2; shift 2 ;;
    --samples) samples=$2; shift 2 ;;
    --views) views=$2; shift 2 ;;
    --size) size=$2; shift 2 ;;
    --threads) threads=$2; shift 2 ;;
    --heap) heap=$2; shift 2 ;;
    -h|--help) sed -n '2,22p' "$0"; exit 0 ;;
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
case "$heap" in
  both) heaps=(system keep_freed) ;;
  system|keep_freed) heaps=("$heap") ;;
  *) echo "--heap: expected both, system or keep_freed, got $heap" >&2; exit 2 ;;
esac
have_ref=0
if [ -f "$ref_script" ] && [ -x "$ref_python" ] && "$ref_python" -c 'import torch, spconv' 2>/dev/null; then
  have_ref=1
else
  echo "reference not run: needs $ref_script and a Python with torch and spconv at $ref_python" >&2
  echo "  (python3 -m venv /tmp/refenv && /tmp/refenv/bin/pip install torch spconv numpy)" >&2
fi
# Peak resident set (kB) from /usr/bin/time -v's report.
peak_kb() { sed -n 's/.*Maximum resident set size (kbytes): //p' "$1"; }
for h in "${heaps[@]}"; do
  if [ "$h" = keep_freed ]; then
    torch_env=(GLIBC_TUNABLES=glibc.malloc.mmap_max=0:glibc.malloc.trim_threshold=4611686018427387904)
    nia_env=()
  else
    torch_env=()
    nia_env=(NIA_HEAP=system)
  fi
  if [ $have_ref = 1 ]; then
    echo "[$h] reference: ${torch_env[*]} $ref_python $ref_script ${dims[*]} --threads $threads" >&2
    env "${torch_env[@]}" OMP_NUM_THREADS=$threads /usr/bin/time -v -o "$out/torch_$h.time" \
      "$ref_python" "$ref_script" "${dims[@]}" --threads "$threads" > "$out/torch_$h.json"
    peak_kb "$out/torch_$h.time" > "$out/torch_$h.rss"
  fi
  echo "[$h] nia-rs: ${nia_env[*]} nia-infer bench --backend $backend ${dims[*]} (RAYON_NUM_THREADS=$threads)" >&2
  env "${nia_env[@]}" RAYON_NUM_THREADS=$threads /usr/bin/time -v -o "$out/nia_$h.time" \
    "$nia_infer" bench --backend "$backend" "${dims[@]}" | tail -n 1 > "$out/nia_$h.json"
  peak_kb "$out/nia_$h.time" > "$out/nia_$h.rss"
done

python3 - "$out" "$backend" "${heaps[@]}" <<'PY'
import json, os, platform, subprocess, sys
out, backend, heaps = sys.argv[1], sys.argv[2], sys.argv[3:]
def load(name):
    path = os.path.join(out, name)
    return json.load(open(path)) if os.path.exists(path) and os.path.getsize(path) else None
def rss(name):
    path = os.path.join(out, name)
    try:
        return int(open(path).read().strip()) / 1e6  # GB
    except (OSError, ValueError):
        return None
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
first = load(f"nia_{heaps[0]}.json")
print(f"machine: {cpu()}, {os.cpu_count()} cores; nia-rs commit {commit}{' (modified)' if dirty else ''}, backend {backend}")
print(f"dimensions: {first['rays']} rays x {first['samples']} samples, {first['views']} views of {first['size']}x{first['size']}")
ref0 = load(f"torch_{heaps[0]}.json")
if ref0:
    print(f"reference: PyTorch {ref0['torch']} + spconv, {ref0['threads']} threads")
fmt = lambda x, d=2: "-" if x is None else f"{x:.{d}f}"
ratio = lambda a, b: f"**{a / b:.2f}x**" if a is not None and b else "-"
for h in heaps:
    nia, ref = load(f"nia_{h}.json"), load(f"torch_{h}.json")
    print(f"\n### heap: {h} on both sides (nia-rs: {nia.get('heap', '?')})\n")
    print("| stage | PyTorch + spconv (s) | nia-rs (s) | nia-rs / PyTorch |")
    print("|---|---:|---:|---:|")
    stages = dict(nia["stages_s"])
    # The reference computes its point inputs before its timed forward: point_inputs has no
    # counterpart there.
    for name in ["encoder", "body_volume", "point_inputs", "sampling", "mlps", "blending", "compositing"]:
        ours = stages.get(name)
        theirs = ref["stages_s"].get({"mlps": "nerf_mlps"}.get(name, name)) if ref else None
        print(f"| {name} | {fmt(theirs)} | {fmt(ours)} | {ratio(ours, theirs)[2:-2] if ratio(ours, theirs) != '-' else '-'} |")
    for key, label in [("forward_s", "**forward**"), ("train_step_s", "**training step**")]:
        ours, theirs = nia.get(key), (ref or {}).get(key)
        print(f"| {label} | {fmt(theirs)} | {fmt(ours)} | {ratio(ours, theirs)} |")
    if nia.get("train_forward_s") is not None:
        print(f"| training step: forward / backward + Adam | - | {nia['train_forward_s']:.2f} / {nia['train_backward_s']:.2f} | - |")
    a, b = rss(f"nia_{h}.rss"), rss(f"torch_{h}.rss")
    print(f"| peak RSS (GB) | {fmt(b)} | {fmt(a)} | {ratio(a, b)} |")
PY
