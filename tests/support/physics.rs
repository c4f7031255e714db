//! The robot in a rapier world and the physics measurements that `tests/physics.rs` asserts on
//! and `benches/solver_fidelity.rs` tabulates for each solver setting.

use std::path::Path;
use std::time::Duration;

use climbsim::robot::{RobotDescription, WheelPosition};
use climbsim::sim::terrain::{TerrainSpec, generate};
use climbsim::sim::{Lockstep, SolverSettings, WorldConfig};
use rapier3d::prelude::Vector;

pub const G: f32 = 9.81;
pub const OPERATING_MODE: u16 = 11;
pub const TORQUE_ENABLE: u16 = 64;
pub const GOAL_VELOCITY: u16 = 104;
pub const PRESENT_CURRENT: u16 = 126;
pub const PRESENT_POSITION: u16 = 132;
pub const VELOCITY_MODE: u8 = 1;

/// The shipped robot's mechanics.
pub fn climber() -> climbsim::robot::Climber {
    robot().climber().expect("the shipped robot is the climbing robot")
}

pub fn robot() -> RobotDescription {
    RobotDescription::load(&RobotDescription::default_path()).expect("robot description")
}

/// The robot resting on `terrain` (seed 7) under `gravity`, with rapier's solver at `solver`.
pub fn world_with(terrain: TerrainSpec, gravity: Vector, magnets_on: bool, payload_kg: f32, solver: SolverSettings) -> Lockstep {
    let terrain = generate(&terrain, 7, Path::new(".")).expect("terrain");
    let config = WorldConfig { gravity, magnets_on, payload_kg, solver, ..WorldConfig::on(terrain) };
    Lockstep::new(&robot(), config).expect("world")
}

/// The robot resting on `terrain` (seed 7) under `gravity`, with the default solver.
pub fn world_with_payload(terrain: TerrainSpec, gravity: Vector, magnets_on: bool, payload_kg: f32) -> Lockstep {
    world_with(terrain, gravity, magnets_on, payload_kg, SolverSettings::default())
}

pub fn flat() -> TerrainSpec {
    TerrainSpec::Flat { size_m: 20.0 }
}

pub fn slope(deg: f32) -> TerrainSpec {
    TerrainSpec::Slope { size_m: 8.0, resolution: 64, slope_x_deg: deg, slope_z_deg: 0.0 }
}

/// Gravity for a surface tilted by `deg` with the robot facing uphill (+x up the slope): the
/// same physics as a tilted terrain under vertical gravity.
pub fn tilted_gravity(deg: f32) -> Vector {
    let a = deg.to_radians();
    Vector::new(-G * a.sin(), -G * a.cos(), 0.0)
}

/// All wheel servos in velocity mode with torque on, at `goal` (0.229 rev/min units).
pub fn drive_wheels(sim: &mut Lockstep, goal: i32) {
    for id in 1..=4 {
        sim.write(id, OPERATING_MODE, &[VELOCITY_MODE]).expect("velocity mode");
        sim.write(id, TORQUE_ENABLE, &[1]).expect("torque on");
    }
    set_wheel_goal(sim, goal);
}

pub fn set_wheel_goal(sim: &mut Lockstep, goal: i32) {
    for id in 1..=4 {
        sim.write(id, GOAL_VELOCITY, &goal.to_le_bytes()).expect("goal velocity");
    }
}

/// Flat ground, all wheels at Goal Velocity 50 after a 4 s ramp: (ground speed over the next
/// 2 s, v·R, the chassis' sideways offset), in m/s and m.
pub fn flat_ground_speed(solver: SolverSettings) -> (f32, f32, f32) {
    let mut sim = world_with(flat(), Vector::new(0.0, -G, 0.0), true, 0.0, solver);
    let goal = 50;
    drive_wheels(&mut sim, goal);
    sim.run(Duration::from_secs(4));
    let x0 = sim.world().chassis_pose().translation.x;
    sim.run(Duration::from_secs(2));
    let speed = (sim.world().chassis_pose().translation.x - x0) / 2.0;
    let expected = goal as f32 * 0.229 / 60.0 * std::f32::consts::TAU * climber().wheel.outer_radius_m;
    (speed, expected, sim.world().chassis_pose().translation.z.abs())
}

/// Settle, then hold with torque on at zero velocity for 10 s; the chassis' displacement.
pub fn drift_while_holding(terrain: TerrainSpec, gravity: Vector, magnets_on: bool, solver: SolverSettings) -> Vector {
    let mut sim = world_with(terrain, gravity, magnets_on, 0.0, solver);
    drive_wheels(&mut sim, 0);
    sim.run(Duration::from_millis(500));
    let p0 = sim.world().chassis_pose().translation;
    sim.run(Duration::from_secs(10));
    sim.world().chassis_pose().translation - p0
}

/// Total Present Current of the wheel servos at Goal Velocity 50 on a surface tilted by `deg`
/// (2.69 mA units): the mean of 20 readings over a second after 2 s, since one instant of a
/// PI-controlled current rides on the velocity loop's ripple.
fn total_wheel_current(deg: f32, solver: SolverSettings) -> i64 {
    let mut sim = world_with(flat(), tilted_gravity(deg), true, 0.0, solver);
    drive_wheels(&mut sim, 50);
    sim.run(Duration::from_secs(2));
    let mut total = 0;
    for _ in 0..20 {
        sim.run(Duration::from_millis(50));
        total += (1..=4).map(|id| sim.read_signed(id, PRESENT_CURRENT, 2).expect("current")).sum::<i64>();
    }
    total / 20
}

