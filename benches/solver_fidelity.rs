//! What rapier's solver effort buys: the physics tests' measurements and the flat line-following
//! scenario for each solver setting (iterations × internal PGS iterations), against an 8 × 2
//! reference. The default setting (`SolverSettings::default`) is the cheapest row that stays
//! inside every physics test's tolerance.
//! `cargo bench --bench solver_fidelity`; results in target/bench-results/solver_fidelity.json.

#[path = "../tests/support/mod.rs"]
mod support;

use climbsim::runner::lockstep::run_lockstep;
use climbsim::scenario::{Override, Scenario};
use climbsim::sim::SolverSettings;
use rapier3d::prelude::Vector;
use support::physics::*;

struct Row {
    solver: SolverSettings,
    speed_error_pct: f32,
    wall_drift_mm: f32,
    slope_drift_mm: f32,
    climbing_current_pct: f32,
    magnet_error_deg: f32,
    wall_pitch_deg: f32,
    wall_weakest_pull_pct: f32,
    stall_slip_mm: f32,
    line_settling_s: f64,
    line_sse_mm: f64,
}

fn measure(solver: SolverSettings) -> Row {
    let (speed, expected, _) = flat_ground_speed(solver);
    let wall_drift = drift_while_holding(flat(), tilted_gravity(90.0), true, solver).length();
    let slope_drift = drift_while_holding(slope(30.0), Vector::new(0.0, -G, 0.0), true, solver).length();
    let (extra, needed) = climbing_current(solver);
    let (magnet_error, ..) = magnet_versus_contact_over_a_bump(solver);
    let wall = floor_to_wall(solver);
    let pull = climber().magnet.pull_at_contact_n;
    let stall_slip = climb_with_payload(30.0, 200.0, solver).slip_m;
    let weakest = wall.world().adhesion().iter().map(|s| s.force_n).fold(f32::INFINITY, f32::min);
    let sets = [
        format!("world.solver.iterations={}", solver.iterations),
        format!("world.solver.internal_iterations={}", solver.internal_iterations),
        format!("world.solver.ticks_per_step={}", solver.ticks_per_step),
    ];
    let overrides: Vec<Override> = sets.iter().map(|s| Override::parse(s).expect("override")).collect();
    let scenario = Scenario::load_with(&support::repo().join("scenarios/flat-line.toml"), &overrides).expect("flat-line scenario");
    let outcome = run_lockstep(&scenario, &robot()).expect("flat-line run");
    let metric = |key: &str| outcome.summary.get(key).and_then(serde_json::Value::as_f64).unwrap_or(f64::NAN);
    Row {
        solver,
        speed_error_pct: (speed / expected - 1.0) * 100.0,
        wall_drift_mm: wall_drift * 1000.0,
        slope_drift_mm: slope_drift * 1000.0,
        climbing_current_pct: (extra / needed - 1.0) * 100.0,
        magnet_error_deg: magnet_error.to_degrees(),
        wall_pitch_deg: pitch_deg(&wall),
        wall_weakest_pull_pct: weakest / pull * 100.0,
        stall_slip_mm: stall_slip * 1000.0,
        line_settling_s: metric("distance.settling_time_s"),
        line_sse_mm: metric("distance.steady_state_error_m") * 1000.0,
    }
}

