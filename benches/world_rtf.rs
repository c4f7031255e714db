//! Real-time factor of the full robot (eight servo models, adhesion, rapier) on a 256×256 Perlin
//! terrain in lockstep, against the same bodies and joints stepped by bare rapier for the same
//! simulated time, for several solver settings (one physics step every one or two 1 ms ticks);
//! and peak memory of a world on a 1024×1024 terrain (in a child process). Two bare baselines:
//! rapier stepping untouched, and rapier with the last step's forces, torques and joint motors
//! written back each step (what any rapier program that drives a robot pays; see
//! `RobotWorld::step_physics_with_held_inputs`).
//! `cargo bench --bench world_rtf`; results in target/bench-results/world_rtf.json.

#[path = "../tests/support/mod.rs"]
mod support;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use climbsim::robot::RobotDescription;
use climbsim::sim::terrain::{TerrainSpec, generate};
use climbsim::sim::{Lockstep, RobotWorld, SolverSettings, WorldConfig};

const MEMORY_PROBE: &str = "--memory-probe";

fn perlin(resolution: u32) -> TerrainSpec {
    TerrainSpec::Perlin { size_m: 16.0, resolution, max_height_m: 0.04, noise_scale: 100.0 }
}

fn config(resolution: u32, solver: SolverSettings) -> WorldConfig {
    let terrain = generate(&perlin(resolution), 42, Path::new(".")).expect("terrain");
    WorldConfig { solver, ..WorldConfig::on(terrain) }
}

/// Medians (µs per step) of one configuration.
struct Timing {
    full: f64,
    bare: f64,
    bare_with_inputs: f64,
}

/// The robot description with the firmware tick set to `period_us`.
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

/// Median µs per step for the full robot and the two bare baselines: `blocks` alternating
/// blocks of `steps_per_block` steps each after a warm-up, so that all three see the same machine
/// conditions; many short blocks, because this VM's neighbours come and go in bursts of seconds
/// and the median of many blocks rejects them better than that of a few long ones.
fn measure(robot: &RobotDescription, solver: SolverSettings, blocks: u32, steps_per_block: u32) -> Timing {
    let mut sim = Lockstep::new(robot, config(256, solver)).expect("world");
    for id in 1..=4 {
        sim.write(id, 11, &[1]).expect("velocity mode");
        sim.write(id, 64, &[1]).expect("torque on");
        sim.write(id, 104, &50i32.to_le_bytes()).expect("goal velocity");
    }
    let tick = sim.bus().servos()[0].control_period();
    sim.run(tick * 200); // warm-up
    let per_step = |started: Instant| started.elapsed().as_secs_f64() * 1e6 / f64::from(steps_per_block);
    let (mut full, mut bare, mut bare_with_inputs) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..blocks {
        let started = Instant::now();
        sim.run(tick * steps_per_block);
        full.push(per_step(started));
        let world: &mut RobotWorld = sim.world_mut();
        let started = Instant::now();
        // Bare rapier covers the same simulated time: one physics step spans `ticks_per_step` ticks.
        let physics_steps = steps_per_block.div_ceil(solver.ticks_per_step.get() as u32);
        for _ in 0..physics_steps {
            world.step_physics_only();
        }
        bare.push(per_step(started));
        let started = Instant::now();
        for _ in 0..physics_steps {
            world.step_physics_with_held_inputs();
        }
        bare_with_inputs.push(per_step(started));
    }
    Timing { full: support::median(&mut full), bare: support::median(&mut bare), bare_with_inputs: support::median(&mut bare_with_inputs) }
}

