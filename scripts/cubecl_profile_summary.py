"""Summary of a cubecl debug log (CUBECL_DEBUG_LOG=FILE CUBECL_DEBUG_OPTION=profile-medium):
kernel compilations, and GPU time per kernel family from the profiler's `| <time> | <kernel>`
lines, largest first.

    python3 scripts/cubecl_profile_summary.py LOG [--top 15]

cubecl includes some sizes in a kernel's identity, so a compilation count that grows with the
number of distinct tensor shapes points at shapes that should be bucketed.
"""
import argparse, collections, re

p = argparse.ArgumentParser()
p.add_argument("log")
p.add_argument("--top", type=int, default=15)
a = p.parse_args()

UNITS = {"ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}
line_re = re.compile(r"^\|\s*([0-9.]+)\s*(ns|µs|us|ms|s)\s*\|\s*(.+?)\s*$")
compilations = collections.Counter()
time_by = collections.defaultdict(float)
calls_by = collections.Counter()
name = None
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
            seconds = float(m.group(1)) * UNITS[m.group(2)]
            # The family: the first field, less the hash that tells variants apart.
            family = re.sub(r"_[0-9a-f]{8}$", "", m.group(3).split("|")[0].strip())
            time_by[family] += seconds
            calls_by[family] += 1
total = sum(time_by.values())
print(f"kernel compilations: {sum(compilations.values())} "
      f"({', '.join(f'{k} {v}' for k, v in compilations.most_common(6))})")
print(f"profiled GPU time: {total:.3f} s in {sum(calls_by.values())} kernel launches")
print("| kernel family | launches | seconds | share |")
print("|---|---:|---:|---:|")
for family, seconds in sorted(time_by.items(), key=lambda kv: -kv[1])[: a.top]:
    print(f"| {family} | {calls_by[family]} | {seconds:.4f} | {100 * seconds / max(total, 1e-12):.1f}% |")