/// (extra current the four wheels draw climbing 60° over flat ground, what lifting the robot's
/// weight needs), in 2.69 mA units: traction torque m·g·sin 60°·R over the four wheels, current =
/// torque / 10.6 N·m × 4.4 A.
pub fn climbing_current(solver: SolverSettings) -> (f32, f32) {
    let extra = (total_wheel_current(60.0, solver) - total_wheel_current(0.0, solver)) as f32;
    let robot = climber();
    let mass = robot.body.front.mass_kg + robot.body.middle.mass_kg + robot.body.rear.mass_kg + 4.0 * (robot.wheel.mass_kg + robot.magnet.mass_kg);
    let torque = mass * G * 60f32.to_radians().sin() * robot.wheel.outer_radius_m;
    (extra, torque / 10.6 * 4.4 / 2.69e-3)
}

/// How far the chassis may slide past its wheels' rotation while stalled on a slope (m).
pub const STALL_SLIP_TOLERANCE_M: f32 = 0.005;

/// A climb with a payload (see [`climb_with_payload`]).
pub struct Climb {
    /// The chassis' travel along the slope (m, negative when it rolls back).
    pub travel_m: f32,
    /// The wheels' mean Present Current (2.69 mA units).
    pub current: i64,
    /// The chassis' travel less the wheels' rolling distance (mean encoder angle × radius): how
    /// far the treads slid (m).
    pub slip_m: f32,
    pub sim: Lockstep,
}

/// Drive at goal speed 100 for 1.5 s on a slope of `deg` carrying `payload_kg`.
pub fn climb_with_payload(deg: f32, payload_kg: f32, solver: SolverSettings) -> Climb {
    let mut sim = world_with(slope(deg), Vector::new(0.0, -G, 0.0), true, payload_kg, solver);
    drive_wheels(&mut sim, 0);
    sim.run(Duration::from_millis(300));
    let start = sim.world().chassis_pose().translation;
    let wheel_angle = |sim: &mut Lockstep| (1..=4).map(|id| sim.read_signed(id, PRESENT_POSITION, 4).expect("wheel position")).sum::<i64>() as f32 / 4.0 * std::f32::consts::TAU / 4096.0;
    let turned_from = wheel_angle(&mut sim);
    set_wheel_goal(&mut sim, 100);
    sim.run(Duration::from_millis(1500));
    let travel_m = (sim.world().chassis_pose().translation - start).x / deg.to_radians().cos();
    let rolled_m = (wheel_angle(&mut sim) - turned_from) * climber().wheel.outer_radius_m;
    let current = (1..=4).map(|id| sim.read_signed(id, PRESENT_CURRENT, 2).expect("current")).sum::<i64>() / 4;
    Climb { travel_m, current, slip_m: travel_m - rolled_m, sim }
}

/// Encoder reading of a magnet servo as an angle from straight down (rad, positive forward).
fn magnet_encoder_angle(sim: &mut Lockstep, id: u8) -> f32 {
    let pulses = sim.read_signed(id, PRESENT_POSITION, 4).expect("magnet position");
    (pulses - i64::from(climber().magnet.encoder_at_down_pulses)) as f32 * std::f32::consts::TAU / 4096.0
}

/// A 30 mm bump under the left wheels' track, on fine cells (4 mm) so that the facets' normals
/// change in steps well under a degree. The robot inches over it with the magnet servos' torque
/// off; at each stop the front-left magnet has settled. Returns (worst |encoder − geometric
/// contact angle|, the encoder and contact angles then, the steepest contact angle seen), rad.
pub fn magnet_versus_contact_over_a_bump(solver: SolverSettings) -> (f32, f32, f32, f32) {
    let bump = TerrainSpec::Bump { size_m: 2.0, resolution: 512, height_m: 0.03, radius_m: 0.2, x_m: 0.5, z_m: -0.13 };
    let mut sim = world_with(bump, Vector::new(0.0, -G, 0.0), true, 0.0, solver);
    let mut worst = (0.0f32, 0.0f32, 0.0f32);
    let mut steepest = 0.0f32;
    drive_wheels(&mut sim, 0);
    for _ in 0..30 {
        set_wheel_goal(&mut sim, 40);
        sim.run(Duration::from_millis(400));
        set_wheel_goal(&mut sim, 0);
        sim.run(Duration::from_millis(600));
        let geometric = sim.world().contact_angle(WheelPosition::FrontLeft).expect("terrain under the wheel");
        let encoder = magnet_encoder_angle(&mut sim, 5);
        steepest = steepest.max(geometric.abs());
        if (encoder - geometric).abs() > worst.0 {
            worst = ((encoder - geometric).abs(), encoder, geometric);
        }
    }
    (worst.0, worst.1, worst.2, steepest)
}

/// The floor-to-wall transition: the wall stands 0.5 m ahead behind a 150 mm fillet; the wheels
/// drive at Goal Velocity 100 (3.6 rev/min, 19 mm/s) for 10 s with the magnet servos' torque
/// off, so each magnet swings on its own toward the surface it faces. Returns the world then.
pub fn floor_to_wall(solver: SolverSettings) -> Lockstep {
    let wall = TerrainSpec::Wall { wall_distance_m: 0.5, wall_height_m: 1.5, width_m: 2.0, fillet_radius_m: 0.15, segments: 24 };
    let mut sim = world_with(wall, Vector::new(0.0, -G, 0.0), true, 0.0, solver);
    drive_wheels(&mut sim, 100);
    sim.run(Duration::from_secs(10));
    sim
}

/// The chassis' pitch (degrees, 90 = nose straight up).
pub fn pitch_deg(sim: &Lockstep) -> f32 {
    let forward = sim.world().chassis_pose().rotation * Vector::X;
    forward.y.atan2(forward.x).to_degrees()
}
