//! Step the robot on a 256×256 Perlin terrain in lockstep for N steps (default 2000), for
//! profilers: `valgrind --tool=callgrind target/release/examples/world_steps 2000`. With `bare`
//! after N, the same world steps by bare rapier after a 200-step warm-up (the world_rtf bench's
//! baseline), so that the two profiles can be compared function by function.

use std::path::Path;
use std::time::Duration;

use climbsim::robot::RobotDescription;
use climbsim::sim::terrain::{TerrainSpec, generate};
use climbsim::sim::{Lockstep, WorldConfig};

fn main() {
    let steps: u32 = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(2000);
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot");
    let spec = TerrainSpec::Perlin { size_m: 16.0, resolution: 256, max_height_m: 0.04, noise_scale: 100.0 };
    let terrain = generate(&spec, 42, Path::new(".")).expect("terrain");
    let config = WorldConfig::on(terrain);
    let mut sim = Lockstep::new(&robot, config).expect("world");
    for id in 1..=4 {
        sim.write(id, 11, &[1]).expect("velocity mode");
        sim.write(id, 64, &[1]).expect("torque on");
        sim.write(id, 104, &50i32.to_le_bytes()).expect("goal velocity");
    }
    if std::env::args().nth(2).as_deref() == Some("bare") {
        sim.run(Duration::from_millis(200));
        for _ in 0..steps {
            sim.world_mut().step_physics_only();
        }
    } else {
        sim.run(Duration::from_millis(u64::from(steps)));
    }
    let p = sim.world().chassis_pose().translation;
    println!("after {steps} steps: x = {:.4} m", p.x);
}
