#!/usr/bin/env python3
"""Signal timers from Python on simulated time: a periodic setitimer whose handler runs during a
sleep that goes on to its end (PEP 475), while another thread sleeps too; alarm and pause; and
sigtimedwait for a blocked SIGALRM. Every instant is printed in ms from the start."""
import signal
import subprocess
import threading
import time

t0 = time.monotonic()


def ms():
    return (time.monotonic() - t0) * 1e3


ticks = []
signal.signal(signal.SIGALRM, lambda signo, frame: ticks.append(ms()))

# A periodic 20 ms timer during a 100 ms sleep of the main thread; a second thread sleeps 50 ms.
woke = []
sleeper = threading.Thread(target=lambda: (time.sleep(0.05), woke.append(ms())))
sleeper.start()
signal.setitimer(signal.ITIMER_REAL, 0.02, 0.02)
time.sleep(0.1)
signal.setitimer(signal.ITIMER_REAL, 0)
sleeper.join()
print(f"setitimer: ticks at {', '.join(f'{t:.3f}' for t in ticks)} ms; the main thread slept until {ms():.3f} ms, the other until {woke[0]:.3f} ms", flush=True)

# alarm + pause.
start = ms()
signal.alarm(1)
signal.pause()
print(f"alarm: pause returned after {ms() - start:.3f} ms, the handler ran at +{ticks[-1] - start:.3f} ms", flush=True)

# SIGALRM blocked and waited for.
signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
start = ms()
signal.setitimer(signal.ITIMER_REAL, 0.03)
info = signal.sigtimedwait({signal.SIGALRM}, 5.0)
print(f"sigtimedwait: signal {signal.Signals(info.si_signo).name} after {ms() - start:.3f} ms", flush=True)
none = signal.sigtimedwait({signal.SIGALRM}, 0.01)
print(f"sigtimedwait: {none} after a 10 ms timeout, at +{ms() - start:.3f} ms", flush=True)

# pause() ended by a signal the kernel raises: a child's SIGCHLD when it exits.
start = ms()
ended = []
signal.signal(signal.SIGCHLD, lambda signo, frame: ended.append(ms()))
child = subprocess.Popen(["sleep", "0.05"])
signal.pause()
child.wait()
print(f"SIGCHLD: pause ended by the child's exit at +{ended[0] - start:.3f} ms", flush=True)
