"""``climbsim serve --device``: the bus on a serial device, with the controller on its far side.

No adapter is needed: two pseudo-terminals joined like a null-modem cable stand in for the USB
adapter and the controller board's UART. climbsim opens one end with ``--device`` (real termios,
exclusive lock, baud switches), the unchanged official SDK opens the other as it would open
``/dev/ttyUSB0``. The cable passes bytes only while both ends are at the same baud, as a UART
hears nothing it can decode at another rate, and it can echo climbsim's sends back to it like a
half-duplex adapter.
"""

from __future__ import annotations

import fcntl
import json
import os
import select
import struct
import subprocess
import threading
import time
import tty
from pathlib import Path

import pytest
from dynamixel_sdk import (
    COMM_SUCCESS,
    GroupSyncRead,
    PacketHandler,
    PortHandler,
)

from conftest import (
    A_BAUD,
    A_GOAL_VEL,
    A_LED,
    A_OP_MODE,
    A_PRESENT_POS,
    A_PRESENT_VEL,
    A_TORQUE,
    SERVO_IDS,
    climbsim_bin,
    describe,
    to_signed,
)

# struct termios2 on Linux: four tcflag_t, c_line, 19 control characters, ispeed, ospeed.
TERMIOS2 = struct.Struct("IIIIB19sII")
TCGETS2 = 0x802C542A  # _IOR('T', 0x2A, struct termios2)


def line_baud(fd: int) -> int:
    """The baud a terminal is set to, standard rate or not (TCGETS2)."""
    raw = fcntl.ioctl(fd, TCGETS2, bytes(TERMIOS2.size))
    return TERMIOS2.unpack(raw)[-1]


class NullModem:
    """Two ptys joined by a thread: the controller's end and the device end climbsim opens.

    ``device_link`` is a symlink to the device end (a stable name, like /dev/serial/by-id/...);
    ``unplug()`` closes the device end and removes the link, ``plug()`` makes a new pair behind
    the same link, like pulling and reinserting a USB adapter."""

    def __init__(self, workdir: Path, echo: bool = False):
        self.echo = echo
        self.device_link = workdir / "ttyUSB0"
        self.dropped = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ctrl_master, self._ctrl_slave = os.openpty()
        tty.setraw(self._ctrl_slave)
        self.controller_path = os.ttyname(self._ctrl_slave)
        self._dev = None
        self.plug()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def plug(self):
        master, slave = os.openpty()
        tty.setraw(slave)
        path = os.ttyname(slave)
        with self._lock:
            self._dev = (master, slave)
        os.symlink(path, self.device_link)

    def unplug(self):
        with self._lock:
            master, slave = self._dev
            self._dev = None
        os.unlink(self.device_link)
        os.close(master)
        os.close(slave)

    def close(self):
        self._stop.set()
        self._thread.join(timeout=2)
        if self._dev is not None:
            self.unplug()
        os.close(self._ctrl_master)
        os.close(self._ctrl_slave)

    def _same_baud(self, dev_slave: int) -> bool:
        return line_baud(self._ctrl_slave) == line_baud(dev_slave)

    def _run(self):
        while not self._stop.is_set():
            with self._lock:
                dev = self._dev
            fds = [self._ctrl_master] + ([dev[0]] if dev else [])
            try:
                readable, _, _ = select.select(fds, [], [], 0.05)
            except (OSError, ValueError):
                continue  # the device end was closed under us: unplugged
            for fd in readable:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue  # EIO: nobody has the other side open yet
                if dev is None:
                    self.dropped += len(data)
                    continue
                if fd == self._ctrl_master:
                    if self._same_baud(dev[1]):
                        os.write(dev[0], data)
                    else:
                        self.dropped += len(data)
                else:
                    if self.echo:
                        os.write(dev[0], data)
                    if self._same_baud(dev[1]):
                        os.write(self._ctrl_master, data)
                    else:
                        self.dropped += len(data)


@pytest.fixture
def null_modem(tmp_path):
    cables = []

    def make(echo: bool = False) -> NullModem:
        cable = NullModem(tmp_path, echo)
        cables.append(cable)
        return cable

    yield make
    for cable in cables:
        cable.close()


def open_controller(path: str, baud: int = 57600):
    port = PortHandler(path)
    assert port.openPort(), f"cannot open {path}"
    assert port.setBaudRate(baud), f"cannot set {baud} bps"
    return port, PacketHandler(2.0)


def serve_device(start_emulator, cable: NullModem, *args: str):
    emu = start_emulator("wire", ("--device", str(cable.device_link), *args))
    deadline = time.monotonic() + 10
    while "device:" not in emu.stdout():
        assert time.monotonic() < deadline, f"no 'device:' line\n{emu.diagnostics()}"
        time.sleep(0.01)
    return emu


