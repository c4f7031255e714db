//! What a run records besides its events: the captured rows of `timeseries.csv` (at
//! `[capture] rate_hz`, cut to `[capture] signals`) and the metric track, the few signals the
//! summary and the plots need, every [`METRIC_PERIOD_S`] of simulated time whatever the capture
//! rate. The rows can go straight into the output folder's CSV file as they come, so that a
//! run of hours holds only the track (about 1 KB per simulated second) in memory; the summary
//! comes from the track, so it does not change with the capture rate.

use std::path::Path;

use crate::metrics::{self, StepOptions};
use crate::report::{self, HeightGrid, PathView, ReportError, Summary, TimeSeries, TimeSeriesWriter};

/// The time series' columns, in order.
pub const COLUMNS: &[&str] = &[
    "t_s",
    "d_m",
    "psi_rad",
    "line_valid",
    "d_true_m",
    "psi_true_rad",
    "speed_m_s",
    "target_speed_m_s",
    "speed_error_m_s",
    "measured_speed_m_s",
    "yaw_rate_command_rad_s",
    "wheel_rate_fl_rad_s",
    "wheel_rate_fr_rad_s",
    "wheel_rate_rl_rad_s",
    "wheel_rate_rr_rad_s",
    "magnet_angle_fl_rad",
    "magnet_angle_fr_rad",
    "magnet_angle_rl_rad",
    "magnet_angle_rr_rad",
    "adhesion_fl_n",
    "adhesion_fr_n",
    "adhesion_rl_n",
    "adhesion_rr_n",
    "x_m",
    "y_m",
    "z_m",
    // Faults (issue #5): Hardware Error Status, winding temperature and supply of servos 1-8
    // (NaN for an ID not on the bus), tread slip per wheel, active faults, bus-fault tally.
    "hw_error_1",
    "hw_error_2",
    "hw_error_3",
    "hw_error_4",
    "hw_error_5",
    "hw_error_6",
    "hw_error_7",
    "hw_error_8",
    "temperature_1_c",
    "temperature_2_c",
    "temperature_3_c",
    "temperature_4_c",
    "temperature_5_c",
    "temperature_6_c",
    "temperature_7_c",
    "temperature_8_c",
    "input_voltage_1_v",
    "input_voltage_2_v",
    "input_voltage_3_v",
    "input_voltage_4_v",
    "input_voltage_5_v",
    "input_voltage_6_v",
    "input_voltage_7_v",
    "input_voltage_8_v",
    "torque_on_1",
    "torque_on_2",
    "torque_on_3",
    "torque_on_4",
    "wheel_slip_fl_m_s",
    "wheel_slip_fr_m_s",
    "wheel_slip_rl_m_s",
    "wheel_slip_rr_m_s",
    "faults_active",
    "bus_faults",
    // The LIDAR's latest scan (NaN without a `[lidar]`; infinite: no return within range).
    "lidar_ahead_m",
    "lidar_nearest_m",
    // Each wheel's contact direction (centre to the closest terrain point) in its section's
    // frame: in the wheel's plane (what a magnet can follow) and out of it (the contact off the
    // tread's middle); NaN without terrain in reach.
    "contact_in_plane_fl_rad",
    "contact_in_plane_fr_rad",
    "contact_in_plane_rl_rad",
    "contact_in_plane_rr_rad",
    "contact_lateral_fl_rad",
    "contact_lateral_fr_rad",
    "contact_lateral_rl_rad",
    "contact_lateral_rr_rad",
    // The built-in controller's wall transition: 0 following, 1 squaring up to the surface
    // ahead, 2 climbing with the front magnets held, 3 done (NaN without one).
    "transition_phase",
    // The built-in controller's relocation between welds: the weld it follows (0 = [line]),
    // that minus 0.5 while driving to it, -1 finished, -2 stuck (NaN without relocation).
    "relocation_leg",
];

/// The metric track's sampling period (s of simulated time): the built-in controller's default
/// control period, the rate at which the summary's figures were always taken.
pub const METRIC_PERIOD_S: f64 = 0.02;

