#!/usr/bin/env bash
# The speed table: the reference Python controller (hil/controllers/line_follower.py, official
# DynamixelSDK) on scenarios/external-line-follower.toml at several --speed values, REPEAT runs
# each; prints one Markdown row per speed with the medians. Needs .venv (./scripts/test.sh makes
# it) and libfaketime. Run it on an otherwise idle machine: the controller busy-polls its port.
#
#   hil/bench/speed-table.sh                 # speeds 1 5 10 20, 3 runs each
#   SPEEDS="1 10" REPEAT=5 hil/bench/speed-table.sh
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$repo"
speeds="${SPEEDS:-1 5 10 20}"
repeat="${REPEAT:-3}"
scenario="${SCENARIO:-scenarios/external-line-follower.toml}"
out="${OUT:-target/bench-results/speed-table}"
cargo build --release --locked --quiet
export PATH="$repo/.venv/bin:$PATH"
rm -rf "$out"
mkdir -p "$out"
for speed in $speeds; do
    for run in $(seq "$repeat"); do
        dir="$out/x$speed-$run"
        start=$(date +%s.%N)
        # A run that misses its pace or a threshold exits 1: that is a result, not an error here.
        code=0
        target/release/climbsim run "$scenario" --speed "$speed" --out "$dir" > "$dir.log" 2>&1 || code=$?
        end=$(date +%s.%N)
        python3 -c "print($end - $start)" > "$dir.wall"
        echo "$code" > "$dir.code"
    done
done
python3 - "$out" "$speeds" "$repeat" <<'EOF'
import json, statistics, sys, pathlib
out, speeds, repeat = pathlib.Path(sys.argv[1]), sys.argv[2].split(), int(sys.argv[3])
def median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None
def cell(value, fmt):
    return "–" if value is None else format(value, fmt)
print("| speed | wall time (s) | loop period p50 (ms) | reply lateness p99 (ms) | tick lateness p99 (ms) | time on line | distance overshoot (%) | pace kept | run passed (exit 0) |")
print("|---|---|---|---|---|---|---|---|---|")
for speed in speeds:
    runs = []
    for run in range(1, repeat + 1):
        summary_path = out / f"x{speed}-{run}" / "summary.json"
        if not summary_path.exists():
            continue
        summary = json.loads(summary_path.read_text())
        wall = float((out / f"x{speed}-{run}.wall").read_text())
        code = int((out / f"x{speed}-{run}.code").read_text())
        runs.append((summary, wall, code == 0))
    get = lambda key: median([s.get(key) for s, _, _ in runs])
    kept = sum(1 for s, _, _ in runs if s.get("pace.kept"))
    passed = sum(1 for _, _, ok in runs if ok)
    print(f"| {speed}× | {cell(median([w for _, w, _ in runs]), '.1f')} | {cell(get('controller.period_p50_ms'), '.1f')} | {cell(get('pace.reply_late_p99_ms'), '.2f')} | {cell(get('pace.tick_late_p99_ms'), '.2f')} | {cell(get('time_on_line_fraction'), '.2f')} | {cell(get('distance.overshoot_pct'), '.1f')} | {kept}/{len(runs)} | {passed}/{len(runs)} |")
EOF
