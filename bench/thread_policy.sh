#!/usr/bin/env bash
# Thread-policy check of issue 17: the 64x64 metric data generator with the default policy vs
# one thread forced (PBDL_THREADS=1), alternating `rounds` times in one run, on this machine.
# Writes target/pbdl/bench/thread_policy.md (every run's medians and the ratio of medians).
#
# Usage: bench/thread_policy.sh [rounds] [reps] [count]     (defaults 3 5 2)
set -eu
root="$(cd "$(dirname "$0")/.." && pwd)"
rounds="${1:-3}" reps="${2:-5}" count="${3:-2}"
out="$root/target/pbdl/bench/thread_policy.md"
mkdir -p "$(dirname "$out")"
cd "$root"
cargo build --release -q -p pbdl-metrics --example data_generation_timing
bin="$root/target/release/examples/data_generation_timing"
raw="$(mktemp)"
for r in $(seq 1 "$rounds"); do
  env -u PBDL_THREADS -u RAYON_NUM_THREADS "$bin" "$reps" "$count" | sed "s/^/default $r /" >> "$raw"
  PBDL_THREADS=1 "$bin" "$reps" "$count" | sed "s/^/one $r /" >> "$raw"
done
python3 - "$raw" "$out" <<'PY'
import json, statistics, sys, datetime, platform, os
rows = {}
for line in open(sys.argv[1]):
    mode, rnd, js = line.split(" ", 2)
    d = json.loads(js)
    rows.setdefault((d["kind"], mode), []).append((d["median_s"], d["threads"]))
kinds = sorted({k for k, _ in rows})
lines = [f"# Thread policy: 64x64 metric data generator ({datetime.date.today()}, {platform.node()}, {os.cpu_count()} logical cores)", "",
         "| kind | default threads | default medians (s) | 1 thread medians (s) | ratio default / 1 thread (median of medians) |", "|---|---|---|---|---|"]
for k in kinds:
    d = rows[(k, "default")]; o = rows[(k, "one")]
    md, mo = statistics.median(x for x, _ in d), statistics.median(x for x, _ in o)
    lines.append(f"| {k} | {d[0][1]} | {', '.join(f'{x:.4f}' for x, _ in d)} | {', '.join(f'{x:.4f}' for x, _ in o)} | {md / mo:.3f} |")
open(sys.argv[2], "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
PY
rm -f "$raw"
