//! `summary.json` (the run's metrics as one flat object) and `settings.json`.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde_json::Value;

use super::ReportError;
use super::atomic::write_bytes_atomically;
use crate::metrics::{LineTracking, StepCharacteristics};

/// File name of the metrics summary in the output directory.
pub const SUMMARY_JSON: &str = "summary.json";
/// File name of the run's settings in the output directory.
pub const SETTINGS_JSON: &str = "settings.json";

/// Metric name → number, `null` (does not exist, e.g. never settled) or bool. Names carry their
/// unit: `distance.rise_time_s`, `speed.steady_state_error_m_s`, `rms_distance_m`. Sorted, so
/// the file diffs well between runs.
pub type Summary = BTreeMap<String, Value>;

/// Flattens the distance step (the line-following error, metres), the speed step (m/s) and the
/// line tracking into a [`Summary`]. Absent parts add no keys. Entries that are not step metrics,
/// such as `realtime_factor`, are added by the caller with [`BTreeMap::insert`].
///
/// Keys: `distance.` and `speed.` each with `step_time_s`, `rise_time_s`, `settling_time_s`,
/// `settled`, `overshoot_pct`, plus `distance.initial_error_m` and
/// `distance.steady_state_error_m`, `speed.target_m_s` and `speed.steady_state_error_m_s`; and
/// `rms_distance_m`, `max_abs_distance_m`, `time_on_line_s`, `time_on_line_fraction`,
/// `line_tolerance_m`.
pub fn summarise(distance: Option<&StepCharacteristics>, speed: Option<&StepCharacteristics>, line: Option<&LineTracking>) -> Summary {
    let mut summary = Summary::new();
    if let Some(step) = distance {
        insert_step(&mut summary, "distance", step, "initial_error_m", "steady_state_error_m");
    }
    if let Some(step) = speed {
        insert_step(&mut summary, "speed", step, "target_m_s", "steady_state_error_m_s");
    }
    if let Some(line) = line {
        let entries = [
            ("rms_distance_m", line.rms),
            ("max_abs_distance_m", line.max_abs),
            ("time_on_line_s", line.time_on_line),
            ("time_on_line_fraction", line.fraction_on_line),
            ("line_tolerance_m", line.tolerance),
        ];
        for (key, value) in entries {
            summary.insert(key.to_owned(), Value::from(value));
        }
    }
    summary
}

fn insert_step(summary: &mut Summary, prefix: &str, step: &StepCharacteristics, reference_key: &str, steady_state_key: &str) {
    // Value::from turns a non-finite f64 into null, and None into null.
    let entries = [
        ("step_time_s", Value::from(step.t_step)),
        (reference_key, Value::from(step.reference)),
        ("rise_time_s", Value::from(step.rise_time)),
        ("settling_time_s", Value::from(step.settling_time)),
        ("settled", Value::from(step.settled)),
        ("overshoot_pct", Value::from(step.overshoot_pct)),
        (steady_state_key, Value::from(step.steady_state_error)),
    ];
    for (key, value) in entries {
        summary.insert(format!("{prefix}.{key}"), value);
    }
}

/// Writes `summary` to `out_dir/summary.json` atomically and returns the file's path.
pub fn write_summary_json(out_dir: &Path, summary: &Summary) -> Result<PathBuf, ReportError> {
    write_json(&out_dir.join(SUMMARY_JSON), summary)
}

/// How the host ran a controller's threads under virtual time (see `runner::time_base`): apart
/// from `summary.json`, which repeats between identical runs, while these counts need not.
pub const SCHEDULER_JSON: &str = "scheduler.json";

/// Writes `counts` to `out_dir/scheduler.json` atomically and returns the file's path.
pub fn write_scheduler_json(out_dir: &Path, counts: &Value) -> Result<PathBuf, ReportError> {
    write_json(&out_dir.join(SCHEDULER_JSON), counts)
}

/// Writes the run's settings (the scenario and options, as the caller assembled them) to
/// `out_dir/settings.json` atomically and returns the file's path.
pub fn write_settings_json(out_dir: &Path, settings: &Value) -> Result<PathBuf, ReportError> {
    write_json(&out_dir.join(SETTINGS_JSON), settings)
}

pub(super) fn write_json(path: &Path, value: &impl serde::Serialize) -> Result<PathBuf, ReportError> {
    let mut text = serde_json::to_vec_pretty(value).map_err(|source| ReportError::Json { path: path.to_path_buf(), source })?;
    // A final newline, as text tools expect; writing into a Vec cannot fail.
    let _ = text.write_all(b"\n");
    write_bytes_atomically(path, &text)?;
    Ok(path.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn step(reference: f64, settling_time: Option<f64>) -> StepCharacteristics {
        StepCharacteristics { t_step: 0.0, reference, rise_time: Some(1.5), settling_time, settled: settling_time.is_some(), overshoot_pct: 4.3, steady_state_error: -0.001 }
    }

    #[test]
    fn flattens_both_steps_and_the_line_tracking_with_units_in_the_keys() {
        let distance = step(0.3, Some(4.0));
        let speed = step(0.004, None);
        let line = LineTracking { max_abs: 0.3, rms: 0.1, tolerance: 0.01, time_on_line: 7.5, fraction_on_line: 0.75 };
        let mut summary = summarise(Some(&distance), Some(&speed), Some(&line));
        summary.insert("realtime_factor".to_owned(), json!(12.5));
        assert_eq!(summary["distance.rise_time_s"], json!(1.5));
        assert_eq!(summary["distance.settling_time_s"], json!(4.0));
        assert_eq!(summary["distance.overshoot_pct"], json!(4.3));
        assert_eq!(summary["distance.steady_state_error_m"], json!(-0.001));
        assert_eq!(summary["distance.initial_error_m"], json!(0.3));
        assert_eq!(summary["speed.settling_time_s"], Value::Null);
        assert_eq!(summary["speed.settled"], json!(false));
        assert_eq!(summary["speed.steady_state_error_m_s"], json!(-0.001));
        assert_eq!(summary["speed.target_m_s"], json!(0.004));
        assert_eq!(summary["rms_distance_m"], json!(0.1));
        assert_eq!(summary["max_abs_distance_m"], json!(0.3));
        assert_eq!(summary["time_on_line_s"], json!(7.5));
        assert_eq!(summary.len(), 7 + 7 + 5 + 1);
    }

    #[test]
    fn absent_parts_add_no_keys() {
        let summary = summarise(None, Some(&step(0.004, Some(2.0))), None);
        assert!(summary.keys().all(|key| key.starts_with("speed.")), "{summary:?}");
    }

    #[test]
    fn both_files_are_flat_json_objects() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let summary = summarise(Some(&step(0.3, None)), None, None);
        let path = write_summary_json(dir.path(), &summary).expect("written");
        let read: Value = serde_json::from_str(&std::fs::read_to_string(path).expect("readable")).expect("JSON");
        assert_eq!(read["distance.settling_time_s"], Value::Null);
        assert_eq!(read["distance.rise_time_s"], json!(1.5));

        let settings = json!({"controller": {"kd": 2.0, "kpsi": -1.5}, "seed": 7});
        let path = write_settings_json(dir.path(), &settings).expect("written");
        let read: Value = serde_json::from_str(&std::fs::read_to_string(path).expect("readable")).expect("JSON");
        assert_eq!(read, settings);
    }
}
