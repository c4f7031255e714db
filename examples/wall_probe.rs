//! Drive the robot with passive magnets from the floor toward a wall with a fillet and print its
//! pitch, wheel centres, magnet pulls and magnet angles every second: the floor-to-wall
//! transition of issue #3. `cargo run --release --example wall_probe -- GOAL_VELOCITY FILLET_M`;
//! `ROBOT=path/to/robot.toml` tries another robot description (absolute profile path).
use climbsim::robot::{RobotDescription, WheelPosition};
use climbsim::sim::terrain::{TerrainSpec, generate};
use climbsim::sim::{Lockstep, WorldConfig};
use rapier3d::prelude::Vector;
use std::path::Path;
use std::time::Duration;

fn main() {
    let args: Vec<f32> = std::env::args().skip(1).map(|a| a.parse().unwrap()).collect();
    let goal = args.first().copied().unwrap_or(100.0) as i32;
    let fillet = args.get(1).copied().unwrap_or(0.15);
    let robot_path = std::env::var("ROBOT").map(std::path::PathBuf::from).unwrap_or_else(|_| RobotDescription::default_path());
    let robot = RobotDescription::load(&robot_path).expect("robot");
    let spec = TerrainSpec::Wall { wall_distance_m: 0.5, wall_height_m: 1.5, width_m: 2.0, fillet_radius_m: fillet, segments: 24 };
    let terrain = generate(&spec, 1, Path::new(".")).expect("terrain");
    let config = WorldConfig::on(terrain);
    let mut sim = Lockstep::new(&robot, config).unwrap();
    for id in 1..=4u8 {
        sim.write(id, 11, &[1]).unwrap();
        sim.write(id, 64, &[1]).unwrap();
        sim.write(id, 104, &goal.to_le_bytes()).unwrap();
    }
    for s in 1..=30 {
        sim.run(Duration::from_secs(1));
        let w = sim.world();
        let p = w.chassis_pose();
        let f = p.rotation * Vector::X;
        let fl = w.wheel_centre(WheelPosition::FrontLeft);
        let rl = w.wheel_centre(WheelPosition::RearLeft);
        let ad: Vec<String> = w.adhesion().iter().map(|a| format!("{:.0}", a.force_n)).collect();
        let ma: Vec<String> = WheelPosition::ALL.iter().map(|&wp| format!("{:.0}", w.magnet_angle(wp).to_degrees())).collect();
        println!("t={s:2} pitch={:5.1} front=({:.3},{:.3}) rear=({:.3},{:.3}) adhesion={ad:?} magnets={ma:?}", f.y.atan2(f.x).to_degrees(), fl.x, fl.y, rl.x, rl.y);
    }
}