/// Ground truth, camera and speed every [`METRIC_PERIOD_S`]: what `summary.json`, the distance
/// and speed plots and a sweep's overlay plots are made of. Samples are f32 (a micrometre at a
/// metre, far below the camera's 1.6 mm pixel) but times f64, which a day of runs needs, and the
/// target speed, which the summary reports as given (`speed.target_m_s`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MetricTrack {
    t_s: Vec<f64>,
    d_true_m: Vec<f32>,
    d_m: Vec<f32>,
    speed_m_s: Vec<f32>,
    target_speed_m_s: Vec<f64>,
    /// The robot's position seen from above, (x, z) every [`PATH_PERIOD_S`], for `path.png`.
    path: Vec<[f32; 2]>,
    /// The weld lines seen from above, (x, z), as the run began: `[line]`, then `[[welds]]`.
    lines: Vec<Vec<[f32; 2]>>,
    /// The terrain's height around the line, for `path.png`'s shading.
    heights: Option<HeightGrid>,
    /// Whether `path` and `line` are seen from above or on a wall terrain laid flat.
    view: PathView,
}

/// How often the robot's position goes into the track's path (a 5-hour run: 90 000 points).
pub const PATH_PERIOD_S: f64 = 0.2;

impl MetricTrack {
    /// The track's signals, named as the time series' columns.
    pub const COLUMNS: [&'static str; 5] = ["t_s", "d_true_m", "d_m", "speed_m_s", "target_speed_m_s"];

    /// Append a sample: time, ground-truth and camera distance (m, + = robot left of the line;
    /// NaN while the camera does not see it), speed and target speed (m/s).
    pub fn push(&mut self, t_s: f64, d_true_m: f64, d_m: f64, speed_m_s: f64, target_speed_m_s: f64) {
        self.t_s.push(t_s);
        self.d_true_m.push(d_true_m as f32);
        self.d_m.push(d_m as f32);
        self.speed_m_s.push(speed_m_s as f32);
        self.target_speed_m_s.push(target_speed_m_s);
    }

    /// The values of the signal `name` (one of [`MetricTrack::COLUMNS`]).
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let values = match name {
            "t_s" => return Some(self.t_s.clone()),
            "d_true_m" => &self.d_true_m,
            "d_m" => &self.d_m,
            "speed_m_s" => &self.speed_m_s,
            "target_speed_m_s" => return Some(self.target_speed_m_s.clone()),
            _ => return None,
        };
        Some(values.iter().map(|&v| f64::from(v)).collect())
    }

    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// The robot's path seen from above, (x, z) in metres.
    pub fn path(&self) -> &[[f32; 2]] {
        &self.path
    }

    /// The weld lines seen from above, (x, z) in metres.
    pub fn lines(&self) -> &[Vec<[f32; 2]>] {
        &self.lines
    }

    /// The terrain's height around the line, if it was sampled.
    pub fn heights(&self) -> Option<&HeightGrid> {
        self.heights.as_ref()
    }

    pub fn view(&self) -> PathView {
        self.view
    }

    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }
}

/// Where the captured rows go.
enum Rows {
    /// Nowhere: `serve SCENARIO` writes no outputs, and a session may last for days.
    Discard,
    /// Kept, for a library caller without an output folder (tests, `replay`).
    Memory(TimeSeries),
    /// Into `timeseries.csv.tmp` in the output folder, row by row.
    Csv(TimeSeriesWriter),
}

/// The captured rows and the metric track of one run (see the module documentation).
pub struct Capture {
    rows: Rows,
    /// Indices into [`COLUMNS`] of the columns the rows keep: `t_s` and `[capture] signals`.
    keep: Vec<usize>,
    period_s: f64,
    next_s: f64,
    track: MetricTrack,
    next_track_s: f64,
    next_path_s: f64,
}

impl Capture {
    /// Rows at `rate_hz` with the columns `signals` (all when `None`; names already checked
    /// against [`COLUMNS`]), kept in memory until [`Capture::stream_to`] or [`Capture::discard`].
    pub fn new(rate_hz: f64, signals: Option<&[String]>) -> Self {
        let keep: Vec<usize> = (0..COLUMNS.len()).filter(|&i| i == 0 || signals.is_none_or(|s| s.iter().any(|name| name == COLUMNS[i]))).collect();
        Self {
            rows: Rows::Memory(TimeSeries::new(keep.iter().map(|&i| COLUMNS[i]))),
            keep,
            // The scenario's range check refuses a rate that is not above 0; this only keeps a
            // library caller's zero from dividing by it.
            period_s: 1.0 / rate_hz.max(1e-3),
            next_s: 0.0,
            track: MetricTrack::default(),
            next_track_s: 0.0,
            next_path_s: 0.0,
        }
    }

