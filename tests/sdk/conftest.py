"""Fixtures for the official-SDK conformance suite.

Every test gets a fresh emulator (``climbsim serve --link <tmp>/ttyDXL``) so tests are
independent, and talks to it only through the unchanged ROBOTIS DynamixelSDK 4.0.5
(``PortHandler`` + ``PacketHandler(2.0)``), exactly as a controller on real hardware would.

The binary is ``$CLIMBSIM_BIN`` (default ``target/debug/climbsim`` under the repo root).
Tests run with ``--timing off`` unless marked ``@pytest.mark.timing("wire")`` (explicit
``--timing wire``) or ``@pytest.mark.timing("default")`` (no ``--timing`` flag at all).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import pytest
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    PacketHandler,
    PortHandler,
)

REPO_ROOT = Path(__file__).resolve().parents[2]
BAUD = 57600
START_TIMEOUT_S = 10.0
STOP_TIMEOUT_S = 10.0
SERVO_IDS = list(range(1, 9))
MODEL_NUMBER = 1120
FIRMWARE_VERSION = 48
# Reboot / factory reset / backup restore: the servo is silent for 100 ms (chosen boot time).
BOOT_WAIT_S = 0.25

# Control-table addresses used across the suite.
A_MODEL = 0
A_FW = 6
A_ID = 7
A_BAUD = 8
A_RDT = 9
A_DRIVE_MODE = 10
A_OP_MODE = 11
A_SECONDARY_ID = 12
A_PROTOCOL = 13
A_HOMING = 20
A_MOVING_THRESHOLD = 24
A_TEMP_LIMIT = 31
A_MAX_VOLT = 32
A_MIN_VOLT = 34
A_PWM_LIMIT = 36
A_CURRENT_LIMIT = 38
A_VEL_LIMIT = 44
A_MAX_POS = 48
A_MIN_POS = 52
A_SHUTDOWN = 63
A_TORQUE = 64
A_LED = 65
A_SRL = 68
A_REGISTERED = 69
A_HW_ERROR = 70
A_POS_P_GAIN = 84
A_WATCHDOG = 98
A_GOAL_PWM = 100
A_GOAL_CURRENT = 102
A_GOAL_VEL = 104
A_PROFILE_ACC = 108
A_PROFILE_VEL = 112
A_GOAL_POS = 116
A_TICK = 120
A_MOVING = 122
A_PRESENT_PWM = 124
A_PRESENT_VEL = 128
A_PRESENT_POS = 132
A_VOLTAGE = 144
A_TEMPERATURE = 146
A_BACKUP_READY = 147
A_INDIRECT_ADDR_1 = 168
A_INDIRECT_DATA_1 = 224
A_INDIRECT_ADDR_29 = 578
A_INDIRECT_DATA_29 = 634

# Status error byte (SDK dxl_error): alert bit + error number in the low 7 bits.
ALERT = 0x80
ERR_RESULT_FAIL = 0x01
ERR_INSTRUCTION = 0x02
ERR_CRC = 0x03
ERR_DATA_RANGE = 0x04
ERR_DATA_LENGTH = 0x05
ERR_DATA_LIMIT = 0x06
ERR_ACCESS = 0x07


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        'timing(mode): run the emulator with "--timing <mode>" ("default" = no --timing flag); '
        "without the marker the suite uses --timing off",
    )


# --------------------------------------------------------------------------------------------
# Emulator process
# --------------------------------------------------------------------------------------------


def climbsim_bin() -> Path:
    env = os.environ.get("CLIMBSIM_BIN")
    path = Path(env) if env else Path("target/debug/climbsim")
    if not path.is_absolute():
        path = REPO_ROOT / path
    return path


class Emulator:
    """One ``climbsim serve`` process and the pty link it publishes."""

    def __init__(self, timing: str | None, extra_args: tuple[str, ...] = ()):
        binary = climbsim_bin()
        if not binary.is_file() or not os.access(binary, os.X_OK):
            pytest.fail(
                f"climbsim binary not found or not executable: {binary} "
                "(build it with `cargo build`, or set CLIMBSIM_BIN)",
                pytrace=False,
            )
        self.workdir = Path(tempfile.mkdtemp(prefix="climbsim-sdk-"))
        self.link = self.workdir / "ttyDXL"
        self.stdout_path = self.workdir / "stdout.log"
        self.stderr_path = self.workdir / "stderr.log"
        self.args = [str(binary), "serve", "--link", str(self.link)]
        if timing is not None:
            self.args += ["--timing", timing]
        self.args += list(extra_args)
        self._stdout = open(self.stdout_path, "wb")
        self._stderr = open(self.stderr_path, "wb")
        self.proc = subprocess.Popen(
            self.args,
            stdin=subprocess.DEVNULL,
            stdout=self._stdout,
            stderr=self._stderr,
            cwd=REPO_ROOT,
        )
        self.returncode: int | None = None
        self.port = self._wait_for_port_line()

    def stderr(self) -> str:
        try:
            return self.stderr_path.read_text(errors="replace")
        except OSError:
            return "<stderr unavailable>"

    def stdout(self) -> str:
        try:
            return self.stdout_path.read_text(errors="replace")
        except OSError:
            return "<stdout unavailable>"

    def diagnostics(self) -> str:
        return (
            f"command: {' '.join(self.args)}\n"
            f"--- emulator stdout ---\n{self.stdout()[-4000:]}\n"
            f"--- emulator stderr ---\n{self.stderr()[-8000:]}"
        )

    def _wait_for_port_line(self) -> str:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            # Only complete lines: a half-written path must not be taken.
            for line in self.stdout().split("\n")[:-1]:
                line = line.strip()
                if line.startswith("port:"):
                    path = line[len("port:"):].strip()
                    if path:
                        return path
            rc = self.proc.poll()
            if rc is not None:
                self._close_logs()
                pytest.fail(
                    f"climbsim exited with code {rc} before printing 'port: <path>'\n"
                    + self.diagnostics(),
                    pytrace=False,
                )
            if time.monotonic() > deadline:
                self.proc.kill()
                self.proc.wait()
                self._close_logs()
                pytest.fail(
                    f"climbsim did not print 'port: <path>' within {START_TIMEOUT_S:.0f} s\n"
                    + self.diagnostics(),
                    pytrace=False,
                )
            time.sleep(0.01)

    def _close_logs(self):
        for f in (self._stdout, self._stderr):
            if not f.closed:
                f.close()

    def stop(self) -> int:
        """SIGTERM, wait for exit; returns the exit code (kills and fails on a hang)."""
        if self.returncode is not None:
            return self.returncode
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                self._close_logs()
                self.returncode = self.proc.returncode
                pytest.fail(
                    f"climbsim did not exit within {STOP_TIMEOUT_S:.0f} s of SIGTERM\n"
                    + self.diagnostics(),
                    pytrace=False,
                )
        self._close_logs()
        self.returncode = self.proc.returncode
        return self.returncode

    def cleanup(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._close_logs()
        shutil.rmtree(self.workdir, ignore_errors=True)


def _stop_and_check(emu: Emulator):
    try:
        rc = emu.stop()
        assert rc == 0, f"climbsim exit code after SIGTERM was {rc}, expected 0\n{emu.diagnostics()}"
        assert not os.path.lexists(emu.link), (
            f"climbsim left its link {emu.link} behind after SIGTERM\n{emu.diagnostics()}"
        )
    finally:
        emu.cleanup()


@pytest.fixture
def start_emulator(request):
    """Factory: ``start_emulator(timing="off", extra_args=()) -> Emulator``. Every emulator it started is
    stopped with SIGTERM at teardown, which asserts exit code 0 and that the link is gone."""
    started: list[Emulator] = []
    request.node._climbsim_emulators = started

    def start(timing: str | None = "off", extra_args: tuple[str, ...] = ()) -> Emulator:
        emu = Emulator(timing, extra_args)
        started.append(emu)
        return emu

    yield start
    errors = []
    for emu in started:
        try:
            _stop_and_check(emu)
        except (AssertionError, pytest.fail.Exception) as e:  # report every emulator
            errors.append(str(e))
    if errors:
        pytest.fail("\n\n".join(errors), pytrace=False)


@pytest.fixture
def emulator_handle(request, start_emulator) -> Emulator:
    marker = request.node.get_closest_marker("timing")
    timing = "off"
    if marker is not None:
        timing = marker.args[0] if marker.args else "default"
    return start_emulator(None if timing == "default" else timing)


@pytest.fixture
def emulator(emulator_handle) -> str:
    """The emulator's port path (the line ``port: <path>`` it printed)."""
    return emulator_handle.port


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.failed:
        for i, emu in enumerate(getattr(item, "_climbsim_emulators", [])):
            report.sections.append((f"climbsim #{i} stderr ({report.when})", emu.stderr()[-8000:]))


