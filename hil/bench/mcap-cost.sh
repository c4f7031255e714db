#!/usr/bin/env bash
# What recording run.mcap costs: `climbsim run scenarios/flat-line.toml` (120 s simulated) with
# [capture] mcap on and off, alternating, REPEAT times each; prints the medians, their ratio and
# the recording's size per simulated minute.
#
#   hil/bench/mcap-cost.sh            # 7 runs each
#   REPEAT=11 hil/bench/mcap-cost.sh
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$repo"
repeat="${REPEAT:-7}"
out="${OUT:-target/bench-results/mcap-cost}"
cargo build --release --locked --quiet
rm -rf "$out"
mkdir -p "$out"
for run in $(seq "$repeat"); do
    for mcap in true false; do
        start=$(date +%s.%N)
        target/release/climbsim run scenarios/flat-line.toml --set "capture.mcap=$mcap" --out "$out/$mcap-$run" > /dev/null
        end=$(date +%s.%N)
        echo "$mcap $start $end" >> "$out/times"
    done
done
python3 - "$out" <<'PY'
import json, os, statistics, sys
out = sys.argv[1]
times = {"true": [], "false": []}
for line in open(os.path.join(out, "times")):
    mcap, start, end = line.split()
    times[mcap].append(float(end) - float(start))
on, off = statistics.median(times["true"]), statistics.median(times["false"])
simulated_s = json.load(open(os.path.join(out, "true-1", "settings.json")))["duration_s"]
size = os.path.getsize(os.path.join(out, "true-1", "run.mcap"))
print(f"| runs each | without run.mcap (s) | with (s) | cost | run.mcap per simulated minute |")
print(f"|---|---|---|---|---|")
print(f"| {len(times['true'])} | {off:.2f} | {on:.2f} | {100 * (on / off - 1):+.1f} % | {size / 1e6 / simulated_s * 60:.2f} MB |")
PY
