"""The table of scripts/gpu_check.sh from the files it wrote: python3 gpu_check_table.py OUT_DIR."""
import json, os, sys

out = sys.argv[1]


def read(name):
    path = os.path.join(out, name)
    return open(path).read() if os.path.exists(path) else ""


def last_json(name):
    """The last line of a file that parses as a JSON object (nia-infer bench ends with one)."""
    for line in reversed(read(name).strip().splitlines()):
        try:
            value = json.loads(line)
            if isinstance(value, dict):
                return value
        except json.JSONDecodeError:
            continue
    return None


def peak(name):
    """(baseline, peak) MiB of the nvidia-smi poll, or None."""
    values = [int(v) for v in read(f"mem_{name}.csv").split() if v.strip().isdigit()]
    return (values[0], max(values)) if values else None


def fmt(x, unit="s", digits=3):
    return "-" if x is None else f"{x:.{digits}f} {unit}".strip()


def quotient(a, b):
    return a / b if a is not None and b else None


def ratio(a, b):
    q = quotient(a, b)
    return "-" if q is None else f"{q:.2f}x"


def mem(name):
    p = peak(name)
    return "-" if p is None else f"{p[1] - p[0]} MiB (peak {p[1]}, idle {p[0]})"


card = read("card.txt").strip()
base = read("baseline.txt").strip()  # the baseline step's older commit, if prepared
nia, tiny, ref = last_json("nia_paper.txt"), last_json("nia_tiny.txt"), last_json("torch_paper.json")
print(f"\ncard: {card}")
if ref:
    print(f"reference: PyTorch {ref['torch']} on {ref['device']}, {ref['precision']}, sparse conv: {ref['sparse_conv']}")
if nia:
    print(f"dimensions: {nia['rays']} rays x {nia['samples']} samples, {nia['views']} views of {nia['size']}^2, paper network")
print()
print("| paper network | PyTorch CUDA | nia-rs wgpu | nia-rs / PyTorch |")
print("|---|---:|---:|---:|")
rows = [("forward", "forward_s"), ("training step", "train_step_s"),
        ("first forward (start-up included)", "first_forward_s"),
        ("first training step", "first_train_step_s")]
for label, key in rows:
    a = nia.get(key) if nia else None
    b = ref.get(key) if ref else None
    print(f"| {label} | {fmt(b)} | {fmt(a)} | {ratio(a, b)} |")
if nia and nia.get("forward_reps_s") is not None:
    # The figures above are medians (as the reference's); every timed repetition, in order:
    print(f"| timed repetitions (s) | - | forward {', '.join(f'{t:.3f}' for t in nia['forward_reps_s'])}; "
          f"training step {', '.join(f'{t:.3f}' for t in nia['train_reps_s'])} | - |")
if nia and nia.get("train_forward_s") is not None:
    print(f"| training step: forward / backward + Adam | - | {nia['train_forward_s']:.3f} / {nia['train_backward_s']:.3f} s | - |")
stage_names = {"mlps": "nerf_mlps"}
if nia:
    for name, ours in nia["stages_s"]:
        # The reference's point inputs are computed before its timed forward: no row of its own.
        theirs = ref["stages_s"].get(stage_names.get(name, name)) if ref else None
        print(f"| forward stage: {name} | {fmt(theirs)} | {fmt(ours)} | {ratio(ours, theirs)} |")
print(f"| GPU memory (nvidia-smi, above idle) | {mem('torch_paper')} | {mem('nia_paper')} | - |")
if ref and ref.get("peak_gpu_mib"):
    print(f"| PyTorch's own peak allocation | {ref['peak_gpu_mib']:.0f} MiB | - | - |")
