#!/usr/bin/env python3
"""Sleeps 0.5 s ten times and prints both clocks relative to its start (--clock virtual test)."""
import time

t0m, t0r = time.monotonic(), time.time()
print(f"start monotonic={t0m!r} time={t0r!r}", flush=True)
for i in range(10):
    time.sleep(0.5)
    print(f"step {i} monotonic+{time.monotonic() - t0m!r} time+{time.time() - t0r!r}", flush=True)
