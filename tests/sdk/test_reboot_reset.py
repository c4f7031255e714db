"""Reboot (0x08), Factory Reset (0x06), Clear (0x10) and Control Table Backup (0x20)."""

import time

from dynamixel_sdk import BROADCAST_ID, COMM_SUCCESS

from conftest import (
    A_BACKUP_READY,
    A_BAUD,
    A_GOAL_POS,
    A_HOMING,
    A_ID,
    A_INDIRECT_ADDR_1,
    A_LED,
    A_MOVING,
    A_OP_MODE,
    A_POS_P_GAIN,
    A_PRESENT_POS,
    A_PROFILE_VEL,
    A_RDT,
    A_SECONDARY_ID,
    A_SRL,
    A_TORQUE,
    BAUD,
    BOOT_WAIT_S,
    ERR_RESULT_FAIL,
    SERVO_IDS,
    describe,
)

BACKUP_STORE = [0x01, 0x43, 0x54, 0x52, 0x4C]
BACKUP_RESTORE = [0x02, 0x43, 0x54, 0x52, 0x4C]


# ---- Reboot -------------------------------------------------------------------------------

def test_reboot_resets_ram_keeps_eeprom(dxl):
    dxl.write_ok(2, A_RDT, 1, 100)  # EEPROM
    dxl.write_ok(2, A_HOMING, 4, 300)  # EEPROM
    dxl.write_ok(2, A_LED, 1, 1)  # RAM
    dxl.write_ok(2, A_PROFILE_VEL, 4, 100)  # RAM
    dxl.write_ok(2, A_POS_P_GAIN, 2, 1000)  # RAM
    dxl.torque(2, True)
    dxl.reboot_ok(2)
    assert dxl.read_u(2, A_RDT, 1) == 100, "EEPROM Return Delay Time lost on reboot"
    assert dxl.read_s(2, A_HOMING, 4) == 300, "EEPROM Homing Offset lost on reboot"
    assert dxl.read_u(2, A_LED, 1) == 0, "LED (RAM) not reset by reboot"
    assert dxl.read_u(2, A_PROFILE_VEL, 4) == 0, "Profile Velocity (RAM) not reset by reboot"
    assert dxl.read_u(2, A_POS_P_GAIN, 2) == 800, "Position P Gain (RAM) not reset by reboot"
    assert dxl.read_u(2, A_TORQUE, 1) == 0, "torque still on after reboot"


def test_reboot_servo_silent_while_booting(dxl):
    result, error = dxl.ph.reboot(dxl.port, 3)
    assert result == COMM_SUCCESS and error == 0, f"reboot: {describe(dxl.ph, result, error)}"
    dxl.ping_timeout(3, "servo is booting for 100 ms after the reboot reply")
    dxl.ping_ok(4)  # the others are unaffected
    time.sleep(BOOT_WAIT_S)
    dxl.ping_ok(3)


def test_reboot_broadcast_reboots_all_without_reply(dxl):
    for dxl_id in SERVO_IDS:
        dxl.write_ok(dxl_id, A_LED, 1, 1)
    result, error = dxl.ph.reboot(dxl.port, BROADCAST_ID)
    assert result == COMM_SUCCESS
    stray = dxl.recv_raw(timeout=0.05)
    assert stray == b"", f"broadcast reboot was answered: {stray.hex(' ')}"
    time.sleep(BOOT_WAIT_S)
    for dxl_id in SERVO_IDS:
        assert dxl.read_u(dxl_id, A_LED, 1) == 0, f"servo {dxl_id} not rebooted by broadcast reboot"


# ---- Factory Reset ------------------------------------------------------------------------

def _dirty(dxl, dxl_id):
    dxl.write_ok(dxl_id, A_RDT, 1, 100)
    dxl.write_ok(dxl_id, A_HOMING, 4, 500)
    dxl.write_ok(dxl_id, A_OP_MODE, 1, 1)
    dxl.write_ok(dxl_id, A_SECONDARY_ID, 1, 77)
    dxl.write_ok(dxl_id, A_LED, 1, 1)


def _assert_reset(dxl, dxl_id):
    assert dxl.read_u(dxl_id, A_RDT, 1) == 250, "Return Delay Time not reset"
    assert dxl.read_s(dxl_id, A_HOMING, 4) == 0, "Homing Offset not reset"
    assert dxl.read_u(dxl_id, A_OP_MODE, 1) == 3, "Operating Mode not reset"
    assert dxl.read_u(dxl_id, A_SECONDARY_ID, 1) == 255, "Secondary ID not reset"
    assert dxl.read_u(dxl_id, A_LED, 1) == 0, "LED not reset"


def test_factory_reset_0x01_keeps_id_resets_baud_and_rest(dxl):
    _dirty(dxl, 3)
    dxl.write_ok(3, A_BAUD, 1, 2)
    dxl.set_baud(115200)
    result, error = dxl.ph.factoryReset(dxl.port, 3, 0x01)
    assert result == COMM_SUCCESS and error == 0, f"factory reset 0x01 (reply at the old baud): {describe(dxl.ph, result, error)}"
    time.sleep(BOOT_WAIT_S)
    dxl.ping_timeout(3, "baud was reset to 57600")
    dxl.set_baud(BAUD)
    dxl.ping_ok(3)
    assert dxl.read_u(3, A_ID, 1) == 3, "ID changed by factory reset 0x01"
    assert dxl.read_u(3, A_BAUD, 1) == 1, "Baud Rate not reset by factory reset 0x01"
    _assert_reset(dxl, 3)


