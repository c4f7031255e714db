//! Physics that can fail: the robot in the rapier world, driven through the real servo bus.

use std::path::Path;
use std::time::Duration;

use climbsim::robot::WheelPosition;
use climbsim::sim::terrain::TerrainSpec;
use climbsim::sim::{Lockstep, SolverSettings};
use rapier3d::prelude::Vector;

mod support;
use support::physics::*;

fn world(terrain: TerrainSpec, gravity: Vector, magnets_on: bool) -> Lockstep {
    world_with_payload(terrain, gravity, magnets_on, 0.0)
}

#[test]
fn flat_ground_speed_matches_goal_velocity_times_radius() {
    let (speed, expected, lateral) = flat_ground_speed(SolverSettings::default());
    let error = (speed - expected).abs() / expected;
    assert!(error < 0.03, "ground speed {speed:.5} m/s vs v·R {expected:.5} m/s ({:.1} %)", error * 100.0);
    assert!(lateral < 0.005, "drove straight: {lateral} m sideways");
}

fn drift_while_holding_on(terrain: TerrainSpec, gravity: Vector, magnets_on: bool) -> Vector {
    support::physics::drift_while_holding(terrain, gravity, magnets_on, SolverSettings::default())
}

fn drift_while_holding(gravity: Vector, magnets_on: bool) -> f32 {
    drift_while_holding_on(flat(), gravity, magnets_on).x
}

#[test]
fn magnets_hold_on_a_30_degree_slope() {
    let drift = drift_while_holding_on(slope(30.0), Vector::new(0.0, -G, 0.0), true);
    assert!(drift.length() < 0.001, "drift {:.2} mm in 10 s", drift.length() * 1000.0);
}

#[test]
fn friction_alone_holds_a_stopped_robot_on_a_30_degree_slope() {
    // Friction 0.6 alone holds at 30° (tan 30° = 0.58); what the magnets add shows on a wall.
    let drift = drift_while_holding_on(slope(30.0), Vector::new(0.0, -G, 0.0), false);
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
    let pull = climber().magnet.pull_at_contact_n;
    for (wheel, sample) in WheelPosition::ALL.iter().zip(sim.world().adhesion()) {
        assert!((sample.force_n - pull).abs() / pull < 0.05, "{wheel:?}: {sample:?}");
        assert!(sample.gap_m < 0.001, "{wheel:?} gap {} m", sample.gap_m);
    }
}

#[test]
fn climbing_current_matches_the_weight_the_wheels_lift() {
    let (extra, expected) = climbing_current(SolverSettings::default());
    assert!((extra - expected).abs() / expected < 0.2, "extra current {extra} units, expected {expected:.0}");
}

#[test]
fn passive_magnet_reads_the_contact_angle_over_a_bump() {
    let (worst, encoder, geometric, steepest) = magnet_versus_contact_over_a_bump(SolverSettings::default());
    assert!(steepest.to_degrees() > 8.0, "the wheel crossed the bump's flanks (steepest contact {:.1}°)", steepest.to_degrees());
    assert!(worst.to_degrees() < 2.0, "magnet {:.2}° vs contact {:.2}°", encoder.to_degrees(), geometric.to_degrees());
}

#[test]
fn front_wheels_roll_like_the_rear_ones_on_a_long_straight_drive() {
    // All four wheels at the same Goal Velocity (14 units, 1000 mm/min) on flat steel for 40 s.
    // With the rocker an impulse joint the front section gathered a pitch rate in rapier's
    // solved velocities (not in its pose) that grew to 0.016 rad/s by 40 s: the front wheels'
    // rate about their axles read 5 % above the rear ones' and the front treads scrubbed.
    let mut sim = world(flat(), Vector::new(0.0, -G, 0.0), true);
    drive_wheels(&mut sim, 14);
    sim.run(Duration::from_secs(40));
    let world = sim.world();
    let rear = world.wheel_rate(WheelPosition::RearLeft);
    for wheel in WheelPosition::ALL {
        let (rate, slip) = (world.wheel_rate(wheel), world.wheel_slip(wheel));
        assert!((rate - rear).abs() < 0.003 * rear, "{wheel:?} turns at {rate:.4} rad/s, the rear left at {rear:.4} rad/s");
        assert!(slip.abs() < 1e-4, "{wheel:?} scrubs at {slip:.6} m/s");
    }
}

