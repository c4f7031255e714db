"""Ping, broadcast ping, factory defaults and the always-changing status items."""

import time

import pytest
from dynamixel_sdk import BROADCAST_ID, COMM_SUCCESS

from conftest import (
    A_TEMPERATURE,
    A_TICK,
    A_VOLTAGE,
    FIRMWARE_VERSION,
    MODEL_NUMBER,
    SERVO_IDS,
    describe,
    hexs,
)


@pytest.mark.parametrize("dxl_id", SERVO_IDS)
def test_ping_reports_model_1120(dxl, dxl_id):
    model, result, error = dxl.ping(dxl_id)
    assert result == COMM_SUCCESS, f"ping {dxl_id}: {describe(dxl.ph, result, error)}"
    assert error == 0, f"ping {dxl_id}: {describe(dxl.ph, result, error)}"
    assert model == MODEL_NUMBER, f"ping {dxl_id}: model number {model}, expected {MODEL_NUMBER}"


def test_ping_reply_bytes_exact(dxl):
    # reference §10: ping ID 1 and the XM540 FW48 reply
    dxl.send_raw(bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E"))
    got = dxl.recv_raw(expected=14)
    want = bytes.fromhex("FF FF FD 00 01 07 00 55 00 60 04 30 EA DA")
    assert got == want, f"ping ID 1 reply: got [{hexs(got)}], expected [{hexs(want)}]"


@pytest.mark.parametrize("dxl_id", [0, 9, 100, 252])
def test_ping_absent_id_times_out(dxl, dxl_id):
    dxl.ping_timeout(dxl_id, "no servo has this ID")


def test_broadcast_ping_lists_all_servos_in_id_order(dxl):
    data, result = dxl.ph.broadcastPing(dxl.port)
    assert result == COMM_SUCCESS, f"broadcastPing: {describe(dxl.ph, result, 0)}"
    assert list(data.keys()) == SERVO_IDS, f"broadcastPing IDs in arrival order: {list(data.keys())}"
    for dxl_id, (model, fw) in data.items():
        assert (model, fw) == (MODEL_NUMBER, FIRMWARE_VERSION), (
            f"broadcastPing id {dxl_id}: model {model} fw {fw}, expected {MODEL_NUMBER}/{FIRMWARE_VERSION}"
        )


def test_broadcast_ping_raw_replies_contiguous_and_ordered(dxl):
    dxl.send_raw(dxl.build(BROADCAST_ID, 0x01))
    got = dxl.recv_raw(expected=14 * 8, timeout=1.0, settle=0.1)
    assert len(got) == 14 * 8, f"broadcast ping: {len(got)} bytes, expected 8 x 14: [{hexs(got)}]"
    ids = []
    for i in range(8):
        chunk = got[14 * i : 14 * (i + 1)]
        assert chunk[:8] == bytes([0xFF, 0xFF, 0xFD, 0x00, chunk[4], 0x07, 0x00, 0x55]), (
            f"reply {i} malformed: [{hexs(chunk)}]"
        )
        assert chunk[8:12] == bytes([0x00, 0x60, 0x04, FIRMWARE_VERSION]), f"reply {i} params: [{hexs(chunk)}]"
        crc = dxl.crc(chunk[:12])
        assert chunk[12:] == bytes([crc & 0xFF, crc >> 8]), f"reply {i} bad CRC: [{hexs(chunk)}]"
        ids.append(chunk[4])
    assert ids == SERVO_IDS, f"broadcast ping reply order {ids}, expected {SERVO_IDS}"


def _defaults(dxl_id):
    items = [
        (0, 2, MODEL_NUMBER, "Model Number"),
        (6, 1, FIRMWARE_VERSION, "Firmware Version"),
        (7, 1, dxl_id, "ID"),
        (8, 1, 1, "Baud Rate"),
        (9, 1, 250, "Return Delay Time"),
        (10, 1, 0, "Drive Mode"),
        (11, 1, 3, "Operating Mode"),
        (12, 1, 255, "Secondary ID"),
        (13, 1, 2, "Protocol Type"),
        (20, 4, 0, "Homing Offset"),
        (24, 4, 10, "Moving Threshold"),
        (31, 1, 80, "Temperature Limit"),
        (32, 2, 160, "Max Voltage Limit"),
        (34, 2, 95, "Min Voltage Limit"),
        (36, 2, 885, "PWM Limit"),
        (38, 2, 2047, "Current Limit"),
        (44, 4, 128, "Velocity Limit"),
        (48, 4, 4095, "Max Position Limit"),
        (52, 4, 0, "Min Position Limit"),
        (56, 1, 3, "External Port Mode 1"),
        (57, 1, 3, "External Port Mode 2"),
        (58, 1, 3, "External Port Mode 3"),
        (60, 1, 0, "Startup Configuration"),
        (63, 1, 0x34, "Shutdown"),
        (64, 1, 0, "Torque Enable"),
        (65, 1, 0, "LED"),
        (68, 1, 2, "Status Return Level"),
        (69, 1, 0, "Registered Instruction"),
        (70, 1, 0, "Hardware Error Status"),
        (76, 2, 1920, "Velocity I Gain"),
        (78, 2, 100, "Velocity P Gain"),
        (80, 2, 0, "Position D Gain"),
        (82, 2, 0, "Position I Gain"),
        (84, 2, 800, "Position P Gain"),
        (88, 2, 0, "Feedforward 2nd Gain"),
        (90, 2, 0, "Feedforward 1st Gain"),
        (98, 1, 0, "Bus Watchdog"),
        (108, 4, 0, "Profile Acceleration"),
        (112, 4, 0, "Profile Velocity"),
        (122, 1, 0, "Moving"),
        (144, 2, 120, "Present Input Voltage"),
        (147, 1, 0, "Backup Ready"),
    ]
    items += [(168 + 2 * k, 2, 224 + k, f"Indirect Address {k + 1}") for k in range(28)]
    items += [(578 + 2 * k, 2, 634 + k, f"Indirect Address {k + 29}") for k in range(28)]
    return items


@pytest.mark.parametrize("dxl_id", SERVO_IDS)
def test_factory_defaults(dxl, dxl_id):
    wrong = []
    for addr, size, want, name in _defaults(dxl_id):
        data, result, error = dxl.read(dxl_id, addr, size)
        if result != COMM_SUCCESS or error != 0 or len(data) != size:
            wrong.append(f"{name} ({addr}): {describe(dxl.ph, result, error)} data=[{hexs(data)}]")
            continue
        got = sum(b << (8 * i) for i, b in enumerate(data))
        if got != want:
            wrong.append(f"{name} ({addr}): {got}, expected {want}")
    assert not wrong, f"servo {dxl_id} defaults differ:\n  " + "\n  ".join(wrong)


def test_realtime_tick_advances_in_ms(dxl):
    t0 = dxl.read_u(1, A_TICK, 2)
    time.sleep(0.3)
    t1 = dxl.read_u(1, A_TICK, 2)
    assert 0 <= t0 <= 32767 and 0 <= t1 <= 32767, f"Realtime Tick out of 0..32767: {t0}, {t1}"
    delta = (t1 - t0) % 32768
    assert 200 <= delta <= 1500, f"Realtime Tick advanced {delta} in ~300 ms (from {t0} to {t1})"


@pytest.mark.parametrize("dxl_id", [1, 8])
def test_present_voltage_and_temperature(dxl, dxl_id):
    volts = dxl.read_u(dxl_id, A_VOLTAGE, 2)
    assert volts == 120, f"Present Input Voltage {volts}, expected 120 (12.0 V)"
    temp = dxl.read_u(dxl_id, A_TEMPERATURE, 1)
    assert 24 <= temp <= 27, f"Present Temperature {temp}, expected about 25 degC"
