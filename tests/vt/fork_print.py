#!/usr/bin/env python3
"""A parent and its forked child print to the same log without waiting between lines: on
virtual time the child starts in its turn, once its parent parks (in waitpid), so the lines
never interleave as the host happened to schedule the two processes."""
import os
import time

pid = os.fork()
who = "child" if pid == 0 else "parent"
for line in range(5):
    print(f"{who} {line} at {time.monotonic():.6f}", flush=True)
if pid == 0:
    os._exit(0)
os.waitpid(pid, 0)
print("both done", flush=True)
