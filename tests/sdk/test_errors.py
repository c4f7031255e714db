"""Status error byte: access, length, range and limit errors; failed writes change nothing;
reads and writes across reserved gaps."""

import pytest
from dynamixel_sdk import COMM_SUCCESS

from conftest import (
    A_GOAL_POS,
    A_GOAL_VEL,
    A_HOMING,
    A_LED,
    A_MAX_POS,
    A_MIN_POS,
    A_OP_MODE,
    A_PRESENT_POS,
    A_PROFILE_VEL,
    A_RDT,
    A_SRL,
    A_VEL_LIMIT,
    A_WATCHDOG,
    ERR_ACCESS,
    ERR_DATA_LENGTH,
    ERR_DATA_LIMIT,
    ERR_DATA_RANGE,
    ERR_INSTRUCTION,
    describe,
    hexs,
)


@pytest.mark.parametrize("inst", [0x07, 0x30, 0x7F])
def test_unknown_instruction_gives_instruction_error(dxl, inst):
    rx, result, error = dxl.ph.txRxPacket(dxl.port, dxl.sdk_packet(1, inst))
    dxl.expect_error(result, error, ERR_INSTRUCTION, f"instruction 0x{inst:02X} to ID 1")
    dxl.ping_ok(1)


# ---- Access Error 0x07 --------------------------------------------------------------------

@pytest.mark.parametrize(
    "addr,size,value,name",
    [
        (A_PRESENT_POS, 4, 1000, "Present Position"),
        (0, 2, 1000, "Model Number"),
        (6, 1, 1, "Firmware Version"),
        (69, 1, 1, "Registered Instruction"),
        (70, 1, 1, "Hardware Error Status"),
        (146, 1, 50, "Present Temperature"),
    ],
)
def test_write_read_only_item_is_access_error(dxl, addr, size, value, name):
    before = dxl.read_u(1, addr, size)
    result, error = dxl.write(1, addr, size, value)
    dxl.expect_error(result, error, ERR_ACCESS, f"write {value} to read-only {name} ({addr})")
    if addr not in (A_PRESENT_POS, 146):  # physical values may move on their own
        after = dxl.read_u(1, addr, size)
        assert after == before, f"{name} changed from {before} to {after} by a refused write"


@pytest.mark.parametrize(
    "addr,size",
    [(40, 4), (40, 1), (14, 2), (99, 1), (300, 2), (700, 1), (662, 1)],
)
def test_write_undefined_address_is_access_error(dxl, addr, size):
    result, error = dxl.write(1, addr, size, 5)
    dxl.expect_error(result, error, ERR_ACCESS, f"write to undefined address {addr} len {size}")


@pytest.mark.parametrize(
    "addr,size",
    [(40, 4), (40, 1), (14, 6), (99, 1), (148, 4), (300, 2), (662, 1), (700, 1), (700, 4)],
)
def test_read_undefined_address_is_access_error_without_params(dxl, addr, size):
    # readTxRx would hand back the CRC bytes as "data" for a parameterless reply, so look at
    # the status packet itself
    pkt = dxl.sdk_packet(1, 0x02, [addr & 0xFF, addr >> 8, size, 0])
    rx, result, error = dxl.ph.txRxPacket(dxl.port, pkt)
    dxl.expect_error(result, error, ERR_ACCESS, f"read undefined address {addr} len {size}")
    length = rx[5] | rx[6] << 8
    assert length == 4, f"read undefined {addr}/{size}: status LEN {length} [{hexs(rx)}], expected 4 (no params)"


def test_access_error_reply_bytes_exact(dxl):
    # reference §5: Access Error reply from ID 1 has LEN = 4 and no params
    dxl.send_raw(dxl.build(1, 0x02, [40, 0, 4, 0]))
    got = dxl.recv_raw(expected=11)
    want = bytes.fromhex("FF FF FD 00 01 04 00 55 07 B0 8C")
    assert got == want, f"read 40/4: got [{hexs(got)}], expected [{hexs(want)}]"


