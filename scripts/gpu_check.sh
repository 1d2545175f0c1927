#!/usr/bin/env bash
# The accelerated path on a real GPU, in one command: wgpu against the CPU backend (parity),
# `nia-infer bench --backend wgpu` at the paper's dimensions against the PyTorch CUDA reference
# (scripts/reference_gpu.py) back to back, one 512x512 unseen-subject image with the paper
# network, peak GPU memory of each, and the time to a first result (shader compilation and
# autotuning included) apart from steady state. Prints a table last; logs, JSON and the images
# go to ./gpu_check_out, packed into $OUT/gpu_check.tar.gz where $OUT is set (the device tool).
#
#   scripts/gpu_check.sh prepare        # here, once: fills .gpu/ (binary, model, data, Vulkan loader)
#   GPU_CHECK_BASELINE=956b182 scripts/gpu_check.sh prepare   # also that commit's binary (`baseline`)
#   scripts/gpu_check.sh run [--quick]  # on the GPU machine, from the repository root
#   GPU_CHECK_STEPS="train render" scripts/gpu_check.sh run   # some steps only (default: all of
#                                       # probe paper 4k tiny torch render flex; train: the paper
#                                       # network's training step alone; autotune: the first
#                                       # forward by CUBECL_AUTOTUNE_LEVEL; spirv: the paper setting
#                                       # with the SPIR-V build; baseline: the 4096-ray forward
#                                       # and the render with an older commit's binary, for a
#                                       # before/after in one run; chunks: the render in chunks
#                                       # of 1024 and 8192 rays, the earlier GPU defaults, against
#                                       # the default). GPU_CHECK_LIMIT and
#                                       # GPU_CHECK_RENDER_LIMIT: seconds for a bench / the render
#   scripts/gpu_check.sh run --dry      # a rehearsal here on lavapipe and CPU torch, small sizes
#                                       # (NIA_PYTHON: a python with torch; default python3)
#
# `prepare` builds nia-infer with the wgpu feature in the release profile (everything at
# opt-level 3: the dev profile keeps the wgpu stack's host side at opt-level 1 for a shorter
# cold build, docs/speed.md "The cold build"), strips and compresses it, exports the
# paper-width model `runs/paper300` (trained with the command in docs/speed.md, "One 512x512
# image"), packs the 512-px unseen subject of data/quickstart512, and downloads the Vulkan
# loader .debs (the GPU machine has a driver but no loader, nor the GL vendor-neutral libraries
# its ICD library needs). Everything lands in .gpu/ (ignored by git): the model bundle (28 MB),
# the .debs and 20 MB per binary. The device tool carries 64 MiB a call, so carry the bundle,
# the .debs and nia-infer.xz in one call and the SPIR-V and baseline binaries in the next, on
# the still warm machine (its files stay). `run` needs nvidia-smi, python3 with torch (CUDA),
# and nothing else.
#
# A user with a GPU runs the same benchmark with `nia-infer bench --backend wgpu` directly.
set -euo pipefail
cd "$(dirname "$0")/.."
mode=${1:-}
shift || true

# The release nia-infer just built, stripped and compressed into .gpu/NAME.xz.
carry_binary() {
  cp "$CARGO_TARGET_DIR/release/nia-infer" ".gpu/$1" && strip ".gpu/$1"
  xz -T2 -6 -f ".gpu/$1"
}

# Marks the Rust sources of our crates in the tree DIR as changed (see the baseline build).
touch_sources() {
  find "$1"/nia-*/src -name '*.rs' -exec touch {} +
}

