"""LeRobot's `KochFollower` (lerobot 0.5.1, unchanged) on climbsim's Koch follower bus: its motor
check, its calibration from a file (its `input()` answered with ENTER), its `configure()`, and its
observation/action loop on the servos' own firmware."""

from __future__ import annotations

import json
import time

from lerobot.robots.koch_follower import KochFollower, KochFollowerConfig

ROBOT = "hil/robots/koch-follower.toml"
# A calibration as `lerobot-calibrate` writes it: each joint's Homing Offset (so that its middle
# reads 2047) and its range in the positions the servo then reports.
CALIBRATION = {
    "shoulder_pan": {"id": 1, "drive_mode": 0, "homing_offset": 0, "range_min": 0, "range_max": 4095},
    "shoulder_lift": {"id": 2, "drive_mode": 0, "homing_offset": 1500, "range_min": 1000, "range_max": 3000},
    "elbow_flex": {"id": 3, "drive_mode": 0, "homing_offset": -700, "range_min": 0, "range_max": 2000},
    "wrist_flex": {"id": 4, "drive_mode": 0, "homing_offset": 0, "range_min": 1200, "range_max": 2900},
    "wrist_roll": {"id": 5, "drive_mode": 0, "homing_offset": 0, "range_min": 0, "range_max": 4095},
    "gripper": {"id": 6, "drive_mode": 0, "homing_offset": 0, "range_min": 2000, "range_max": 3000},
}


def follower(port, tmp_path) -> KochFollower:
    (tmp_path / "calibration").mkdir()
    (tmp_path / "calibration" / "climbsim.json").write_text(json.dumps(CALIBRATION))
    return KochFollower(KochFollowerConfig(port=str(port), id="climbsim", calibration_dir=tmp_path / "calibration"))


def test_koch_follower_connects_calibrates_from_its_file_and_configures(serve, tmp_path, monkeypatch):
    bus = serve(ROBOT)
    robot = follower(bus.link, tmp_path)
    asked = []
    monkeypatch.setattr("builtins.input", lambda prompt="": asked.append(prompt) or "")
    robot.connect(calibrate=True)
    try:
        # The servos had factory limits, so LeRobot asked (once) and wrote its file to them.
        assert len(asked) == 1 and "calibration file" in asked[0], asked
        assert robot.is_calibrated
        raw = robot.bus.sync_read("Min_Position_Limit", normalize=False)
        assert raw == {motor: c["range_min"] for motor, c in CALIBRATION.items()}
        raw = robot.bus.sync_read("Max_Position_Limit", normalize=False)
        assert raw == {motor: c["range_max"] for motor, c in CALIBRATION.items()}
        raw = robot.bus.sync_read("Homing_Offset", normalize=False)
        assert raw == {motor: c["homing_offset"] for motor, c in CALIBRATION.items()}
        # Present Position is the shaft plus the offset: the bench's shafts start at 0.
        raw = robot.bus.sync_read("Present_Position", normalize=False)
        assert raw["shoulder_lift"] == 1500 and raw["elbow_flex"] == -700, raw
        # configure(): extended position everywhere but the gripper (current-based position), torque on.
        modes = robot.bus.sync_read("Operating_Mode", normalize=False)
        assert modes == {"shoulder_pan": 4, "shoulder_lift": 4, "elbow_flex": 4, "wrist_flex": 4, "wrist_roll": 4, "gripper": 5}
        assert set(robot.bus.sync_read("Torque_Enable", normalize=False).values()) == {1}
        assert robot.bus.read("Position_P_Gain", "elbow_flex", normalize=False) == 1500
    finally:
        robot.disconnect()


def test_koch_follower_follows_its_actions(serve, tmp_path, monkeypatch):
    bus = serve(ROBOT)
    robot = follower(bus.link, tmp_path)
    monkeypatch.setattr("builtins.input", lambda prompt="": "")
    robot.connect(calibrate=True)
    try:
        # LeRobot's normalised units: -100..100 over each joint's range, the gripper 0..100.
        target = {"shoulder_pan.pos": 10.0, "shoulder_lift.pos": -20.0, "elbow_flex.pos": 30.0, "wrist_flex.pos": -40.0, "wrist_roll.pos": 50.0, "gripper.pos": 60.0}
        # The shafts start at 0: every joint is away from its target (at or past one end).
        observation = robot.get_observation()
        assert all(abs(observation[key] - value) > 10.0 for key, value in target.items()), observation
        # Observe and act until every joint holds its target for 20 rounds in a row (the longest
        # move, the shoulder's 200 degrees at the XL430's speed, takes under a second).
        rounds, held, started = 0, 0, time.monotonic()
        missed = {}
        while held < 20 and time.monotonic() - started < 15.0:
            observation = robot.get_observation()
            robot.send_action(target)
            rounds += 1
            missed = {key: (observation[key], value) for key, value in target.items() if abs(observation[key] - value) > 1.0}
            held = 0 if missed else held + 1
        assert held >= 20, f"after {rounds} rounds of observe and act, joints off their targets (observed, target): {missed}"
    finally:
        robot.disconnect()