@pytest.mark.parametrize(
    "addr,size,value,name",
    [
        (A_RDT, 1, 100, "Return Delay Time"),
        (7, 1, 20, "ID"),
        (8, 1, 2, "Baud Rate"),
        (A_OP_MODE, 1, 1, "Operating Mode"),
        (A_HOMING, 4, 100, "Homing Offset"),
        (A_MAX_POS, 4, 3000, "Max Position Limit"),
        (63, 1, 0x35, "Shutdown"),
    ],
)
def test_eeprom_write_with_torque_on_is_access_error(dxl, addr, size, value, name):
    before = dxl.read_u(1, addr, size)
    dxl.torque(1, True)
    result, error = dxl.write(1, addr, size, value)
    dxl.expect_error(result, error, ERR_ACCESS, f"EEPROM write {name} ({addr}) = {value} with torque on")
    assert dxl.read_u(1, addr, size) == before, f"{name} changed by a refused EEPROM write"
    dxl.ping_ok(1)
    dxl.torque(1, False)
    if addr not in (7, 8):  # ID / baud changes are tested in test_addressing.py
        dxl.write_ok(1, addr, size, value)
        assert dxl.read_u(1, addr, size) == value, f"{name} not written with torque off"


# ---- Data Length Error 0x05 ---------------------------------------------------------------

@pytest.mark.parametrize(
    "addr,data,check",
    [
        (116, [0x10, 0x00], (A_GOAL_POS, 4)),  # 2 of 4 bytes of Goal Position
        (118, [0x00, 0x00], (A_GOAL_POS, 4)),  # upper half of Goal Position
        (117, [0x01], (A_GOAL_POS, 4)),  # one byte in the middle
        (114, [0x01, 0x00, 0x10, 0x00], (A_PROFILE_VEL, 4)),  # straddles Profile Velocity/Goal Position
        (32, [100], (32, 2)),  # 1 of 2 bytes of Max Voltage Limit
        (20, [1, 2, 3], (A_HOMING, 4)),  # 3 of 4 bytes of Homing Offset
    ],
)
def test_partial_item_write_is_data_length_error(dxl, addr, data, check):
    caddr, csize = check
    before = dxl.read_u(1, caddr, csize)
    before_goal = dxl.read_u(1, A_GOAL_POS, 4)
    result, error = dxl.write_bytes(1, addr, data)
    dxl.expect_error(result, error, ERR_DATA_LENGTH, f"write [{hexs(data)}] at {addr}")
    assert dxl.read_u(1, caddr, csize) == before, f"item at {caddr} changed by a refused partial write"
    assert dxl.read_u(1, A_GOAL_POS, 4) == before_goal, "Goal Position changed by a refused partial write"


# ---- Data Range Error 0x04 ----------------------------------------------------------------

@pytest.mark.parametrize(
    "addr,size,value,default,name",
    [
        (A_OP_MODE, 1, 2, 3, "Operating Mode 2 (no such mode)"),
        (A_OP_MODE, 1, 17, 3, "Operating Mode 17"),
        (A_RDT, 1, 255, 250, "Return Delay Time 255"),
        (7, 1, 253, 1, "ID 253"),
        (8, 1, 8, 1, "Baud Rate code 8"),
        (13, 1, 3, 2, "Protocol Type 3"),
        (A_HOMING, 4, -1044480, 0, "Homing Offset -1044480"),
        (A_HOMING, 4, 1044480, 0, "Homing Offset 1044480"),
        (24, 4, 1024, 10, "Moving Threshold 1024"),
        (31, 1, 101, 80, "Temperature Limit 101"),
        (32, 2, 161, 160, "Max Voltage Limit 161"),
        (34, 2, 94, 95, "Min Voltage Limit 94"),
        (36, 2, 886, 885, "PWM Limit 886"),
        (A_VEL_LIMIT, 4, 1024, 128, "Velocity Limit 1024"),
        (A_MAX_POS, 4, 4096, 4095, "Max Position Limit 4096"),
        (64, 1, 2, 0, "Torque Enable 2"),
        (A_LED, 1, 2, 0, "LED 2"),
        (A_SRL, 1, 3, 2, "Status Return Level 3"),
        (84, 2, 16384, 800, "Position P Gain 16384"),
        (A_WATCHDOG, 1, 128, 0, "Bus Watchdog 128"),
        (168, 2, 30, 224, "Indirect Address 1 = 30"),
        (168, 2, 63, 224, "Indirect Address 1 = 63 (EEPROM)"),
        (168, 2, 662, 224, "Indirect Address 1 = 662"),
        (578, 2, 700, 634, "Indirect Address 29 = 700"),
    ],
)
def test_out_of_range_value_is_data_range_error(dxl, addr, size, value, default, name):
    result, error = dxl.write(1, addr, size, value)
    dxl.expect_error(result, error, ERR_DATA_RANGE, f"write {name} (addr {addr})")
    got = dxl.read_u(1, addr, size)
    assert got == default & ((1 << (8 * size)) - 1), f"{name}: item reads {got} after a refused write, expected {default}"
    dxl.ping_ok(1)


