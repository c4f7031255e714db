"""Bus Watchdog (98) and latched hardware errors (70) with the status alert bit."""

import time

from dynamixel_sdk import COMM_SUCCESS

from conftest import (
    A_GOAL_POS,
    A_GOAL_PWM,
    A_GOAL_VEL,
    A_HW_ERROR,
    A_MAX_VOLT,
    A_MOVING,
    A_OP_MODE,
    A_PRESENT_POS,
    A_PRESENT_PWM,
    A_PRESENT_VEL,
    A_PWM_LIMIT,
    A_SHUTDOWN,
    A_TEMP_LIMIT,
    A_TORQUE,
    A_WATCHDOG,
    ALERT,
    ERR_DATA_RANGE,
    describe,
)

# ---- Bus Watchdog -------------------------------------------------------------------------


def test_bus_watchdog_trips_and_blocks_goals(dxl):
    dxl.torque(1, True)
    present = dxl.read_s(1, A_PRESENT_POS, 4)
    dxl.write_ok(1, A_WATCHDOG, 1, 5)  # 100 ms
    time.sleep(0.3)  # silence on the bus
    assert dxl.read_u(1, A_WATCHDOG, 1) == 0xFF, "Bus Watchdog did not trip (read 0xFF) after 300 ms of silence"
    result, error = dxl.write(1, A_GOAL_POS, 4, present)
    dxl.expect_error(result, error, ERR_DATA_RANGE, "Goal Position write after watchdog expiry")
    result, error = dxl.write(1, A_GOAL_VEL, 4, 0)
    dxl.expect_error(result, error, ERR_DATA_RANGE, "Goal Velocity write after watchdog expiry")
    dxl.write_ok(1, A_WATCHDOG, 1, 0)
    assert dxl.read_u(1, A_WATCHDOG, 1) == 0
    dxl.write_ok(1, A_GOAL_POS, 4, present)
    assert dxl.read_u(1, A_HW_ERROR, 1) == 0, "the watchdog must not set a hardware error"


def test_bus_watchdog_cleared_velocity_servo_moves_again(dxl):
    """e-Manual, Bus Watchdog(98): after expiry the servo stops and refuses goals; writing 0 clears
    the error and new goals work. The expiry had zeroed Goal PWM, which limits the output in
    velocity mode, so the cleared servo accepted Goal Velocity 60 and never moved."""
    dxl.write_ok(7, A_OP_MODE, 1, 1)
    dxl.torque(7, True)
    dxl.write_ok(7, A_GOAL_VEL, 4, 50)
    dxl.write_ok(7, A_WATCHDOG, 1, 5)  # 100 ms
    time.sleep(0.4)  # silence on the bus
    assert dxl.read_s(7, A_WATCHDOG, 1) == -1, "Bus Watchdog did not expire after 400 ms of silence"
    result, error = dxl.write(7, A_GOAL_VEL, 4, 60)
    dxl.expect_error(result, error, ERR_DATA_RANGE, "Goal Velocity write after watchdog expiry")
    time.sleep(1.0)
    stopped = dxl.read_s(7, A_PRESENT_VEL, 4)
    assert abs(stopped) <= 1, f"Present Velocity {stopped} a second after the expiry, expected a stop"

    dxl.write_ok(7, A_WATCHDOG, 1, 0)
    assert dxl.read_s(7, A_WATCHDOG, 1) == 0
    dxl.write_ok(7, A_GOAL_VEL, 4, 60)
    assert dxl.read_s(7, A_GOAL_VEL, 4) == 60
    assert dxl.read_u(7, A_TORQUE, 1) == 1
    assert dxl.read_u(7, A_HW_ERROR, 1) == 0, "the watchdog must not set a hardware error"
    pwm_limit = dxl.read_u(7, A_PWM_LIMIT, 2)
    goal_pwm = dxl.read_s(7, A_GOAL_PWM, 2)
    assert goal_pwm == pwm_limit, f"Goal PWM {goal_pwm} after the expiry, expected PWM Limit {pwm_limit} (a limit in velocity mode)"
    time.sleep(1.0)
    velocity = dxl.read_s(7, A_PRESENT_VEL, 4)
    assert abs(velocity - 60) <= 5, f"Present Velocity {velocity} a second after Goal Velocity 60, expected 60 +- 5"
    assert dxl.read_u(7, A_MOVING, 1) == 1, "Moving not 1 after the watchdog was cleared"
    assert dxl.read_s(7, A_PRESENT_PWM, 2) != 0, "Present PWM 0 after the watchdog was cleared"


def test_bus_watchdog_restarted_by_traffic(dxl):
    dxl.torque(1, True)
    dxl.write_ok(1, A_WATCHDOG, 1, 10)  # 200 ms
    for _ in range(12):  # 0.6 s of traffic, one packet every 50 ms
        time.sleep(0.05)
        dxl.ping_ok(1)
    assert dxl.read_u(1, A_WATCHDOG, 1) == 10, "watchdog tripped although the servo was pinged every 50 ms"
    time.sleep(0.4)
    assert dxl.read_u(1, A_WATCHDOG, 1) == 0xFF, "watchdog did not trip after 400 ms of silence"


