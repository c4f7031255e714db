//! Step the robot on a 256×256 Perlin terrain in lockstep for N firmware ticks of 1 ms (default
//! 2000), for profilers: `valgrind --tool=callgrind target/release/examples/world_steps 2000`.
//! With `bare` (or `held`) after N, the same world steps by bare rapier (or bare rapier with the
//! last step's inputs written back) for the same simulated time, N ms, after a 200 ms warm-up:
//! the world_rtf bench's baselines, so that the profiles can be compared function by function.
//! Then optionally the solver's iterations and internal iterations (default:
//! `SolverSettings::default()`, which also sets the ticks per physics step).

use std::path::Path;
use std::time::Duration;

use climbsim::robot::RobotDescription;
use climbsim::sim::terrain::{TerrainSpec, generate};
use climbsim::sim::{Lockstep, RobotWorld, SolverSettings, WorldConfig};

fn main() {
    let steps: u32 = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(2000);
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot");
    let spec = TerrainSpec::Perlin { size_m: 16.0, resolution: 256, max_height_m: 0.04, noise_scale: 100.0 };
    let terrain = generate(&spec, 42, Path::new(".")).expect("terrain");
    let arg = |n: usize| std::env::args().nth(n);
    let solver = match (arg(3).and_then(|a| a.parse().ok()), arg(4).and_then(|a| a.parse().ok())) {
        (Some(iterations), Some(internal)) => SolverSettings::new(iterations, internal),
        _ => SolverSettings::default(),
    };
    let config = WorldConfig { solver, ..WorldConfig::on(terrain) };
    let mut sim = Lockstep::new(&robot, config).expect("world");
    for id in 1..=4 {
        sim.write(id, 11, &[1]).expect("velocity mode");
        sim.write(id, 64, &[1]).expect("torque on");
        sim.write(id, 104, &50i32.to_le_bytes()).expect("goal velocity");
    }
    let bare_step: Option<fn(&mut RobotWorld)> = match arg(2).as_deref() {
        Some("bare") => Some(RobotWorld::step_physics_only),
        Some("held") => Some(RobotWorld::step_physics_with_held_inputs),
        _ => None,
    };
    if let Some(bare_step) = bare_step {
        sim.run(Duration::from_millis(200));
        // One physics step spans `ticks_per_step` ticks: the same N ms of simulated time.
        for _ in 0..steps.div_ceil(solver.ticks_per_step.get() as u32) {
            bare_step(sim.world_mut());
        }
    } else {
        sim.run(Duration::from_millis(u64::from(steps)));
    }
    let p = sim.world().chassis_pose().translation;
    println!("after {steps} steps: x = {:.4} m", p.x);
}
