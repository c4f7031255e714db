"""Every instruction of reference §4 through the SDK: Read/Write, Reg Write + Action,
Sync/Bulk Write, Sync/Bulk Read, Fast Sync/Bulk Read (GroupSyncRead.fastSyncRead /
GroupBulkRead.fastBulkRead in dynamixel-sdk 4.0.5), plus the raw reply layouts."""

import time

import pytest
from dynamixel_sdk import (
    BROADCAST_ID,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    GroupSyncWrite,
)

from conftest import (
    A_ID,
    A_LED,
    A_MODEL,
    A_POS_P_GAIN,
    A_PROFILE_ACC,
    A_PROFILE_VEL,
    A_REGISTERED,
    A_RDT,
    ERR_INSTRUCTION,
    MODEL_NUMBER,
    SERVO_IDS,
    describe,
    hexs,
    le_bytes,
)


def _distinct_profile_velocities(dxl, ids=SERVO_IDS):
    for dxl_id in ids:
        dxl.write_ok(dxl_id, A_PROFILE_VEL, 4, 1000 + 37 * dxl_id)


def _pv(dxl_id):
    return 1000 + 37 * dxl_id


# ---- Read / Write -------------------------------------------------------------------------

@pytest.mark.parametrize(
    "addr,size,value",
    [(A_LED, 1, 1), (A_POS_P_GAIN, 2, 1234), (A_PROFILE_VEL, 4, 32767), (A_PROFILE_ACC, 4, 0x1234)],
)
def test_write_then_read_back(dxl, addr, size, value):
    dxl.write_ok(4, addr, size, value)
    got = dxl.read_u(4, addr, size)
    assert got == value, f"addr {addr}: wrote {value}, read {got}"


def test_read_several_items_at_once(dxl):
    dxl.write_bytes_ok(2, A_PROFILE_ACC, le_bytes(300, 4) + le_bytes(400, 4))
    data = dxl.read_bytes_ok(2, A_PROFILE_ACC, 8)
    assert data == le_bytes(300, 4) + le_bytes(400, 4), f"read 108..115: [{hexs(data)}]"


def test_read_one_byte_of_a_multibyte_item(dxl):
    # partial *reads* are fine (only partial writes are refused)
    assert dxl.read_u(1, A_MODEL, 1) == MODEL_NUMBER & 0xFF
    assert dxl.read_u(1, A_MODEL + 1, 1) == MODEL_NUMBER >> 8


def test_write_reply_bytes_exact(dxl):
    # reference §10: Write Goal Position = 512 to ID 1, and the "no error" reply
    dxl.send_raw(bytes.fromhex("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89"))
    got = dxl.recv_raw(expected=11)
    want = bytes.fromhex("FF FF FD 00 01 04 00 55 00 A1 0C")
    assert got == want, f"write reply: got [{hexs(got)}], expected [{hexs(want)}]"
    assert dxl.read_u(1, 116, 4) == 512


# ---- Reg Write / Action -------------------------------------------------------------------

def test_reg_write_then_action(dxl):
    result, error = dxl.ph.regWriteTxRx(dxl.port, 1, A_PROFILE_VEL, 4, le_bytes(555, 4))
    assert result == COMM_SUCCESS and error == 0, f"reg write: {describe(dxl.ph, result, error)}"
    assert dxl.read_u(1, A_PROFILE_VEL, 4) == 0, "Reg Write applied before Action"
    assert dxl.read_u(1, A_REGISTERED, 1) == 1, "Registered Instruction not 1 after Reg Write"
    result = dxl.ph.action(dxl.port, 1)
    assert result == COMM_SUCCESS, describe(dxl.ph, result, 0)
    # the SDK does not wait for the Action reply; the next call flushes it
    time.sleep(0.02)
    assert dxl.read_u(1, A_PROFILE_VEL, 4) == 555, "Action did not apply the registered write"
    assert dxl.read_u(1, A_REGISTERED, 1) == 0, "Registered Instruction not back to 0 after Action"


def test_action_reply_is_a_normal_status(dxl):
    result, error = dxl.ph.regWriteTxRx(dxl.port, 2, A_LED, 1, [1])
    assert result == COMM_SUCCESS and error == 0
    rx, result, error = dxl.tx_rx_sdk(dxl.sdk_packet(2, 0x05))
    assert result == COMM_SUCCESS and error == 0, f"Action reply: {describe(dxl.ph, result, error)}"
    assert rx[4] == 2
    assert dxl.read_u(2, A_LED, 1) == 1