def test_factory_reset_0x02_keeps_id_and_baud(dxl):
    _dirty(dxl, 4)
    dxl.write_ok(4, A_BAUD, 1, 2)
    dxl.set_baud(115200)
    result, error = dxl.ph.factoryReset(dxl.port, 4, 0x02)
    assert result == COMM_SUCCESS and error == 0, f"factory reset 0x02: {describe(dxl.ph, result, error)}"
    time.sleep(BOOT_WAIT_S)
    dxl.ping_ok(4)
    assert dxl.read_u(4, A_BAUD, 1) == 2, "Baud Rate changed by factory reset 0x02"
    assert dxl.read_u(4, A_ID, 1) == 4
    _assert_reset(dxl, 4)


def test_factory_reset_0xff_resets_id_to_1(dxl):
    # free ID 1 first so the reset servo does not collide: servo 1 -> 30, servo 5 -> 40
    dxl.write_ok(1, A_ID, 1, 30)
    dxl.write_ok(5, A_ID, 1, 40)
    _dirty(dxl, 40)
    result, error = dxl.ph.factoryReset(dxl.port, 40, 0xFF)
    assert result == COMM_SUCCESS and error == 0, f"factory reset 0xFF: {describe(dxl.ph, result, error)}"
    time.sleep(BOOT_WAIT_S)
    dxl.ping_timeout(40, "factory reset 0xFF sets ID 1")
    dxl.ping_ok(1)
    _assert_reset(dxl, 1)
    data, result = dxl.ph.broadcastPing(dxl.port)
    assert result == COMM_SUCCESS
    assert list(data.keys()) == [1, 2, 3, 4, 6, 7, 8, 30], f"IDs after reset: {list(data.keys())}"
    assert dxl.read_u(30, A_RDT, 1) == 250  # untouched servo


def test_broadcast_factory_reset_0xff_is_ignored(dxl):
    for dxl_id in (2, 6):
        dxl.write_ok(dxl_id, A_RDT, 1, 100)
    result, error = dxl.ph.factoryReset(dxl.port, BROADCAST_ID, 0xFF)
    assert result == COMM_SUCCESS
    time.sleep(BOOT_WAIT_S)
    stray = dxl.recv_raw(timeout=0.05)
    assert stray == b"", f"broadcast factory reset was answered: {stray.hex(' ')}"
    data, result = dxl.ph.broadcastPing(dxl.port)
    assert result == COMM_SUCCESS and list(data.keys()) == SERVO_IDS, f"IDs: {list(data.keys())}"
    for dxl_id in (2, 6):
        assert dxl.read_u(dxl_id, A_RDT, 1) == 100, f"servo {dxl_id} was reset by broadcast factory reset 0xFF"


def test_factory_reset_servo_silent_while_booting(dxl):
    result, error = dxl.ph.factoryReset(dxl.port, 6, 0x02)
    assert result == COMM_SUCCESS and error == 0
    dxl.ping_timeout(6, "servo is booting after factory reset")
    time.sleep(BOOT_WAIT_S)
    dxl.ping_ok(6)


# ---- Clear (multi-turn) -------------------------------------------------------------------

def _wait_stopped(dxl, dxl_id, goal, timeout=4.0):
    def arrived():
        pos = dxl.read_s(dxl_id, A_PRESENT_POS, 4)
        return abs(pos - goal) <= 10 and dxl.read_u(dxl_id, A_MOVING, 1) == 0

    return dxl.wait_until(arrived, timeout)


def test_clear_multi_turn(dxl):
    dxl.write_ok(1, A_OP_MODE, 1, 4)  # extended position
    dxl.torque(1, True)
    p0 = dxl.read_s(1, A_PRESENT_POS, 4)
    base = p0 - p0 % 4096  # start of the current turn
    # cross the nearest turn boundary by 300 pulses: at most ~2350 pulses of travel
    goal = base - 300 if p0 % 4096 < 2048 else base + 4096 + 300
    dxl.write_ok(1, A_GOAL_POS, 4, goal)
    time.sleep(0.05)
    assert dxl.read_u(1, A_MOVING, 1) == 1, "Moving not 1 right after a new goal"
    result, error = dxl.ph.clearMultiTurn(dxl.port, 1)
    dxl.expect_error(result, error, ERR_RESULT_FAIL, "Clear while moving")
    assert _wait_stopped(dxl, 1, goal), (
        f"servo did not reach {goal} (present {dxl.read_s(1, A_PRESENT_POS, 4)})"
    )
    result, error = dxl.ph.clearMultiTurn(dxl.port, 1)
    assert result == COMM_SUCCESS and error == 0, f"Clear when stopped: {describe(dxl.ph, result, error)}"
    pos = dxl.read_s(1, A_PRESENT_POS, 4)
    assert 0 <= pos <= 4095, f"Present Position {pos} after Clear, expected within one turn"
    assert abs(pos - goal % 4096) <= 20, f"Present Position {pos} after Clear, expected about {goal % 4096}"
    # the servo must stay where it is: Clear renumbers the turn, it is not a new goal
    time.sleep(0.3)
    later = dxl.read_s(1, A_PRESENT_POS, 4)
    goal_after = dxl.read_s(1, A_GOAL_POS, 4)
    assert abs(later - pos) <= 10, (
        f"servo moved after Clear: Present {pos} -> {later} (Goal Position now {goal_after})"
    )


