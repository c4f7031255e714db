#!/usr/bin/env python3
"""Computes for 3 s of wall time without a call climbsim follows (as loading a model does),
then sleeps 1 s of simulated time."""
import os
import time


def uptime(fd):
    """The wall clock, read where the shim does not follow it: /proc/uptime through pread (the
    clocks, the vDSO and times() all tell simulated time)."""
    return float(os.pread(fd, 64, 0).split()[0])


start = time.monotonic()
fd = os.open("/proc/uptime", os.O_RDONLY)
until = uptime(fd) + 3.0
x = 0
while uptime(fd) < until:
    x += 1
print(f"computed; simulated time meanwhile {time.monotonic() - start:.6f} s", flush=True)
time.sleep(1)
print(f"slept {time.monotonic() - start:.6f} s", flush=True)
