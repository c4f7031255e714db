"""A mixed bus: LeRobot's Koch follower (two XL430-W250 and four XL330-M288 at 1 Mbps), served on
the bench from ``hil/robots/koch-follower.toml`` and driven through the unchanged SDK."""

from __future__ import annotations

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


def test_an_xl430_in_velocity_mode_reads_its_load(start_emulator):
    emu = start_emulator(extra_args=("--robot", str(KOCH)))
    port, packet = open_port(emu)
    try:
        assert packet.write1ByteTxRx(port, 2, A_OP_MODE, 1) == (COMM_SUCCESS, 0)
        assert packet.write1ByteTxRx(port, 2, A_TORQUE, 1) == (COMM_SUCCESS, 0)
        assert packet.write4ByteTxRx(port, 2, A_GOAL_VEL, 100) == (COMM_SUCCESS, 0)
        loads = []
        for _ in range(20):
            value, result, error = packet.read2ByteTxRx(port, 2, A_PRESENT_LOAD_OR_CURRENT)
            assert (result, error) == (COMM_SUCCESS, 0)
            loads.append(value - 65536 if value >= 32768 else value)
        assert any(0 < load <= 1000 for load in loads), loads
    finally:
        port.closePort()
