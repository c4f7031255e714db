#!/usr/bin/env python3
"""Runs the program given as its arguments with /dev/null under descriptor 1000, where climbsim
passes the port's pty master to the processes it starts (shim/src/outbox.rs): what a program
that opens many files, or closes what it did not open, may do. The replies must reach it all
the same, none written to that file. Prints what it found there first."""
import os
import sys

print("descriptor 1000:", os.readlink("/proc/self/fd/1000"), flush=True)
os.dup2(os.open("/dev/null", os.O_WRONLY), 1000)
os.execv(sys.argv[1], sys.argv[1:])
