//! The scenario benchmarks, one run each:
//! - real-time factor of a 20 s flat line-following scenario (camera 128×128 at 30 Hz, built-in
//!   controller, lockstep, one core), and what the camera adds: the same run with the camera
//!   at 0.05 Hz (one frame) costs the physics and controller alone;
//! - a sweep of 32 such runs with `--jobs 1` and `--jobs 2` (wall time and speed-up).
//!
//! `cargo bench --bench scenario_rtf`; results in target/bench-results/scenario_rtf.json.

#[path = "../tests/support/mod.rs"]
mod support;

use std::path::PathBuf;
use std::process::Command;
use std::time::Instant;

use climbsim::robot::RobotDescription;
use climbsim::runner::lockstep::run_lockstep;
use climbsim::scenario::{Override, Scenario};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Wall seconds of one 20 s flat-line run with the camera at `frame_rate_hz`.
fn run_seconds(robot: &RobotDescription, frame_rate_hz: f64) -> f64 {
    let overrides = ["world.duration_s=20", "expect={}", &format!("camera.frame_rate_hz={frame_rate_hz}")].map(|s| Override::parse(s).expect("override"));
    let scenario = Scenario::load_with(&repo().join("scenarios/flat-line.toml"), &overrides).expect("scenario");
    let started = Instant::now();
    run_lockstep(&scenario, robot).expect("run");
    started.elapsed().as_secs_f64()
}

fn sweep_seconds(jobs: u32, runs: u32, out: &std::path::Path) -> f64 {
    let zetas: Vec<String> = (0..runs).map(|i| format!("{:.2}", 0.3 + 0.05 * f64::from(i))).collect();
    let started = Instant::now();
    let status = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["sweep", "scenarios/flat-line.toml", "--set", &format!("controller.zeta={}", zetas.join(",")), "--set", "world.duration_s=20", "--jobs", &jobs.to_string(), "--out"])
        .arg(out)
        .current_dir(repo())
        .stderr(std::process::Stdio::null())
        .status()
        .expect("climbsim sweep");
    assert!(status.success(), "sweep failed");
    started.elapsed().as_secs_f64()
}

fn main() {
    let full_run = std::env::args().any(|a| a == "--bench");
    let (blocks, runs) = if full_run { (5, 32) } else { (1, 4) };
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot");
    let (mut with_camera, mut without) = (Vec::new(), Vec::new());
    for _ in 0..blocks {
        with_camera.push(run_seconds(&robot, 30.0));
        without.push(run_seconds(&robot, 0.05));
    }
    let (with_camera, without) = (support::median(&mut with_camera), support::median(&mut without));
    let rtf = 20.0 / with_camera;
    let camera_share = with_camera / without - 1.0;
    let out = support::scratch_dir("sweep-bench");
    let serial = sweep_seconds(1, runs, &out.join("jobs1"));
    let parallel = sweep_seconds(2, runs, &out.join("jobs2"));
    println!("\n20 s flat line scenario, camera 128×128 at 30 Hz, built-in controller, lockstep (median of {blocks} runs{})", if full_run { "" } else { ", smoke run" });
    println!("| run | wall s | × real time |");
    println!("|-----|-------:|------------:|");
    println!("| with camera at 30 Hz | {with_camera:.2} | {rtf:.1} |");
    println!("| camera at 0.05 Hz (physics + controller) | {without:.2} | {:.1} |", 20.0 / without);
    println!("camera adds {:.0} % to the physics cost (target ≤ 50 %)", 100.0 * camera_share);
    println!("sweep of {runs} runs: --jobs 1 {serial:.1} s, --jobs 2 {parallel:.1} s, speed-up {:.2}× (target ≥ 1.8×)", serial / parallel);
    if full_run {
        let json = format!(
            "{{\"with_camera_s\":{with_camera:.3},\"without_camera_s\":{without:.3},\"rtf\":{rtf:.2},\"camera_share\":{camera_share:.3},\"sweep_runs\":{runs},\"sweep_jobs1_s\":{serial:.2},\"sweep_jobs2_s\":{parallel:.2},\"speedup\":{:.3}}}\n",
            serial / parallel
        );
        let path = support::results_dir().join("scenario_rtf.json");
        std::fs::write(&path, json).expect("write results");
        println!("results: {}", path.display());
        use support::history::figure;
        support::history::record(
            "scenario_rtf",
            &[
                figure("flat_line_20s_wall", with_camera, "s"),
                figure("real_time_factor", rtf, "x"),
                figure("camera_share", 100.0 * camera_share, "%"),
                figure("sweep_speedup_2_jobs", serial / parallel, "x"),
            ],
        );
    }
}
