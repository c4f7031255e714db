#!/usr/bin/env python3
"""A Sync Read of the eight servos on a raw pyserial port, for the virtual-time tests: when each
status arrives (FIONREAD polled in a spin, as a tight controller would), what tcflush keeps of a
Sync Read whose replies are still on their way, and a ping sent into the middle of the replies
(a collision on the half-duplex wire). Prints one line per finding."""
import os
import sys
import time

import serial

port = serial.Serial(os.environ["DXL_PORT"], 1_000_000, timeout=0)


def crc16(data):
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def packet(dxl_id, instruction, params):
    body = bytes([0xFF, 0xFF, 0xFD, 0x00, dxl_id]) + (len(params) + 3).to_bytes(2, "little") + bytes([instruction]) + bytes(params)
    return body + crc16(body).to_bytes(2, "little")


SYNC_READ = packet(0xFE, 0x82, [132, 0, 4, 0] + list(range(1, 9)))
STATUS = 15


def valid_statuses(data):
    """Status packets with a good CRC, in order."""
    found, at = 0, 0
    while at + STATUS <= len(data):
        chunk = data[at : at + STATUS]
        if chunk[:4] == b"\xff\xff\xfd\x00" and crc16(chunk[:-2]) == int.from_bytes(chunk[-2:], "little"):
            found += 1
            at += STATUS
        else:
            at += 1
    return found


def collect(seconds):
    data = b""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        data += port.read(4096)
    return data


# 1. Arrivals: the byte count FIONREAD shows, each time it changes.
port.write(SYNC_READ)
started = time.monotonic()
seen, data = 0, b""
while len(data) < 8 * STATUS and time.monotonic() - started < 0.05:
    waiting = port.in_waiting
    if waiting != seen:
        print(f"arrival {len(data) + waiting} bytes at {(time.monotonic() - started) * 1e6:.0f} us", flush=True)
        seen = waiting
    if waiting >= STATUS:
        data += port.read(waiting)
        seen = 0
print(f"arrivals: {valid_statuses(data)} valid statuses", flush=True)

# 2. tcflush once the first status has arrived: the seven still on their way are kept.
time.sleep(0.01)
port.write(SYNC_READ)
time.sleep(0.001)
port.reset_input_buffer()
kept = collect(0.01)
print(f"flush: {len(kept)} bytes kept, {valid_statuses(kept)} valid statuses", flush=True)

# 3. A ping of servo 1 sent while the second status is on the wire.
port.write(SYNC_READ)
time.sleep(0.0014)
port.write(packet(1, 0x01, []))
mixed = collect(0.02)
print(f"collision: {len(mixed)} bytes, {valid_statuses(mixed)} valid statuses", flush=True)
sys.exit(0)