prepare() {
  export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$HOME/.cache/nia-rs/target}
  mkdir -p .gpu
  # The dev build runs the export and the generator below; the carried binary is the release one.
  cargo build --quiet --workspace --all-features
  cargo build --quiet --release --features wgpu -p nia-infer
  carry_binary nia-infer
  # The same binary with cubecl's SPIR-V compiler for Vulkan (burn's `vulkan` feature) in place
  # of WGSL through naga, for the `spirv` step. Not a feature of ours: Mesa 22.3's lavapipe, which
  # CI tests wgpu on, crashes creating its first float-atomic kernel (docs/speed.md, "Where a
  # first forward's time goes, and the shader compiler"). The extra feature adds crates to
  # Cargo.lock; the checked-in lock file is put back after.
  cargo build --quiet --release --features wgpu,burn/vulkan -p nia-infer
  git checkout -- Cargo.lock
  carry_binary nia-infer-spirv
  # An older commit's binary for the `baseline` step (the same kernels' cost before a change, in
  # the same device run). Only our crates differ, so this rebuilds those alone.
  if [ -n "${GPU_CHECK_BASELINE:-}" ]; then
    local tree=/tmp/nia-baseline-$GPU_CHECK_BASELINE
    [ -d "$tree" ] || git worktree add --detach "$tree" "$GPU_CHECK_BASELINE"
    # Both trees build into one target folder, and cargo names a workspace crate's artifacts
    # without its path: the two trees' nia-data, nia-model and nia-infer overwrite each other,
    # and a tree whose sources are older than the other's artifacts counts as built. Touching
    # a tree's sources before its build makes cargo rebuild our crates from them.
    touch_sources "$tree"
    (cd "$tree" && cargo build --quiet --release --features wgpu -p nia-infer)
    carry_binary nia-infer-baseline
    git -C "$tree" rev-parse --short HEAD > .gpu/baseline.txt
    touch_sources .
  fi
  cargo build --quiet --release --features wgpu -p nia-infer   # the uplifted binary back to WGSL
  [ -d runs/paper300 ] || { echo "runs/paper300 missing: train it first (docs/speed.md)" >&2; exit 1; }
  "$CARGO_TARGET_DIR/debug/nia-infer" export --checkpoint runs/paper300 --out .gpu/paper300.nia
  [ -d data/quickstart512 ] || "$CARGO_TARGET_DIR/debug/nia-train" synth --out data/quickstart512 \
    --subjects 4 --frames 6 --cameras 6 --size 512 --seed 0
  tar -cJf .gpu/bundle.tar.xz .gpu/paper300.nia data/quickstart512/body_model.npz \
    data/quickstart512/synth.json data/quickstart512/CoreView_4
  rm .gpu/paper300.nia
  mkdir -p .gpu/debs /tmp/amd64/partial
  local o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
  # shellcheck disable=SC2086
  apt-get $o update >/dev/null && (cd .gpu/debs && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 >/dev/null)
  du -sh .gpu
  local mib
  mib=$(du -sm .gpu | cut -f1)
  [ "$mib" -lt 58 ] || echo "note: .gpu is $mib MiB; with the working tree that is over the device tool's 64 MiB carry, so carry it in two calls (see the top of this file)" >&2
}

# Runs a command with HOME in a new empty folder, so that cubecl's autotune cache and the
# driver's shader cache start empty and its first call pays the whole start-up.
in_fresh_home() {
  local home rc=0
  home=$(mktemp -d)
  HOME="$home" XDG_CACHE_HOME="$home/.cache" "$@" || rc=$?
  rm -rf "$home"
  return $rc
}

# Peak of `nvidia-smi --query-gpu=memory.used` (MiB) while a command runs, polled every 100 ms;
# the baseline before it starts is printed too, so the command's own share is the difference.
with_memory() {
  local name=$1; shift
  if ! command -v nvidia-smi >/dev/null; then "$@"; return; fi
  nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits -lms 100 > "$out/mem_$name.csv" &
  local poller=$!
  sleep 0.3
  local rc=0
  "$@" || rc=$?
  kill "$poller" 2>/dev/null || true
  wait "$poller" 2>/dev/null || true
  return $rc
}

