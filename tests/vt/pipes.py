#!/usr/bin/env python3
"""Pipes on simulated time: `subprocess.check_output` of a shell that sleeps, a shell's command
substitution, a forked child writing to a pipe its parent reads with a blocking `os.read`, and
multiprocessing (processes feeding a queue, then a pool). Each waiter blocks in a read or a
poll of a pipe that another followed process writes."""
import multiprocessing
import os
import subprocess
import time


def took(t0):
    return f"{time.monotonic() - t0:.3f} s"


def worker(queue, n):
    time.sleep(0.1 * n)
    queue.put(n)


if __name__ == "__main__":
    t0 = time.monotonic()
    out = subprocess.check_output(["sh", "-c", "sleep 0.5; echo hi"])
    print(f"check_output {out!r} after {took(t0)}", flush=True)

    t0 = time.monotonic()
    out = subprocess.run("echo $(sleep 0.25; echo nested)", shell=True, capture_output=True, check=True).stdout
    print(f"command substitution {out!r} after {took(t0)}", flush=True)

    read_end, write_end = os.pipe()
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:
        os.close(read_end)
        time.sleep(0.125)
        os.write(write_end, b"from child")
        os._exit(0)
    os.close(write_end)
    data = os.read(read_end, 100)
    print(f"pipe {data!r} after {took(t0)}", flush=True)
    os.waitpid(pid, 0)

    t0 = time.monotonic()
    queue = multiprocessing.Queue()
    processes = [multiprocessing.Process(target=worker, args=(queue, n)) for n in (1, 2, 3)]
    for process in processes:
        process.start()
    order = [queue.get(timeout=5) for _ in processes]
    print(f"queue {order} after {took(t0)}", flush=True)
    for process in processes:
        process.join()
    with multiprocessing.Pool(2) as pool:
        print(f"pool {pool.map(abs, [-1, -2, -3])}", flush=True)
    print("done", flush=True)
