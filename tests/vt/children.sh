#!/bin/sh
# A shell that sleeps 10 s through a child (sleep(1)) and then starts Python: every process of
# the controller is on the simulation's clock.
date +%s.%N
sleep 10
date +%s.%N
python3 -c 'import time; print(f"{time.monotonic():.6f}")'