def test_broadcast_action_applies_all_registered(dxl):
    for dxl_id in (1, 3, 5):
        result, error = dxl.ph.regWriteTxRx(dxl.port, dxl_id, A_LED, 1, [1])
        assert result == COMM_SUCCESS and error == 0, describe(dxl.ph, result, error)
    result = dxl.ph.action(dxl.port, BROADCAST_ID)
    assert result == COMM_SUCCESS
    stray = dxl.recv_raw(timeout=0.1)
    assert stray == b"", f"broadcast Action was answered: [{hexs(stray)}]"
    for dxl_id in SERVO_IDS:
        want = 1 if dxl_id in (1, 3, 5) else 0
        assert dxl.read_u(dxl_id, A_LED, 1) == want, f"servo {dxl_id} LED after broadcast Action"
        assert dxl.read_u(dxl_id, A_REGISTERED, 1) == 0


def test_action_with_nothing_registered_is_instruction_error(dxl):
    rx, result, error = dxl.tx_rx_sdk(dxl.sdk_packet(1, 0x05))
    dxl.expect_error(result, error, ERR_INSTRUCTION, "Action with nothing registered")


# ---- Sync Write / Bulk Write --------------------------------------------------------------

def test_sync_write(dxl):
    group = GroupSyncWrite(dxl.port, dxl.ph, A_PROFILE_VEL, 4)
    for dxl_id in (1, 2, 3, 4, 5, 6, 7):  # 8 not listed
        assert group.addParam(dxl_id, le_bytes(100 * dxl_id, 4))
    result = group.txPacket()
    assert result == COMM_SUCCESS, describe(dxl.ph, result, 0)
    stray = dxl.recv_raw(timeout=0.1)
    assert stray == b"", f"Sync Write was answered: [{hexs(stray)}]"
    for dxl_id in SERVO_IDS:
        want = 100 * dxl_id if dxl_id != 8 else 0
        got = dxl.read_u(dxl_id, A_PROFILE_VEL, 4)
        assert got == want, f"servo {dxl_id}: Profile Velocity {got}, expected {want}"


def test_bulk_write(dxl):
    group = GroupBulkWrite(dxl.port, dxl.ph)
    assert group.addParam(1, A_LED, 1, [1])
    assert group.addParam(2, A_PROFILE_VEL, 4, le_bytes(77, 4))
    assert group.addParam(7, A_POS_P_GAIN, 2, le_bytes(900, 2))
    result = group.txPacket()
    assert result == COMM_SUCCESS, describe(dxl.ph, result, 0)
    stray = dxl.recv_raw(timeout=0.1)
    assert stray == b"", f"Bulk Write was answered: [{hexs(stray)}]"
    assert dxl.read_u(1, A_LED, 1) == 1
    assert dxl.read_u(2, A_PROFILE_VEL, 4) == 77
    assert dxl.read_u(7, A_POS_P_GAIN, 2) == 900
    assert dxl.read_u(3, A_LED, 1) == 0 and dxl.read_u(1, A_PROFILE_VEL, 4) == 0


# ---- Sync Read / Bulk Read ----------------------------------------------------------------

def test_sync_read_all_ids(dxl):
    group = GroupSyncRead(dxl.port, dxl.ph, A_ID, 1)
    for dxl_id in SERVO_IDS:
        assert group.addParam(dxl_id)
    result = group.txRxPacket()
    assert result == COMM_SUCCESS, f"sync read of ID: {describe(dxl.ph, result, 0)}"
    for dxl_id in SERVO_IDS:
        assert group.isAvailable(dxl_id, A_ID, 1)
        assert group.getData(dxl_id, A_ID, 1) == dxl_id


def test_sync_read_unsorted_id_list(dxl):
    _distinct_profile_velocities(dxl)
    order = [7, 2, 5, 1]
    group = GroupSyncRead(dxl.port, dxl.ph, A_PROFILE_VEL, 4)
    for dxl_id in order:
        assert group.addParam(dxl_id)
    result = group.txRxPacket()
    assert result == COMM_SUCCESS, f"sync read IDs {order} (replies must come in listed order): {describe(dxl.ph, result, 0)}"
    got = [group.getData(i, A_PROFILE_VEL, 4) for i in order]
    assert got == [_pv(i) for i in order], f"sync read values {got}"