    /// Write the rows into `out_dir/timeseries.csv.tmp` from now on (renamed to `timeseries.csv`
    /// by [`Capture::finish`]).
    pub fn stream_to(&mut self, out_dir: &Path) -> Result<(), ReportError> {
        self.rows = Rows::Csv(TimeSeriesWriter::create(out_dir, self.keep.iter().map(|&i| COLUMNS[i]))?);
        Ok(())
    }

    /// Keep no rows and no metric track: for `serve`, whose session may last days and which
    /// reports no step metrics (the track alone grows 1.4 KB per simulated second).
    pub fn discard(&mut self) {
        self.rows = Rows::Discard;
        self.next_track_s = f64::INFINITY;
    }

    /// A row is due at `t_s` (never while rows are discarded: building one costs a servo scan).
    pub fn row_due(&self, t_s: f64) -> bool {
        !matches!(self.rows, Rows::Discard) && self.row_time(t_s)
    }

    /// The capture rate has a row at `t_s`, kept or not: what a view shows while rows are
    /// discarded (`serve`'s `/signals`).
    pub fn row_time(&self, t_s: f64) -> bool {
        t_s + 1e-9 >= self.next_s
    }

    /// A metric-track sample is due at `t_s`.
    pub fn track_due(&self, t_s: f64) -> bool {
        t_s + 1e-9 >= self.next_track_s
    }

    /// The weld lines, seen from above, for the path picture.
    pub fn set_lines(&mut self, lines: Vec<Vec<[f32; 2]>>) {
        self.track.lines = lines;
    }

    /// The terrain's height around the line, for `path.png`.
    pub fn set_heights(&mut self, heights: HeightGrid) {
        self.track.heights = Some(heights);
    }

    /// The path picture's view (positions are then recorded in its coordinates).
    pub fn set_view(&mut self, view: PathView) {
        self.track.view = view;
    }

    /// The robot at (x, z) at `t_s`: kept if a path point is due (every [`PATH_PERIOD_S`]).
    pub fn record_position(&mut self, t_s: f64, x: f32, z: f32) {
        if t_s + 1e-9 >= self.next_path_s {
            self.next_path_s += PATH_PERIOD_S;
            self.track.path.push([x, z]);
        }
    }

    /// Record the track's sample due now (see [`MetricTrack::push`]).
    pub fn record_track(&mut self, t_s: f64, d_true_m: f64, d_m: f64, speed_m_s: f64, target_speed_m_s: f64) {
        self.next_track_s += METRIC_PERIOD_S;
        self.track.push(t_s, d_true_m, d_m, speed_m_s, target_speed_m_s);
    }

    /// Record the row due now: one value per [`COLUMNS`] entry, of which the kept ones are
    /// written.
    pub fn record_row(&mut self, row: &[f64]) -> Result<(), ReportError> {
        if row.len() != COLUMNS.len() {
            return Err(ReportError::RowWidth { expected: COLUMNS.len(), got: row.len() });
        }
        self.next_s += self.period_s;
        if matches!(self.rows, Rows::Discard) {
            return Ok(());
        }
        let kept: Vec<f64> = self.keep.iter().map(|&i| row[i]).collect();
        match &mut self.rows {
            Rows::Discard => Ok(()),
            Rows::Memory(series) => series.push_row(&kept),
            Rows::Csv(writer) => writer.push_row(&kept),
        }
    }

    pub fn track(&self) -> &MetricTrack {
        &self.track
    }

    pub fn into_track(self) -> MetricTrack {
        self.track
    }

    /// End the rows: a streamed file is flushed and renamed to `timeseries.csv`; rows kept in
    /// memory are returned. Rows recorded after this are discarded.
    pub fn finish(&mut self) -> Result<Option<TimeSeries>, ReportError> {
        match std::mem::replace(&mut self.rows, Rows::Discard) {
            Rows::Discard => Ok(None),
            Rows::Memory(series) => Ok(Some(series)),
            Rows::Csv(writer) => writer.finish().map(|_| None),
        }
    }
}

