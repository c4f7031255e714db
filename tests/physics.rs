//! Physics that can fail: the robot in the rapier world, driven through the real servo bus.

use std::path::Path;
use std::time::Duration;

use climbsim::robot::{RobotDescription, WheelPosition};
use climbsim::sim::terrain::{TerrainSpec, generate};
use climbsim::sim::{Lockstep, StartPose, WorldConfig};
use rapier3d::prelude::Vector;

const G: f32 = 9.81;
const OPERATING_MODE: u16 = 11;
const TORQUE_ENABLE: u16 = 64;
const GOAL_VELOCITY: u16 = 104;
const PRESENT_CURRENT: u16 = 126;
const VELOCITY_MODE: u8 = 1;

fn robot() -> RobotDescription {
    RobotDescription::load(&RobotDescription::default_path()).expect("robot description")
}

fn world(terrain: TerrainSpec, gravity: Vector, magnets_on: bool) -> Lockstep {
    let terrain = generate(&terrain, 7, Path::new(".")).expect("terrain");
    let config = WorldConfig { gravity, terrain, start: StartPose::default(), friction: None, magnets_on, payload_kg: 0.0 };
    Lockstep::new(&robot(), config).expect("world")
}

fn flat() -> TerrainSpec {
    TerrainSpec::Flat { size_m: 20.0 }
}

/// Gravity for a surface tilted by `deg` with the robot facing uphill (+x up the slope): the
/// same physics as a tilted terrain under vertical gravity.
fn tilted_gravity(deg: f32) -> Vector {
    let a = deg.to_radians();
    Vector::new(-G * a.sin(), -G * a.cos(), 0.0)
}

/// All wheel servos in velocity mode with torque on, at `goal` (0.229 rev/min units).
fn drive_wheels(sim: &mut Lockstep, goal: i32) {
    for id in 1..=4 {
        sim.write(id, OPERATING_MODE, &[VELOCITY_MODE]).expect("velocity mode");
        sim.write(id, TORQUE_ENABLE, &[1]).expect("torque on");
        sim.write(id, GOAL_VELOCITY, &goal.to_le_bytes()).expect("goal velocity");
    }
}

fn chassis_x(sim: &Lockstep) -> f32 {
    sim.world().chassis_pose().translation.x
}

#[test]
fn flat_ground_speed_matches_goal_velocity_times_radius() {
    let mut sim = world(flat(), Vector::new(0.0, -G, 0.0), true);
    let goal = 50;
    drive_wheels(&mut sim, goal);
    sim.run(Duration::from_secs(4)); // ramp
    let x0 = chassis_x(&sim);
    sim.run(Duration::from_secs(2));
    let speed = (chassis_x(&sim) - x0) / 2.0;
    let radius = robot().wheel.outer_radius_m;
    let expected = goal as f32 * 0.229 / 60.0 * std::f32::consts::TAU * radius;
    let error = (speed - expected).abs() / expected;
    assert!(error < 0.03, "ground speed {speed:.5} m/s vs v·R {expected:.5} m/s ({:.1} %)", error * 100.0);
    let lateral = sim.world().chassis_pose().translation.z.abs();
    assert!(lateral < 0.005, "drove straight: {lateral} m sideways");
}

/// Settle, then hold with torque on at zero velocity for 10 s; return the chassis' displacement.
fn drift_while_holding_on(terrain: TerrainSpec, gravity: Vector, magnets_on: bool) -> Vector {
    let mut sim = world(terrain, gravity, magnets_on);
    drive_wheels(&mut sim, 0);
    sim.run(Duration::from_millis(500));
    let p0 = sim.world().chassis_pose().translation;
    sim.run(Duration::from_secs(10));
    sim.world().chassis_pose().translation - p0
}

fn drift_while_holding(gravity: Vector, magnets_on: bool) -> f32 {
    drift_while_holding_on(flat(), gravity, magnets_on).x
}

#[test]
fn magnets_hold_on_a_30_degree_slope() {
    let slope = TerrainSpec::Slope { size_m: 8.0, resolution: 64, slope_x_deg: 30.0, slope_z_deg: 0.0 };
    let drift = drift_while_holding_on(slope, Vector::new(0.0, -G, 0.0), true);
    assert!(drift.length() < 0.001, "drift {:.2} mm in 10 s", drift.length() * 1000.0);
}

#[test]
fn friction_alone_holds_a_stopped_robot_on_a_30_degree_slope() {
    // Friction 0.6 alone holds at 30° (tan 30° = 0.58); what the magnets add shows on a wall.
    let slope = TerrainSpec::Slope { size_m: 8.0, resolution: 64, slope_x_deg: 30.0, slope_z_deg: 0.0 };
    let drift = drift_while_holding_on(slope, Vector::new(0.0, -G, 0.0), false);
    assert!(drift.length() < 0.005, "friction alone holds at 30°: drift {:.2} mm", drift.length() * 1000.0);
}

#[test]
fn magnets_hold_on_a_vertical_wall() {
    let drift = drift_while_holding(tilted_gravity(90.0), true);
    assert!(drift.abs() < 0.001, "drift {:.2} mm in 10 s", drift * 1000.0);
}

#[test]
fn without_magnets_the_robot_falls_off_a_vertical_wall() {
    let drift = drift_while_holding(tilted_gravity(90.0), false);
    assert!(drift < -1.0, "fell only {:.3} m in 10 s", -drift);
}

#[test]
fn magnets_pull_every_wheel_on_flat_ground() {
    let mut sim = world(flat(), Vector::new(0.0, -G, 0.0), true);
    sim.run(Duration::from_millis(200));
    let pull = robot().magnet.pull_at_contact_n;
    for (wheel, sample) in WheelPosition::ALL.iter().zip(sim.world().adhesion()) {
        assert!((sample.force_n - pull).abs() / pull < 0.05, "{wheel:?}: {sample:?}");
        assert!(sample.gap_m < 0.001, "{wheel:?} gap {} m", sample.gap_m);
    }
}

/// Total Present Current of the wheel servos after 3 s at Goal Velocity 50 on a surface tilted by
/// `deg` (2.69 mA units).
fn total_wheel_current(deg: f32) -> i64 {
    let mut sim = world(flat(), tilted_gravity(deg), true);
    drive_wheels(&mut sim, 50);
    sim.run(Duration::from_secs(3));
    (1..=4).map(|id| sim.read_signed(id, PRESENT_CURRENT, 2).expect("current")).sum()
}

#[test]
fn climbing_current_matches_the_weight_the_wheels_lift() {
    let extra = (total_wheel_current(60.0) - total_wheel_current(0.0)) as f32;
    // Traction torque = m·g·sin(60°)·R over the four wheels; current = torque / 10.6 N·m × 4.4 A.
    let robot = robot();
    let mass = robot.body.front.mass_kg + robot.body.middle.mass_kg + robot.body.rear.mass_kg + 4.0 * (robot.wheel.mass_kg + robot.magnet.mass_kg);
    let torque = mass * G * 60f32.to_radians().sin() * robot.wheel.outer_radius_m;
    let expected = torque / 10.6 * 4.4 / 2.69e-3;
    assert!((extra - expected).abs() / expected < 0.2, "extra current {extra} units, expected {expected:.0}");
}