#[test]
fn rocker_keeps_all_four_wheels_on_a_one_sided_step() {
    // A 15 mm step under the right track only (z ≥ 0): the front section rolls about the rocker
    // so that the right front wheel climbs it while the left front wheel stays down.
    let step = TerrainSpec::Step { size_m: 2.0, resolution: 512, height_m: 0.015, x_m: 0.3, z_from_m: 0.0 };
    let mut sim = world(step, Vector::new(0.0, -G, 0.0), true);
    drive_wheels(&mut sim, 40);
    let mut on_step = false;
    for _ in 0..100 {
        sim.run(Duration::from_millis(100));
        let front_left = sim.world().wheel_centre(WheelPosition::FrontLeft);
        let front_right = sim.world().wheel_centre(WheelPosition::FrontRight);
        if front_right.x > 0.35 && front_right.y - front_left.y > 0.012 {
            on_step = true;
            break;
        }
    }
    assert!(on_step, "the front right wheel climbed the step");
    set_wheel_goal(&mut sim, 0);
    sim.run(Duration::from_millis(300));
    for (wheel, sample) in WheelPosition::ALL.iter().zip(sim.world().adhesion()) {
        assert!(sample.force_n > 0.5 * climber().magnet.pull_at_contact_n && sample.gap_m < 0.001, "{wheel:?} lost contact: {sample:?}");
    }
}

#[test]
fn a_slope_beyond_the_wheels_torque_stalls_them_and_a_shallow_one_does_not() {
    // 200 kg towed on 30°: about 1000 N along the slope, more than four wheels at 10.6 N·m on a
    // 50 mm radius give (848 N); friction (0.6 × (4 × 80 N + 1740 N)) still holds them.
    let payload = 200.0;
    let Climb { travel_m: travel, current, slip_m: slip, mut sim } = climb_with_payload(30.0, payload, SolverSettings::default());
    let stall_current = (4.4 / 2.69e-3) as i64;
    assert!(travel < 0.005, "climbed {travel:.3} m beyond stall torque");
    assert!(current > stall_current * 9 / 10, "Present Current {current} units, stall is {stall_current}");
    // The overloaded motors are back-driven and the robot rolls back, but friction holds the
    // treads: the chassis moves as far as the wheels turn (a solver that converges too little
    // lets it slide down past them).
    assert!(slip.abs() < STALL_SLIP_TOLERANCE_M, "slid {:.1} mm past the wheels' rotation at stall (rolled back {:.1} mm)", slip * 1e3, -travel * 1e3);
    // Held at stall, the servos' overload protection trips (Hardware Error Status bit 5).
    sim.run(Duration::from_secs(2));
    let status = sim.read(1, 70, 1).expect("hardware error status")[0];
    assert_eq!(status & 0x20, 0x20, "overload latched after 2 s at stall: {status:#04X}");
    let Climb { travel_m: travel, current, .. } = climb_with_payload(3.0, payload, SolverSettings::default());
    assert!(travel > 0.05, "on 3° the same load climbs: {travel:.3} m, current {current}");
}

/// Run a scenario file in lockstep for `seconds` with all wheels at Goal Velocity 50; return the
/// chassis pose's bits.
fn run_scenario(path: &str, seconds: u64) -> Vec<u32> {
    let scenario = climbsim::scenario::Scenario::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join(path)).expect("scenario");
    let mut sim = Lockstep::new(&robot(), scenario.world_config().expect("world config")).expect("world");
    drive_wheels(&mut sim, 50);
    sim.run(Duration::from_secs(seconds));
    let pose = sim.world().chassis_pose();
    let t = pose.translation;
    let r = pose.rotation;
    [t.x, t.y, t.z, r.x, r.y, r.z, r.w].iter().map(|v| v.to_bits()).collect()
}

#[test]
fn same_scenario_and_seed_give_a_bit_identical_trajectory() {
    let first = run_scenario("scenarios/bumpy-deck.toml", 3);
    let second = run_scenario("scenarios/bumpy-deck.toml", 3);
    assert_eq!(first, second);
    assert_ne!(first, run_scenario("scenarios/flat.toml", 3), "a different world gives a different trajectory");
}

#[test]
fn passive_magnets_carry_the_robot_from_the_floor_up_a_filleted_wall() {
    let sim = floor_to_wall(SolverSettings::default());
    let pitch = pitch_deg(&sim);
    assert!(pitch > 88.0, "the robot stands on the wall: pitch {pitch:.1}°");
    let rear = sim.world().wheel_centre(WheelPosition::RearLeft);
    assert!(rear.y > 0.4, "the rear axle has left the fillet and climbs: {:.3} m up", rear.y);
    for (wheel, sample) in WheelPosition::ALL.iter().zip(sim.world().adhesion()) {
        assert!(sample.force_n > 0.9 * climber().magnet.pull_at_contact_n, "{wheel:?} holds: {sample:?}");
    }
}