def test_sync_read_raw_replies_in_listed_order(dxl):
    _distinct_profile_velocities(dxl)
    order = [6, 3, 8]
    dxl.send_raw(dxl.build(BROADCAST_ID, 0x82, [A_PROFILE_VEL, 0, 4, 0] + order))
    got = dxl.recv_raw(expected=15 * 3, timeout=0.5)
    assert len(got) == 45, f"sync read: {len(got)} bytes [{hexs(got)}], expected 3 x 15"
    ids = []
    for k in range(3):
        pkt = got[15 * k : 15 * (k + 1)]
        crc = dxl.crc(pkt[:13])
        assert pkt[:9] == bytes([0xFF, 0xFF, 0xFD, 0, pkt[4], 8, 0, 0x55, 0]) and pkt[13:] == bytes(
            [crc & 0xFF, crc >> 8]
        ), f"reply {k} malformed [{hexs(pkt)}]"
        assert pkt[9:13] == bytes(le_bytes(_pv(pkt[4]), 4)), f"reply {k} data [{hexs(pkt)}]"
        ids.append(pkt[4])
    assert ids == order, f"sync read reply order {ids}, expected {order}"


def test_bulk_read(dxl):
    _distinct_profile_velocities(dxl)
    group = GroupBulkRead(dxl.port, dxl.ph)
    assert group.addParam(4, A_ID, 1)
    assert group.addParam(2, A_MODEL, 2)
    assert group.addParam(6, A_PROFILE_VEL, 4)
    assert group.addParam(1, A_RDT, 1)
    result = group.txRxPacket()
    assert result == COMM_SUCCESS, f"bulk read: {describe(dxl.ph, result, 0)}"
    assert group.getData(4, A_ID, 1) == 4
    assert group.getData(2, A_MODEL, 2) == MODEL_NUMBER
    assert group.getData(6, A_PROFILE_VEL, 4) == _pv(6)
    assert group.getData(1, A_RDT, 1) == 250


def test_bulk_read_raw_replies_in_listed_order(dxl):
    params = [5, A_ID, 0, 1, 0, 2, A_RDT, 0, 1, 0, 8, A_MODEL, 0, 2, 0]
    dxl.send_raw(dxl.build(BROADCAST_ID, 0x92, params))
    got = dxl.recv_raw(expected=12 + 12 + 13, timeout=0.5)
    assert len(got) == 37, f"bulk read: {len(got)} bytes [{hexs(got)}]"
    ids = [got[4], got[12 + 4], got[24 + 4]]
    assert ids == [5, 2, 8], f"bulk read reply order {ids}, expected [5, 2, 8]"
    assert got[9] == 5 and got[12 + 9] == 250 and got[24 + 9 : 24 + 11] == bytes([0x60, 0x04])


# ---- Fast Sync Read / Fast Bulk Read -----------------------------------------------------

def test_fast_sync_read(dxl):
    _distinct_profile_velocities(dxl)
    order = [3, 7, 4]
    group = GroupSyncRead(dxl.port, dxl.ph, A_PROFILE_VEL, 4)
    for dxl_id in order:
        assert group.addParam(dxl_id)
    result = group.fastSyncRead()
    assert result == COMM_SUCCESS, f"fast sync read: {describe(dxl.ph, result, 0)}"
    got = [group.getData(i, A_PROFILE_VEL, 4) for i in order]
    assert got == [_pv(i) for i in order], f"fast sync read values {got}"


def test_fast_sync_read_all_servos(dxl):
    group = GroupSyncRead(dxl.port, dxl.ph, A_ID, 1)
    for dxl_id in SERVO_IDS:
        assert group.addParam(dxl_id)
    result = group.fastSyncRead()
    assert result == COMM_SUCCESS, f"fast sync read: {describe(dxl.ph, result, 0)}"
    assert [group.getData(i, A_ID, 1) for i in SERVO_IDS] == SERVO_IDS


