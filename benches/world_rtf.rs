//! Real-time factor of the full robot (eight servo models, adhesion, rapier) on a 256×256 Perlin
//! terrain in lockstep, against the same bodies and joints stepped by bare rapier, at 1 kHz and
//! 500 Hz; and peak memory of a world on a 1024×1024 terrain (in a child process).
//! `cargo bench --bench world_rtf`; results in target/bench-results/world_rtf.json.

#[path = "../tests/support/mod.rs"]
mod support;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use climbsim::robot::RobotDescription;
use climbsim::sim::terrain::{TerrainSpec, generate};
use climbsim::sim::{Lockstep, RobotWorld, StartPose, WorldConfig};
use rapier3d::prelude::Vector;

const MEMORY_PROBE: &str = "--memory-probe";

fn perlin(resolution: u32) -> TerrainSpec {
    TerrainSpec::Perlin { size_m: 16.0, resolution, max_height_m: 0.04, noise_scale: 100.0 }
}

fn config(resolution: u32) -> WorldConfig {
    let terrain = generate(&perlin(resolution), 42, Path::new(".")).expect("terrain");
    WorldConfig { gravity: Vector::new(0.0, -9.81, 0.0), terrain, start: StartPose::default(), friction: None, magnets_on: true, payload_kg: 0.0 }
}

/// The robot description with the firmware tick (= physics step) set to `period_us`.
fn robot_with_period(period_us: u64, dir: &Path) -> RobotDescription {
    let base = RobotDescription::load(&RobotDescription::default_path()).expect("robot");
    let profile = std::fs::read_to_string(base.profile_path()).expect("profile");
    let profile = profile.replace("control_period_us = 1000", &format!("control_period_us = {period_us}"));
    let profile_path = dir.join("profile.toml");
    std::fs::write(&profile_path, profile).expect("write profile");
    let robot_text = std::fs::read_to_string(&base.path).expect("robot text").replace("../firmware-profiles/xm540-w270-r.toml", profile_path.to_str().expect("utf-8 path"));
    let robot_path = dir.join("robot.toml");
    std::fs::write(&robot_path, robot_text).expect("write robot");
    RobotDescription::load(&robot_path).expect("robot copy")
}

/// Median µs per step for the full robot and for bare rapier: `blocks` alternating blocks of
/// `steps_per_block` steps each after a warm-up, so that both see the same machine conditions
/// (this VM's neighbours make single runs vary by ±30 %).
fn measure(robot: &RobotDescription, blocks: u32, steps_per_block: u32) -> (f64, f64) {
    let mut sim = Lockstep::new(robot, config(256)).expect("world");
    for id in 1..=4 {
        sim.write(id, 11, &[1]).expect("velocity mode");
        sim.write(id, 64, &[1]).expect("torque on");
        sim.write(id, 104, &50i32.to_le_bytes()).expect("goal velocity");
    }
    let tick = sim.bus().servos()[0].control_period();
    sim.run(tick * 200); // warm-up
    let (mut full, mut bare) = (Vec::new(), Vec::new());
    for _ in 0..blocks {
        let started = Instant::now();
        sim.run(tick * steps_per_block);
        full.push(started.elapsed().as_secs_f64() * 1e6 / f64::from(steps_per_block));
        let world: &mut RobotWorld = sim.world_mut();
        let started = Instant::now();
        for _ in 0..steps_per_block {
            world.step_physics_only();
        }
        bare.push(started.elapsed().as_secs_f64() * 1e6 / f64::from(steps_per_block));
    }
    (support::median(&mut full), support::median(&mut bare))
}

fn peak_rss_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status.lines().find_map(|l| l.strip_prefix("VmHWM:")).and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok()).unwrap_or(f64::NAN) / 1024.0
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.iter().any(|a| a == MEMORY_PROBE) {
        let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot");
        let mut sim = Lockstep::new(&robot, config(1024)).expect("world");
        sim.run(Duration::from_millis(100));
        println!("{:.1}", peak_rss_mb());
        return;
    }
    let full_run = args.iter().any(|a| a == "--bench");
    let (blocks, steps_per_block) = if full_run { (9, 2_000) } else { (1, 200) };
    let steps = blocks * steps_per_block;
    let dir = std::env::temp_dir().join(format!("climbsim-rtf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let mut rows = Vec::new();
    for (hz, period_us) in [(1000u32, 1000u64), (500, 2000)] {
        let robot = robot_with_period(period_us, &dir);
        let (full, bare) = measure(&robot, blocks, steps_per_block);
        let dt_us = period_us as f64;
        rows.push((hz, full, bare, dt_us / full, dt_us / bare, full / bare));
    }
    let _ = std::fs::remove_dir_all(&dir);
    let exe = std::env::current_exe().expect("current exe");
    let memory = std::process::Command::new(exe).arg(MEMORY_PROBE).output().expect("memory probe");
    let peak_mb: f64 = String::from_utf8_lossy(&memory.stdout).trim().parse().unwrap_or(f64::NAN);

    println!("\nrobot world, 256×256 Perlin terrain, lockstep, one core (medians of {blocks} alternating blocks of {steps_per_block} steps{})", if full_run { "" } else { ", smoke run" });
    println!("| step rate | full µs/step | bare rapier µs/step | full × real time | bare × real time | overhead full/bare |");
    println!("|----------:|-------------:|--------------------:|-----------------:|-----------------:|-------------------:|");
    for (hz, full, bare, rtf, bare_rtf, ratio) in &rows {
        println!("| {hz} Hz | {full:.1} | {bare:.1} | {rtf:.1} | {bare_rtf:.1} | {ratio:.2} |");
    }
    println!("peak memory (VmHWM) of a world on a 1024×1024 terrain: {peak_mb:.1} MB (target < 200 MB)");
    if full_run {
        let json = format!(
            "{{\"steps\":{steps},\"rows\":[{}],\"peak_memory_1024_mb\":{peak_mb:.1}}}\n",
            rows.iter()
                .map(|(hz, full, bare, rtf, bare_rtf, ratio)| format!("{{\"hz\":{hz},\"full_us\":{full:.2},\"bare_us\":{bare:.2},\"rtf\":{rtf:.2},\"bare_rtf\":{bare_rtf:.2},\"overhead\":{ratio:.3}}}"))
                .collect::<Vec<_>>()
                .join(",")
        );
        let path: PathBuf = support::results_dir().join("world_rtf.json");
        std::fs::write(&path, json).expect("write results");
        println!("results: {}", path.display());
    }
}
