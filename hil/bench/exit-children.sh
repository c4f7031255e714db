#!/usr/bin/env bash
# What a forked child that ends with _exit() costs on virtual time, in wall time: a run whose
# controller forks and reaps N children one after the other (hil/bench/exit_children.c), against
# the same run with none, with farm-bench (median of pairs). Usage: hil/bench/exit-children.sh
# [N=1000] (from the checkout; climbsim is $CLIMBSIM or target/release/climbsim).
set -euo pipefail
children="${1:-1000}"
climbsim="$(realpath "${CLIMBSIM:-target/release/climbsim}")"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cc hil/bench/exit_children.c -o "$work/exit_children"
source hil/bench/controller-scenario.sh
controller_scenario "$work/many.toml" 1.0 "$work/exit_children" "$children"
controller_scenario "$work/none.toml" 1.0 "$work/exit_children" 0
farm-bench -n 7 --vs "$climbsim run $work/none.toml --clock virtual --set capture.mcap=false --out $work/none" -- \
    "$climbsim" run "$work/many.toml" --clock virtual --set capture.mcap=false --out "$work/many"
"$climbsim" run "$work/many.toml" --clock virtual --set capture.mcap=false --out "$work/check" > /dev/null
cat "$work/check/controller.log"
echo "each child: (A's wall median - B's) / $children"
