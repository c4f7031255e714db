#!/usr/bin/env python3
"""Reference external controller: the seed's line follower and speed PID on the official
DynamixelSDK, written as code for the real robot would be. It knows nothing of climbsim except
two environment variables any HIL rig would set:

  DXL_PORT           serial port of the Dynamixel bus (the emulator's pty, or /dev/ttyUSB0)
  CLIMBSIM_SENSORS   base URL of the camera/line-sensor HTTP server (GET /line -> JSON
                     {"t", "d", "psi", "valid"}: the robot relative to the line, d > 0 when
                     the robot is left of it, psi > 0 when it points left of it)

and, optionally, DXL_BAUD (default 57600) and CLIMBSIM_TARGET_SPEED_MM_MIN (default 250).
The algorithm is the built-in reference controller's (src/control/reference.rs):

  - every period: Sync Read Present Position (132, 4 B) of wheels 1-4 and magnet shafts 5-8
    (with --read-current, Present Current to Position: 126, 10 B);
  - wheel rates from position differences over a sliding window (Present Velocity's 0.229 rpm
    step is 29 % of 250 mm/min on a 50 mm wheel);
  - speed = mean of rate x R / cos(alpha) with normal compensation (alpha = magnet angle);
  - speed PID -> commanded speed; line follower yaw rate = K_d d_err + K_psi psi_err with
    K_psi = -2 zeta omega_n, K_d = -omega_n^2 / V, or with --integral-pole p > 0 also
    + K_i * integral(d_err) with K_psi = -(2 zeta omega_n + p), K_d = -(omega_n^2 + 2 zeta omega_n p) / V,
    K_i = -omega_n^2 p / V (integrated only while the command is inside the limit);
  - skid steering, Goal Velocity (104) dithered (rounding residual carried over), Sync Write.

It runs until SIGTERM/SIGINT, then stops the wheels and turns their torque off.
"""

import argparse
import collections
import json
import math
import os
import signal
import sys
import time
import http.client
import urllib.parse

from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

ADDR_OPERATING_MODE = 11
ADDR_TORQUE_ENABLE = 64
ADDR_GOAL_VELOCITY = 104
ADDR_PRESENT_CURRENT = 126
ADDR_PRESENT_POSITION = 132
VELOCITY_MODE = 1
RPM_PER_UNIT = 0.229
PULSES_PER_REV = 4096
MAGNET_DOWN_PULSES = 2048
VELOCITY_LIMIT = 128
WHEELS = [1, 2, 3, 4]  # front-left, front-right, rear-left, rear-right
MAGNETS = [5, 6, 7, 8]
LEFT = [True, False, True, False]

running = True


def stop(_signum, _frame):
    global running
    running = False


def parse_args():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--period", type=float, default=0.02, help="control period (s)")
    p.add_argument("--zeta", type=float, default=0.7)
    p.add_argument("--omega-n", type=float, default=0.3)
    p.add_argument("--max-yaw-rate", type=float, default=0.2)
    p.add_argument("--integral-pole", type=float, default=0.0, help="integral action's pole p (rad/s); 0 = none")
    # As the built-in controller: feedforward of the target plus a PID with kp = 1. Without the
    # feedforward a P-only loop drives at kp/(1 + kp) of the target (80 % at kp = 4).
    p.add_argument("--kp", type=float, default=1.0)
    p.add_argument("--no-feedforward", action="store_true", help="PID output alone as the speed command (the seed's Fig. 14)")
    p.add_argument("--ki", type=float, default=0.0)
    p.add_argument("--kd", type=float, default=0.0)
    p.add_argument("--no-compensation", action="store_true")
    p.add_argument("--speed-window", type=float, default=0.5)
    p.add_argument("--radius", type=float, default=0.05, help="wheel radius (m)")
    p.add_argument("--track", type=float, default=0.26, help="wheel track (m)")
    p.add_argument("--read-current", action="store_true", help="Sync Read Present Current and Velocity too (126-135, 10 B): a tapped session then shows the motors' load (climbsim fit)")
    p.add_argument("--log-offset", metavar="FILE", help="write the measured line offset, t_s,d_m (s since the start, m), each period (climbsim compare --signals)")
    return p.parse_args()


