#!/usr/bin/env python3
"""A 20 ms control loop that computes for 30 ms of CPU time each period (time.thread_time, which
is the kernel's): too slow for its period on this machine. Prints its overruns."""
import time

PERIOD = 0.02
next_tick = time.monotonic()
overruns = 0
for _ in range(20):
    spent = time.thread_time()
    while time.thread_time() - spent < 0.03:
        pass
    next_tick += PERIOD
    delay = next_tick - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    else:
        overruns += 1
        next_tick = time.monotonic()
print(f"overruns {overruns} of 20", flush=True)