def test_bus_watchdog_idle_with_torque_off(dxl):
    dxl.write_ok(2, A_WATCHDOG, 1, 5)
    time.sleep(0.3)
    assert dxl.read_u(2, A_WATCHDOG, 1) == 5, "watchdog counted down with torque off"
    dxl.write_ok(2, A_GOAL_POS, 4, 100)


# ---- Hardware errors ----------------------------------------------------------------------


def _wait_hw_error(dxl, dxl_id, bit, timeout=1.0):
    last = {}
    # a real servo latches within a control period, whatever the bus traffic; poll gently
    time.sleep(0.05)

    def check():
        data, result, error = dxl.read(dxl_id, A_HW_ERROR, 1)
        last.update(result=result, error=error, data=data)
        return result == COMM_SUCCESS and data and data[0] & bit

    ok = dxl.wait_until(check, timeout)
    assert ok, (
        f"Hardware Error Status bit 0x{bit:02X} not set within {timeout} s: "
        f"{describe(dxl.ph, last.get('result', 0), last.get('error', 0))} data={last.get('data')}"
    )
    return last


def test_input_voltage_error_latches_and_shuts_down(dxl):
    dxl.write_ok(3, A_SHUTDOWN, 1, 0x35)
    result, error = dxl.write(3, A_MAX_VOLT, 2, 100)  # 10.0 V < 12.0 V supply
    assert result == COMM_SUCCESS and error & 0x7F == 0, f"write Max Voltage Limit 100: {describe(dxl.ph, result, error)}"
    last = _wait_hw_error(dxl, 3, 0x01)
    assert last["error"] & ALERT, f"read reply lacks the alert bit: error 0x{last['error']:02X}"
    assert last["error"] & 0x7F == 0, f"read reply has an error number: 0x{last['error']:02X}"
    model, result, error = dxl.ping(3)
    assert result == COMM_SUCCESS and error & ALERT, f"ping reply lacks the alert bit: {describe(dxl.ph, result, error)}"
    model, result, error = dxl.ping(4)
    assert result == COMM_SUCCESS and error == 0, f"servo 4 must be unaffected: {describe(dxl.ph, result, error)}"

    result, error = dxl.write(3, A_TORQUE, 1, 1)
    assert result == COMM_SUCCESS and error & ALERT, f"torque-on reply: {describe(dxl.ph, result, error)}"
    time.sleep(0.05)
    assert dxl.read_u(3, A_TORQUE, 1, allow_alert=True) == 0, "torque on while an input-voltage shutdown is latched"

    # restoring the limit does not clear the latch; only reboot does
    dxl.write_ok(3, A_MAX_VOLT, 2, 160, allow_alert=True)
    time.sleep(0.05)
    assert dxl.read_u(3, A_HW_ERROR, 1, allow_alert=True) & 0x01, "error cleared without reboot"
    result, error = dxl.ph.reboot(dxl.port, 3)
    assert result == COMM_SUCCESS and error & 0x7F == 0, f"reboot: {describe(dxl.ph, result, error)}"
    time.sleep(0.25)
    data, result, error = dxl.read(3, A_HW_ERROR, 1)
    assert result == COMM_SUCCESS and error == 0 and data == [0], (
        f"after reboot: {describe(dxl.ph, result, error)} Hardware Error Status {data}"
    )
    dxl.torque(3, True)
    assert dxl.read_u(3, A_TORQUE, 1) == 1


def test_overheating_error_with_default_shutdown(dxl):
    assert dxl.read_u(5, A_SHUTDOWN, 1) == 0x34
    result, error = dxl.write(5, A_TEMP_LIMIT, 1, 20)  # below the 25 degC ambient
    assert result == COMM_SUCCESS and error & 0x7F == 0, f"write Temperature Limit 20: {describe(dxl.ph, result, error)}"
    last = _wait_hw_error(dxl, 5, 0x04)
    assert last["error"] & ALERT, f"reply lacks the alert bit: error 0x{last['error']:02X}"
    result, error = dxl.write(5, A_TORQUE, 1, 1)
    assert result == COMM_SUCCESS and error & ALERT, f"torque-on reply: {describe(dxl.ph, result, error)}"
    time.sleep(0.05)
    assert dxl.read_u(5, A_TORQUE, 1, allow_alert=True) == 0, "torque on while an overheating shutdown is latched"
    dxl.write_ok(5, A_TEMP_LIMIT, 1, 80, allow_alert=True)
    dxl.reboot_ok(5, allow_alert=True)
    data, result, error = dxl.read(5, A_HW_ERROR, 1)
    assert result == COMM_SUCCESS and error == 0 and data == [0], (
        f"after reboot: {describe(dxl.ph, result, error)} Hardware Error Status {data}"
    )