def signed32(value):
    return value - (1 << 32) if value & 0x80000000 else value


def check(packet, result, error, what):
    if result != COMM_SUCCESS:
        raise RuntimeError(f"{what}: {packet.getTxRxResult(result)}")
    if error & 0x7F:
        raise RuntimeError(f"{what}: {packet.getRxPacketError(error)}")


def write1(packet, port, dxl, address, value, what, attempts=3):
    """A setup write, tried again when no status came back: a real bus loses a packet now and
    then (noise, a servo still booting), and a controller that gives up on its first write
    never starts."""
    for attempt in range(attempts):
        result, error = packet.write1ByteTxRx(port, dxl, address, value)
        if result == COMM_SUCCESS or attempt == attempts - 1:
            return check(packet, result, error, what)


class SensorClient:
    """The sensor server over one kept connection (``Connection: keep-alive``), as an HTTP client
    library keeps it: no new TCP connection each period. Opened again after any failure."""

    def __init__(self, url):
        parts = urllib.parse.urlsplit(url)
        self.host, self.port = parts.hostname, parts.port
        self.connection = None

    def get_json(self, path):
        """The JSON of a 200 answer to GET ``path``, or None. A kept connection the server has
        closed meanwhile is tried once more, on a new one; an answer that took too long is not
        (a second try would cost the period another timeout)."""
        for _ in range(2):
            if self.connection is None:
                self.connection = http.client.HTTPConnection(self.host, self.port, timeout=0.05)
            try:
                self.connection.request("GET", path, headers={"Connection": "keep-alive"})
                response = self.connection.getresponse()
                body = response.read()
            except TimeoutError:
                self.drop()
                return None
            except (OSError, http.client.HTTPException):
                self.drop()
                continue
            if response.status != 200:
                return None
            try:
                return json.loads(body)
            except ValueError:
                return None
        return None

    def drop(self):
        """Close the connection; the next request opens a new one."""
        self.connection.close()
        self.connection = None


def read_line(sensors):
    """The sensor server's latest line measurement, or None."""
    line = sensors.get_json("/line")
    return line if isinstance(line, dict) and line.get("valid") else None


