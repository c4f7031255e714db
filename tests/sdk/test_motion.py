"""Torque, position and velocity control as the SDK observes it, and operating-mode side effects."""

import time

from conftest import (
    A_CURRENT_LIMIT,
    A_GOAL_CURRENT,
    A_GOAL_POS,
    A_GOAL_PWM,
    A_GOAL_VEL,
    A_HOMING,
    A_MOVING,
    A_OP_MODE,
    A_PRESENT_POS,
    A_PRESENT_VEL,
    A_PROFILE_ACC,
    A_PROFILE_VEL,
    A_PWM_LIMIT,
    A_TORQUE,
)


def test_torque_on_sets_goal_to_present_position(dxl):
    dxl.write_ok(1, A_GOAL_POS, 4, 3000)  # a stale goal far away must not be chased
    dxl.torque(1, True)
    goal = dxl.read_s(1, A_GOAL_POS, 4)
    present = dxl.read_s(1, A_PRESENT_POS, 4)
    assert abs(goal - present) <= 5, f"after torque on: Goal Position {goal}, Present Position {present}"
    time.sleep(0.3)
    later = dxl.read_s(1, A_PRESENT_POS, 4)
    assert abs(later - present) <= 10, f"servo jumped after torque on: {present} -> {later}"


def test_present_position_single_turn_after_torque_on_mode3(dxl):
    dxl.torque(2, True)
    pos = dxl.read_s(2, A_PRESENT_POS, 4)
    assert 0 <= pos <= 4095, f"Present Position {pos} in mode 3 after torque on"


def test_homing_offset_shifts_present_position(dxl):
    dxl.torque(2, True)
    p0 = dxl.read_s(2, A_PRESENT_POS, 4)
    dxl.torque(2, False)
    dxl.write_ok(2, A_HOMING, 4, 500)
    dxl.torque(2, True)
    p1 = dxl.read_s(2, A_PRESENT_POS, 4)
    assert 500 <= p1 <= 4095 + 500, f"Present Position {p1} with Homing Offset 500"
    assert abs(p1 - (p0 + 500)) <= 5, f"Present Position {p1}, expected about {p0} + 500"


def test_position_mode_moves_to_goal(dxl):
    dxl.torque(3, True)
    p0 = dxl.read_s(3, A_PRESENT_POS, 4)
    goal = p0 + 200 if p0 + 200 <= 4095 else p0 - 200
    dxl.write_ok(3, A_GOAL_POS, 4, goal)
    saw_moving = False
    deadline = time.monotonic() + 3.0
    pos = p0
    while time.monotonic() < deadline:
        if dxl.read_u(3, A_MOVING, 1) == 1:
            saw_moving = True
        pos = dxl.read_s(3, A_PRESENT_POS, 4)
        if abs(pos - goal) <= 10 and saw_moving:
            break
        time.sleep(0.005)
    assert saw_moving, "Moving (122) never read 1 during a 200-pulse move"
    assert abs(pos - goal) <= 10, f"Present Position {pos} did not reach goal {goal} (start {p0}) within 3 s"
    assert dxl.wait_until(lambda: dxl.read_u(3, A_MOVING, 1) == 0, 2.0), "Moving stayed 1 after arrival"


def test_goal_outside_limits_does_not_move(dxl):
    dxl.torque(3, True)
    p0 = dxl.read_s(3, A_PRESENT_POS, 4)
    result, error = dxl.write(3, A_GOAL_POS, 4, 5000)
    dxl.expect_error(result, error, 0x06, "Goal Position 5000 in mode 3")
    time.sleep(0.3)
    p1 = dxl.read_s(3, A_PRESENT_POS, 4)
    assert abs(p1 - p0) <= 10, f"servo moved from {p0} to {p1} on a refused goal"


def _velocity_samples(dxl, dxl_id, n=3):
    """n readings over ~0.1 s."""
    out = []
    for _ in range(n):
        out.append(dxl.read_s(dxl_id, A_PRESENT_VEL, 4))
        time.sleep(0.05)
    return out


def test_velocity_mode_reaches_goal_velocity(dxl):
    dxl.write_ok(4, A_OP_MODE, 1, 1)
    dxl.torque(4, True)
    dxl.write_ok(4, A_GOAL_VEL, 4, 50)
    # The velocity PI with the factory gains (KvP 100/128, KvI 1920/65536 per 1 ms tick) settles
    # with a ~0.26 s time constant on the bench; see docs/serve-and-bus.md, "Servo model".
    time.sleep(1.5)
    samples = _velocity_samples(dxl, 4)
    assert all(abs(v - 50) <= 5 for v in samples), f"Present Velocity {samples}, expected 50 +- 5"
    assert dxl.read_u(4, A_MOVING, 1) == 1, "Moving not 1 while turning at 50"
    dxl.write_ok(4, A_GOAL_VEL, 4, -50)
    time.sleep(2.0)
    samples = _velocity_samples(dxl, 4)
    assert all(abs(v + 50) <= 5 for v in samples), f"Present Velocity {samples}, expected -50 +- 5"


def test_velocity_mode_position_keeps_counting(dxl):
    dxl.write_ok(4, A_OP_MODE, 1, 1)
    dxl.torque(4, True)
    p0 = dxl.read_s(4, A_PRESENT_POS, 4)
    dxl.write_ok(4, A_GOAL_VEL, 4, 100)
    time.sleep(0.5)
    p1 = dxl.read_s(4, A_PRESENT_POS, 4)
    # 100 * 0.229 rev/min = 0.38 rev/s = ~1560 pulses/s; allow the ramp-up
    assert p1 - p0 > 300, f"Present Position went {p0} -> {p1} in 0.5 s at Goal Velocity 100"


def test_operating_mode_change_side_effects(dxl):
    dxl.write_ok(5, A_PWM_LIMIT, 2, 500)
    dxl.write_ok(5, A_CURRENT_LIMIT, 2, 1000)
    dxl.write_ok(5, A_PROFILE_ACC, 4, 100)
    dxl.write_ok(5, A_PROFILE_VEL, 4, 200)
    dxl.write_ok(5, A_GOAL_PWM, 2, 300)
    dxl.write_ok(5, A_GOAL_CURRENT, 2, 400)
    dxl.write_ok(5, A_OP_MODE, 1, 1)
    got = {
        "Profile Acceleration": dxl.read_u(5, A_PROFILE_ACC, 4),
        "Profile Velocity": dxl.read_u(5, A_PROFILE_VEL, 4),
        "Goal PWM": dxl.read_s(5, A_GOAL_PWM, 2),
        "Goal Current": dxl.read_s(5, A_GOAL_CURRENT, 2),
    }
    want = {"Profile Acceleration": 0, "Profile Velocity": 0, "Goal PWM": 500, "Goal Current": 1000}
    assert got == want, f"after Operating Mode 3 -> 1: {got}, expected {want}"


def test_all_valid_operating_modes_accepted(dxl):
    dxl.write_ok(6, A_OP_MODE, 1, 3)
    dxl.write_ok(6, A_OP_MODE, 1, 4)
    dxl.write_ok(6, A_OP_MODE, 1, 16)
    dxl.write_ok(6, A_OP_MODE, 1, 0)
    dxl.write_ok(6, A_OP_MODE, 1, 5)
    assert dxl.read_u(6, A_OP_MODE, 1) == 5
    assert dxl.read_u(6, A_TORQUE, 1) == 0
