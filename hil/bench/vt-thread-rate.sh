#!/usr/bin/env bash
# How fast a run goes on virtual time when its controller starts and joins a thread every
# PERIOD_US (hil/bench/thread_per_period.c), for SECONDS of simulated time: the run's own
# realtime factor (wall time against simulated, world included), and its wall time against the
# same run whose controller only sleeps through the periods (farm-bench, median of pairs).
# Usage: hil/bench/vt-thread-rate.sh [PERIOD_US=1000] [SECONDS=5] (from the checkout; climbsim
# is $CLIMBSIM or target/release/climbsim).
set -euo pipefail
period_us="${1:-1000}"; seconds="${2:-5}"
climbsim="$(realpath "${CLIMBSIM:-target/release/climbsim}")"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cc -O2 -pthread hil/bench/thread_per_period.c -o "$work/program"
source hil/bench/controller-scenario.sh
# The world runs a little longer than the controller, which ends the run.
duration="$(awk -v s="$seconds" 'BEGIN { print s + 1 }')"
controller_scenario "$work/threads.toml" "$duration" "$work/program" "$period_us" "$seconds" 1
controller_scenario "$work/sleeps.toml" "$duration" "$work/program" "$period_us" "$seconds" 0
farm-bench -n 7 --vs "$climbsim run $work/sleeps.toml --clock virtual --set capture.mcap=false --out $work/sleeps" -- \
    "$climbsim" run "$work/threads.toml" --clock virtual --set capture.mcap=false --out "$work/threads"
cat "$work/threads/controller.log"
echo "simulated: $(grep -o '"controller_exited_at_s": [0-9.]*' "$work/threads/summary.json")"
echo "realtime factor of the run with the threads: $(grep -o '"realtime_factor": [0-9.]*' "$work/threads/summary.json")"
echo "each thread: (A's wall median - B's) / $(awk -v s="$seconds" -v p="$period_us" 'BEGIN { print int(s * 1e6 / p) }')"