def test_the_sdk_pings_syncs_and_drives_a_wheel_through_the_device(start_emulator, null_modem):
    cable = null_modem()
    emu = serve_device(start_emulator, cable)
    assert f"device: {cable.device_link} at 57600 bps" in emu.stdout()
    port, ph = open_controller(cable.controller_path)
    try:
        for dxl_id in SERVO_IDS:
            model, result, error = ph.ping(port, dxl_id)
            assert result == COMM_SUCCESS and error == 0, f"ping {dxl_id}: {describe(ph, result, error)}\n{emu.diagnostics()}"
        sync = GroupSyncRead(port, ph, A_PRESENT_POS, 4)
        for dxl_id in SERVO_IDS:
            assert sync.addParam(dxl_id)
        result = sync.txRxPacket()
        assert result == COMM_SUCCESS, describe(ph, result, 0)
        assert all(sync.isAvailable(i, A_PRESENT_POS, 4) for i in SERVO_IDS)

        # Velocity mode, torque on, 50 units (11.45 rpm): the servo's rotor turns.
        for address, value, size in ((A_OP_MODE, 1, 1), (A_TORQUE, 1, 1), (A_GOAL_VEL, 50, 4)):
            write = ph.write1ByteTxRx if size == 1 else ph.write4ByteTxRx
            result, error = write(port, 1, address, value)
            assert result == COMM_SUCCESS and error == 0, describe(ph, result, error)
        # The velocity loop settles with a ~0.26 s time constant (as in test_motion.py).
        time.sleep(1.5)
        velocity, result, error = ph.read4ByteTxRx(port, 1, A_PRESENT_VEL)
        assert result == COMM_SUCCESS and error == 0, describe(ph, result, error)
        assert abs(to_signed(velocity, 4) - 50) <= 5, f"present velocity {to_signed(velocity, 4)}"
    finally:
        port.closePort()


def test_the_device_follows_a_baud_change_and_names_the_servos_that_went_deaf(start_emulator, null_modem):
    cable = null_modem()
    emu = serve_device(start_emulator, cable)
    port, ph = open_controller(cable.controller_path)
    try:
        # Baud Rate 3 = 1 Mbps, broadcast (no reply): every servo and the device switch.
        result = ph.write1ByteTxOnly(port, 0xFE, A_BAUD, 3)
        assert result == COMM_SUCCESS, describe(ph, result, 0)
        time.sleep(0.1)
        _, result, _ = ph.ping(port, 1)
        assert result != COMM_SUCCESS, "a ping at the old rate must go unheard"
        assert port.setBaudRate(1_000_000)
        for dxl_id in SERVO_IDS:
            _, result, error = ph.ping(port, dxl_id)
            assert result == COMM_SUCCESS, f"ping {dxl_id} at 1 Mbps: {describe(ph, result, error)}\n{emu.diagnostics()}"
        # ID 1 alone back to 57600 (Baud Rate 1): it answers at 1 Mbps, then goes deaf to it.
        result, error = ph.write1ByteTxRx(port, 1, A_BAUD, 1)
        assert result == COMM_SUCCESS and error == 0, describe(ph, result, error)
        _, result, _ = ph.ping(port, 1)
        assert result != COMM_SUCCESS, "ID 1 now listens at 57600"
        _, result, error = ph.ping(port, 2)
        assert result == COMM_SUCCESS, describe(ph, result, error)
    finally:
        port.closePort()
    deadline = time.monotonic() + 2
    while "went deaf" not in emu.stderr() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert "ID 1 at 57600 bps" in emu.stderr(), emu.diagnostics()


def sync_read_rounds(port, ph, rounds: int):
    sync = GroupSyncRead(port, ph, A_PRESENT_POS, 4)
    for dxl_id in SERVO_IDS:
        sync.addParam(dxl_id)
    for _ in range(rounds):
        result = sync.txRxPacket()
        assert result == COMM_SUCCESS, describe(ph, result, 0)


def stop_and_read_report(emu, report: Path) -> dict:
    assert emu.stop() == 0, emu.diagnostics()
    return json.loads(report.read_text())


@pytest.mark.parametrize("echo", ["auto", "on"])
def test_the_devices_echo_of_its_own_replies_is_dropped(start_emulator, null_modem, tmp_path, echo):
    cable = null_modem(echo=True)
    report = tmp_path / f"echo-{echo}.json"
    emu = serve_device(start_emulator, cable, "--echo", echo, "--report", str(report))
    port, ph = open_controller(cable.controller_path)
    try:
        sync_read_rounds(port, ph, 20)
    finally:
        port.closePort()
    # Only the controller's 20 instructions reached the bus, none of the 160 echoed replies.
    assert stop_and_read_report(emu, report)["requests"] == 20, emu.diagnostics()


