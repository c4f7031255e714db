#!/usr/bin/env python3
"""Starts programs that run on the wall clock (their environment drops CLIMBSIM_VT), forked
(a preexec_fn makes subprocess fork) and vforked, and prints the longest simulated time that
one Popen took: the parent waits on a pipe that the child's exec closes. It never waits for a
child: how long a program on the wall clock runs is the host's, and so would be the simulated
time such a wait took. (Kept, so that Popen's clean-up does not poll them either.)"""
import os
import subprocess
import time

env = {k: v for k, v in os.environ.items() if k != "CLIMBSIM_VT"}
children = []
for how, preexec in (("forked", lambda: None), ("vforked", None)):
    longest = 0.0
    for _ in range(20):
        before = time.monotonic()
        children.append(subprocess.Popen(["/bin/true"], env=env, preexec_fn=preexec))
        longest = max(longest, time.monotonic() - before)
    print(f"{how}: 20 execs, the longest {longest * 1000:.3f} ms", flush=True)
    # An exec that fails: the child stays followed, says why through the pipe, and ends.
    before = time.monotonic()
    try:
        subprocess.Popen(["/nonexistent/program"], env=env, preexec_fn=preexec)
    except FileNotFoundError:
        print(f"{how}: a missing program refused after {(time.monotonic() - before) * 1000:.3f} ms", flush=True)