def _check_fast_reply(dxl, got: bytes, blocks: list[tuple[int, int]]):
    """blocks: [(id, data_len)] in the listed order. Returns {id: data bytes}."""
    want_len = 1 + sum(n + 4 for _, n in blocks)
    assert len(got) == want_len + 7, f"fast reply: {len(got)} bytes, expected {want_len + 7}: [{hexs(got)}]"
    assert got[:5] == bytes([0xFF, 0xFF, 0xFD, 0x00, 0xFE]), f"fast reply header/ID: [{hexs(got[:8])}]"
    assert got[5] | got[6] << 8 == want_len, f"fast reply LEN {got[5] | got[6] << 8}, expected {want_len}"
    assert got[7] == 0x55
    out = {}
    pos = 8
    for k, (dxl_id, n) in enumerate(blocks):
        assert got[pos] == 0, f"block {k}: error byte 0x{got[pos]:02X}"
        assert got[pos + 1] == dxl_id, f"block {k}: ID {got[pos + 1]}, expected {dxl_id} (listed order)"
        out[dxl_id] = got[pos + 2 : pos + 2 + n]
        crc_pos = pos + 2 + n
        crc = dxl.crc(got[:crc_pos])
        assert got[crc_pos : crc_pos + 2] == bytes([crc & 0xFF, crc >> 8]), (
            f"block {k}: CRC [{hexs(got[crc_pos:crc_pos + 2])}] is not the running CRC {crc:04X}"
        )
        pos = crc_pos + 2
    return out


def test_fast_sync_read_raw_layout(dxl):
    _distinct_profile_velocities(dxl)
    order = [3, 7, 4]
    dxl.send_raw(dxl.build(BROADCAST_ID, 0x8A, [A_PROFILE_VEL, 0, 4, 0] + order))
    got = dxl.recv_raw(expected=7 + 1 + 3 * 8, timeout=0.5)
    data = _check_fast_reply(dxl, got, [(i, 4) for i in order])
    for dxl_id in order:
        assert data[dxl_id] == bytes(le_bytes(_pv(dxl_id), 4)), f"ID {dxl_id} data [{hexs(data[dxl_id])}]"


def test_fast_sync_read_reply_is_not_stuffed(dxl):
    # Homing Offset -131073 = 0xFFFDFFFF, little-endian FF FF FD FF: would need stuffing elsewhere
    dxl.write_ok(2, 20, 4, -131073)
    dxl.write_ok(3, 20, 4, -131073)
    dxl.send_raw(dxl.build(BROADCAST_ID, 0x8A, [20, 0, 4, 0, 2, 3]))
    got = dxl.recv_raw(expected=7 + 1 + 2 * 8, timeout=0.5)
    data = _check_fast_reply(dxl, got, [(2, 4), (3, 4)])
    assert data[2] == bytes([0xFF, 0xFF, 0xFD, 0xFF]) and data[3] == bytes([0xFF, 0xFF, 0xFD, 0xFF])


def test_fast_bulk_read(dxl):
    _distinct_profile_velocities(dxl)
    group = GroupBulkRead(dxl.port, dxl.ph)
    assert group.addParam(5, A_ID, 1)
    assert group.addParam(2, A_PROFILE_VEL, 4)
    assert group.addParam(8, A_MODEL, 2)
    result = group.fastBulkRead()
    assert result == COMM_SUCCESS, f"fast bulk read: {describe(dxl.ph, result, 0)}"
    assert group.getData(5, A_ID, 1) == 5
    assert group.getData(2, A_PROFILE_VEL, 4) == _pv(2)
    assert group.getData(8, A_MODEL, 2) == MODEL_NUMBER


def test_fast_bulk_read_raw_layout(dxl):
    _distinct_profile_velocities(dxl)
    params = [5, A_ID, 0, 1, 0, 2, A_PROFILE_VEL, 0, 4, 0, 8, A_MODEL, 0, 2, 0]
    dxl.send_raw(dxl.build(BROADCAST_ID, 0x9A, params))
    got = dxl.recv_raw(expected=7 + 1 + (5 + 8 + 6), timeout=0.5)
    data = _check_fast_reply(dxl, got, [(5, 1), (2, 4), (8, 2)])
    assert data[5] == bytes([5]) and data[2] == bytes(le_bytes(_pv(2), 4)) and data[8] == bytes([0x60, 0x04])


def test_fast_sync_read_reference_example_layout(dxl):
    # reference §6: Fast Sync Read of 132/4 from IDs 3, 7, 4 - instruction bytes verbatim
    dxl.send_raw(bytes.fromhex("FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2"))
    got = dxl.recv_raw(expected=7 + 0x19, timeout=0.5)
    _check_fast_reply(dxl, got, [(3, 4), (7, 4), (4, 4)])
