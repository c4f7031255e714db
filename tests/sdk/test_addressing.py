"""ID change, Secondary ID and Baud Rate: who hears a packet and who answers it."""

import pytest
from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS

from conftest import (
    A_BAUD,
    A_ID,
    A_LED,
    A_PROFILE_VEL,
    A_RDT,
    A_SECONDARY_ID,
    BAUD,
    SERVO_IDS,
    describe,
)

BAUD_CODES = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000, 5: 3_000_000, 6: 4_000_000}


# ---- ID -----------------------------------------------------------------------------------

def test_id_change_replies_from_old_id_then_answers_at_new_id(dxl):
    # the SDK only accepts the reply if it comes from the ID it wrote to (the old one)
    result, error = dxl.write(1, A_ID, 1, 20)
    assert result == COMM_SUCCESS and error == 0, f"write ID 1 -> 20: {describe(dxl.ph, result, error)}"
    dxl.ping_timeout(1, "servo moved to ID 20")
    dxl.ping_ok(20)
    assert dxl.read_u(20, A_ID, 1) == 20
    data, result = dxl.ph.broadcastPing(dxl.port)
    assert result == COMM_SUCCESS
    assert list(data.keys()) == [2, 3, 4, 5, 6, 7, 8, 20], f"broadcast ping after ID change: {list(data.keys())}"


def test_id_change_survives_reboot(dxl):
    dxl.write_ok(6, A_ID, 1, 60)
    dxl.reboot_ok(60)
    dxl.ping_ok(60)
    dxl.ping_timeout(6)


# ---- Secondary ID -------------------------------------------------------------------------

def test_secondary_id_executes_ram_write_without_reply(dxl):
    dxl.write_ok(3, A_SECONDARY_ID, 1, 100)
    result, error = dxl.write(100, A_LED, 1, 1)
    assert result == COMM_RX_TIMEOUT, f"write via secondary ID must not be answered: {describe(dxl.ph, result, error)}"
    assert dxl.read_u(3, A_LED, 1) == 1, "RAM write via secondary ID 100 was not executed by servo 3"
    for dxl_id in SERVO_IDS:
        if dxl_id != 3:
            assert dxl.read_u(dxl_id, A_LED, 1) == 0, f"servo {dxl_id} executed a write to ID 100"


def test_secondary_id_does_not_write_eeprom(dxl):
    dxl.write_ok(3, A_SECONDARY_ID, 1, 100)
    result, error = dxl.write(100, A_RDT, 1, 100)
    assert result == COMM_RX_TIMEOUT, describe(dxl.ph, result, error)
    assert dxl.read_u(3, A_RDT, 1) == 250, "EEPROM write via secondary ID was executed"


def test_secondary_id_read_and_ping_not_answered(dxl):
    dxl.write_ok(3, A_SECONDARY_ID, 1, 100)
    data, result, error = dxl.read(100, A_LED, 1)
    assert result == COMM_RX_TIMEOUT, f"read via secondary ID: {describe(dxl.ph, result, error)}"
    dxl.ping_timeout(100, "secondary ID is never answered")
    dxl.ping_ok(3)


def test_secondary_id_shared_by_group(dxl):
    for dxl_id in (5, 6, 7, 8):
        dxl.write_ok(dxl_id, A_SECONDARY_ID, 1, 100)
    result, error = dxl.write(100, A_PROFILE_VEL, 4, 321)
    assert result == COMM_RX_TIMEOUT, describe(dxl.ph, result, error)
    for dxl_id in SERVO_IDS:
        want = 321 if dxl_id >= 5 else 0
        got = dxl.read_u(dxl_id, A_PROFILE_VEL, 4)
        assert got == want, f"servo {dxl_id} Profile Velocity {got} after write to secondary ID 100, expected {want}"


def test_primary_id_wins_over_secondary(dxl):
    # servo 4's secondary ID equals servo 2's primary ID: a packet to 2 gets servo 2's reply,
    # uncorrupted (whether servo 4 also executes it is left open by the reference)
    dxl.write_ok(4, A_SECONDARY_ID, 1, 2)
    dxl.write_ok(2, A_LED, 1, 1)
    assert dxl.read_u(2, A_LED, 1) == 1
    dxl.ping_ok(2)


# ---- Baud rate ----------------------------------------------------------------------------

@pytest.mark.parametrize("code", [0, 2, 3, 4, 5, 6])
def test_baud_change_takes_effect_after_reply(dxl, code):
    bps = BAUD_CODES[code]
    result, error = dxl.write(1, A_BAUD, 1, code)
    assert result == COMM_SUCCESS and error == 0, (
        f"write Baud Rate {code}: the reply must still come at 57600: {describe(dxl.ph, result, error)}"
    )
    dxl.ping_timeout(1, f"servo 1 now listens at {bps} bps, port is at {BAUD}")
    dxl.ping_ok(2)
    dxl.set_baud(bps)
    dxl.ping_ok(1)
    assert dxl.read_u(1, A_BAUD, 1) == code
    dxl.ping_timeout(2, f"servo 2 is still at {BAUD}, port is at {bps}")
    # and back again
    dxl.write_ok(1, A_BAUD, 1, 1)
    dxl.set_baud(BAUD)
    dxl.ping_ok(1)
    dxl.ping_ok(2)


def test_baud_rate_survives_reboot(dxl):
    dxl.write_ok(2, A_BAUD, 1, 2)
    dxl.set_baud(115200)
    dxl.reboot_ok(2)
    dxl.ping_ok(2)
    dxl.set_baud(BAUD)
    dxl.ping_timeout(2)


def test_mixed_baud_bus_broadcast_ping(dxl):
    dxl.write_ok(3, A_BAUD, 1, 3)
    dxl.write_ok(5, A_BAUD, 1, 3)
    data, result = dxl.ph.broadcastPing(dxl.port)
    assert result == COMM_SUCCESS
    assert list(data.keys()) == [1, 2, 4, 6, 7, 8], f"at 57600: {list(data.keys())}"
    dxl.set_baud(1_000_000)
    data, result = dxl.ph.broadcastPing(dxl.port)
    assert result == COMM_SUCCESS
    assert list(data.keys()) == [3, 5], f"at 1 Mbps: {list(data.keys())}"
