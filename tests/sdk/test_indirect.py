"""Indirect Address 1..56 / Indirect Data 1..56: aliases of RAM bytes 64..661 with the target
byte's access rights."""

from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead

from conftest import (
    A_GOAL_POS,
    A_HOMING,
    A_INDIRECT_ADDR_1,
    A_INDIRECT_ADDR_29,
    A_INDIRECT_DATA_1,
    A_INDIRECT_DATA_29,
    A_LED,
    A_PRESENT_POS,
    A_PROFILE_VEL,
    ERR_ACCESS,
    ERR_DATA_RANGE,
    describe,
    le_bytes,
)


def _map(dxl, dxl_id, first_addr_item, targets):
    data = []
    for t in targets:
        data += le_bytes(t, 2)
    dxl.write_bytes_ok(dxl_id, first_addr_item, data)


def test_indirect_read_of_present_position(dxl):
    dxl.write_ok(1, A_HOMING, 4, 1000)  # make Present Position clearly non-zero
    dxl.torque(1, True)  # mode 3 torque-on re-bases Present Position into [0, 4095] + 1000
    _map(dxl, 1, A_INDIRECT_ADDR_1, [132, 133, 134, 135])
    indirect = dxl.read_s(1, A_INDIRECT_DATA_1, 4)
    direct = dxl.read_s(1, A_PRESENT_POS, 4)
    assert direct >= 1000, f"Present Position {direct} with Homing Offset 1000"
    assert abs(indirect - direct) <= 3, f"Indirect Data 1..4 = {indirect}, Present Position = {direct}"


def test_indirect_read_of_writable_item(dxl):
    dxl.write_ok(1, A_PROFILE_VEL, 4, 0x1234)
    _map(dxl, 1, A_INDIRECT_ADDR_1, [112, 113, 114, 115])
    assert dxl.read_u(1, A_INDIRECT_DATA_1, 4) == 0x1234
    # bytes in a different order than the item
    _map(dxl, 1, A_INDIRECT_ADDR_1, [113, 112])
    assert dxl.read_bytes_ok(1, A_INDIRECT_DATA_1, 2) == [0x12, 0x34]


def test_indirect_write_through_to_goal_position(dxl):
    _map(dxl, 2, A_INDIRECT_ADDR_1, [116, 117, 118, 119])
    dxl.write_ok(2, A_INDIRECT_DATA_1, 4, 2345)
    assert dxl.read_u(2, A_GOAL_POS, 4) == 2345, "write through Indirect Data did not reach Goal Position"
    assert dxl.read_u(2, A_INDIRECT_DATA_1, 4) == 2345


def test_indirect_write_to_read_only_target_is_access_error(dxl):
    _map(dxl, 3, A_INDIRECT_ADDR_1, [132])
    result, error = dxl.write(3, A_INDIRECT_DATA_1, 1, 5)
    dxl.expect_error(result, error, ERR_ACCESS, "write Indirect Data 1 -> Present Position byte")


def test_upper_indirect_bank(dxl):
    dxl.write_ok(4, A_INDIRECT_ADDR_29, 2, A_LED)
    dxl.write_ok(4, A_INDIRECT_DATA_29, 1, 1)
    assert dxl.read_u(4, A_LED, 1) == 1, "Indirect Data 29 -> LED write not applied"
    assert dxl.read_u(4, A_INDIRECT_DATA_29, 1) == 1
    # the last pair: Indirect Address 56 (632) / Indirect Data 56 (661)
    dxl.write_ok(4, 632, 2, A_PROFILE_VEL)
    dxl.write_ok(4, A_PROFILE_VEL, 4, 77)
    assert dxl.read_u(4, 661, 1) == 77


def test_indirect_address_out_of_ram_is_range_error(dxl):
    for bad in (30, 63, 662, 1000):
        result, error = dxl.write(5, A_INDIRECT_ADDR_1, 2, bad)
        dxl.expect_error(result, error, ERR_DATA_RANGE, f"Indirect Address 1 = {bad}")
    assert dxl.read_u(5, A_INDIRECT_ADDR_1, 2) == 224
    dxl.write_ok(5, A_INDIRECT_ADDR_1, 2, 64)
    dxl.write_ok(5, A_INDIRECT_ADDR_1, 2, 661)


def test_sync_read_of_indirect_data(dxl):
    ids = [1, 2, 3, 4]
    for dxl_id in ids:
        dxl.write_ok(dxl_id, A_PROFILE_VEL, 4, 500 + dxl_id)
        _map(dxl, dxl_id, A_INDIRECT_ADDR_1, [112, 113, 114, 115, 65])
        dxl.write_ok(dxl_id, A_LED, 1, dxl_id % 2)
    group = GroupSyncRead(dxl.port, dxl.ph, A_INDIRECT_DATA_1, 5)
    for dxl_id in ids:
        assert group.addParam(dxl_id)
    for name, call in (("sync read", group.txRxPacket), ("fast sync read", group.fastSyncRead)):
        result = call()
        assert result == COMM_SUCCESS, f"{name} of Indirect Data: {describe(dxl.ph, result, 0)}"
        for dxl_id in ids:
            pv = group.getData(dxl_id, A_INDIRECT_DATA_1, 4)
            led = group.getData(dxl_id, A_INDIRECT_DATA_1 + 4, 1)
            assert (pv, led) == (500 + dxl_id, dxl_id % 2), f"{name} servo {dxl_id}: PV {pv} LED {led}"