def test_clear_reply_bytes(dxl):
    # reference §10 instruction verbatim; stopped servo answers with no error
    dxl.send_raw(bytes.fromhex("FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC"))
    got = dxl.recv_raw(expected=11)
    assert got == bytes.fromhex("FF FF FD 00 01 04 00 55 00 A1 0C"), f"Clear reply {got.hex(' ')}"


# ---- Control Table Backup -----------------------------------------------------------------

def _backup(dxl, dxl_id, params):
    rx, result, error = dxl.ph.txRxPacket(dxl.port, dxl.sdk_packet(dxl_id, 0x20, params))
    return result, error


def test_backup_store_needs_torque_off(dxl):
    dxl.torque(2, True)
    result, error = _backup(dxl, 2, BACKUP_STORE)
    dxl.expect_error(result, error, ERR_RESULT_FAIL, "Control Table Backup store with torque on")
    assert dxl.read_u(2, A_BACKUP_READY, 1) == 0, "Backup Ready set by a refused backup"


def test_backup_store_sets_backup_ready(dxl):
    assert dxl.read_u(2, A_BACKUP_READY, 1) == 0
    result, error = _backup(dxl, 2, BACKUP_STORE)
    assert result == COMM_SUCCESS and error == 0, f"backup store: {describe(dxl.ph, result, error)}"
    assert dxl.read_u(2, A_BACKUP_READY, 1) == 1, "Backup Ready not 1 after a backup"


def test_backup_store_reference_bytes(dxl):
    dxl.send_raw(bytes.fromhex("FF FF FD 00 01 08 00 20 01 43 54 52 4C 16 F5"))
    got = dxl.recv_raw(expected=11)
    assert got == bytes.fromhex("FF FF FD 00 01 04 00 55 00 A1 0C"), f"backup reply {got.hex(' ')}"
    assert dxl.read_u(1, A_BACKUP_READY, 1) == 1


def test_backup_restore(dxl):
    dxl.write_ok(5, A_RDT, 1, 100)
    dxl.write_ok(5, A_HOMING, 4, -200)
    dxl.write_ok(5, A_POS_P_GAIN, 2, 900)
    dxl.write_ok(5, A_PROFILE_VEL, 4, 50)
    dxl.write_ok(5, A_INDIRECT_ADDR_1, 2, A_PRESENT_POS)
    result, error = _backup(dxl, 5, BACKUP_STORE)
    assert result == COMM_SUCCESS and error == 0, f"backup store: {describe(dxl.ph, result, error)}"

    dxl.write_ok(5, A_RDT, 1, 200)
    dxl.write_ok(5, A_HOMING, 4, 100)
    dxl.write_ok(5, A_POS_P_GAIN, 2, 1000)
    dxl.write_ok(5, A_PROFILE_VEL, 4, 60)
    dxl.write_ok(5, A_INDIRECT_ADDR_1, 2, A_LED)
    dxl.write_ok(5, A_LED, 1, 1)
    dxl.write_ok(5, A_SRL, 1, 2)

    result, error = _backup(dxl, 5, BACKUP_RESTORE)
    assert result == COMM_SUCCESS and error == 0, f"backup restore: {describe(dxl.ph, result, error)}"
    time.sleep(BOOT_WAIT_S)  # restore reboots
    assert dxl.read_u(5, A_RDT, 1) == 100, "EEPROM (Return Delay Time) not restored"
    assert dxl.read_s(5, A_HOMING, 4) == -200, "EEPROM (Homing Offset) not restored"
    assert dxl.read_u(5, A_POS_P_GAIN, 2) == 900, "Position P Gain not restored"
    assert dxl.read_u(5, A_PROFILE_VEL, 4) == 50, "Profile Velocity not restored"
    assert dxl.read_u(5, A_INDIRECT_ADDR_1, 2) == A_PRESENT_POS, "Indirect Address 1 not restored"
    assert dxl.read_u(5, A_LED, 1) == 0, "LED not reset: restore must reboot"
    assert dxl.read_u(5, A_BACKUP_READY, 1) == 1, "Backup Ready cleared by restore"


def test_backup_is_per_servo(dxl):
    result, error = _backup(dxl, 7, BACKUP_STORE)
    assert result == COMM_SUCCESS and error == 0
    assert dxl.read_u(7, A_BACKUP_READY, 1) == 1
    assert dxl.read_u(8, A_BACKUP_READY, 1) == 0, "servo 8 reports a backup it never stored"
