//! `climbsim compare --signals FILE`: the seed's own experiment, closed loop. The real run's
//! line offset as the controller measured it (a CSV with `t_s` and `d_m` columns) beside the
//! same controller's run of the scenario in the world, with the seed's step metrics of each
//! (rise time, settling time, overshoot, steady-state error; `crate::metrics`).
//!
//! The world's side is its `d_m`, the camera's measurement that the controller is given (the
//! sensor server's `/line`), not the ground truth: the real robot's log is what *its* camera
//! measured, so the two are the same kind of signal. Samples where the line was not seen (NaN)
//! are left out on both sides.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use serde::Serialize;

use super::compare::{CompareError, CompareOptions};
use super::outputs::failures;
use super::{Console, Pace, run_scenario};
use crate::metrics::{StepCharacteristics, StepOptions, decaying_error_step};
use crate::report::{PlotLabels, PlotSeries, plot_series, read_timeseries_csv};
use crate::robot::{RobotDescription, RobotOverrides};
use crate::scenario::{Override, Scenario};

/// The columns the real run's CSV must have (others are ignored).
pub const TIME_COLUMN: &str = "t_s";
pub const OFFSET_COLUMN: &str = "d_m";

/// One side's line offset and its step metrics.
#[derive(Debug, Clone, Serialize)]
pub struct OffsetStep {
    /// Samples with the line seen.
    pub samples: usize,
    pub duration_s: f64,
    /// `None` when the series cannot be measured (too short, or time not increasing), with
    /// the reason in `error`.
    pub step: Option<StepCharacteristics>,
    pub error: Option<String>,
    /// Time from the first sample (s) and the offset (m), for the plot.
    #[serde(skip)]
    pub series: (Vec<f64>, Vec<f64>),
}

impl OffsetStep {
    /// From raw `t` and `d`: NaN samples dropped, time from the first sample, and samples
    /// later than `within_s` from it left out.
    fn measure(t: &[f64], d: &[f64], within_s: f64) -> Self {
        let (mut times, mut offsets) = (Vec::new(), Vec::new());
        for (&t, &d) in t.iter().zip(d).filter(|(t, d)| t.is_finite() && d.is_finite()) {
            times.push(t);
            offsets.push(d);
        }
        let start = times.first().copied().unwrap_or(0.0);
        times.iter_mut().for_each(|t| *t -= start);
        let kept = times.iter().take_while(|t| **t <= within_s).count();
        times.truncate(kept);
        offsets.truncate(kept);
        let measured = decaying_error_step(&times, &offsets, &StepOptions::default());
        Self { samples: times.len(), duration_s: times.last().copied().unwrap_or(0.0), step: measured.as_ref().ok().copied(), error: measured.err().map(|e| e.to_string()), series: (times, offsets) }
    }
}

/// The real run against the world's, side by side (`signals.json`).
#[derive(Debug, Clone, Serialize)]
pub struct SignalsComparison {
    pub file: PathBuf,
    /// The world's run of the scenario (its usual outputs).
    pub run_dir: PathBuf,
    pub robot: OffsetStep,
    pub world: OffsetStep,
    /// RMS of world − robot (m) at the robot's samples (the world's interpolated), over the
    /// time both cover, each from its first sample: how far apart the two closed loops ran.
    pub rms_difference_m: Option<f64>,
}

/// One of the step's metrics, if the step has it.
type Metric = fn(&StepCharacteristics) -> Option<f64>;