spirv = last_json("nia_paper_spirv.txt")
if spirv:
    # The shader compiler: the same dimensions with the SPIR-V build.
    print()
    print("| paper network, nia-rs wgpu | WGSL (`paper`) | SPIR-V build (`spirv`) | SPIR-V / WGSL |")
    print("|---|---:|---:|---:|")
    for label, key in rows:
        a, b = spirv.get(key), (nia.get(key) if nia else None)
        print(f"| {label} | {fmt(b)} | {fmt(a)} | {ratio(a, b)} |")
    wgsl_stages = dict(nia["stages_s"]) if nia else {}
    for name, spirv_s in spirv["stages_s"]:
        wgsl_s = wgsl_stages.get(name)
        print(f"| forward stage: {name} | {fmt(wgsl_s)} | {fmt(spirv_s)} | {ratio(spirv_s, wgsl_s)} |")
    print(f"| GPU memory (nvidia-smi, above idle) | {mem('nia_paper')} | {mem('nia_paper_spirv')} | - |")
print()
for name, r, err in [("paper", nia, "nia_paper.err"), ("tiny", tiny, "nia_tiny.err"),
                     ("paper, SPIR-V build", spirv, "nia_paper_spirv.err")]:
    if r and r.get("check"):
        c = r["check"]
        print(f"parity ({name} network): wgpu against {c['against']}: max |difference| {c['max_abs_diff']:.2e}, relative L2 {c['rel_l2']:.2e}")
        grads = c.get("gradients") or []
        if grads:
            print(f"  gradients of one training forward, largest |difference| / largest |gradient|: "
                  + ", ".join(f"{g} {'non-finite' if v is None else f'{v:.2e}'}" for g, v in grads))
    else:
        print(f"parity ({name} network): not measured (see {err})")
tunes = [(level, last_json(f"autotune_{level}.txt")) for level in ("default", "minimal")]
if any(r for _, r in tunes):
    print("first forward in a fresh process and fresh caches, by CUBECL_AUTOTUNE_LEVEL: "
          + "; ".join(f"{level}: first {r['first_forward_s']:.1f} s, then {r['forward_s']:.3f} s" if r
                      else f"{level}: not measured" for level, r in tunes))
big = last_json("nia_paper4k.txt")
if big:
    print(f"paper network, forward only, {big['rays']} rays: {big['forward_s']:.3f} s ({big['forward_rays_per_s']:.0f} rays/s; "
          + ", ".join(f"{k} {v:.3f}" for k, v in big["stages_s"]) + ")")
base_big = last_json("nia_paper4k_baseline.txt")
if base_big:
    # Before and after on the same card in one run: the baseline step's older binary.
    now = big or {}
    print()
    print(f"| paper network forward, 4096 rays x 64 samples | commit {base} | this build | after / before |")
    print("|---|---:|---:|---:|")
    now_stages = dict(now.get("stages_s", []))
    base_stages = dict(base_big["stages_s"])
    for name, before in base_big["stages_s"]:
        after = now_stages.get(name)
        if name == "sampling" and "point_inputs" not in base_stages and after is not None:
            # Older builds charged the host point inputs to sampling.
            after += now_stages.get("point_inputs") or 0.0
            name = "sampling, point inputs included"
        print(f"| {name} | {fmt(before)} | {fmt(after)} | {ratio(after, before)} |")
    forward = "forward"
    if now.get("stages_timed_apart") and not base_big.get("stages_timed_apart"):
        # Builds before the split timed the forward with a device synchronisation per stage.
        forward = "forward (the older build's with its stages timed, this build's without)"
    for label, key in [(forward, "forward_s"), ("first forward of the process", "first_forward_s")]:
        print(f"| {label} | {fmt(base_big.get(key))} | {fmt(now.get(key))} | {ratio(now.get(key), base_big.get(key))} |")
if tiny:
    print(f"tiny network (the quickstart's), {tiny['rays']} rays x {tiny['samples']}: forward {tiny['forward_s']:.4f} s "
          f"({tiny['forward_rays_per_s']:.0f} rays/s), training step {fmt(tiny.get('train_step_s'), digits=4)} "
          f"({tiny.get('train_rays_per_s') or 0:.0f} rays/s); first forward {tiny['first_forward_s']:.2f} s")
