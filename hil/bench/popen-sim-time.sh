#!/usr/bin/env bash
# How much simulated time a Python controller's subprocess.Popen of a program on the wall clock
# takes, forked and vforked, and whether it is the same in every run: tests/vt/popen_wall_clock.py
# (20 execs each way, and one of a missing program) run N times by hil/bench/vt-repeat.sh, then
# once more to show its log. Usage: hil/bench/popen-sim-time.sh [N=10] [--loaded] (from the
# checkout; climbsim is $CLIMBSIM or target/release/climbsim). --loaded: beside two busy loops.
set -euo pipefail
export CLIMBSIM="${CLIMBSIM:-target/release/climbsim}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
source hil/bench/controller-scenario.sh
controller_scenario "$work/popen.toml" 5.0 "$(realpath tests/vt/popen_wall_clock.py)"
hil/bench/vt-repeat.sh "$work/popen.toml" "${1:-10}" "${2:-}"
"$CLIMBSIM" run "$work/popen.toml" --clock virtual --set capture.mcap=false --out "$work/shown" > /dev/null 2>&1
echo "one more run's controller log:"
sed 's/^/  /' "$work/shown/controller.log"