impl SignalsComparison {
    /// A table for the terminal: each metric, the robot's, the world's and their difference.
    pub fn table(&self) -> String {
        let pick = |side: &OffsetStep, f: Metric| side.step.as_ref().and_then(f);
        // (name, the metric, its scale to the unit shown, the unit)
        let rows: [(&str, Metric, f64, &str); 4] = [
            ("rise time", |s| s.rise_time, 1.0, "s"),
            ("settling time", |s| s.settling_time, 1.0, "s"),
            ("overshoot", |s| Some(s.overshoot_pct), 1.0, "%"),
            ("steady-state error", |s| Some(s.steady_state_error), 1e3, "mm"),
        ];
        let shown = |v: Option<f64>, scale: f64| v.map_or_else(|| "-".to_owned(), |v| format!("{:.3}", v * scale));
        let mut out =
            format!("the line offset's step, robot ({} samples over {:.1} s) and world ({} over {:.1} s):\n", self.robot.samples, self.robot.duration_s, self.world.samples, self.world.duration_s);
        if let Some(rms) = self.rms_difference_m {
            out.push_str(&format!("  d(t), world against robot: RMS {:.3} mm\n", rms * 1e3));
        }
        out.push_str("  metric                 unit       robot       world    world − robot\n");
        for (name, f, scale, unit) in rows {
            let (robot, world) = (pick(&self.robot, f), pick(&self.world, f));
            let difference = robot.zip(world).map(|(r, w)| w - r);
            out.push_str(&format!("  {name:<22} {unit:<6} {:>10} {:>11} {:>16}\n", shown(robot, scale), shown(world, scale), shown(difference, scale)));
        }
        for (side, step) in [("robot", &self.robot), ("world", &self.world)] {
            if let Some(error) = &step.error {
                out.push_str(&format!("  the {side}'s offset cannot be measured: {error}\n"));
            }
        }
        out
    }
}

/// Read the real run's offsets from `file`, run the scenario of `options` (its controller, as
/// `check` runs it, with `options`' robot and keys) for as long as the real run lasted into
/// `out/world-run`, and set the two side by side; writes `signals.json` and
/// `plots/line_offset.png`/`.svg` into `options.out`.
pub fn compare_signals(file: &Path, options: &CompareOptions, pace: Pace, stop: &AtomicBool) -> Result<SignalsComparison, CompareError> {
    let real = read_timeseries_csv(file).map_err(CompareError::Plot)?;
    let column = |name: &str| {
        real.column(name).ok_or_else(|| CompareError::Signals {
            path: file.to_owned(),
            message: format!("no `{name}` column (the header has {}; the file needs `{TIME_COLUMN}` and `{OFFSET_COLUMN}`)", real.columns().join(", ")),
        })
    };
    let (t, d) = (column(TIME_COLUMN)?, column(OFFSET_COLUMN)?);
    let robot_side = OffsetStep::measure(&t, &d, f64::INFINITY);
    if robot_side.samples < 2 {
        return Err(CompareError::Signals { path: file.to_owned(), message: format!("{} samples with a finite `{OFFSET_COLUMN}`: at least 2 are needed", robot_side.samples) });
    }
    // The world runs a little longer than the robot's log lasts (its controller starts a few
    // periods in), unless a `--set world.duration_s` says otherwise; its series is then cut to
    // the robot's length.
    let (mut scenario_sets, robot_sets) = RobotOverrides::split(&options.overrides);
    if !scenario_sets.iter().any(|o| o.key == DURATION_KEY) {
        let duration_s = (t.iter().copied().filter(|t| t.is_finite()).fold(f64::NEG_INFINITY, f64::max) + 0.5).max(1.0);
        scenario_sets.push(Override { key: DURATION_KEY.to_owned(), value: toml::Value::Float(duration_s) });
    }
    let scenario = Scenario::load_with(&options.scenario, &scenario_sets)?;
    let robot = RobotDescription::load_with(&options.robot, &robot_sets)?;
    let run_dir = options.out.join("world-run");
    std::fs::create_dir_all(&run_dir).map_err(|source| CompareError::Write { path: run_dir.clone(), source })?;
    // Its notes (timing tables, files written) would bury the comparison: they are in its folder.
    let outcome = run_scenario(&scenario, &robot, &run_dir, pace, stop, &Unheard)?;
    let failed = failures(&outcome.summary);
    if !failed.is_empty() {
        return Err(CompareError::Signals { path: options.scenario.clone(), message: format!("the world's run failed ({}; its outputs are in {})", failed.join("; "), run_dir.display()) });
    }
    let (world_t, world_d) = (outcome.track.column(TIME_COLUMN).unwrap_or_default(), outcome.track.column(OFFSET_COLUMN).unwrap_or_default());
    // The same window on both sides: the step's metrics depend on it.
    let world_side = OffsetStep::measure(&world_t, &world_d, robot_side.duration_s);
    let rms_difference_m = rms_difference(&robot_side.series, &world_side.series);
    let comparison = SignalsComparison { file: file.to_owned(), run_dir, robot: robot_side, world: world_side, rms_difference_m };
    write_signals(&comparison, &options.out)?;
    Ok(comparison)
}

