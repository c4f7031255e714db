#!/usr/bin/env bash
# Peak resident memory against simulated time: `climbsim run scenarios/flat-line.toml` for
# DURATIONS simulated seconds (built-in controller, lockstep; at the welding speed, 250 mm/min,
# on a line and terrain long enough for 5 hours: the shipped 3.5 m line ends after 3 minutes,
# and a robot that wanders off the terrain fails the run), and `climbsim serve
# scenarios/flat-line.toml --speed 10` with no controller for SERVE_SECONDS wall seconds each
# (ten times that simulated). Prints one Markdown row per run; GNU time measures the peak.
#
#   hil/bench/memory.sh                              # 600 and 3600 s runs; serve 30 and 120 s
#   DURATIONS="600 3600 18000" hil/bench/memory.sh   # add the 5-hour run (~11 min here)
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$repo"
durations="${DURATIONS:-600 3600}"
serve_seconds="${SERVE_SECONDS:-30 120}"
out="${OUT:-target/bench-results/memory}"
cargo build --release --locked --quiet
rm -rf "$out"
mkdir -p "$out"
echo "| command | simulated s | wall s | peak RSS (MB) |"
echo "|---|---|---|---|"
for duration in $durations; do
    /usr/bin/time -f "%e %M" -o "$out/run-$duration.time" target/release/climbsim run scenarios/flat-line.toml \
        --set "world.duration_s=$duration" --set 'expect={}' --set speed.target_mm_min=250 \
        --set terrain.size_m=200 --set 'line.points=[[-0.5, 0.0], [90.0, 0.0]]' --out "$out/run-$duration" > /dev/null
    read -r wall kb < <(tail -n 1 "$out/run-$duration.time")
    echo "| run flat-line.toml | $duration | $wall | $(python3 -c "print(f'{$kb / 1024:.1f}')") |"
done
for seconds in $serve_seconds; do
    # SIGINT ends serve cleanly; timeout's own exit status (124) is expected here.
    /usr/bin/time -f "%e %M" -o "$out/serve-$seconds.time" timeout -s INT "$seconds" \
        target/release/climbsim serve scenarios/flat-line.toml --speed 10 > /dev/null 2>&1 || true
    read -r wall kb < <(tail -n 1 "$out/serve-$seconds.time")
    echo "| serve flat-line.toml --speed 10 | $((seconds * 10)) | $wall | $(python3 -c "print(f'{$kb / 1024:.1f}')") |"
done
