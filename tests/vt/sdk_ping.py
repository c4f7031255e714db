#!/usr/bin/env python3
"""The official SDK on the servo port, timed with its own clock (time.time()): pings, a read, a
Sync Read of the eight servos and pings of an absent ID. Under --clock virtual every latency is
the wire model's, to the microsecond, and repeats exactly. `--absent N` pings only the absent
ID, N times (the wall cost of the SDK's timeout)."""
import os
import sys
import time

from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS, GroupSyncRead, PacketHandler, PortHandler

ABSENT = 42
port = PortHandler(os.environ["DXL_PORT"])
packet = PacketHandler(2.0)
if not port.openPort() or not port.setBaudRate(int(os.environ.get("DXL_BAUD", "57600"))):
    sys.exit("cannot open the port")


def timed(what, call):
    started = time.time()
    result = call()
    print(f"{what}: {(time.time() - started) * 1e6:.1f} us -> {result}", flush=True)
    return result


if len(sys.argv) > 2 and sys.argv[1] == "--absent":
    for _ in range(int(sys.argv[2])):
        _, result, _ = packet.ping(port, ABSENT)
        assert result == COMM_RX_TIMEOUT, result
    sys.exit(0)

for attempt in range(3):
    _, result, _ = timed(f"ping 1 #{attempt}", lambda: packet.ping(port, 1))
    assert result == COMM_SUCCESS, result
timed("read4 1 present position", lambda: packet.read4ByteTxRx(port, 1, 132)[1])
reader = GroupSyncRead(port, packet, 132, 4)
for dxl in range(1, 9):
    reader.addParam(dxl)
for attempt in range(2):
    result = timed(f"sync read 8 #{attempt}", reader.txRxPacket)
    assert result == COMM_SUCCESS, result
for attempt in range(2):
    _, result, _ = timed(f"ping {ABSENT} #{attempt}", lambda: packet.ping(port, ABSENT))
    assert result == COMM_RX_TIMEOUT, result
time.sleep(0.1)
