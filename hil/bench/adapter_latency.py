#!/usr/bin/env python3
"""What the modelled USB adapter (`climbsim serve --adapter`) does to a controller, measured with
the official DynamixelSDK at 1 Mbps against the model's prediction.

For `--adapter ideal`, `--adapter u2d2 --latency-timer-ms 1` and `--adapter u2d2` (16 ms), each
on a fresh `climbsim serve --baud 1000000`: the median time of a Ping (ID 1), and the loop rate
of Sync Write (Goal Velocity, 4 wheel servos) + Sync Read (Present Position, all 8).

The prediction replays the same loop through an independent Python copy of the model's rules
(FTDI AN232B-04: a USB packet when 62 bytes are buffered or the latency timer expires, every
packet restarting the timer) on the wire schedule of the servos (Return Delay Time 500 µs, 10
bits a byte). The controller's own time between receiving a reply and sending its next request
is taken from the `ideal` measurement (the SDK's Python overhead on this machine).

    .venv/bin/python hil/bench/adapter_latency.py            # prints a Markdown table
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

REPO = Path(__file__).resolve().parents[2]
BIN = Path(os.environ.get("CLIMBSIM_BIN", REPO / "target/release/climbsim"))
BAUD = 1_000_000
BYTE_S = 10 / BAUD
RDT_S = 500e-6
PINGS = 300
LOOP_SECONDS = 3.0
CONFIGS = [("ideal", []), ("u2d2, 1 ms", ["--adapter", "u2d2", "--latency-timer-ms", "1"]), ("u2d2, 16 ms", ["--adapter", "u2d2"])]

PING_REQUEST, PING_REPLY = 10, 14
SYNC_WRITE = 7 + 1 + 4 + 4 * (1 + 4) + 2  # 4 IDs × Goal Velocity
SYNC_READ = 7 + 1 + 4 + 8 + 2  # Present Position of 8 IDs
SYNC_READ_REPLY = 11 + 4


class Ftdi:
    """The FTDI rules, written again from the application note (not from climbsim's code)."""

    def __init__(self, timer_s: float | None):
        self.timer = timer_s
        self.last_packet = 0.0

    def deliver(self, arrivals: list[float]) -> float:
        """When the last of these bytes reaches the host."""
        if self.timer is None:
            return arrivals[-1]
        buffered, t = 0, self.last_packet
        for a in arrivals:
            expiries = int((a - self.last_packet) // self.timer)
            if expiries > 0:
                if buffered:
                    t = self.last_packet + self.timer
                    buffered = 0
                self.last_packet += expiries * self.timer
            buffered += 1
            if buffered == 62:
                t, buffered, self.last_packet = a, 0, a
        if buffered:
            self.last_packet += self.timer
            t = self.last_packet
        return t


def predicted_ping_s(timer_s, overhead_s, rounds=200):
    adapter, t, took = Ftdi(timer_s), 0.0, []
    for _ in range(rounds):
        sent = t + overhead_s
        start = sent + PING_REQUEST * BYTE_S + RDT_S
        t = adapter.deliver([start + (i + 1) * BYTE_S for i in range(PING_REPLY)])
        # A ping call spans the SDK's own time and the wait for the reply.
        took.append(overhead_s + t - sent)
    return statistics.median(took[20:])


def predicted_loop_hz(timer_s, overhead_s, rounds=200):
    adapter, t, starts = Ftdi(timer_s), 0.0, []
    for _ in range(rounds):
        sent = t + overhead_s
        starts.append(sent)
        cursor = sent + (SYNC_WRITE + SYNC_READ) * BYTE_S
        arrivals = []
        for _ in range(8):
            cursor += RDT_S
            arrivals += [cursor + (i + 1) * BYTE_S for i in range(SYNC_READ_REPLY)]
            cursor += SYNC_READ_REPLY * BYTE_S
        t = adapter.deliver(arrivals)
    return (len(starts) - 21) / (starts[-1] - starts[20])


def measure(extra: list[str]) -> tuple[float, float]:
    workdir = Path(tempfile.mkdtemp(prefix="climbsim-adapter-"))
    link = workdir / "ttyDXL"
    proc = subprocess.Popen([str(BIN), "serve", "--baud", str(BAUD), "--link", str(link), *extra], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout.readline().startswith("port:"), "climbsim did not start"
        port, ph = PortHandler(str(link)), PacketHandler(2.0)
        assert port.openPort() and port.setBaudRate(BAUD)
        took = []
        for _ in range(PINGS):
            start = time.perf_counter()
            _, result, _ = ph.ping(port, 1)
            took.append(time.perf_counter() - start)
            assert result == COMM_SUCCESS, ph.getTxRxResult(result)
        write = GroupSyncWrite(port, ph, 104, 4)
        for dxl_id in (1, 2, 3, 4):
            write.addParam(dxl_id, [0, 0, 0, 0])
        read = GroupSyncRead(port, ph, 132, 4)
        for dxl_id in range(1, 9):
            read.addParam(dxl_id)
        loops, start = 0, time.perf_counter()
        while time.perf_counter() - start < LOOP_SECONDS:
            assert write.txPacket() == COMM_SUCCESS
            result = read.txRxPacket()
            assert result == COMM_SUCCESS, ph.getTxRxResult(result)
            loops += 1
        rate = loops / (time.perf_counter() - start)
        port.closePort()
        return statistics.median(took[20:]), rate
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def main() -> int:
    rows, overhead = [], None
    for name, extra in CONFIGS:
        ping_s, loop_hz = measure(extra)
        timer = None if name == "ideal" else (0.001 if "1 ms" in name else 0.016)
        if overhead is None:
            # The controller's own time per ping and per loop, from the ideal adapter: measured
            # minus the wire schedule.
            loop_wire = (SYNC_WRITE + SYNC_READ + 8 * SYNC_READ_REPLY) * BYTE_S + 8 * RDT_S
            overhead = (ping_s - (PING_REQUEST + PING_REPLY) * BYTE_S - RDT_S, 1 / loop_hz - loop_wire)
        rows.append((name, ping_s, predicted_ping_s(timer, overhead[0]), loop_hz, predicted_loop_hz(timer, overhead[1])))
    print(f"official SDK at {BAUD} bps, {PINGS} pings and {LOOP_SECONDS:.0f} s of loops each; "
          f"controller's own time {overhead[0] * 1e3:.2f} ms a ping, {overhead[1] * 1e3:.2f} ms a loop")
    print("| adapter | ping median (ms) | predicted (ms) | Sync Write 4 + Sync Read 8 loop (Hz) | predicted (Hz) |")
    print("|---|---|---|---|---|")
    for name, ping_s, ping_pred, hz, hz_pred in rows:
        print(f"| {name} | {ping_s * 1e3:.2f} | {ping_pred * 1e3:.2f} | {hz:.1f} | {hz_pred:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
