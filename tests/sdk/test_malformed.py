"""Bad input on the wire: silently dropped packets, garbage before a valid packet, packets for
other IDs, broadcast instructions that must not be answered."""

import pytest
from dynamixel_sdk import BROADCAST_ID, COMM_RX_TIMEOUT, COMM_SUCCESS

from conftest import A_LED, MODEL_NUMBER, SERVO_IDS, describe, hexs


def _expect_silence(dxl, packet: bytes, what: str):
    dxl.send_raw(packet)
    # the SDK's own receive path: a dropped packet means COMM_RX_TIMEOUT
    dxl.port.setPacketTimeout(11)
    rx, result = dxl.ph.rxPacket(dxl.port, False)
    assert result == COMM_RX_TIMEOUT, (
        f"{what} [{hexs(packet)}] must be dropped silently; SDK got {describe(dxl.ph, result, 0)} [{hexs(rx)}]"
    )
    late = dxl.recv_raw(timeout=0.05)
    assert late == b"", f"{what}: late bytes [{hexs(late)}]"


def test_crc_error_is_dropped(dxl):
    _expect_silence(dxl, dxl.build(1, 0x01, bad_crc=True), "ping with a bad CRC")
    dxl.ping_ok(1)


def test_crc_error_on_write_is_not_executed(dxl):
    _expect_silence(dxl, dxl.build(1, 0x03, [A_LED, 0, 1], bad_crc=True), "write LED=1 with a bad CRC")
    assert dxl.read_u(1, A_LED, 1) == 0, "a write with a bad CRC was executed"


@pytest.mark.parametrize("reserved", [0x01, 0xFD, 0xFF])
def test_nonzero_reserved_byte_is_dropped(dxl, reserved):
    _expect_silence(dxl, dxl.build(1, 0x01, reserved=reserved), f"ping with reserved byte 0x{reserved:02X}")
    dxl.ping_ok(1)


@pytest.mark.parametrize(
    "inst,params,what",
    [
        (0x02, [132, 0, 4], "read with 3 parameter bytes"),
        (0x02, [132], "read with 1 parameter byte"),
        (0x03, [A_LED], "write with only 1 address byte"),
    ],
)
def test_malformed_parameter_length_is_dropped(dxl, inst, params, what):
    _expect_silence(dxl, dxl.build(1, inst, params), what)
    dxl.ping_ok(1)
    assert dxl.read_u(1, A_LED, 1) == 0


def test_garbage_before_valid_packet(dxl):
    dxl.port.writePort(bytes([0x00, 0x13, 0xFF, 0x55, 0xAA, 0xFD, 0xFF, 0xFF, 0x00, 0x7E]))
    model, result, error = dxl.ping(1)
    assert result == COMM_SUCCESS and error == 0, f"ping after garbage: {describe(dxl.ph, result, error)}"
    assert model == MODEL_NUMBER


def test_bad_crc_packet_then_valid_packet_back_to_back(dxl):
    dxl.port.writePort(dxl.build(1, 0x01, bad_crc=True))
    dxl.ping_ok(2)
    dxl.ping_ok(1)


def test_garbage_then_write_and_read(dxl):
    dxl.port.writePort(bytes(range(0x20, 0x40)))
    dxl.write_ok(3, A_LED, 1, 1)
    dxl.port.writePort(bytes([0xFF] * 7))
    assert dxl.read_u(3, A_LED, 1) == 1


def test_packet_for_absent_id_is_ignored(dxl):
    result, error = dxl.write(9, A_LED, 1, 1)
    assert result == COMM_RX_TIMEOUT, f"write to absent ID 9: {describe(dxl.ph, result, error)}"
    for dxl_id in SERVO_IDS:
        assert dxl.read_u(dxl_id, A_LED, 1) == 0, f"servo {dxl_id} executed a write addressed to ID 9"


def test_broadcast_write_executes_without_reply(dxl):
    result, error = dxl.write(BROADCAST_ID, A_LED, 1, 1)  # SDK does not wait for broadcast
    assert result == COMM_SUCCESS, describe(dxl.ph, result, error)
    stray = dxl.recv_raw(timeout=0.1)
    assert stray == b"", f"broadcast write was answered: [{hexs(stray)}]"
    for dxl_id in SERVO_IDS:
        assert dxl.read_u(dxl_id, A_LED, 1) == 1, f"servo {dxl_id} did not execute the broadcast write"


def test_broadcast_read_is_not_answered(dxl):
    dxl.send_raw(dxl.build(BROADCAST_ID, 0x02, [A_LED, 0, 1, 0]))
    stray = dxl.recv_raw(timeout=0.15)
    assert stray == b"", f"broadcast Read was answered: [{hexs(stray)}]"
    dxl.ping_ok(1)