# ---- Data Limit Error 0x06 ----------------------------------------------------------------

@pytest.mark.parametrize("goal", [4096, 5000, -1, -2000])
def test_goal_position_outside_default_limits_is_data_limit_error(dxl, goal):
    dxl.write_ok(1, A_GOAL_POS, 4, 1000)
    result, error = dxl.write(1, A_GOAL_POS, 4, goal)
    dxl.expect_error(result, error, ERR_DATA_LIMIT, f"Goal Position {goal} in mode 3 (limits 0..4095)")
    assert dxl.read_s(1, A_GOAL_POS, 4) == 1000, "Goal Position changed by a refused write"


def test_goal_position_outside_custom_limits_is_data_limit_error(dxl):
    dxl.write_ok(1, A_MAX_POS, 4, 3000)
    dxl.write_ok(1, A_MIN_POS, 4, 1000)
    dxl.write_ok(1, A_GOAL_POS, 4, 2000)
    for goal in (3001, 999, 4095, 0):
        result, error = dxl.write(1, A_GOAL_POS, 4, goal)
        dxl.expect_error(result, error, ERR_DATA_LIMIT, f"Goal Position {goal} with limits 1000..3000")
    assert dxl.read_s(1, A_GOAL_POS, 4) == 2000, "Goal Position changed by refused writes"
    dxl.write_ok(1, A_GOAL_POS, 4, 3000)
    dxl.write_ok(1, A_GOAL_POS, 4, 1000)


def test_goal_velocity_beyond_velocity_limit_is_data_limit_error(dxl):
    dxl.write_ok(1, A_OP_MODE, 1, 1)  # velocity mode, torque off
    dxl.write_ok(1, A_GOAL_VEL, 4, 128)
    dxl.write_ok(1, A_GOAL_VEL, 4, -128)
    for goal in (129, -129, 1000):
        result, error = dxl.write(1, A_GOAL_VEL, 4, goal)
        dxl.expect_error(result, error, ERR_DATA_LIMIT, f"Goal Velocity {goal} with Velocity Limit 128")
    assert dxl.read_s(1, A_GOAL_VEL, 4) == -128, "Goal Velocity changed by refused writes"
    dxl.write_ok(1, A_VEL_LIMIT, 4, 50)
    result, error = dxl.write(1, A_GOAL_VEL, 4, 51)
    dxl.expect_error(result, error, ERR_DATA_LIMIT, "Goal Velocity 51 with Velocity Limit 50")
    dxl.write_ok(1, A_GOAL_VEL, 4, 50)


# ---- multi-item writes are all-or-nothing -------------------------------------------------

def test_multi_item_write_with_bad_last_item_applies_nothing(dxl):
    # 9 RDT=100 (ok), 10 Drive Mode=0 (ok), 11 Operating Mode=2 (range error)
    result, error = dxl.write_bytes(1, A_RDT, [100, 0, 2])
    dxl.expect_error(result, error, ERR_DATA_RANGE, "write 9..11 = [100, 0, 2]")
    assert dxl.read_u(1, A_RDT, 1) == 250, "Return Delay Time was applied from a refused multi-item write"
    assert dxl.read_u(1, A_OP_MODE, 1) == 3


