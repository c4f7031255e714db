"""Teleoperation as LeRobot does it (`lerobot-teleoperate`'s loop): its own `KochLeader` read and
its `KochFollower` commanded with what the leader reads, each on its own climbsim bus (two
ports). The leader's joints rest where their calibration puts them, its gripper springs to
`gripper_open_pos` under its own torque, and the follower must come to the same positions; then
the leader's wrist is turned (by its own torque, standing in for a hand) and the follower's must
go with it."""

from __future__ import annotations

import json
import time

from lerobot.robots.koch_follower import KochFollower, KochFollowerConfig
from lerobot.teleoperators.koch_leader import KochLeader, KochLeaderConfig

from test_koch_follower import CALIBRATION as FOLLOWER_CALIBRATION

# The leader's calibration: its shafts rest at 0, so each Homing Offset is where the joint reads.
LEADER_CALIBRATION = {
    "shoulder_pan": {"id": 1, "drive_mode": 0, "homing_offset": 2047, "range_min": 0, "range_max": 4095},
    "shoulder_lift": {"id": 2, "drive_mode": 0, "homing_offset": 2300, "range_min": 1000, "range_max": 3000},
    "elbow_flex": {"id": 3, "drive_mode": 0, "homing_offset": 1200, "range_min": 0, "range_max": 2000},
    "wrist_flex": {"id": 4, "drive_mode": 0, "homing_offset": 1800, "range_min": 1200, "range_max": 2900},
    "wrist_roll": {"id": 5, "drive_mode": 0, "homing_offset": 3000, "range_min": 0, "range_max": 4095},
    "gripper": {"id": 6, "drive_mode": 0, "homing_offset": 2200, "range_min": 2000, "range_max": 3000},
}
# How close the follower must hold the leader, in LeRobot's normalised units (±100 over a joint's
# range, 0..100 for the gripper): 1.0 is a hundredth of a half-range.
TOLERANCE = 1.0


def calibration_dir(tmp_path, name, calibration):
    folder = tmp_path / name
    folder.mkdir()
    (folder / "climbsim.json").write_text(json.dumps(calibration))
    return folder


def teleoperate(leader, follower, until=lambda action: True):
    """LeRobot's loop, leader read and follower commanded, until the follower has held every one
    of the leader's joints for 20 rounds in a row with `until(action)` true."""
    rounds, held, started = 0, 0, time.monotonic()
    off = {}
    while held < 20 and time.monotonic() - started < 15.0:
        action = leader.get_action()
        follower.send_action(action)
        observation = follower.get_observation()
        rounds += 1
        off = {key: (observation[key], value) for key, value in action.items() if abs(observation[key] - value) > TOLERANCE}
        held = 0 if off or not until(action) else held + 1
    assert held >= 20, f"after {rounds} rounds, follower joints away from the leader's (follower, leader): {off}"


def test_the_follower_follows_the_leader_through_two_climbsim_buses(serve, tmp_path, monkeypatch):
    leader_bus, follower_bus = serve("hil/robots/koch-leader.toml"), serve("hil/robots/koch-follower.toml")
    monkeypatch.setattr("builtins.input", lambda prompt="": "")
    leader = KochLeader(KochLeaderConfig(port=str(leader_bus.link), id="climbsim", calibration_dir=calibration_dir(tmp_path, "leader", LEADER_CALIBRATION)))
    follower = KochFollower(KochFollowerConfig(port=str(follower_bus.link), id="climbsim", calibration_dir=calibration_dir(tmp_path, "follower", FOLLOWER_CALIBRATION)))
    leader.connect(calibrate=True)
    follower.connect(calibrate=True)
    try:
        # LeRobot's leader check: its six XL330-M077s answered with their model, and it is calibrated.
        assert leader.is_calibrated and follower.is_calibrated
        teleoperate(leader, follower)
        # The leader's gripper went to its open position under its own torque; the rest stayed
        # where their calibration puts them (the follower's own rest would read otherwise).
        action = leader.get_action()
        assert abs(action["gripper.pos"] - leader.config.gripper_open_pos) < TOLERANCE, action
        assert abs(action["shoulder_lift.pos"] - 30.0) < TOLERANCE and abs(action["elbow_flex.pos"] - 20.0) < TOLERANCE, action
        # A hand turns the leader's wrist: its own torque stands in for the hand here. The
        # follower's wrist goes with it.
        before = follower.get_observation()["wrist_roll.pos"]
        leader.bus.enable_torque("wrist_roll")
        leader.bus.write("Goal_Position", "wrist_roll", 3800, normalize=False)
        teleoperate(leader, follower, until=lambda action: abs(action["wrist_roll.pos"] - before) > 25.0)
        after = follower.get_observation()["wrist_roll.pos"]
        assert after - before > 25.0, (before, after)
    finally:
        leader.disconnect()
        follower.disconnect()
