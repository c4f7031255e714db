#!/usr/bin/env bash
# The cost of the seccomp trap under --clock virtual: compiles hil/bench/trap_cost.c and runs it
# as an external controller on virtual time (docs/virtual-time.md, "What a trap costs").
# Usage: hil/bench/trap-cost.sh [climbsim binary, default target/release/climbsim]
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
climbsim="${1:-$repo/target/release/climbsim}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cc -O2 -o "$work/trap_cost" "$repo/hil/bench/trap_cost.c"
source "$repo/hil/bench/controller-scenario.sh"
climbsim_not_stale "$climbsim"
controller_scenario "$work/trap-cost.toml" 60.0 "$work/trap_cost"
(cd "$repo" && "$climbsim" run "$work/trap-cost.toml" --clock virtual --out "$work/out" > "$work/run.log" 2>&1) || { cat "$work/run.log"; exit 1; }
cat "$work/out/controller.log"
