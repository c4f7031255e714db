#!/usr/bin/env bash
# Threads that sleep briefly in a loop, beside two busy loops, against the kernel's pty worker:
# a reply written to a pty's master every 20 ms, and how long the worker took to hand it to the
# slave (docs/performance-virtual-time.md, "A starved pty worker"). On Linux 6.18 on this VM,
# eight threads sleeping 1 ms in a loop held it off for seconds; it carries climbsim's replies
# to the controller under virtual time, whose parked threads look at the kernel and sleep.
# Usage: hil/bench/short-sleepers.sh [SECONDS=15] (prints one line per setting).
set -euo pipefail
seconds="${1:-15}"
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
work="$(mktemp -d)"
busy=()
cleanup() { kill "${busy[@]}" 2>/dev/null || true; rm -rf "$work"; }
trap cleanup EXIT
cc -O2 -pthread -o "$work/short_sleepers" "$repo/hil/bench/short_sleepers.c"
for _ in 1 2; do sh -c 'while :; do :; done' & busy+=($!); done
for setting in "0 1000" "8 1000" "8 64000" "2 1000"; do
    "$work/short_sleepers" $setting "$seconds"
done
