#!/usr/bin/env bash
# What a forked child that ends with _exit() costs on virtual time, in wall time (see
# vt-churn.sh). Usage: hil/bench/exit-children.sh [N=1000] (from the checkout).
exec "$(dirname "$0")/vt-churn.sh" hil/bench/exit_children.c "${1:-1000}"