# --------------------------------------------------------------------------------------------
# SDK access
# --------------------------------------------------------------------------------------------


def to_signed(value: int, size: int) -> int:
    bits = 8 * size
    value &= (1 << bits) - 1
    return value - (1 << bits) if value & (1 << (bits - 1)) else value


def le_bytes(value: int, size: int) -> list[int]:
    value &= (1 << (8 * size)) - 1
    return [(value >> (8 * i)) & 0xFF for i in range(size)]


def describe(ph, result: int, error: int) -> str:
    text = f"comm={result} {ph.getTxRxResult(result)!r} error=0x{error:02X}"
    if error:
        text += f" {ph.getRxPacketError(error)!r}"
    return text


def hexs(data) -> str:
    return " ".join(f"{b:02X}" for b in data)


class Bus:
    """An opened PortHandler at 57600 bps plus PacketHandler(2.0), with checked helpers."""

    def __init__(self, port: PortHandler, ph, emu: Emulator):
        self.port = port
        self.ph = ph
        self.emu = emu

    # ---- plain SDK calls ---------------------------------------------------------------

    def ping(self, dxl_id):
        return self.ph.ping(self.port, dxl_id)

    def read(self, dxl_id, addr, size):
        """-> (data list, comm result, dxl_error) straight from readTxRx."""
        return self.ph.readTxRx(self.port, dxl_id, addr, size)

    def write(self, dxl_id, addr, size, value):
        """Write ``value`` (two's complement if negative) as ``size`` bytes -> (result, error)."""
        return self.write_bytes(dxl_id, addr, le_bytes(value, size))

    def write_bytes(self, dxl_id, addr, data):
        return self.ph.writeTxRx(self.port, dxl_id, addr, len(data), list(data))

    def set_baud(self, bps):
        assert self.port.setBaudRate(bps), f"PortHandler.setBaudRate({bps}) failed"

    # ---- checked helpers ---------------------------------------------------------------

    def read_bytes_ok(self, dxl_id, addr, size, allow_alert=False) -> list[int]:
        data, result, error = self.read(dxl_id, addr, size)
        assert result == COMM_SUCCESS, (
            f"read id={dxl_id} addr={addr} len={size}: {describe(self.ph, result, error)}"
        )
        err = error & 0x7F if allow_alert else error
        assert err == 0, f"read id={dxl_id} addr={addr} len={size}: {describe(self.ph, result, error)}"
        assert len(data) == size, (
            f"read id={dxl_id} addr={addr} len={size}: got {len(data)} data bytes ({hexs(data)})"
        )
        return list(data)

    def read_u(self, dxl_id, addr, size, allow_alert=False) -> int:
        data = self.read_bytes_ok(dxl_id, addr, size, allow_alert)
        return sum(b << (8 * i) for i, b in enumerate(data))

    def read_s(self, dxl_id, addr, size, allow_alert=False) -> int:
        return to_signed(self.read_u(dxl_id, addr, size, allow_alert), size)

    def write_ok(self, dxl_id, addr, size, value, allow_alert=False):
        result, error = self.write(dxl_id, addr, size, value)
        err = error & 0x7F if allow_alert else error
        assert result == COMM_SUCCESS and err == 0, (
            f"write id={dxl_id} addr={addr} len={size} value={value}: {describe(self.ph, result, error)}"
        )

    def write_bytes_ok(self, dxl_id, addr, data):
        result, error = self.write_bytes(dxl_id, addr, data)
        assert result == COMM_SUCCESS and error == 0, (
            f"write id={dxl_id} addr={addr} data=[{hexs(data)}]: {describe(self.ph, result, error)}"
        )

    def expect_error(self, result, error, expected, what):
        assert result == COMM_SUCCESS, (
            f"{what}: expected a status packet with error 0x{expected:02X}, got {describe(self.ph, result, error)}"
        )
        assert error & 0x7F == expected, (
            f"{what}: expected error 0x{expected:02X}, got {describe(self.ph, result, error)}"
        )

    def ping_ok(self, dxl_id):
        model, result, error = self.ping(dxl_id)
        assert result == COMM_SUCCESS and error == 0, f"ping id={dxl_id}: {describe(self.ph, result, error)}"
        assert model == MODEL_NUMBER, f"ping id={dxl_id}: model {model}, expected {MODEL_NUMBER}"

    def ping_timeout(self, dxl_id, why=""):
        model, result, error = self.ping(dxl_id)
        assert result == COMM_RX_TIMEOUT, (
            f"ping id={dxl_id} should get no answer{(' (' + why + ')') if why else ''}, "
            f"got {describe(self.ph, result, error)} model={model}"
        )

    def torque(self, dxl_id, on: bool):
        self.write_ok(dxl_id, A_TORQUE, 1, 1 if on else 0)

    def reboot_ok(self, dxl_id, allow_alert=False):
        result, error = self.ph.reboot(self.port, dxl_id)
        err = error & 0x7F if allow_alert else error
        assert result == COMM_SUCCESS and err == 0, f"reboot id={dxl_id}: {describe(self.ph, result, error)}"
        time.sleep(BOOT_WAIT_S)

    # ---- raw packets -------------------------------------------------------------------

    def build(self, dxl_id, inst, params=(), reserved=0x00, length=None, bad_crc=False) -> bytes:
        """An instruction packet with correct LEN and CRC (no stuffing), optionally corrupted."""
        params = list(params)
        ln = len(params) + 3 if length is None else length
        pkt = [0xFF, 0xFF, 0xFD, reserved, dxl_id, ln & 0xFF, ln >> 8, inst] + params
        crc = self.ph.updateCRC(0, pkt, len(pkt))
        if bad_crc:
            crc ^= 0x5A5A
        return bytes(pkt + [crc & 0xFF, crc >> 8])

    def crc(self, data) -> int:
        return self.ph.updateCRC(0, list(data), len(data))

    def send_raw(self, data: bytes):
        self.port.clearPort()
        n = self.port.writePort(bytes(data))
        assert n == len(data), f"writePort wrote {n} of {len(data)} bytes"

    def recv_raw(self, expected: int | None = None, timeout: float = 0.2, settle: float = 0.03) -> bytes:
        """Collect bytes until ``expected`` arrived (then ``settle`` more) or ``timeout``."""
        buf = bytearray()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            chunk = self.port.readPort(4096)
            if chunk:
                buf += chunk
                if expected is not None and len(buf) >= expected:
                    end = time.monotonic() + settle
                    while time.monotonic() < end:
                        buf += self.port.readPort(4096)
                        time.sleep(0.002)
                    break
            else:
                time.sleep(0.001)
        return bytes(buf)

    def tx_rx_sdk(self, pkt_list, rx_len=11):
        """Send a hand-made packet with the SDK's txPacket (LEN/CRC filled in by the SDK) and
        read one status packet with its rxPacket. Works for instructions txRxPacket won't wait
        for (Action). -> (rxpacket, result, error)"""
        result = self.ph.txPacket(self.port, pkt_list)
        assert result == COMM_SUCCESS, f"txPacket: {describe(self.ph, result, 0)}"
        self.port.setPacketTimeout(rx_len)
        rx, result = self.ph.rxPacket(self.port, False)
        error = rx[8] if result == COMM_SUCCESS and len(rx) > 8 else 0
        return rx, result, error

    def sdk_packet(self, dxl_id, inst, params=()):
        """A list in the shape the SDK's txPacket/txRxPacket expect (LEN set, CRC slots zero)."""
        params = list(params)
        pkt = [0] * (len(params) + 10)
        pkt[4] = dxl_id
        pkt[5] = (len(params) + 3) & 0xFF
        pkt[6] = (len(params) + 3) >> 8
        pkt[7] = inst
        pkt[8 : 8 + len(params)] = params
        return pkt

    def wait_until(self, fn, timeout, interval=0.02, what="condition"):
        deadline = time.monotonic() + timeout
        last = None
        while True:
            last = fn()
            if last:
                return last
            if time.monotonic() > deadline:
                return last
            time.sleep(interval)


@pytest.fixture
def dxl(emulator, emulator_handle):
    """Opened PortHandler at 57600 bps + PacketHandler(2.0), wrapped in :class:`Bus`."""
    port = PortHandler(emulator)
    assert port.openPort(), f"PortHandler.openPort() failed on {emulator}"
    assert port.setBaudRate(BAUD), f"PortHandler.setBaudRate({BAUD}) failed on {emulator}"
    bus = Bus(port, PacketHandler(2.0), emulator_handle)
    yield bus
    if port.is_open:
        port.closePort()