run() {
  local quick=0 dry=0
  [ "${1:-}" = "--quick" ] && quick=1
  [ "${1:-}" = "--dry" ] && quick=1 dry=1
  local python=${NIA_PYTHON:-python3}
  out=$PWD/gpu_check_out
  rm -rf "$out" && mkdir -p "$out"
  # The Vulkan loader (the image has NVIDIA's driver and ICD file but no libvulkan).
  if ! ldconfig -p | grep -q libvulkan.so.1 && [ $dry = 0 ]; then
    for f in .gpu/debs/*.deb; do dpkg -x "$f" /; done
    ldconfig
  fi
  for icd in /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json /usr/share/vulkan/icd.d/nvidia_icd.json \
             /etc/vulkan/icd.d/nvidia_icd.json; do
    [ -f "$icd" ] && { export VK_DRIVER_FILES=$icd; break; }
  done
  local egl=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  [ -f $egl ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$egl
  local bin=/tmp/nia-infer
  xz -dc .gpu/nia-infer.xz > $bin && chmod +x $bin
  local bin_spirv=/tmp/nia-infer-spirv
  [ -f .gpu/nia-infer-spirv.xz ] && xz -dc .gpu/nia-infer-spirv.xz > $bin_spirv && chmod +x $bin_spirv
  local bin_base=/tmp/nia-infer-baseline
  [ -f .gpu/nia-infer-baseline.xz ] && xz -dc .gpu/nia-infer-baseline.xz > $bin_base && chmod +x $bin_base \
    && cp .gpu/baseline.txt "$out/baseline.txt"
  tar -xJf .gpu/bundle.tar.xz
  if command -v nvidia-smi >/dev/null; then
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/card.txt"
  else
    echo "no nvidia-smi (rehearsal)" | tee "$out/card.txt"
  fi
  echo "VK_DRIVER_FILES=${VK_DRIVER_FILES:-unset}; CPU: $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2)"

  # Each step has its own time limit, so a slow one cannot keep the rest from running.
  local steps=" ${GPU_CHECK_STEPS:-probe paper 4k tiny torch render flex} "
  # Not in the default list: train (the training step alone), profile (the paper forward and
  # training step under cubecl's profiler: compilations and GPU time per kernel family) and autotune (the
  # first forward with CUBECL_AUTOTUNE_LEVEL=minimal against the default, fresh caches) and
  # spirv (the paper setting with the SPIR-V build, against `paper`'s WGSL build).
  # Every step check first packs what the steps before it wrote, so a run stopped at the device
  # tool's time limit still brings those back.
  step() { pack; [[ "$steps" == *" $1 "* ]]; }
  # wgpu must find the GPU before anything is timed; if not, say why and stop. The first process
  # on a fresh machine (empty driver and cubecl caches) took over 60 s for this tiny forward on
  # the H200, so the probe has 180 s, and running out of time is told apart from failing.
  local probe_rc=0
  if step probe; then
    timeout 180 $bin bench --backend wgpu --tiny --rays 8 --samples 4 --size 32 --reps 1 --no-train \
      > "$out/probe.txt" 2> "$out/probe.err" || probe_rc=$?
  fi
  if [ $probe_rc = 124 ]; then
    echo "wgpu probe: no result within 180 s (compiling on a fresh machine?); going on"
  elif [ $probe_rc != 0 ]; then
    echo "wgpu probe failed ($probe_rc): $(grep -v XDG "$out/probe.err" | tail -n 3)"
    echo "the Vulkan loader says:"
    VK_LOADER_DEBUG=error,warn,info timeout 60 $bin bench --backend wgpu --tiny --rays 8 --samples 4 \
      --size 32 --reps 1 --no-train 2>&1 | grep -v "^$" | head -40
    ldconfig -p | grep -iE "vulkan|glx|gldispatch|nvidia" | head -20
    cat "${VK_DRIVER_FILES:-/dev/null}"
    pack
    exit 1
  fi
  [ $probe_rc = 0 ] && step probe && echo "wgpu probe: $(tail -n 1 "$out/probe.txt" | cut -c1-120)"

  # Shader compilation and autotuning make the first call of every new shape slow (a minute for
  # the paper network's forward on an H200), so the limits are generous.
  local reps=3 limit=${GPU_CHECK_LIMIT:-150} short=60 render_limit=${GPU_CHECK_RENDER_LIMIT:-60}
  [ $quick = 1 ] && reps=2 limit=90 short=45
  local dims=(--rays 1024 --samples 64 --views 3 --size 512)
  local tiny=(--rays 256 --samples 32 --size 128)
  local big=(--rays 4096 --samples 64 --views 3 --size 512)
  local render_ratio=1.0
  if [ $dry = 1 ]; then
    dims=(--rays 32 --samples 8 --views 3 --size 64) tiny=(--rays 16 --samples 8 --size 64)
    big=(--rays 64 --samples 8 --views 3 --size 64)
    render_ratio=0.125 limit=900 short=900 render_limit=900 reps=1
  fi

  if step train; then
    echo "== nia-rs wgpu, paper dimensions, training step only =="
    with_memory nia_paper timeout $limit $bin bench --backend wgpu "${dims[@]}" --reps $reps \
      --train-only > "$out/nia_paper.txt" 2> "$out/nia_paper.err" || echo "bench failed: $?"
    grep -v XDG "$out/nia_paper.err" | tail -n 3 || true
  fi
  # The shader compiler: the SPIR-V build on the same dimensions, with its parity against flex
  # (cubecl's SPIR-V path has never run under nia-rs on a GPU), forward and training step. In a
  # fresh HOME, so its first forward pays the whole start-up, as `paper`'s does on a fresh
  # machine.
  if step spirv; then
    echo "== nia-rs wgpu, paper dimensions, SPIR-V build (cubecl's Vulkan compiler) =="
    if [ -x "$bin_spirv" ]; then
      in_fresh_home with_memory nia_paper_spirv timeout $limit $bin_spirv bench --backend wgpu \
        "${dims[@]}" --reps $reps --check-against flex > "$out/nia_paper_spirv.txt" \
        2> "$out/nia_paper_spirv.err" || echo "spirv bench failed: $?"
      grep -v XDG "$out/nia_paper_spirv.err" | tail -n 3 || true
    else
      echo "no .gpu/nia-infer-spirv.xz: rerun prepare"
    fi
  fi
  if step paper; then
    echo "== nia-rs wgpu, paper dimensions, against flex (CPU) =="
    with_memory nia_paper timeout $limit $bin bench --backend wgpu "${dims[@]}" --reps $reps \
      --check-against flex > "$out/nia_paper.txt" 2> "$out/nia_paper.err" || echo "bench failed: $?"
    grep -v XDG "$out/nia_paper.err" | tail -n 3 || true
  fi

  if step profile; then
    echo "== cubecl profile of the paper forward (kernel compilations, GPU time per kernel) =="
    CUBECL_DEBUG_LOG="$out/cubecl_forward.log" CUBECL_DEBUG_OPTION=profile-medium \
      timeout $limit $bin bench --backend wgpu "${dims[@]}" --reps 2 --no-train \
      > "$out/nia_profile.txt" 2> "$out/nia_profile.err" || echo "profile failed: $?"
    "$python" scripts/cubecl_profile_summary.py "$out/cubecl_forward.log" | tee "$out/profile.md" || true
    gzip -f "$out/cubecl_forward.log" || true
    # The training step's GPU time by kernel family: the last of three steps (the first one
    # compiles and autotunes), counted from its encoder's max-pool on.
    echo "== cubecl profile of the paper training step (GPU time per kernel, last of 3 steps) =="
    CUBECL_DEBUG_LOG="$out/cubecl_train.log" CUBECL_DEBUG_OPTION=profile-medium \
      timeout $limit $bin bench --backend wgpu "${dims[@]}" --reps 2 --train-only \
      > "$out/nia_profile_train.txt" 2> "$out/nia_profile_train.err" || echo "profile failed: $?"
    "$python" scripts/cubecl_profile_summary.py "$out/cubecl_train.log" --top 25 \
      --after Pool2dDirect --nth 3 | tee "$out/profile_train.md" || true
    gzip -f "$out/cubecl_train.log" || true
  fi

  # The first forward by cubecl's autotune level, each run in a fresh HOME (cubecl's autotune
  # cache and the driver's shader cache empty): does `minimal` shorten the start-up, and what
  # does it cost in steady state?
  if step autotune; then
    echo "== first forward by CUBECL_AUTOTUNE_LEVEL (fresh caches) =="
    for level in default minimal; do
      local env=()
      [ $level = minimal ] && env+=(CUBECL_AUTOTUNE_LEVEL=minimal)
      in_fresh_home env "${env[@]}" timeout $limit $bin bench --backend wgpu "${dims[@]}" --reps 2 \
        --no-train > "$out/autotune_$level.txt" 2> "$out/autotune_$level.err" || echo "autotune $level failed: $?"
    done
  fi

  if step 4k && [ $quick = 0 ]; then
    echo "== nia-rs wgpu, forward only, 4x the rays (fixed cost against per-ray cost) =="
    timeout $limit $bin bench --backend wgpu "${big[@]}" --reps 3 \
      --no-train > "$out/nia_paper4k.txt" 2> "$out/nia_paper4k.err" || echo "4k bench failed: $?"
  fi

  if step tiny; then
    echo "== nia-rs wgpu, the quickstart's tiny network (256 rays x 32 samples, 128 px) =="
    with_memory nia_tiny timeout $short $bin bench --backend wgpu --tiny "${tiny[@]}" \
      --reps $reps --check-against flex > "$out/nia_tiny.txt" 2> "$out/nia_tiny.err" || echo "tiny bench failed: $?"
  fi

  if step torch; then
    echo "== PyTorch CUDA reference =="
    with_memory torch_paper timeout $((2 * short)) "$python" scripts/reference_gpu.py "${dims[@]}" \
      --reps $reps > "$out/torch_paper.json" 2> "$out/torch_paper.err" || echo "reference failed: $?"
    tail -n 2 "$out/torch_paper.err" || true
  fi

  # One ray per pixel (the paper's), the model's other [render] settings (skipping, termination,
  # culling, carving). Two target views in one process, in a fresh HOME: the first pays the whole
  # start-up (shader compilation, autotuning) as on a new machine, the second is close to steady
  # state.
  local render=(render --model .gpu/paper300.nia --samples 64 --data data/quickstart512 --subject CoreView_4
                --ratio $render_ratio --frame 0 --views 0,2,4 --targets 1,3 --supersample 1)
  # The render by BIN in a fresh HOME into $out/NAME/, its output in NAME.txt, the command's
  # start and end in NAME_wall.txt, GPU memory in mem_NAME.csv.
  fresh_render() {
    local name=$1 bin=$2 t0
    t0=$(date +%s.%N)
    in_fresh_home with_memory "$name" timeout $render_limit "$bin" "${render[@]}" --backend wgpu \
      --out "$out/$name" > "$out/$name.txt" 2>&1 || echo "$name failed: $?"
    echo "$t0 $(date +%s.%N)" > "$out/${name}_wall.txt"
    grep -v XDG "$out/$name.txt" | tail -n 4 || true
  }
  if step render; then
    echo "== one 512x512 unseen-subject image, paper network (wgpu) =="
    fresh_render render_wgpu $bin
  fi
  # Fewer, larger network calls (docs/speed.md, "Fewer, larger calls" and "Chunks apart from
  # calls"): on a GPU a render's chunk was 1024 rays, then 8192 rays of 64 samples, and is now
  # 65,536 (2^22 samples, nia_model::renderer::call_size) with each depth segment's points in
  # calls of up to 65,536. After `render`, in the same HOME as the other steps, so that the
  # renders find most kernels compiled: the two old chunks, then the default once more, then
  # the default without stage timings (`--no-stage-times`: no device synchronisation at the end
  # of every stage of every call, so the host's work for the next call overlaps the device's).
  # Their second images compare the steady state.
  if step chunks; then
    echo "== the same render in chunks of 1024 and 8192 rays, then the default again, timed and untimed =="
    for c in 1024 8192 default untimed; do
      local flag=()
      case $c in default) ;; untimed) flag=(--no-stage-times) ;; *) flag=(--chunk $c) ;; esac
      timeout $render_limit $bin "${render[@]}" --backend wgpu "${flag[@]}" --out "$out/render_chunk_$c" \
        > "$out/render_chunk_$c.txt" 2>&1 || echo "chunk $c render failed: $?"
      grep -v XDG "$out/render_chunk_$c.txt" | grep "^view" || true
    done
  fi
  # The older commit's binary (prepare with GPU_CHECK_BASELINE) on the 4096-ray forward's stages
  # and on the same render in a fresh HOME: before and after on the same card in one run.
  if step baseline; then
    if [ -x "$bin_base" ]; then
      echo "== baseline binary (commit $(cat "$out/baseline.txt")): 4096-ray forward, then the render =="
      timeout $limit $bin_base bench --backend wgpu "${big[@]}" --reps 3 --no-train \
        > "$out/nia_paper4k_baseline.txt" 2> "$out/nia_paper4k_baseline.err" || echo "baseline 4k bench failed: $?"
      pack
      fresh_render render_baseline $bin_base
    else
      echo "no .gpu/nia-infer-baseline.xz: prepare with GPU_CHECK_BASELINE=<commit>"
    fi
  fi
  if step flex && [ $quick = 0 ]; then
    echo "== the same image on the CPU (flex, $(nproc) cores) =="
    timeout $short $bin "${render[@]}" --backend flex --out "$out/render_flex" > "$out/render_flex.txt" 2>&1 \
      || echo "flex render failed: $?"
  fi
  "$python" scripts/gpu_check_table.py "$out" | tee "$out/table.md"
  pack
}

# Packs ./gpu_check_out into $OUT/gpu_check.tar.gz when the device tool set $OUT.
pack() {
  [ -z "${OUT:-}" ] || tar -czf "$OUT/gpu_check.tar.gz" -C "$out" .
}

case "$mode" in
  prepare) prepare "$@" ;;
  run) run "$@" ;;
  *) sed -n '2,20p' "$0"; exit 2 ;;
esac
