#!/usr/bin/env bash
# What a short-lived child or thread costs on virtual time, in wall time: a run whose controller
# (a C program, SOURCE, that takes a count) starts and ends N of them one after the other,
# against the same run with none, with farm-bench (median of pairs). Usage:
# hil/bench/vt-churn.sh SOURCE [N=1000] (from the checkout; climbsim is $CLIMBSIM or
# target/release/climbsim). SOURCE: hil/bench/exit_children.c (forked children ending with
# _exit), hil/bench/thread_churn.c (threads created and joined).
set -euo pipefail
source_file="$1"; count="${2:-1000}"
climbsim="$(realpath "${CLIMBSIM:-target/release/climbsim}")"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cc -O2 -pthread "$source_file" -o "$work/program"
source hil/bench/controller-scenario.sh
controller_scenario "$work/many.toml" 1.0 "$work/program" "$count"
controller_scenario "$work/none.toml" 1.0 "$work/program" 0
farm-bench -n 7 --vs "$climbsim run $work/none.toml --clock virtual --set capture.mcap=false --out $work/none" -- \
    "$climbsim" run "$work/many.toml" --clock virtual --set capture.mcap=false --out "$work/many"
"$climbsim" run "$work/many.toml" --clock virtual --set capture.mcap=false --out "$work/check" > /dev/null
cat "$work/check/controller.log"
echo "natively: $("$work/program" "$count")"
echo "each one: (A's wall median - B's) / $count"
