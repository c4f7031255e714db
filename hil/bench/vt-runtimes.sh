#!/usr/bin/env bash
# Every runtime's wheel controller of the virtual-time tests (the same programs and the same 3 s,
# 1 Mbps world as tests/virtual_time.rs), plus the thread-heavy C programs, each run RUNS times
# on virtual time by hil/bench/vt-repeat.sh: a deterministic runtime gives RUNS passed, one
# distinct controller log and one distinct time series. Usage (from the checkout, after
# scripts/test.sh has made .venv, the Node.js modules and the Rust examples):
#   hil/bench/vt-runtimes.sh [RUNS=20] [--loaded] [NAME...]
# NAMEs: cpp java rust tokio node go python asyncio pipes handoffs yield threads200 spin pingpong
# (default: all).
# climbsim is $CLIMBSIM or target/debug/climbsim.
set -euo pipefail
runs="${1:-20}"; shift || true
loaded=""
if [[ "${1:-}" == "--loaded" ]]; then loaded="--loaded"; shift; fi
names=("$@")
[[ ${#names[@]} -gt 0 ]] || names=(cpp java rust tokio node go python asyncio pipes handoffs yield threads200 spin pingpong)
repo="$(pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
export PATH="$repo/.venv/bin:$PATH"
source hil/bench/controller-scenario.sh

# A scenario for COMMAND... lasting DURATION_S, at 1 Mbps when the name's runtime talks to the
# servos (the wheel controllers).
make_scenario() { # NAME DURATION_S BAUD|- COMMAND...
    local name="$1" duration="$2" baud="$3"
    shift 3
    controller_scenario "$work/$name.toml" "$duration" "$@"
    if [[ "$baud" != "-" ]]; then printf '[bus]\nbaud_bps = %s\n' "$baud" >> "$work/$name.toml"; fi
}

for name in "${names[@]}"; do
    case "$name" in
        cpp)
            c++ -O1 -std=c++17 -pthread tests/vt/cpp_threads.cpp -o "$work/cpp_threads"
            make_scenario cpp 3.0 1000000 "$work/cpp_threads" ;;
        java)
            javac -cp /usr/share/java/jssc.jar -d "$work" tests/vt/java/JsscController.java
            make_scenario java 3.0 1000000 java -Djava.library.path=/usr/lib/jni -cp "/usr/share/java/jssc.jar:$work" JsscController ;;
        rust) make_scenario rust 3.0 1000000 "$repo/target/debug/examples/vt_threads_controller" ;;
        tokio) make_scenario tokio 3.0 1000000 "$repo/target/debug/examples/vt_tokio_controller" ;;
        node) make_scenario node 3.0 1000000 node "$repo/tests/vt/node/serialport_controller.js" ;;
        go)
            (cd tests/vt/go && CGO_ENABLED=1 GOTOOLCHAIN=local GOCACHE="$repo/target/go-cache/build" GOPATH="$repo/target/go-cache/path" go build -o "$work/go_controller" .)
            make_scenario go 3.0 1000000 "$work/go_controller" ;;
        python) make_scenario python 3.0 - "$repo/tests/vt/threads.py" ;;
        asyncio) make_scenario asyncio 3.0 1000000 "$repo/tests/vt/asyncio_controller.py" ;;
        pipes) make_scenario pipes 5.0 - "$repo/tests/vt/pipes.py" ;;
        handoffs)
            cc tests/vt/handoffs.c -o "$work/handoffs"
            make_scenario handoffs 2.0 - "$work/handoffs" 2000 ;;
        yield)
            cc tests/vt/yield_wait.c -o "$work/yield_wait"
            make_scenario yield 2.0 - "$work/yield_wait" ;;
        threads200)
            cc -pthread tests/vt/many_threads.c -o "$work/many_threads"
            make_scenario threads200 2.0 - "$work/many_threads" 200 ;;
        spin|pingpong)
            cc -O2 -pthread tests/vt/spin_wait.c -o "$work/spin_wait"
            if [[ "$name" == spin ]]; then make_scenario spin 2.0 - "$work/spin_wait" sleeper
            else make_scenario pingpong 2.0 - "$work/spin_wait" pingpong 20; fi ;;
        *) echo "unknown runtime: $name" >&2; exit 2 ;;
    esac
    echo "== $name"
    hil/bench/vt-repeat.sh "$work/$name.toml" "$runs" $loaded
done
