//! Drive the robot straight on flat ground with all wheel servos at one Goal Velocity and print
//! its speed against v·R. `cargo run --release --example flat_drive`.

use std::path::Path;
use std::time::Duration;

use climbsim::bus::Timing;
use climbsim::protocol::{Decoder, encode_instruction, opcode};
use climbsim::robot::RobotDescription;
use climbsim::sim::terrain::{TerrainSpec, generate};
use climbsim::sim::{RobotWorld, WorldConfig};

fn main() {
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot");
    let terrain = generate(&TerrainSpec::Flat { size_m: 20.0 }, 1, Path::new(".")).expect("terrain");
    let config = WorldConfig::on(terrain);
    let servos = robot.servos(None).expect("servos");
    let world = RobotWorld::new(&robot, config, &servos).expect("world");
    let mut bus = robot.bus_of(servos, Box::new(world), Timing::Off, None).expect("bus");
    let mut now = Duration::ZERO;
    let send = |bus: &mut climbsim::bus::Bus, now: Duration, id: u8, code: u8, params: &[u8]| {
        let bytes = encode_instruction(id, code, params);
        for packet in Decoder::default().push(now, &bytes) {
            bus.handle(packet.expect("packet"), now, None);
        }
    };
    for id in 1..=4u8 {
        send(&mut bus, now, id, opcode::WRITE, &[11, 0, 1]); // velocity mode
        send(&mut bus, now, id, opcode::WRITE, &[64, 0, 1]); // torque on
        send(&mut bus, now, id, opcode::WRITE, &[104, 0, 50, 0, 0, 0]); // goal velocity 50
    }
    let v_goal = 50.0 * 0.229 / 60.0 * std::f64::consts::TAU * f64::from(robot.climber().expect("the climbing robot").wheel.outer_radius_m);
    let started = std::time::Instant::now();
    for second in 1..=6 {
        now += Duration::from_secs(1);
        bus.advance(now);
        let world = bus.plant::<RobotWorld>().expect("world");
        let pose = world.chassis_pose();
        let v = world.chassis_velocity();
        println!(
            "t={second}s x={:.4} y={:.4} z={:.4} vx={:.5} m/s (v·R = {:.5}) adhesion={:?}",
            pose.translation.x,
            pose.translation.y,
            pose.translation.z,
            v.x,
            v_goal,
            world.adhesion().iter().map(|a| a.force_n).collect::<Vec<_>>()
        );
    }
    println!("6 s simulated in {:?}", started.elapsed());
}
