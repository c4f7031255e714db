#!/usr/bin/env python3
"""A controller that cleans up on SIGTERM as the reference controllers do: a period of pings
(of servo 5) until the run ends, then the wheels' torque turned off, each write waiting for
its status. Prints each clean-up write's result and how long it took on the clock the clean-up
runs on (the wall's): the servos still answer after the run, at once, not after the SDK's
timeout.
Servo 5 holds torque with its Bus Watchdog at 100 ms, fed by the run's pings; the clean-up
first sleeps 300 ms (on the wall clock, as clean-ups do), so a clean-up that reached the run's
own servos would trip it after the run."""
import os
import signal
import sys
import time

import dynamixel_sdk.port_handler
from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

ADDR_TORQUE_ENABLE = 64
ADDR_BUS_WATCHDOG = 98
WATCHED = 5
port = PortHandler(os.environ["DXL_PORT"])
packet = PacketHandler(2.0)
if not port.openPort() or not port.setBaudRate(int(os.environ.get("DXL_BAUD", "57600"))):
    sys.exit("cannot open the port")

running = True


def stop(_signum, _frame):
    global running
    running = False


signal.signal(signal.SIGTERM, stop)
for address, value in ((ADDR_TORQUE_ENABLE, 1), (ADDR_BUS_WATCHDOG, 5)):
    result, error = packet.write1ByteTxRx(port, WATCHED, address, value)
    assert result == COMM_SUCCESS and error == 0, (address, packet.getTxRxResult(result), error)
periods = 0
while running:
    _, result, _ = packet.ping(port, WATCHED)
    if not running:
        break
    assert result == COMM_SUCCESS, packet.getTxRxResult(result)
    periods += 1
    time.sleep(0.02)
print(f"periods: {periods}", flush=True)
slept = time.monotonic()
time.sleep(0.3)
print(f"slept {time.monotonic() - slept:.3f} s", flush=True)
# The clean-up runs on the wall clock, where a host kept busy by other work can delay a reply
# past the SDK's 35 ms at 1 Mbps (once, beside two busy loops and other runs: no status in
# 36.8 ms). Its timeout goes to 0.4 s: servos that no longer answer still fail every write.
dynamixel_sdk.port_handler.LATENCY_TIMER = 200
for dxl in (1, 2, 3, 4):
    started = time.monotonic()
    result, error = packet.write1ByteTxRx(port, dxl, ADDR_TORQUE_ENABLE, 0)
    print(f"torque off {dxl}: {packet.getTxRxResult(result)} error {error} in {(time.monotonic() - started) * 1e3:.1f} ms", flush=True)
port.closePort()
