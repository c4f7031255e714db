#!/usr/bin/env bash
# How much simulated time a Python controller's subprocess.Popen of a program on the wall clock
# takes, forked and vforked, and whether it is the same in every run: tests/vt/popen_wall_clock.py
# (20 execs each way, and one of a missing program) run N times on virtual time; prints each
# distinct log with how many runs gave it, and the distinct end instants. Usage:
# hil/bench/popen-sim-time.sh [N=10] [--loaded] (from the checkout; climbsim is $CLIMBSIM or
# target/release/climbsim). --loaded: beside two busy loops.
set -euo pipefail
runs="${1:-10}"
climbsim="$(realpath "${CLIMBSIM:-target/release/climbsim}")"
work="$(mktemp -d)"
busy=()
trap 'kill "${busy[@]}" 2>/dev/null || true; rm -rf "$work"' EXIT
if [ "${2:-}" = --loaded ]; then
    for _ in 1 2; do sh -c 'while :; do :; done' & busy+=($!); done
fi
source hil/bench/controller-scenario.sh
controller_scenario "$work/popen.toml" 5.0 "$(realpath tests/vt/popen_wall_clock.py)"
for run in $(seq "$runs"); do
    "$climbsim" run "$work/popen.toml" --clock virtual --set capture.mcap=false --out "$work/$run" > /dev/null 2>&1
    cat "$work/$run/controller.log" > "$work/log-$run"
    grep -o '"controller_exited_at_s": [0-9.]*' "$work/$run/summary.json" >> "$work/ends"
done
for run in $(seq "$runs"); do sha256sum < "$work/log-$run"; done | sort | uniq -c | while read -r count hash _; do
    echo "$count of $runs runs:"
    for run in $(seq "$runs"); do
        if [ "$(sha256sum < "$work/log-$run" | cut -d' ' -f1)" = "$hash" ]; then sed 's/^/  /' "$work/log-$run"; break; fi
    done
done
echo "end instants: $(sort "$work/ends" | uniq -c | tr -s ' ' | tr '\n' ';')"
