"""Byte stuffing: values whose bytes contain FF FF FD.

-131073 = 0xFFFDFFFF, little-endian FF FF FD FF. It is a valid Goal Position in Extended
Position mode (4, range +-1048575) and a valid Homing Offset (+-1044479).
The Python SDK sends such writes *unstuffed* (its txPacket discards addStuffing's result), so the
emulator must frame by LEN; the read reply must be stuffed, and the SDK unstuffs it."""

import pytest
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead

from conftest import A_GOAL_POS, A_HOMING, A_OP_MODE, describe, hexs

VALUE = -131073
RAW = 0xFFFDFFFF


def test_goal_position_with_header_bytes_round_trip(dxl):
    dxl.write_ok(1, A_OP_MODE, 1, 4)
    dxl.write_ok(1, A_GOAL_POS, 4, VALUE)  # the SDK sends FF FF FD FF unstuffed
    value, result, error = dxl.ph.read4ByteTxRx(dxl.port, 1, A_GOAL_POS)
    assert result == COMM_SUCCESS and error == 0, f"read Goal Position: {describe(dxl.ph, result, error)}"
    assert value == RAW, f"Goal Position read 0x{value:08X}, expected 0x{RAW:08X}"


def test_homing_offset_with_header_bytes_round_trip(dxl):
    dxl.write_ok(2, A_HOMING, 4, VALUE)
    value, result, error = dxl.ph.read4ByteTxRx(dxl.port, 2, A_HOMING)
    assert result == COMM_SUCCESS and error == 0, f"read Homing Offset: {describe(dxl.ph, result, error)}"
    assert value == RAW, f"Homing Offset read 0x{value:08X}, expected 0x{RAW:08X}"


def test_read_reply_is_stuffed_on_the_wire(dxl):
    dxl.write_ok(1, A_HOMING, 4, VALUE)
    dxl.send_raw(dxl.build(1, 0x02, [A_HOMING, 0, 4, 0]))
    got = dxl.recv_raw(expected=16)
    body = bytes([0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x09, 0x00, 0x55, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0xFF])
    crc = dxl.crc(body)
    want = body + bytes([crc & 0xFF, crc >> 8])
    assert got == want, f"stuffed read reply: got [{hexs(got)}], expected [{hexs(want)}]"


def test_stuffed_instruction_is_accepted(dxl):
    # a spec-conforming (stuffed) write, as the C/C++ SDK would send it
    dxl.write_ok(3, A_OP_MODE, 1, 4)
    body = bytes([0xFF, 0xFF, 0xFD, 0x00, 0x03, 0x0A, 0x00, 0x03, A_GOAL_POS, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0xFF])
    crc = dxl.crc(body)
    dxl.send_raw(body + bytes([crc & 0xFF, crc >> 8]))
    got = dxl.recv_raw(expected=11)
    assert got == bytes.fromhex("FF FF FD 00 03 04 00 55 00") + got[9:11] and len(got) == 11, (
        f"reply to stuffed write: [{hexs(got)}]"
    )
    assert dxl.read_u(3, A_GOAL_POS, 4) == RAW


def test_unstuffed_sdk_packet_bytes_are_framed_by_len(dxl):
    # reference §3: the exact unstuffed bytes the Python SDK emits for 0x00FDFFFF at 116 on ID 1
    # (out of range here, so a Data Limit/Range error reply is the proof it was framed and parsed)
    dxl.send_raw(bytes.fromhex("FF FF FD 00 01 09 00 03 74 00 FF FF FD 00 C9 07"))
    got = dxl.recv_raw(expected=11)
    assert len(got) == 11 and got[:8] == bytes.fromhex("FF FF FD 00 01 04 00 55"), (
        f"reply to unstuffed SDK write: [{hexs(got)}]"
    )
    assert got[8] in (0x04, 0x06), f"Goal Position 0x00FDFFFF in mode 3: error 0x{got[8]:02X}"
    dxl.ping_ok(1)


@pytest.mark.parametrize("dxl_id", [1, 8])
def test_sync_read_of_stuffed_values(dxl, dxl_id):
    dxl.write_ok(dxl_id, A_HOMING, 4, VALUE)
    group = GroupSyncRead(dxl.port, dxl.ph, A_HOMING, 4)
    assert group.addParam(dxl_id)
    result = group.txRxPacket()
    assert result == COMM_SUCCESS, describe(dxl.ph, result, 0)
    assert group.getData(dxl_id, A_HOMING, 4) == RAW
