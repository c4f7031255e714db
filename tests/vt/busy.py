#!/usr/bin/env python3
"""Reads the clock once, then computes for ever without a call climbsim follows."""
import time

time.monotonic()
x = 0
while True:
    x += 1