def test_multi_item_write_across_gap_with_bad_item_applies_nothing(dxl):
    # 65 LED=1 (ok), 66-67 gap, 68 SRL=3 (range error)
    result, error = dxl.write_bytes(1, A_LED, [1, 0, 0, 3])
    dxl.expect_error(result, error, ERR_DATA_RANGE, "write 65..68 = [1, 0, 0, 3]")
    assert dxl.read_u(1, A_LED, 1) == 0, "LED was applied from a refused multi-item write"
    assert dxl.read_u(1, A_SRL, 1) == 2


def test_multi_item_write_with_limit_error_applies_nothing(dxl):
    # 112 Profile Velocity=100 (ok), 116 Goal Position=5000 (limit error in mode 3)
    data = [100, 0, 0, 0] + [0x88, 0x13, 0, 0]
    result, error = dxl.write_bytes(1, A_PROFILE_VEL, data)
    dxl.expect_error(result, error, ERR_DATA_LIMIT, "write 112..119 = PV 100, Goal 5000")
    assert dxl.read_u(1, A_PROFILE_VEL, 4) == 0, "Profile Velocity applied from a refused multi-item write"


def test_multi_item_write_with_read_only_item_applies_nothing(dxl):
    # 68 SRL=1 (ok), 69 Registered Instruction (read-only)
    result, error = dxl.write_bytes(1, A_SRL, [1, 1])
    dxl.expect_error(result, error, ERR_ACCESS, "write 68..69 = [1, 1]")
    assert dxl.read_u(1, A_SRL, 1) == 2, "SRL applied from a refused multi-item write"


# ---- reserved gaps ------------------------------------------------------------------------

def test_write_spanning_gap_works_and_gap_reads_zero(dxl):
    dxl.write_bytes_ok(1, A_LED, [1, 7, 7, 2])  # LED, gap 66-67, SRL
    got = dxl.read_bytes_ok(1, A_LED, 4)
    assert got == [1, 0, 0, 2], f"read 65..68 = [{hexs(got)}], expected [01 00 00 02]"


def test_bus_watchdog_two_byte_write_into_reserved_99(dxl):
    # Dynamixel2Arduino declares Bus Watchdog as 2 bytes (98-99)
    dxl.write_bytes_ok(1, A_WATCHDOG, [3, 0])
    assert dxl.read_u(1, A_WATCHDOG, 1) == 3
    dxl.write_bytes_ok(1, A_WATCHDOG, [0, 0])
    assert dxl.read_u(1, A_WATCHDOG, 1) == 0


def test_read_spanning_gaps_returns_zeros_in_gaps(dxl):
    data = dxl.read_bytes_ok(1, 0, 148)
    gaps = list(range(14, 20)) + [28, 29, 30] + list(range(40, 44)) + [59, 61, 62, 66, 67] + \
        list(range(71, 76)) + [86, 87] + list(range(92, 98)) + [99]
    nonzero = {a: data[a] for a in gaps if data[a] != 0}
    assert not nonzero, f"reserved bytes read non-zero: {nonzero}"
    assert data[0] | data[1] << 8 == 1120 and data[7] == 1 and data[9] == 250 and data[11] == 3, (
        f"items inside the 0..147 read are wrong: [{hexs(data[:16])} ...]"
    )
    assert data[63] == 0x34 and data[68] == 2 and data[84] | data[85] << 8 == 800
    assert data[144] | data[145] << 8 == 120


def test_read_spanning_gap_before_indirect_block(dxl):
    data = dxl.read_bytes_ok(1, 156, 20)  # 156 Ext Port Data 3, gap 158..167, 168.. Indirect Address 1..4
    assert data[2:12] == [0] * 10, f"gap 158..167 reads [{hexs(data[2:12])}]"
    got = [data[12 + 2 * k] | data[13 + 2 * k] << 8 for k in range(4)]
    assert got == [224, 225, 226, 227], f"Indirect Address 1..4 read as {got}"


def test_failed_write_keeps_servo_responsive(dxl):
    result, error = dxl.write(1, 40, 4, 1)
    assert result == COMM_SUCCESS, describe(dxl.ph, result, error)
    dxl.write_ok(1, A_LED, 1, 1)
    assert dxl.read_u(1, A_LED, 1) == 1
