#!/usr/bin/env bash
# Runs one scenario N times on virtual time, optionally beside two busy loops that keep both
# cores loaded, and counts the runs that passed and the distinct controller logs and time
# series and end instants and summaries (without the wall-clock ratio) among them: a
# deterministic controller run gives N passed, 1 distinct of each.
# Usage: hil/bench/vt-repeat.sh SCENARIO [RUNS=20] [--loaded] (from the checkout; climbsim is
# $CLIMBSIM or target/debug/climbsim). Its last line names the distinct logs, series and end
# instants themselves (md5 prefixes), so that two builds' runs can be held side by side.
set -euo pipefail
scenario="$1"; runs="${2:-20}"; loaded="${3:-}"
climbsim="${CLIMBSIM:-target/debug/climbsim}"
source "$(dirname "${BASH_SOURCE[0]}")/controller-scenario.sh"
climbsim_not_stale "$climbsim"
work="$(mktemp -d)"
busy=()
cleanup() { for pid in "${busy[@]}"; do kill "$pid" 2> /dev/null || true; done; rm -rf "$work"; }
trap cleanup EXIT
if [[ "$loaded" == "--loaded" ]]; then
    for _ in 1 2; do sh -c 'while :; do :; done' & busy+=($!); done
fi
passed=0
started=$SECONDS
for run in $(seq 1 "$runs"); do
    if timeout 120 "$climbsim" run "$scenario" --clock virtual --out "$work/$run" > "$work/$run.out" 2>&1; then
        passed=$((passed + 1))
        md5sum < "$work/$run/controller.log" >> "$work/logs"
        # The first log that differs from the first run's, shown once.
        if [[ ! -e "$work/shown" ]] && ! cmp -s "$work/1/controller.log" "$work/$run/controller.log"; then
            echo "run $run's controller log differs from run 1's:"; { diff "$work/1/controller.log" "$work/$run/controller.log" || true; } | head -10
            touch "$work/shown"
        fi
        md5sum < "$work/$run/timeseries.csv" >> "$work/series"
        # The simulated instant the controller's end was seen at (the run's length).
        grep -o '"controller_exited_at_s": [^,}]*' "$work/$run/summary.json" >> "$work/ends" || echo none >> "$work/ends"
        # The whole summary but what measures the host (the wall-clock ratio).
        grep -v '"realtime_factor"' "$work/$run/summary.json" > "$work/$run/repeatable.json"
        md5sum < "$work/$run/repeatable.json" >> "$work/summaries"
        if [[ ! -e "$work/shown-summary" ]] && ! cmp -s "$work/1/repeatable.json" "$work/$run/repeatable.json"; then
            echo "run $run's summary differs from run 1's:"; { diff "$work/1/repeatable.json" "$work/$run/repeatable.json" || true; } | head -10
            touch "$work/shown-summary"
        fi
    else
        echo "run $run failed:"; tail -3 "$work/$run.out"
    fi
done
# A run can pass with its controller stuck (a controller killed at the scenario's end exits 0):
# the last line it printed says how far it got.
echo "last line of the first run's controller log: $(tail -n 1 "$work/1/controller.log" 2>/dev/null)"
echo "$scenario: $passed of $runs passed${loaded:+ (both cores loaded)}; distinct controller logs: $(sort -u "$work/logs" 2>/dev/null | wc -l), distinct time series: $(sort -u "$work/series" 2>/dev/null | wc -l), distinct end instants: $(sort -u "$work/ends" 2>/dev/null | wc -l), distinct summaries: $(sort -u "$work/summaries" 2>/dev/null | wc -l); $((SECONDS - started)) s"
short() { sort -u "$1" 2>/dev/null | cut -c1-12 | paste -sd, -; }
echo "distinct: logs $(short "$work/logs"); series $(short "$work/series"); summaries $(short "$work/summaries"); end instants $(sort -u "$work/ends" 2>/dev/null | sed 's/.*: //' | paste -sd, -)"
