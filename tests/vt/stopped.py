#!/usr/bin/env python3
"""Stops itself (SIGSTOP) for about 3 s of wall time; a helper outside virtual time continues it.
Prints how much simulated time passed meanwhile."""
import os
import signal
import subprocess
import time

env = {k: v for k, v in os.environ.items() if k not in ("LD_PRELOAD", "CLIMBSIM_VT")}
before = time.monotonic()
subprocess.Popen(["/bin/sh", "-c", f"sleep 3; kill -CONT {os.getpid()}"], env=env)
os.kill(os.getpid(), signal.SIGSTOP)
print(f"stopped for {time.monotonic() - before:.6f} s of simulated time", flush=True)
time.sleep(1.0)
