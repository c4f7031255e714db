"""A mixed bus: LeRobot's Koch follower (two XL430-W250 and four XL330-M288 at 1 Mbps), served on
the bench from ``hil/robots/koch-follower.toml`` and driven through the unchanged SDK."""

from __future__ import annotations

import time

from dynamixel_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from conftest import A_GOAL_VEL, A_OP_MODE, A_TORQUE, REPO_ROOT

KOCH = REPO_ROOT / "hil" / "robots" / "koch-follower.toml"
# Model numbers by ID, as LeRobot's KochFollower expects them (its _assert_motors_exist).
MODELS = {1: 1060, 2: 1060, 3: 1200, 4: 1200, 5: 1200, 6: 1200}
A_PRESENT_LOAD_OR_CURRENT = 126
A_CURRENT_LIMIT = 38
A_VOLTAGE = 144
A_HW_ERROR = 70


def open_port(emu, baud=1_000_000):
    port = PortHandler(emu.port)
    assert port.openPort() and port.setBaudRate(baud)
    return port, PacketHandler(2.0)


def test_each_id_answers_with_its_own_model(start_emulator):
    emu = start_emulator(extra_args=("--robot", str(KOCH)))
    port, packet = open_port(emu)
    try:
        found, result = packet.broadcastPing(port)
        assert result == COMM_SUCCESS, packet.getTxRxResult(result)
        assert {dxl_id: model for dxl_id, (model, _fw) in found.items()} == MODELS
        for dxl_id, model in MODELS.items():
            number, result, error = packet.read2ByteTxRx(port, dxl_id, 0)
            assert (number, result, error) == (model, COMM_SUCCESS, 0), dxl_id
    finally:
        port.closePort()


def test_each_servo_keeps_its_own_table_and_supply(start_emulator):
    emu = start_emulator(extra_args=("--robot", str(KOCH)))
    port, packet = open_port(emu)
    try:
        # The XL430 has no Current Limit: 38-39 is a gap in its table, and an access that reaches
        # no item is an Access Error; the XL330 has one, 1750 mA.
        assert packet.read2ByteTxRx(port, 1, A_CURRENT_LIMIT)[1:] == (COMM_SUCCESS, 0x07)
        assert packet.write2ByteTxRx(port, 1, A_CURRENT_LIMIT, 100) == (COMM_SUCCESS, 0x07)
        limit, result, error = packet.read2ByteTxRx(port, 3, A_CURRENT_LIMIT)
        assert (result, error) == (COMM_SUCCESS, 0) and limit == 1750
        # Current control mode (0): the XL330 has it, the XL430 does not (Data Range Error).
        assert packet.write1ByteTxRx(port, 3, A_OP_MODE, 0) == (COMM_SUCCESS, 0)
        assert packet.write1ByteTxRx(port, 1, A_OP_MODE, 0) == (COMM_SUCCESS, 0x04)
        # Each at its page's recommended supply, inside its own voltage limits: no input error.
        for dxl_id, volts in {1: 111, 3: 50}.items():
            assert packet.read2ByteTxRx(port, dxl_id, A_VOLTAGE) == (volts, COMM_SUCCESS, 0)
            assert packet.read1ByteTxRx(port, dxl_id, A_HW_ERROR) == (0, COMM_SUCCESS, 0)
    finally:
        port.closePort()


def test_an_xl430_reads_its_load_where_an_xl330_reads_its_current(start_emulator):
    emu = start_emulator(extra_args=("--robot", str(KOCH)))
    port, packet = open_port(emu)
    try:
        # Both turning freely at 100 × 0.229 rev/min against their gearbox friction alone.
        for dxl_id in (2, 3):
            assert packet.write1ByteTxRx(port, dxl_id, A_OP_MODE, 1) == (COMM_SUCCESS, 0)
            assert packet.write1ByteTxRx(port, dxl_id, A_TORQUE, 1) == (COMM_SUCCESS, 0)
            assert packet.write4ByteTxRx(port, dxl_id, A_GOAL_VEL, 100) == (COMM_SUCCESS, 0)
        time.sleep(0.3)
        readings = {}
        for dxl_id in (2, 3):
            value, result, error = packet.read2ByteTxRx(port, dxl_id, A_PRESENT_LOAD_OR_CURRENT)
            assert (result, error) == (COMM_SUCCESS, 0)
            readings[dxl_id] = value - 65536 if value >= 32768 else value
        # The XL430's Present Load is 0.1 % of its maximum: its friction is a few per mille. The
        # XL330-M288's Present Current is in mA: its identified friction draws about 90 mA.
        assert 0 < readings[2] < 20, readings
        assert 50 < readings[3] < 150, readings
    finally:
        port.closePort()