def test_without_the_echo_filter_the_echo_reaches_the_bus(start_emulator, null_modem, tmp_path):
    cable = null_modem(echo=True)
    report = tmp_path / "echo-off.json"
    emu = serve_device(start_emulator, cable, "--echo", "off", "--report", str(report))
    port, ph = open_controller(cable.controller_path)
    try:
        sync_read_rounds(port, ph, 20)
    finally:
        port.closePort()
    assert stop_and_read_report(emu, report)["requests"] > 20, emu.diagnostics()


def test_a_device_in_use_is_refused_with_a_clear_error(start_emulator, null_modem):
    cable = null_modem()
    serve_device(start_emulator, cable)
    second = subprocess.run(
        [str(climbsim_bin()), "serve", "--device", str(cable.device_link)],
        capture_output=True, text=True, timeout=20,
    )
    assert second.returncode != 0
    assert "in use by another program" in second.stderr, second.stderr


def test_an_unplugged_device_is_reopened_and_the_bus_kept_its_state(start_emulator, null_modem):
    cable = null_modem()
    emu = serve_device(start_emulator, cable)
    port, ph = open_controller(cable.controller_path)
    try:
        result, error = ph.write1ByteTxRx(port, 3, A_LED, 1)
        assert result == COMM_SUCCESS and error == 0, describe(ph, result, error)
        cable.unplug()
        time.sleep(1.0)
        cable.plug()
        deadline = time.monotonic() + 5
        while True:
            led, result, error = ph.read1ByteTxRx(port, 3, A_LED)
            if result == COMM_SUCCESS or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        assert result == COMM_SUCCESS, f"no answer after replugging: {describe(ph, result, error)}\n{emu.diagnostics()}"
        assert led == 1, "the servo lost its LED setting"
    finally:
        port.closePort()
    assert "the device is back" in emu.stderr(), emu.diagnostics()


def fake_sysfs(tmp_path: Path, cable: NullModem, ms: int) -> Path:
    """A directory standing in for /sys with the cable's device end as a USB-serial adapter."""
    name = os.path.basename(os.path.realpath(cable.device_link))
    root = tmp_path / "sys"
    timer = root / "bus/usb-serial/devices" / name / "latency_timer"
    timer.parent.mkdir(parents=True)
    timer.write_text(f"{ms}\n")
    return root


def test_a_slow_latency_timer_is_reported(start_emulator, null_modem, tmp_path, monkeypatch):
    cable = null_modem()
    monkeypatch.setenv("CLIMBSIM_SYSFS_ROOT", str(fake_sysfs(tmp_path, cable, 16)))
    emu = serve_device(start_emulator, cable)
    deadline = time.monotonic() + 2
    while "latency timer" not in emu.stderr() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert "up to 16 ms" in emu.stderr() and "--low-latency" in emu.stderr(), emu.diagnostics()


def test_low_latency_sets_the_timer_to_1_ms_and_puts_it_back_on_exit(start_emulator, null_modem, tmp_path, monkeypatch):
    cable = null_modem()
    sysfs = fake_sysfs(tmp_path, cable, 16)
    timer = next(sysfs.glob("bus/usb-serial/devices/*/latency_timer"))
    monkeypatch.setenv("CLIMBSIM_SYSFS_ROOT", str(sysfs))
    emu = serve_device(start_emulator, cable, "--low-latency")
    assert timer.read_text().strip() == "1", emu.diagnostics()
    assert "up to 16 ms" not in emu.stderr()
    assert emu.stop() == 0, emu.diagnostics()
    assert timer.read_text().strip() == "16", "the timer was not put back"


def test_low_latency_on_a_device_without_a_timer_is_a_clear_error(null_modem, tmp_path):
    cable = null_modem()
    env = dict(os.environ, CLIMBSIM_SYSFS_ROOT=str(tmp_path / "empty-sys"))
    run = subprocess.run(
        [str(climbsim_bin()), "serve", "--device", str(cable.device_link), "--low-latency"],
        capture_output=True, text=True, timeout=20, env=env,
    )
    assert run.returncode == 2 and "has no USB latency timer" in run.stderr, run.stderr


def test_rs485_on_a_driver_without_it_is_a_clear_error(null_modem):
    cable = null_modem()
    run = subprocess.run(
        [str(climbsim_bin()), "serve", "--device", str(cable.device_link), "--rs485", "--rs485-delay-ms", "0,1"],
        capture_output=True, text=True, timeout=20,
    )
    assert run.returncode == 2, run.stderr
    assert "has no RS-485 mode" in run.stderr and "leave --rs485 off" in run.stderr, run.stderr