/// RMS of `b` − `a` at `a`'s times within `b`'s span, `b` interpolated linearly (both sorted
/// by time); `None` without an overlap.
fn rms_difference((a_t, a_d): &(Vec<f64>, Vec<f64>), (b_t, b_d): &(Vec<f64>, Vec<f64>)) -> Option<f64> {
    let (mut sum, mut count, mut j) = (0.0, 0usize, 0usize);
    for (&t, &d) in a_t.iter().zip(a_d) {
        while j + 1 < b_t.len() && b_t[j + 1] < t {
            j += 1;
        }
        let (Some(&t0), Some(&t1)) = (b_t.get(j), b_t.get(j + 1)) else { break };
        if t < t0 || t > t1 {
            continue;
        }
        let fraction = if t1 > t0 { (t - t0) / (t1 - t0) } else { 0.0 };
        let at = b_d[j] + fraction * (b_d[j + 1] - b_d[j]);
        sum += (at - d) * (at - d);
        count += 1;
    }
    (count > 0).then(|| (sum / count as f64).sqrt())
}

/// The scenario key the world's run length is set with.
const DURATION_KEY: &str = "world.duration_s";

/// A console nobody reads.
struct Unheard;

impl Console for Unheard {
    fn say(&self, _: &str) {}
    fn note(&self, _: &str) {}
}

fn write_signals(comparison: &SignalsComparison, out: &Path) -> Result<(), CompareError> {
    let path = out.join("signals.json");
    let text = serde_json::to_string_pretty(comparison).unwrap_or_default() + "\n";
    std::fs::write(&path, text).map_err(|source| CompareError::Write { path, source })?;
    let plots = out.join("plots");
    std::fs::create_dir_all(&plots).map_err(|source| CompareError::Write { path: plots.clone(), source })?;
    let millimetres = |d: &[f64]| d.iter().map(|d| d * 1e3).collect::<Vec<f64>>();
    let (robot_d, world_d) = (millimetres(&comparison.robot.series.1), millimetres(&comparison.world.series.1));
    let labels = PlotLabels { title: "line offset, measured: the robot and the world", x: "t (s, from the first sample)", y: "d (mm)" };
    let lines = [PlotSeries { label: "robot", x: &comparison.robot.series.0, y: &robot_d }, PlotSeries { label: "world", x: &comparison.world.series.0, y: &world_d }];
    plot_series(&plots, "line_offset", &labels, &lines).map_err(CompareError::Plot)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_difference_is_taken_where_both_have_samples_the_second_interpolated() {
        let a = (vec![0.0, 0.5, 1.0, 3.0], vec![1.0, 1.0, 1.0, 9.0]);
        let b = (vec![0.0, 1.0, 2.0], vec![1.0, 2.0, 2.0]);
        // At 0: 0; at 0.5: 1.5 − 1; at 1: 2 − 1; 3 is past b's end.
        let expected = ((0.0 + 0.25 + 1.0) / 3.0_f64).sqrt();
        assert!((rms_difference(&a, &b).expect("an overlap") - expected).abs() < 1e-12);
        assert_eq!(rms_difference(&a, &(vec![5.0, 6.0], vec![0.0, 0.0])), None);
    }

    #[test]
    fn a_measured_offset_leaves_out_unseen_samples_and_starts_at_its_first() {
        let t = [2.0, 2.5, 3.0, 3.5, 4.0, 4.5];
        let d = [0.01, f64::NAN, 0.005, 0.001, 0.0, 0.0];
        let step = OffsetStep::measure(&t, &d, f64::INFINITY);
        assert_eq!(step.samples, 5);
        assert_eq!(step.series.0, vec![0.0, 1.0, 1.5, 2.0, 2.5]);
        assert_eq!(OffsetStep::measure(&t, &d, 1.5).series.0, vec![0.0, 1.0, 1.5]);
        assert!(step.step.is_some_and(|s| s.reference == 0.01), "{step:?}");
    }
}
