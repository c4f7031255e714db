#!/usr/bin/env python3
"""Computes for 3 s of wall time without a call climbsim follows (as loading a model does),
then sleeps 1 s of simulated time."""
import os
import time

start = time.monotonic()
until = os.times().elapsed + 3.0  # times(2): the wall clock, which the shim leaves alone
x = 0
while os.times().elapsed < until:
    x += 1
print(f"computed; simulated time meanwhile {time.monotonic() - start:.6f} s", flush=True)
time.sleep(1)
print(f"slept {time.monotonic() - start:.6f} s", flush=True)