fn peak_rss_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status.lines().find_map(|l| l.strip_prefix("VmHWM:")).and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok()).unwrap_or(f64::NAN) / 1024.0
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.iter().any(|a| a == MEMORY_PROBE) {
        let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot");
        let mut sim = Lockstep::new(&robot, config(1024, SolverSettings::default())).expect("world");
        sim.run(Duration::from_millis(100));
        println!("{:.1}", peak_rss_mb());
        return;
    }
    let full_run = args.iter().any(|a| a == "--bench");
    let (blocks, steps_per_block) = if full_run { (31, 500) } else { (1, 200) };
    let steps = blocks * steps_per_block;
    let dir = std::env::temp_dir().join(format!("climbsim-rtf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let default = SolverSettings::default();
    // The default, and the physics stepping at every tick with 3 × 2 passes (the default before
    // physics could step less often than the firmware).
    let mut configurations = vec![(1000u32, 1000u64, default), (1000, 1000, SolverSettings::new(3, 2).every(1))];
    if full_run {
        configurations.extend([(1000, 1000, SolverSettings::new(3, 2)), (1000, 1000, SolverSettings::new(2, 2))].into_iter().filter(|c| c.2 != default));
    }
    let mut rows = Vec::new();
    for (hz, period_us, solver) in configurations {
        let robot = robot_with_period(period_us, &dir);
        rows.push((hz, period_us as f64, solver, measure(&robot, solver, blocks, steps_per_block)));
    }
    let _ = std::fs::remove_dir_all(&dir);
    let exe = std::env::current_exe().expect("current exe");
    let memory = std::process::Command::new(exe).arg(MEMORY_PROBE).output().expect("memory probe");
    let peak_mb: f64 = String::from_utf8_lossy(&memory.stdout).trim().parse().unwrap_or(f64::NAN);

    println!("\nrobot world, 256×256 Perlin terrain, lockstep, one core (medians of {blocks} alternating blocks of {steps_per_block} steps{})", if full_run { "" } else { ", smoke run" });
    println!("(µs per firmware tick, i.e. per simulated tick whatever the physics step; bare rapier steps once per physics step)");
    println!("| tick rate | solver | full µs/tick | bare rapier µs/tick | bare rapier + held inputs µs/tick | full × real time | overhead full/bare | overhead full/(bare + inputs) |");
    println!("|---|---|---|---|---|---|---|---|");
    for (hz, dt_us, solver, t) in &rows {
        println!(
            "| {hz} Hz | {solver}{} | {:.1} | {:.1} | {:.1} | {:.1} | {:.2} | {:.2} |",
            if *solver == default { " (default)" } else { "" },
            t.full,
            t.bare,
            t.bare_with_inputs,
            dt_us / t.full,
            t.full / t.bare,
            t.full / t.bare_with_inputs
        );
    }
    println!("peak memory (VmHWM) of a world on a 1024×1024 terrain: {peak_mb:.1} MB (target < 200 MB)");
    if full_run {
        let json = rows
            .iter()
            .map(|(hz, dt_us, solver, t)| {
                format!(
                    "{{\"hz\":{hz},\"iterations\":{},\"internal_iterations\":{},\"ticks_per_step\":{},\"full_us\":{:.2},\"bare_us\":{:.2},\"bare_with_inputs_us\":{:.2},\"rtf\":{:.2},\"overhead\":{:.3},\"overhead_vs_inputs\":{:.3}}}",
                    solver.iterations, solver.internal_iterations, solver.ticks_per_step, t.full, t.bare, t.bare_with_inputs, dt_us / t.full, t.full / t.bare, t.full / t.bare_with_inputs
                )
            })
            .collect::<Vec<_>>()
            .join(",");
        let path: PathBuf = support::results_dir().join("world_rtf.json");
        std::fs::write(&path, format!("{{\"steps\":{steps},\"rows\":[{json}],\"peak_memory_1024_mb\":{peak_mb:.1}}}\n")).expect("write results");
        println!("results: {}", path.display());
        use support::history::figure;
        let mut figures = Vec::new();
        for (hz, _, _, t) in rows.iter().filter(|(_, _, solver, _)| *solver == default) {
            figures.push(figure(format!("{hz}hz_full_us_per_step"), t.full, "us"));
            figures.push(figure(format!("{hz}hz_bare_us_per_step"), t.bare, "us"));
        }
        figures.push(figure("peak_memory_1024", peak_mb, "MB"));
        support::history::record("world_rtf", &figures);
    }
}
