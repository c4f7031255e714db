#!/bin/sh
# Reproduce the seed report's experiments with climbsim (docs/scenarios-and-runs.md):
#   Fig. 13   distance step as the line follower's damping ratio zeta varies (flat line);
#   Figs 14-15  speed steady-state error and rise time as Kp varies, normal compensation on/off
#               (Perlin bumps, 250 mm/min).
# Outputs go to results/seed-zeta and results/seed-kp (sweep.csv, sweep.json, PNG/SVG plots).
set -eu
cd "$(dirname "$0")/../.."
cargo build --release --quiet
./target/release/climbsim sweep scenarios/flat-line.toml \
    --set controller.zeta=0.3,0.5,0.7,1.0,1.4 --out results/seed-zeta
./target/release/climbsim sweep scenarios/perlin-compensation-on.toml \
    --set controller.kp=0.5,1,2,4 --set controller.normal_compensation=true,false --out results/seed-kp
