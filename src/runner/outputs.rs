//! What a finished run leaves behind: its outcome (summary, metric track, settings), the
//! summary's shared keys (failures, faults), and the output folder's files.

use serde_json::{Value, json};

use crate::bus::Bus;
use crate::report::{self, Summary, TimeSeries};
use crate::robot::RobotDescription;
use crate::runner::observe::capture::MetricTrack;
use crate::runner::observe::watch::RunFailure;
use crate::scenario::{ControllerSection, Scenario};
use crate::sim::LineCameraSettings;

use std::path::Path;

use crate::transport::{BusHandle, PhysicsPace, TimingReport};

use super::RunError;
use super::{Console, During as _, RunnerError};

/// Why a run failed other than by its thresholds (`summary.json`'s `failures`, one line each;
/// empty for a run that went as far as it should).
pub fn failures(summary: &Summary) -> Vec<String> {
    summary.get("failures").and_then(Value::as_array).map_or_else(Vec::new, |lines| lines.iter().map(|l| l.as_str().map_or_else(|| l.to_string(), str::to_owned)).collect())
}

/// Test a finished run against its scenario's `[expect]` thresholds (`run` and `check`; a sweep
/// does not): every reason it failed, its own verdict's first, also written into
/// `summary.json`'s `failures` in `out_dir`, so that the file says what the exit code says.
pub fn judge(outcome: &mut RunOutcome, scenario: &Scenario, out_dir: &Path) -> Result<Vec<String>, RunError> {
    let mut all = failures(&outcome.summary);
    let broken = scenario.failed_expectations(&outcome.summary);
    if broken.is_empty() {
        return Ok(all);
    }
    all.extend(broken);
    outcome.summary.insert("failures".to_owned(), json!(all));
    report::write_summary_json(out_dir, &outcome.summary)?;
    Ok(all)
}

/// Record `failure` in `summary` (`failures` and `failure_at_s`).
pub fn record_failure(summary: &mut Summary, failure: &RunFailure) {
    let mut lines = failures(summary);
    lines.push(failure.message.clone());
    summary.insert("failures".to_owned(), json!(lines));
    summary.insert("failure_at_s".to_owned(), json!(failure.at_s));
}

/// A finished run.
pub struct RunOutcome {
    /// The captured rows when the run kept them in memory ([`super::lockstep::run_lockstep`], replay); `None`
    /// when it wrote them into its output folder's `timeseries.csv` as they came.
    pub series: Option<TimeSeries>,
    /// The fixed-rate signals the summary and plots were made of (see [`MetricTrack`]).
    pub track: MetricTrack,
    pub summary: Summary,
    pub settings: Value,
    /// Simulated and wall-clock seconds.
    pub sim_s: f64,
    pub wall_s: f64,
}

/// An f32 setting as JSON with the digits it was written with (`0.05`, not the f64 widening
/// `0.05000000074505806`).
fn f32_json(value: f32) -> Value {
    value.to_string().parse::<f64>().map_or(Value::Null, Value::from)
}

/// What `settings.json` records: everything that shaped the run — the scenario as run (after
/// overrides, which are listed too), the values taken from the robot description where the
/// scenario gives none (camera, friction), the start pose as computed, and the robot.
pub fn settings_json(scenario: &Scenario, robot: &RobotDescription) -> Value {
    // The run's world was built from the robot's mechanics; a description without them has no
    // camera or tread of its own to record.
    let camera = scenario.camera.clone().or_else(|| robot.camera.as_ref().map(LineCameraSettings::from_mount));
    let start = scenario.start.clone().unwrap_or_default();
    let pose = scenario.start_pose();
    json!({
        "scenario": scenario.path.display().to_string(),
        "overrides": scenario.overrides,
        "seed": scenario.world.seed,
        "duration_s": scenario.world.duration_s,
        "gravity_m_s2": scenario.world.gravity_m_s2,
        "terrain": serde_json::to_value(&scenario.terrain).unwrap_or(Value::Null),
        "line": serde_json::to_value(&scenario.line).unwrap_or(Value::Null),
        "speed": { "target_mm_min": scenario.speed.target_mm_min, "step_at_s": scenario.speed.step_at_s },
        "controller": match &scenario.controller {
            ControllerSection::Builtin(config) => serde_json::to_value(config).unwrap_or(Value::Null),
            ControllerSection::External(external) => json!({ "command": external.command }),
        },
        "robot": robot.path.display().to_string(),
        "faults": scenario.faults(),
        "events": serde_json::to_value(&scenario.events).unwrap_or(Value::Null),
        "camera": serde_json::to_value(&camera).unwrap_or(Value::Null),
        "start": {
            "x_m": f32_json(start.x_m), "z_m": f32_json(start.z_m), "yaw_deg": f32_json(start.yaw_deg), "line_offset_m": f32_json(start.line_offset_m),
            "pose": { "x_m": f32_json(pose.x_m), "z_m": f32_json(pose.z_m), "yaw_deg": f32_json(pose.yaw_deg), "clearance_m": f32_json(pose.clearance_m) },
        },
        "solver": scenario.world.solver,
        "payload_kg": f32_json(scenario.world.payload_kg),
        "friction": scenario.world.friction.or(robot.wheel.as_ref().map(|wheel| wheel.friction)).map_or(Value::Null, f32_json),
        "magnets": scenario.world.magnets,
        "bus_baud_bps": scenario.bus.baud_bps.unwrap_or(robot.bus.baud_bps),
        "capture": {
            "rate_hz": scenario.capture.rate_hz,
            "on_line_tolerance_m": scenario.capture.on_line_tolerance_m,
            "signals": scenario.capture.signals,
            "metric_period_s": crate::runner::observe::capture::METRIC_PERIOD_S,
            "mcap": scenario.capture.mcap,
            "bus_packets": scenario.capture.bus_packets,
        },
    })
}