print()
renders = {}  # each render folder's report, read once, for the goals below
# (folder, label, whether a missing one is worth a line: the optional steps' only when prepared)
for name, label, expected in [("render_wgpu", "512x512 images, wgpu", True),
                              ("render_baseline", f"512x512 images, wgpu, commit {base}", bool(base)),
                              ("render_chunk_1024", "512x512 images, wgpu, warm caches", False),
                              ("render_chunk_8192", "512x512 images, wgpu, warm caches", False),
                              ("render_chunk_default", "512x512 images, wgpu, warm caches", False),
                              ("render_chunk_untimed", "512x512 images, wgpu, warm caches, --no-stage-times", False),
                              ("render_flex", "512x512 images, flex (CPU)", True)]:
    path = os.path.join(out, name, "render.json")
    if not os.path.exists(path):
        if expected:
            print(f"{label}: not rendered")
        continue
    r = renders[name] = json.load(open(path))
    wall = ""
    if read(f"{name}_wall.txt"):
        t0, t1 = map(float, read(f"{name}_wall.txt").split())
        wall = f"; command wall {t1 - t0:.1f} s (process start, model load, shader compilation included)"
    print(f"{label}, chunks of {r['chunk']} rays: encoding {r['encode_seconds']:.2f} s{wall}")
    for k, img in enumerate(r["images"]):
        which = "first image" if k == 0 else "next image (kernels compiled)"
        print(f"  {which} (view {img['target_view']}), {img['width']}x{img['height']}: render {img['seconds']:.2f} s; "
              f"{img['point_evaluations']} network points, {img['colour_evaluations']} coloured; stages (ms) "
              + (", ".join(f"{k2} {v:.0f}" for k2, v in sorted(img["stage_ms"].items())) or "not timed"))
print(f"GPU memory of the wgpu render: {mem('render_wgpu')}")


def render_images(name):
    """(target view, seconds) of each image of a render's report, or [] where it did not run."""
    return [(img["target_view"], img["seconds"]) for img in renders.get(name, {}).get("images", [])]


def goal(label, value, limit, what):
    """One line of the goals: met where VALUE <= LIMIT."""
    if value is None:
        return f"- {label}: not measured"
    return f"- {label}: {'met' if value <= limit else 'not met'} ({what})"


# Issue 38's goals, side by side in this run. A steady 512x512 image is the fastest of the
# warm-cache renders with the default chunk (timed and untimed), view by view; without the
# chunks step, the fresh render's later images (its first pays the start-up).
print()
print("Goals (issue 38), this run:")
fwd = nia.get("forward_s") if nia else None
step = nia.get("train_step_s") if nia else None
ref_fwd = ref.get("forward_s") if ref else None
ref_step = ref.get("train_step_s") if ref else None
print(goal("forward no slower than PyTorch CUDA", quotient(fwd, ref_fwd), 1.0,
           f"{ratio(fwd, ref_fwd)}: {fmt(fwd)} against {fmt(ref_fwd)}"))
print(goal("training step no slower than PyTorch CUDA", quotient(step, ref_step), 1.0,
           f"{ratio(step, ref_step)}: {fmt(step)} against {fmt(ref_step)}"))
print(goal("training step at the paper's size in 0.15 s", step, 0.15, fmt(step)))
steady = {}
warm = [img for name in ("render_chunk_default", "render_chunk_untimed") for img in render_images(name)]
for view, seconds in warm or render_images("render_wgpu")[1:]:
    steady[view] = min(seconds, steady.get(view, seconds))
worst = max(steady.values()) if steady else None
print(goal("a 512x512 image with the paper network in 0.5 s", worst, 0.5,
           ", ".join(f"view {v} {s:.2f} s" for v, s in sorted(steady.items()))
           + (" (warm caches, default chunk)" if warm else " (the fresh render's later images)")))