/// Distance and speed step characteristics and line tracking over the metric track, flattened
/// as in `summary.json`.
pub fn summarise(track: &MetricTrack, speed_step_at_s: f64, on_line_tolerance_m: f64) -> Summary {
    let column = |name: &str| track.column(name).unwrap_or_default();
    let (t, d, speed, target) = (column("t_s"), column("d_true_m"), column("speed_m_s"), column("target_speed_m_s"));
    let final_target = target.last().copied().unwrap_or(0.0);
    let t_first = t.first().copied().unwrap_or(0.0);
    let distance = metrics::decaying_error_step(&t, &d, &StepOptions::default()).ok();
    // A step "at 0" is at the first sample (the world has stepped once before capture begins).
    let speed_options = StepOptions { t_step: Some(speed_step_at_s.max(t_first)), ..StepOptions::default() };
    let speed_step = metrics::rising_step(&t, &speed, final_target, &speed_options).ok();
    let tracking = metrics::line_tracking(&t, &d, on_line_tolerance_m).ok();
    let mut summary = report::summarise(distance.as_ref(), speed_step.as_ref(), tracking.as_ref());
    summary.extend(speed_tracking(&t, &speed, &target, speed_step_at_s.max(t_first)));
    summary
}

/// How far the speed stays from its target after the step, averaged over the run's last 80 %
/// after it (the step's own transient left out): `speed.mean_error_m_s` (target − speed, signed)
/// and `speed.mean_abs_error_m_s`. On bumpy ground the step's steady-state error is averaged
/// from wherever the speed last entered its 2 % band, which can be a few samples before the
/// end; these are what a speed controller did over the whole run.
fn speed_tracking(t: &[f64], speed: &[f64], target: &[f64], t_step: f64) -> Vec<(String, serde_json::Value)> {
    let Some(&t_end) = t.last() else { return Vec::new() };
    let from = t_step + 0.2 * (t_end - t_step);
    let errors: Vec<f64> = t.iter().zip(speed.iter().zip(target)).filter(|(ti, (v, _))| **ti >= from && v.is_finite()).map(|(_, (v, goal))| goal - v).collect();
    if errors.is_empty() || t_end <= t_step {
        return Vec::new();
    }
    let n = errors.len() as f64;
    vec![
        ("speed.mean_error_m_s".to_owned(), serde_json::json!(errors.iter().sum::<f64>() / n)),
        ("speed.mean_abs_error_m_s".to_owned(), serde_json::json!(errors.iter().map(|e| e.abs()).sum::<f64>() / n)),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speed_tracking_averages_the_last_80_percent_after_the_step() {
        // Step at 1 s, end at 11 s: averaged from 3 s. Before it the speed is far off.
        let t: Vec<f64> = (0..=110).map(|i| f64::from(i) * 0.1).collect();
        let speed: Vec<f64> = t
            .iter()
            .map(|&ti| {
                if ti < 3.0 {
                    0.0
                } else if ti < 7.0 {
                    0.9
                } else {
                    1.3
                }
            })
            .collect();
        let target = vec![1.0; t.len()];
        let metrics: std::collections::BTreeMap<String, serde_json::Value> = speed_tracking(&t, &speed, &target, 1.0).into_iter().collect();
        let (mean, abs) = (metrics["speed.mean_error_m_s"].as_f64().unwrap_or(f64::NAN), metrics["speed.mean_abs_error_m_s"].as_f64().unwrap_or(f64::NAN));
        // 40 samples at +0.1 (3.0..6.9 s), 41 at -0.3 (7.0..11.0 s).
        assert!((mean - (40.0 * 0.1 - 41.0 * 0.3) / 81.0).abs() < 1e-9, "{mean}");
        assert!((abs - (40.0 * 0.1 + 41.0 * 0.3) / 81.0).abs() < 1e-9, "{abs}");
        assert!(speed_tracking(&[], &[], &[], 0.0).is_empty());
    }

    /// `serve` discards: a session of days must not keep a sample every 20 ms.
    #[test]
    fn a_discarding_capture_keeps_neither_rows_nor_metric_track() {
        let mut capture = Capture::new(50.0, None);
        assert!(capture.row_due(0.0) && capture.track_due(0.0));
        capture.discard();
        assert!(!capture.row_due(0.0) && !capture.track_due(0.0) && !capture.track_due(1e6));
    }
}