/// The summary's fault keys: how many faults were scheduled and what the bus-level ones did.
pub fn fault_summary(bus: &Bus) -> Vec<(String, Value)> {
    let faults = bus.faults();
    let counts = faults.counts();
    let mut entries = vec![("faults.scheduled".to_owned(), json!(faults.scheduled().len()))];
    if faults.is_empty() {
        return entries;
    }
    let kinds: Vec<String> = faults.scheduled().iter().map(|f| f.fault.kind().to_owned()).collect();
    entries.extend([
        ("faults.kinds".to_owned(), json!(kinds.join(","))),
        ("faults.instructions_corrupted".to_owned(), json!(counts.instructions_corrupted)),
        ("faults.replies_corrupted".to_owned(), json!(counts.replies_corrupted)),
        ("faults.replies_dropped".to_owned(), json!(counts.replies_dropped)),
        ("faults.replies_delayed".to_owned(), json!(counts.replies_delayed)),
        ("faults.instructions_unheard".to_owned(), json!(counts.instructions_unheard)),
    ]);
    for servo in bus.servos() {
        entries.push((format!("faults.hw_error_{}", servo.id()), json!(servo.hardware_error_status())));
    }
    entries
}

/// Write a run's outputs into `out_dir`: `timeseries.csv` (unless the run streamed it there
/// already: `outcome.series` is `None`), `summary.json`, `settings.json`, `report.xlsx` (its raw
/// sheet read back from the CSV file), and distance and speed plots (PNG and SVG) of the metric
/// track.
pub fn write_outputs(outcome: &RunOutcome, out_dir: &std::path::Path) -> Result<(), RunError> {
    std::fs::create_dir_all(out_dir).map_err(|source| report::ReportError::Io { path: out_dir.to_owned(), source })?;
    let csv = match &outcome.series {
        Some(series) => report::write_timeseries_csv(out_dir, series)?,
        None => out_dir.join(report::TIMESERIES_CSV),
    };
    report::write_summary_json(out_dir, &outcome.summary)?;
    report::write_settings_json(out_dir, &outcome.settings)?;
    report::write_workbook(out_dir, &csv, &outcome.settings, &outcome.summary)?;
    let column = |name: &str| outcome.track.column(name).unwrap_or_default();
    // Plotted in the units scenarios use (mm, mm/min); the files keep SI.
    let shown = |name: &str| {
        let (factor, _) = report::units::shown_unit(name);
        column(name).into_iter().map(|v| v * factor).collect::<Vec<f64>>()
    };
    let t = column("t_s");
    for (stem, title, y, [(first, first_label), (second, second_label)]) in [
        ("distance", "Distance error", "d (mm)", [("d_true_m", "ground truth"), ("d_m", "camera")]),
        ("speed", "Speed", "speed (mm/min)", [("speed_m_s", "ground truth"), ("target_speed_m_s", "target")]),
    ] {
        let (first_y, second_y) = (shown(first), shown(second));
        report::plot_series(
            out_dir,
            stem,
            &report::PlotLabels { title, x: "t (s)", y },
            &[report::PlotSeries { label: first_label, x: &t, y: &first_y }, report::PlotSeries { label: second_label, x: &t, y: &second_y }],
        )?;
    }
    if !outcome.track.path().is_empty() {
        report::plot_path(out_dir, "path", outcome.track.lines(), outcome.track.path(), outcome.track.heights(), outcome.track.view())?;
    }
    Ok(())
}

/// Tell the session's timing summary and, if asked, write the report and its plot.
pub fn finish_timing_report(handle: &BusHandle, pace: &PhysicsPace, path: Option<&Path>, console: &dyn Console) -> Result<TimingReport, RunnerError> {
    let report = handle.timing_report(pace);
    console.note(&report.human_summary());
    if let Some(path) = path {
        let files = report::write_timing_report(path, &report).during(|| format!("cannot write the timing report {}", path.display()))?;
        for file in files {
            console.note(&format!("  wrote {}", file.display()));
        }
    }
    Ok(report)
}