def main():
    args = parse_args()
    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    port_name = os.environ.get("DXL_PORT")
    if not port_name:
        sys.exit("DXL_PORT is not set")
    sensors = os.environ.get("CLIMBSIM_SENSORS", "")
    sensor_client = SensorClient(sensors) if sensors else None
    baud = int(os.environ.get("DXL_BAUD", "57600"))
    target = float(os.environ.get("CLIMBSIM_TARGET_SPEED_MM_MIN", "250")) / 60000.0

    port = PortHandler(port_name)
    packet = PacketHandler(2.0)
    if not port.openPort() or not port.setBaudRate(baud):
        sys.exit(f"cannot open {port_name} at {baud} bps")
    for dxl in WHEELS:
        write1(packet, port, dxl, ADDR_TORQUE_ENABLE, 0, f"torque off {dxl}")
        write1(packet, port, dxl, ADDR_OPERATING_MODE, VELOCITY_MODE, f"velocity mode {dxl}")
        write1(packet, port, dxl, ADDR_TORQUE_ENABLE, 1, f"torque on {dxl}")
    for dxl in MAGNETS:
        # Passive magnets: they follow the surface normal, their encoders read its angle.
        write1(packet, port, dxl, ADDR_TORQUE_ENABLE, 0, f"torque off {dxl}")

    if args.read_current:
        reader = GroupSyncRead(port, packet, ADDR_PRESENT_CURRENT, ADDR_PRESENT_POSITION + 4 - ADDR_PRESENT_CURRENT)
    else:
        reader = GroupSyncRead(port, packet, ADDR_PRESENT_POSITION, 4)
    for dxl in WHEELS + MAGNETS:
        reader.addParam(dxl)
    writer = GroupSyncWrite(port, packet, ADDR_GOAL_VELOCITY, 4)
    rad_per_pulse = 2 * math.pi / PULSES_PER_REV
    history = collections.deque()
    residual = [0.0] * 4
    integral = 0.0
    line_integral = 0.0
    last_error = None
    last_time = None
    next_tick = time.monotonic()
    started = next_tick
    offset_log = open(args.log_offset, "w", buffering=1) if args.log_offset else None
    if offset_log:
        offset_log.write("t_s,d_m\n")
    ticks = 0
    blind = 0
    while running:
        now = time.monotonic()
        result = reader.txRxPacket()
        if not running:
            # Stopped during the transaction (the run ended): not a period of the run.
            break
        if result != COMM_SUCCESS:
            print(f"sync read failed: {packet.getTxRxResult(result)}", file=sys.stderr)
        else:
            pos = {dxl: signed32(reader.getData(dxl, ADDR_PRESENT_POSITION, 4)) for dxl in WHEELS + MAGNETS}
            wheels = [pos[d] for d in WHEELS]
            alphas = [(pos[d] - MAGNET_DOWN_PULSES) * rad_per_pulse for d in MAGNETS]
            history.append((now, wheels))
            while len(history) > 2 and now - history[1][0] >= args.speed_window:
                history.popleft()
            rates = [0.0] * 4
            t0, p0 = history[0]
            if len(history) > 1 and now > t0:
                rates = [(w - p) * rad_per_pulse / (now - t0) for w, p in zip(wheels, p0)]
            radius = [args.radius if args.no_compensation else args.radius / max(math.cos(a), 0.5) for a in alphas]
            speed = sum(r * rr for r, rr in zip(rates, radius)) / 4.0

            dt = now - last_time if last_time is not None else 0.0
            last_time = now
            error = target - speed
            if args.ki and dt > 0:
                top = VELOCITY_LIMIT * RPM_PER_UNIT / 60 * 2 * math.pi * args.radius
                limit = top / abs(args.ki)
                integral = max(-limit, min(limit, integral + error * dt))
            derivative = (error - last_error) / dt if last_error is not None and dt > 0 else 0.0
            last_error = error
            command = (0.0 if args.no_feedforward else target) + args.kp * error + args.ki * integral + args.kd * derivative

            yaw_rate = 0.0
            line = read_line(sensor_client) if sensor_client else None
            blind += line is None
            if line is not None and target > 0:
                # /line gives the robot relative to the line (d > 0: the robot is left of it),
                # the errors the control law takes.
                d_err, psi_err = line["d"], line["psi"]
                if offset_log:
                    offset_log.write(f"{now - started:.6f},{d_err:.6g}\n")
                w, pole = args.omega_n, args.integral_pole
                damping = 2 * args.zeta * w
                k_d, k_psi, k_i = -(w ** 2 + damping * pole) / target, -(damping + pole), -(w ** 2) * pole / target
                proportional = k_d * d_err + k_psi * psi_err
                candidate = line_integral + d_err * max(dt, 0.0)
                if abs(proportional + k_i * candidate) <= args.max_yaw_rate:
                    line_integral = candidate
                yaw_rate = max(-args.max_yaw_rate, min(args.max_yaw_rate, proportional + k_i * line_integral))

            writer.clearParam()
            for i, dxl in enumerate(WHEELS):
                side = -1.0 if LEFT[i] else 1.0
                wheel = (command + side * yaw_rate * args.track / 2) / args.radius
                units = wheel * 60 / (2 * math.pi) / RPM_PER_UNIT + residual[i]
                # Half away from zero, as the Rust reference rounds (Python's round() is half-to-even).
                rounded = max(-VELOCITY_LIMIT, min(VELOCITY_LIMIT, math.copysign(math.floor(abs(units) + 0.5), units)))
                residual[i] = max(-1.0, min(1.0, units - rounded))
                writer.addParam(dxl, int(rounded).to_bytes(4, "little", signed=True))
            writer.txPacket()
            ticks += 1
        next_tick += args.period
        delay = next_tick - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            next_tick = time.monotonic()

    writer.clearParam()
    for dxl in WHEELS:
        writer.addParam(dxl, (0).to_bytes(4, "little", signed=True))
    writer.txPacket()
    for dxl in WHEELS:
        packet.write1ByteTxRx(port, dxl, ADDR_TORQUE_ENABLE, 0)
    port.closePort()
    if offset_log:
        offset_log.close()
    print(f"line_follower: {ticks} control periods, {blind} without a line measurement", flush=True)


if __name__ == "__main__":
    main()
