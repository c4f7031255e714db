"""Status Return Level (68): 0 = Ping only, 1 = Ping + Read family, 2 = everything."""

import time

from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS, GroupBulkRead, GroupSyncRead

from conftest import A_LED, A_PROFILE_VEL, A_SRL, SERVO_IDS, describe


def _set_srl_blind(dxl, dxl_id, level):
    """Set SRL without relying on a reply (the reply policy is what is under test)."""
    dxl.ph.write1ByteTxOnly(dxl.port, dxl_id, A_SRL, level)
    time.sleep(0.05)


def test_srl0_answers_ping_only(dxl):
    _set_srl_blind(dxl, 1, 0)
    dxl.ping_ok(1)
    data, result, error = dxl.read(1, A_LED, 1)
    assert result == COMM_RX_TIMEOUT, f"read with SRL 0: {describe(dxl.ph, result, error)}"
    result, error = dxl.write(1, A_LED, 1, 1)
    assert result == COMM_RX_TIMEOUT, f"write with SRL 0: {describe(dxl.ph, result, error)}"
    result, error = dxl.ph.regWriteTxRx(dxl.port, 1, A_PROFILE_VEL, 4, [5, 0, 0, 0])
    assert result == COMM_RX_TIMEOUT, f"reg write with SRL 0: {describe(dxl.ph, result, error)}"
    # other servos keep SRL 2
    dxl.write_ok(2, A_LED, 1, 1)
    # the unanswered write was still executed
    _set_srl_blind(dxl, 1, 2)
    assert dxl.read_u(1, A_LED, 1) == 1, "write under SRL 0 was not executed"
    assert dxl.read_u(1, A_SRL, 1) == 2


def test_srl0_servo_still_in_broadcast_ping(dxl):
    _set_srl_blind(dxl, 4, 0)
    data, result = dxl.ph.broadcastPing(dxl.port)
    assert result == COMM_SUCCESS, describe(dxl.ph, result, 0)
    assert list(data.keys()) == SERVO_IDS, f"broadcast ping with servo 4 at SRL 0 saw {list(data.keys())}"


def test_srl0_sync_read_not_answered(dxl):
    _set_srl_blind(dxl, 2, 0)
    group = GroupSyncRead(dxl.port, dxl.ph, A_SRL, 1)
    assert group.addParam(2)
    result = group.txRxPacket()
    assert result == COMM_RX_TIMEOUT, f"sync read from SRL-0 servo: {describe(dxl.ph, result, 0)}"


def test_srl1_answers_ping_and_reads_not_writes(dxl):
    _set_srl_blind(dxl, 1, 1)
    dxl.ping_ok(1)
    assert dxl.read_u(1, A_SRL, 1) == 1
    result, error = dxl.write(1, A_LED, 1, 1)
    assert result == COMM_RX_TIMEOUT, f"write with SRL 1 must not be answered: {describe(dxl.ph, result, error)}"
    assert dxl.read_u(1, A_LED, 1) == 1, "write under SRL 1 was not executed"
    result, error = dxl.ph.regWriteTxRx(dxl.port, 1, A_PROFILE_VEL, 4, [5, 0, 0, 0])
    assert result == COMM_RX_TIMEOUT, f"reg write with SRL 1: {describe(dxl.ph, result, error)}"
    result = dxl.ph.clearMultiTurn(dxl.port, 1)[0]
    assert result == COMM_RX_TIMEOUT, f"clear with SRL 1 must not be answered: {describe(dxl.ph, result, 0)}"


def test_srl1_answers_sync_and_bulk_and_fast_reads(dxl):
    for dxl_id in (1, 2, 3):
        dxl.write_ok(dxl_id, A_PROFILE_VEL, 4, 10 * dxl_id)
        _set_srl_blind(dxl, dxl_id, 1)
    group = GroupSyncRead(dxl.port, dxl.ph, A_PROFILE_VEL, 4)
    for dxl_id in (1, 2, 3):
        assert group.addParam(dxl_id)
    result = group.txRxPacket()
    assert result == COMM_SUCCESS, f"sync read with SRL 1: {describe(dxl.ph, result, 0)}"
    assert [group.getData(i, A_PROFILE_VEL, 4) for i in (1, 2, 3)] == [10, 20, 30]
    result = group.fastSyncRead()
    assert result == COMM_SUCCESS, f"fast sync read with SRL 1: {describe(dxl.ph, result, 0)}"
    assert [group.getData(i, A_PROFILE_VEL, 4) for i in (1, 2, 3)] == [10, 20, 30]
    bulk = GroupBulkRead(dxl.port, dxl.ph)
    assert bulk.addParam(2, A_PROFILE_VEL, 4) and bulk.addParam(3, A_SRL, 1)
    result = bulk.txRxPacket()
    assert result == COMM_SUCCESS, f"bulk read with SRL 1: {describe(dxl.ph, result, 0)}"
    assert bulk.getData(2, A_PROFILE_VEL, 4) == 20 and bulk.getData(3, A_SRL, 1) == 1


def test_srl1_reboot_unanswered_then_srl_back_to_2(dxl):
    _set_srl_blind(dxl, 1, 1)
    result, error = dxl.ph.reboot(dxl.port, 1)
    assert result == COMM_RX_TIMEOUT, f"reboot with SRL 1 must not be answered: {describe(dxl.ph, result, error)}"
    time.sleep(0.25)
    assert dxl.read_u(1, A_SRL, 1) == 2, "SRL (RAM) not back to its default 2 after reboot"
    dxl.write_ok(1, A_LED, 1, 1)


def test_srl2_answers_writes(dxl):
    result, error = dxl.write(1, A_LED, 1, 1)
    assert result == COMM_SUCCESS and error == 0, describe(dxl.ph, result, error)
