"""Summary of a cubecl debug log (CUBECL_DEBUG_LOG=FILE CUBECL_DEBUG_OPTION=profile-medium):
kernel compilations, and GPU time per kernel family from the profiler's `| <time> | <kernel>`
lines, largest first.

    python3 scripts/cubecl_profile_summary.py LOG [--top 15] [--after Pool2dDirect --nth 3]

With --after, only the launches from the NTH launch of that kernel family on are counted: the
encoder's max-pool starts each forward, so `--after Pool2dDirect --nth 3` keeps the last of a
`bench --train-only --reps 2` process's three training steps (its warm-up one compiles and
autotunes), less the few kernels of that step before the encoder's pool. Compilations are
counted over the whole log.

cubecl includes some sizes in a kernel's identity, so a compilation count that grows with the
number of distinct tensor shapes points at shapes that should be bucketed.
"""
import argparse, collections, re

p = argparse.ArgumentParser()
p.add_argument("log")
p.add_argument("--top", type=int, default=15)
p.add_argument("--after", help="count from the NTH launch of this kernel family on")
p.add_argument("--nth", type=int, default=1)
a = p.parse_args()

UNITS = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}
line_re = re.compile(r"^\|\s*([^|]+?)\s*\|\s*(.+?)\s*$")
time_re = re.compile(r"^([0-9.]+)\s*(ns|µs|us|ms|s)$")
unmeasured = collections.Counter()
compilations = collections.Counter()
time_by = collections.defaultdict(float)
calls_by = collections.Counter()
name = None
seen_marker = 0
with open(a.log, encoding="utf-8", errors="replace") as f:
    for line in f:
        if line.startswith("[START_KERNEL_COMPILATION]"):
            name = ""
            continue
        if name == "" and line.startswith("name:"):
            name = line[5:].strip().split("<")[0].split("::")[-1] or "?"
            compilations[name] += 1
            continue
        m = line_re.match(line)
        if m:
            # The family: the first field, less the hash that tells variants apart.
            family = re.sub(r"_[0-9a-f]{8}$", "", m.group(2).split("|")[0].strip())
            if a.after is not None and seen_marker < a.nth:
                seen_marker += family == a.after
                if seen_marker < a.nth:
                    continue
            t = time_re.match(m.group(1))
            if t is None:  # "not measured": a launch without a duration
                unmeasured[family] += 1
                continue
            time_by[family] += float(t.group(1)) * UNITS[t.group(2)]
            calls_by[family] += 1
if a.after is not None and seen_marker < a.nth:
    raise SystemExit(f"{a.log}: only {seen_marker} launches of {a.after}, not {a.nth}")
total = sum(time_by.values())
print(f"kernel compilations: {sum(compilations.values())} "
      f"({', '.join(f'{k} {v}' for k, v in compilations.most_common(6))})")
print(f"profiled GPU time: {total:.3f} s in {sum(calls_by.values())} kernel launches")
if unmeasured:
    print(f"launches without a duration (not measured): {sum(unmeasured.values())}")
print("| kernel family | launches | seconds | share |")
print("|---|---:|---:|---:|")
for family, seconds in sorted(time_by.items(), key=lambda kv: -kv[1])[: a.top]:
    print(f"| {family} | {calls_by[family]} | {seconds:.4f} | {100 * seconds / max(total, 1e-12):.1f}% |")
