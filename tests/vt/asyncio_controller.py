#!/usr/bin/env python3
"""A wheel controller as asyncio programs are written: the port's descriptor watched with
`loop.add_reader` (pyserial, non-blocking), replies awaited with a timeout, and a statistics
task fed through an `asyncio.Queue`. Pings servos 1-8, then 100 cycles of a 50 Hz Sync Read of
the wheels' Present Velocity and a Sync Write of their Goal Velocity. With --until-stopped it runs
until SIGTERM (`loop.add_signal_handler`), as services do, and reports then."""
import asyncio
import os
import signal
import sys
import time

import serial

WHEELS = [1, 2, 3, 4]


def crc16(data):
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def packet(dxl_id, instruction, params=()):
    length = len(params) + 3
    body = bytes([0xFF, 0xFF, 0xFD, 0x00, dxl_id, length & 0xFF, length >> 8, instruction, *params])
    crc = crc16(body)
    return body + bytes([crc & 0xFF, crc >> 8])


class Bus:
    def __init__(self, loop, port):
        self.port = port
        self.buffer = bytearray()
        self.arrived = asyncio.Event()
        loop.add_reader(port.fileno(), self.on_readable)

    def on_readable(self):
        self.buffer += self.port.read(4096)
        self.arrived.set()

    def take_packet(self):
        start = self.buffer.find(b"\xff\xff\xfd\x00")
        if start < 0 or len(self.buffer) < start + 7:
            return None
        total = 7 + self.buffer[start + 5] + (self.buffer[start + 6] << 8)
        if len(self.buffer) < start + total:
            return None
        reply = bytes(self.buffer[start:start + total])
        del self.buffer[:start + total]
        return reply

    async def transact(self, data, expected, timeout):
        self.buffer.clear()
        self.port.write(data)
        replies = []
        deadline = time.monotonic() + timeout
        while len(replies) < expected:
            reply = self.take_packet()
            if reply is not None:
                replies.append(reply)
                continue
            self.arrived.clear()
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                await asyncio.wait_for(self.arrived.wait(), left)
            except asyncio.TimeoutError:
                break
        return replies


async def statistics(queue):
    cycles = answered = 0
    while (item := await queue.get()) is not None:
        cycles += 1
        answered += item
    print(f"stats: {cycles} cycles, {answered} replies", flush=True)


async def main():
    port = serial.Serial(os.environ["DXL_PORT"], int(os.environ.get("DXL_BAUD", "57600")), timeout=0)
    bus = Bus(asyncio.get_running_loop(), port)
    found = 0
    for dxl_id in range(1, 9):
        found += len(await bus.transact(packet(dxl_id, 0x01), 1, 0.01))
    print(f"ping 1-8: {found} found", flush=True)
    queue = asyncio.Queue()
    stats = asyncio.create_task(statistics(queue))
    sync_read = packet(0xFE, 0x82, [128, 0, 4, 0, *WHEELS])
    until_stopped = "--until-stopped" in sys.argv[1:]
    stop = asyncio.Event()
    if until_stopped:
        asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, stop.set)
    start = time.monotonic()
    longest, previous = 0.0, start
    cycle = 0
    while until_stopped or cycle < 100:
        now = time.monotonic()
        longest, previous = max(longest, now - previous), now
        replies = await bus.transact(sync_read, len(WHEELS), 0.01)
        goal = (cycle % 50) * 2
        port.write(packet(0xFE, 0x83, [104, 0, 4, 0, *[b for w in WHEELS for b in (w, goal, 0, 0, 0)]]))
        await queue.put(len(replies))
        pause = start + 0.02 * (cycle + 1) - time.monotonic()
        cycle += 1
        if not until_stopped:
            await asyncio.sleep(pause)
            continue
        try:
            await asyncio.wait_for(stop.wait(), max(pause, 0))
            break
        except asyncio.TimeoutError:
            pass
    await queue.put(None)
    await stats
    if until_stopped:
        # Stopped, the report comes after the run's end, on the wall clock: no time of it is told.
        print(f"loop: {cycle} cycles, longest period {longest * 1e3:.3f} ms", flush=True)
    else:
        print(f"loop: {cycle} cycles in {(time.monotonic() - start) * 1e3:.3f} ms, longest period {longest * 1e3:.3f} ms", flush=True)


asyncio.run(main())
