#!/usr/bin/env bash
# A shell that forks: 40 command substitutions, each a child whose output the shell waits for
# on a pipe, then the simulated time they took. Each child must be followed from its start, so
# that time stands still while the shell waits for it, on every run and under load.
set -e
start="$(date +%s.%N)"
for i in $(seq 1 40); do
    last="$(echo "$i")"
done
echo "40 subshells, the last printed $last; $(date +%s.%N) - $start s simulated"
