#!/usr/bin/env bash
# A C++ controller on virtual time against the built-in controller in lockstep, in one bench
# run: the reference line follower in C++ (hil/controllers/line_follower.cpp, the official C++
# SDK's port pattern) on scenarios/external-line-follower.toml (40 s at 1 Mbps), against the
# same world and gains with the built-in controller. farm-bench alternates the two, so the
# ratio's median is taken pair by pair.
# Usage: hil/bench/cpp-vs-lockstep.sh [RUNS=5] (from the checkout; climbsim is $CLIMBSIM or
# target/release/climbsim).
set -euo pipefail
runs="${1:-5}"
climbsim="$(realpath "${CLIMBSIM:-target/release/climbsim}")"
source "$(dirname "${BASH_SOURCE[0]}")/controller-scenario.sh"
climbsim_not_stale "$climbsim"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
c++ -O2 -std=c++17 -o "$work/line_follower" hil/controllers/line_follower.cpp
# The scenario without its [expect] (the built-in run has no controller period to judge),
# once with the C++ controller and once with the built-in one at the same gains.
body="$(sed '/^\[expect\]/,$d; /^\[controller\]/,$d' scenarios/external-line-follower.toml)"
printf '%s\n[controller]\nkind = "external"\ncommand = ["%s", "--zeta", "1.4", "--omega-n", "0.3", "--max-yaw-rate", "0.5"]\n' "$body" "$work/line_follower" > "$work/cpp.toml"
printf '%s\n[controller]\nkind = "builtin"\nzeta = 1.4\nomega_n = 0.3\nmax_yaw_rate_rad_s = 0.5\n' "$body" > "$work/builtin.toml"
# Each once first, so that a failing run shows here rather than as a fast time.
"$climbsim" run "$work/cpp.toml" --clock virtual --out "$work/out-cpp" > "$work/cpp.log" 2>&1 || { tail -5 "$work/cpp.log"; exit 1; }
"$climbsim" run "$work/builtin.toml" --out "$work/out-builtin" > "$work/builtin.log" 2>&1 || { tail -5 "$work/builtin.log"; exit 1; }
echo "C++ controller: $(cat "$work/out-cpp/controller.log")"
farm-bench -n "$runs" --timeout 900 --vs "$climbsim run $work/builtin.toml --out $work/b" -- "$climbsim" run "$work/cpp.toml" --clock virtual --out "$work/a"
