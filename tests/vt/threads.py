#!/usr/bin/env python3
"""Threads on simulated time: a worker that sleeps then sets an event the main thread waits on,
an event wait that times out, and a camera-like thread beside a 20 ms control loop."""
import threading
import time

t0 = time.monotonic()
event = threading.Event()


def worker():
    time.sleep(0.3)
    event.set()


thread = threading.Thread(target=worker)
thread.start()
got = event.wait(timeout=5)
print(f"event after {time.monotonic() - t0:.3f} s: {got}", flush=True)
thread.join()
got = threading.Event().wait(timeout=0.25)
print(f"timeout after {time.monotonic() - t0:.3f} s: {got}", flush=True)

frames = []
stop = threading.Event()


def camera():
    while not stop.is_set():
        frames.append(time.monotonic())
        time.sleep(1 / 30)


cam = threading.Thread(target=camera)
cam.start()
start = time.monotonic()
periods = []
next_tick = start
for _ in range(50):
    next_tick += 0.02
    time.sleep(max(0.0, next_tick - time.monotonic()))
    periods.append(time.monotonic())
stop.set()
cam.join()
spans = [b - a for a, b in zip(periods, periods[1:])]
print(f"control: {len(periods)} periods, longest {max(spans) * 1e3:.3f} ms; camera: {len(frames)} frames", flush=True)
