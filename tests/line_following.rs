//! The seed's line-following task end to end: camera, detector, reference controller on the
//! real bus, rapier physics, metrics. These are closed-loop physics results that can fail.

use std::path::{Path, PathBuf};

use climbsim::robot::RobotDescription;
use climbsim::runner::lockstep::run_lockstep;
use climbsim::scenario::{Override, Scenario};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn robot() -> RobotDescription {
    RobotDescription::load(&RobotDescription::default_path()).expect("robot")
}

fn run(scenario: &str, sets: &[&str]) -> climbsim::runner::RunOutcome {
    let overrides: Vec<Override> = sets.iter().map(|s| Override::parse(s).expect("override")).collect();
    let scenario = Scenario::load_with(&repo().join(scenario), &overrides).unwrap_or_else(|e| panic!("{e}"));
    run_lockstep(&scenario, &robot()).unwrap_or_else(|e| panic!("{e}"))
}

/// The rows `run_lockstep` keeps in memory (it has no output folder to stream them to).
fn series(outcome: &climbsim::runner::RunOutcome) -> &climbsim::report::TimeSeries {
    outcome.series.as_ref().expect("run_lockstep keeps the captured rows")
}

fn metric(outcome: &climbsim::runner::RunOutcome, key: &str) -> Option<f64> {
    outcome.summary.get(key).and_then(serde_json::Value::as_f64)
}

#[test]
fn the_flat_line_scenario_converges_onto_the_line() {
    let outcome = run("scenarios/flat-line.toml", &[]);
    let settling = metric(&outcome, "distance.settling_time_s");
    let sse = metric(&outcome, "distance.steady_state_error_m").expect("steady-state error");
    assert!(settling.is_some_and(f64::is_finite), "never settled: {:?}", outcome.summary);
    assert!(sse.abs() < 0.002, "steady-state error {sse} m");
    // The camera saw the line the whole way and agreed with the ground truth.
    let seen = series(&outcome).column("line_valid").expect("line_valid");
    assert!(seen.iter().all(|&v| v == 1.0), "the camera lost the line");
    let (camera, truth) = (series(&outcome).column("d_m").expect("d_m"), series(&outcome).column("d_true_m").expect("d_true_m"));
    let mut differences: Vec<f64> = camera.iter().zip(&truth).map(|(c, t)| (c - t).abs()).collect();
    differences.sort_by(f64::total_cmp);
    let (median, worst) = (differences[differences.len() / 2], differences[differences.len() - 1]);
    // The camera measures across the robot's own axis and up to a frame late (33 ms at 17 mm/s);
    // the ground truth is the perpendicular distance now. They agree to a pixel (1.6 mm) or so.
    assert!(median < 0.0005 && worst < 0.005, "camera vs ground truth: median {median} m, worst {worst} m");
}

#[test]
fn raising_zeta_lowers_the_overshoot() {
    let overshoot = |zeta: &str| {
        let outcome = run("scenarios/flat-line.toml", &[&format!("controller.zeta={zeta}"), "world.duration_s=70"]);
        metric(&outcome, "distance.overshoot_pct").expect("overshoot")
    };
    let (low, high) = (overshoot("0.5"), overshoot("1.4"));
    assert!(low > 10.0, "zeta 0.5 overshoots clearly ({low:.1} %)");
    assert!(high < low / 2.0, "zeta 1.4 overshoots {high:.1} % against {low:.1} % at zeta 0.5");
}

#[test]
fn a_speed_step_event_changes_the_target_and_the_robot_follows() {
    let outcome = run("scenarios/flat-line.toml", &["world.duration_s=30", "events=[{at_s = 15.0, set_speed_mm_min = 2000.0}]"]);
    let (t, speed, target) = (series(&outcome).column("t_s").expect("t"), series(&outcome).column("speed_m_s").expect("speed"), series(&outcome).column("target_speed_m_s").expect("target"));
    let mean_between = |from: f64, to: f64| {
        let values: Vec<f64> = t.iter().zip(&speed).filter(|(t, _)| **t >= from && **t < to).map(|(_, v)| *v).collect();
        values.iter().sum::<f64>() / values.len() as f64
    };
    assert_eq!(target.last().copied(), Some(2000.0 / 60_000.0));
    let (before, after) = (mean_between(8.0, 15.0), mean_between(23.0, 30.0));
    assert!((after / before - 2.0).abs() < 0.3, "speed {before:.5} → {after:.5} m/s for a 1000 → 2000 mm/min step");
}

#[test]
fn a_scenario_without_a_line_is_refused_by_name() {
    let scenario = Scenario::load(Path::new(&repo().join("scenarios/flat.toml"))).expect("scenario");
    let error = run_lockstep(&scenario, &robot()).err().expect("no line, no run").to_string();
    assert!(error.contains("flat.toml") && error.contains("[line]"), "{error}");
}

#[test]
fn captured_signals_select_the_columns_and_unknown_ones_are_named() {
    let outcome = run("scenarios/flat-line.toml", &["world.duration_s=1", "capture.signals=[\"d_m\", \"speed_m_s\"]"]);
    assert_eq!(series(&outcome).columns(), ["t_s", "d_m", "speed_m_s"]);
    // Metrics still come from the full series.
    assert!(metric(&outcome, "rms_distance_m").is_some());
    let overrides = [Override::parse("capture.signals=[\"d_mm\"]").expect("override")];
    let scenario = Scenario::load_with(&repo().join("scenarios/flat-line.toml"), &overrides).expect("scenario");
    let error = run_lockstep(&scenario, &robot()).err().expect("unknown signal").to_string();
    assert!(error.contains("flat-line.toml") && error.contains("`d_mm`"), "{error}");
}

/// A weld line that curves with a 1 m radius: the seed's proportional law needs a standing
/// distance error to hold the turn (ω = K_d·d_err = V/R, about 2 mm here), and integral action
/// (`controller.integral_pole_rad_s`) removes it. Both are measured by the robot's own camera.
#[test]
fn integral_action_removes_the_standing_error_on_a_curved_line() {
    let radius = 1.0f64;
    let arc: Vec<String> = (1..=60).map(|i| f64::from(i) * 0.05).map(|a| format!("[{:.4}, {:.4}]", radius * a.sin(), radius * (1.0 - a.cos()))).collect();
    let points = format!("line.points=[[-0.5, 0.0], [0.0, 0.0], {}]", arc.join(", "));
    let standing_error = |pole: &str| {
        let outcome = run("scenarios/flat-line.toml", &[&points, &format!("controller.integral_pole_rad_s={pole}"), "world.duration_s=150", "expect={}"]);
        let (t, d) = (series(&outcome).column("t_s").expect("t"), series(&outcome).column("d_m").expect("d_m"));
        let tail: Vec<f64> = t.iter().zip(&d).filter(|(t, _)| **t >= 100.0).map(|(_, d)| *d).collect();
        tail.iter().sum::<f64>() / tail.len() as f64
    };
    let (proportional, integral) = (standing_error("0"), standing_error("0.1"));
    assert!(proportional.abs() > 0.0015, "the proportional law holds the turn with a standing error: {proportional} m");
    assert!(integral.abs() < 0.0003, "integral action removes it: {integral} m (proportional: {proportional} m)");
}