fn main() {
    let full_run = std::env::args().any(|a| a == "--bench");
    // Settings named on the command line (`-- --bench 3x1 5x1/2`: iterations x internal
    // iterations, optionally / ticks per physics step) replace the standard list.
    let named: Vec<SolverSettings> = std::env::args().filter_map(|a| parse_setting(&a)).collect();
    let standard = |list: &[(usize, usize, usize)]| list.iter().map(|&(i, j, t)| SolverSettings::new(i, j).every(t)).collect::<Vec<_>>();
    let settings = if !named.is_empty() {
        named
    } else if full_run {
        standard(&[(8, 2, 1), (8, 2, 2), (4, 2, 2), (3, 3, 2), (3, 2, 1), (3, 2, 2), (2, 4, 2), (2, 2, 2), (2, 1, 2), (1, 8, 2), (1, 2, 2)])
    } else {
        vec![SolverSettings::default()]
    };
    let rows: Vec<Row> = settings.iter().map(|&solver| measure(solver)).collect();
    println!("\nsolver fidelity (tolerances of tests/physics.rs in the header; the flat-line scenario's expect: settles, |SSE| ≤ 2 mm)");
    println!(
        "| solver | flat speed vs v·R (±3 %) | wall drift 10 s (< 1 mm) | 30° drift 10 s (< 1 mm) | 60° climbing current vs weight (±20 %) | magnet vs contact angle (< 2°) | wall transition pitch (> 88°) | weakest pull on the wall (> 90 %) | slide at stall, 200 kg on 30° (< {:.0} mm) | flat-line settling (s) | flat-line SSE (mm) |",
        STALL_SLIP_TOLERANCE_M * 1000.0
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for r in &rows {
        println!(
            "| {} | {:+.2} % | {:.3} mm | {:.3} mm | {:+.1} % | {:.2}° | {:.1}° | {:.0} % | {:+.1} mm | {:.1} | {:+.2} |",
            r.solver,
            r.speed_error_pct,
            r.wall_drift_mm,
            r.slope_drift_mm,
            r.climbing_current_pct,
            r.magnet_error_deg,
            r.wall_pitch_deg,
            r.wall_weakest_pull_pct,
            r.stall_slip_mm,
            r.line_settling_s,
            r.line_sse_mm
        );
    }
    if full_run {
        let json = rows
            .iter()
            .map(|r| {
                format!(
                    "{{\"iterations\":{},\"internal_iterations\":{},\"ticks_per_step\":{},\"speed_error_pct\":{:.3},\"wall_drift_mm\":{:.4},\"slope_drift_mm\":{:.4},\"climbing_current_pct\":{:.2},\"magnet_error_deg\":{:.3},\"wall_pitch_deg\":{:.2},\"wall_weakest_pull_pct\":{:.1},\"stall_slip_mm\":{:.2},\"line_settling_s\":{},\"line_sse_mm\":{:.3}}}",
                    r.solver.iterations, r.solver.internal_iterations, r.solver.ticks_per_step, r.speed_error_pct, r.wall_drift_mm, r.slope_drift_mm, r.climbing_current_pct, r.magnet_error_deg, r.wall_pitch_deg, r.wall_weakest_pull_pct, r.stall_slip_mm,
                    if r.line_settling_s.is_finite() { format!("{:.2}", r.line_settling_s) } else { "null".into() }, r.line_sse_mm
                )
            })
            .collect::<Vec<_>>()
            .join(",");
        let path = support::results_dir().join("solver_fidelity.json");
        std::fs::write(&path, format!("{{\"rows\":[{json}]}}\n")).expect("write results");
        println!("results: {}", path.display());
        use support::history::figure;
        let mut figures = Vec::new();
        for r in &rows {
            let s = setting_name(&r.solver);
            figures.extend([
                figure(format!("{s}_speed_error"), r.speed_error_pct, "%"),
                figure(format!("{s}_wall_drift"), r.wall_drift_mm, "mm"),
                figure(format!("{s}_slope_drift"), r.slope_drift_mm, "mm"),
                figure(format!("{s}_climbing_current"), r.climbing_current_pct, "%"),
                figure(format!("{s}_magnet_error"), r.magnet_error_deg, "deg"),
                figure(format!("{s}_wall_pitch"), r.wall_pitch_deg, "deg"),
                figure(format!("{s}_wall_weakest_pull"), r.wall_weakest_pull_pct, "%"),
                figure(format!("{s}_stall_slip"), r.stall_slip_mm, "mm"),
                figure(format!("{s}_line_sse"), r.line_sse_mm, "mm"),
            ]);
        }
        support::history::record("solver_fidelity", &figures);
    }
}

/// `IxJ` or `IxJ/T` (iterations, internal iterations, ticks per physics step; 1 tick if left out).
fn parse_setting(arg: &str) -> Option<SolverSettings> {
    let (passes, ticks) = arg.split_once('/').map_or((arg, Some("1")), |(p, t)| (p, Some(t)));
    let (i, j) = passes.split_once('x')?;
    Some(SolverSettings::new(i.parse().ok()?, j.parse().ok()?).every(ticks?.parse().ok()?))
}

/// The history's name for a setting: `3x2` at one tick per step (the names recorded before
/// physics could step less often than the firmware), `3x2/2` otherwise.
fn setting_name(solver: &SolverSettings) -> String {
    let passes = format!("{}x{}", solver.iterations, solver.internal_iterations);
    match solver.ticks_per_step.get() {
        1 => passes,
        ticks => format!("{passes}/{ticks}"),
    }
}
