//! What a run measures: the captured rows of `timeseries.csv` and the metric track
//! ([`super::capture`]), and every metric fed from the track's samples ([`TrackMetric`]:
//! surfaces and adhesion, relocation between welds). A new metric is one file implementing
//! [`TrackMetric`] and one line where the observer is assembled ([`super::Observer::new`]).

use std::path::Path;

use serde_json::Value;

use crate::bus::Bus;
use crate::control::ControlSample;
use crate::device::Servo;
use crate::report::{HeightGrid, PathView, Summary, TimeSeries};
use crate::robot::WheelPosition;
use crate::runner::RunError;
use crate::scenario::Scenario;
use crate::sim::RobotWorld;
use crate::sim::lidar::LidarScan;

use super::capture::{Capture, MetricTrack, summarise};
use super::welds::{GroundTruth, Welds};

/// Servo IDs with per-servo fault columns.
const FAULT_COLUMN_IDS: std::ops::RangeInclusive<u8> = 1..=8;
/// Wheel servo IDs with a torque column.
const TORQUE_COLUMN_IDS: std::ops::RangeInclusive<u8> = 1..=4;
/// The longer side of `path.png`'s height grid, in cells.
const HEIGHT_GRID_CELLS: usize = 160;

/// One sample of the metric track, as each [`TrackMetric`] is given it.
pub struct TrackSample<'a> {
    pub t_s: f64,
    pub world: &'a RobotWorld,
    pub welds: &'a Welds,
    pub truth: &'a GroundTruth,
}

/// A metric accumulated sample by sample over the run's metric track (every
/// [`super::capture::METRIC_PERIOD_S`] of simulated time, whatever the capture rate), so that a
/// run of days keeps no history; its summary keys at the end.
pub trait TrackMetric: Send {
    fn push(&mut self, sample: &TrackSample<'_>);
    fn summary(&self) -> Vec<(String, Value)>;
}

/// What a run needs to build its row: what the controller and the sensors said this tick.
pub struct RowInputs<'a> {
    pub t_s: f64,
    pub truth: &'a GroundTruth,
    pub target_m_s: f64,
    /// The camera's measurement in the ground truth's convention (None: the line is not seen).
    pub seen: Option<crate::control::LineError>,
    /// The built-in controller's view (an external controller's is unknown: its columns are NaN).
    pub control: Option<&'a ControlSample>,
    pub lidar: Option<&'a LidarScan>,
}

pub struct Metrics {
    capture: Capture,
    track_metrics: Vec<Box<dyn TrackMetric>>,
    speed_step_at_s: f64,
}

impl Metrics {
    pub fn new(scenario: &Scenario, welds: &Welds, world: &RobotWorld) -> Self {
        let mut capture = Capture::new(scenario.capture.rate_hz, scenario.capture.signals.as_deref());
        if !welds.is_empty() {
            capture.set_lines(welds.lines().iter().map(|w| w.smoothed().to_vec()).collect());
            // On a wall terrain the picture is the sheet laid flat, in the line's own
            // coordinates: no heights from above.
            match welds.sheet() {
                Some(_) => capture.set_view(PathView::LaidFlat),
                None => capture.set_heights(heights_around(welds.lines().iter().flat_map(|w| w.smoothed().iter().copied()), world)),
            }
        }
        Self { capture, track_metrics: Vec::new(), speed_step_at_s: scenario.speed.step_at_s }
    }

    /// Feed `metric` every sample of the track, and add its keys to the summary.
    pub fn add(&mut self, metric: Box<dyn TrackMetric>) {
        self.track_metrics.push(metric);
    }

    /// Write the captured rows into `out_dir/timeseries.csv` as they come (see
    /// [`Capture::stream_to`]) instead of keeping them.
    pub fn stream_to(&mut self, out_dir: &Path) -> Result<(), RunError> {
        Ok(self.capture.stream_to(out_dir)?)
    }

    /// Keep no captured rows and no metric track (`serve SCENARIO`, which writes no outputs).
    pub fn discard_rows(&mut self) {
        self.capture.discard();
    }

    /// Whether a row, or a sample of the metric track, is due at `t_s`. With a view `shown`, a
    /// row is due at the capture rate even while rows are discarded: the view's `/signals` are
    /// made of rows.
    pub fn due(&self, t_s: f64, shown: bool) -> (bool, bool) {
        let row = if shown { self.capture.row_time(t_s) } else { self.capture.row_due(t_s) };
        (row, self.capture.track_due(t_s))
    }

    /// The metric track's sample at `t_s` and every track metric's.
    pub fn record_track(&mut self, sample: &TrackSample<'_>, camera_d_m: f64, target_m_s: f64) {
        let TrackSample { t_s, world, welds, truth } = *sample;
        self.capture.record_track(t_s, truth.d_err_m, camera_d_m, truth.speed_m_s, target_m_s);
        let position = world.chassis_pose().translation;
        let [x, z] = welds.sheet().map_or([position.x, position.z], |sheet| sheet.unroll(position));
        self.capture.record_position(t_s, x, z);
        for metric in &mut self.track_metrics {
            metric.push(sample);
        }
    }

    /// Record a captured row (see [`row`]).
    pub fn record_row(&mut self, row: &[f64]) -> Result<(), RunError> {
        Ok(self.capture.record_row(row)?)
    }

    /// The seed's metrics over the metric track (the same whatever `[capture] rate_hz`), then
    /// every track metric's.
    pub fn summary(&self, on_line_tolerance_m: f64) -> Summary {
        let mut summary = summarise(self.capture.track(), self.speed_step_at_s, on_line_tolerance_m);
        for metric in &self.track_metrics {
            summary.extend(metric.summary());
        }
        summary
    }

    /// End the capture: a streamed `timeseries.csv` is completed (flushed and renamed), rows kept
    /// in memory are returned, with the metric track.
    pub fn finish(mut self) -> Result<(Option<TimeSeries>, MetricTrack), RunError> {
        let series = self.capture.finish()?;
        Ok((series, self.capture.into_track()))
    }
}

/// One row of `timeseries.csv`, every column of [`super::capture::COLUMNS`] in order.
pub fn row(inputs: &RowInputs<'_>, world: &RobotWorld, bus: &Bus) -> Vec<f64> {
    let RowInputs { t_s, truth, target_m_s: target, seen, control, lidar } = *inputs;
    // The camera's measurement in the same convention as the ground truth (NaN when the line is
    // not seen).
    let (d_m, psi_rad) = seen.map_or((f64::NAN, f64::NAN), |l| (l.d_err_m, l.psi_err_rad));
    let position = world.chassis_pose().translation;
    let adhesion = world.adhesion();
    let mut row = vec![
        t_s,
        d_m,
        psi_rad,
        f64::from(u8::from(seen.is_some())),
        truth.d_err_m,
        truth.psi_err_rad,
        truth.speed_m_s,
        target,
        target - truth.speed_m_s,
        control.map_or(f64::NAN, |c| c.measured_speed_m_s),
        control.map_or(f64::NAN, |c| c.yaw_rate_command_rad_s),
    ];
    row.extend(WheelPosition::ALL.map(|w| f64::from(world.wheel_rate(w))));
    row.extend(WheelPosition::ALL.map(|w| f64::from(world.magnet_angle(w))));
    row.extend(adhesion.iter().map(|a| f64::from(a.force_n)));
    row.extend([position.x, position.y, position.z].map(f64::from));
    let servo = |id: u8| bus.servos().iter().find(|s| s.id() == id);
    row.extend(FAULT_COLUMN_IDS.map(|id| servo(id).map_or(f64::NAN, |s| f64::from(s.hardware_error_status()))));
    row.extend(FAULT_COLUMN_IDS.map(|id| servo(id).map_or(f64::NAN, Servo::temperature_c)));
    row.extend(FAULT_COLUMN_IDS.map(|id| servo(id).map_or(f64::NAN, Servo::supply_voltage)));
    row.extend(TORQUE_COLUMN_IDS.map(|id| servo(id).map_or(f64::NAN, |s| f64::from(u8::from(s.torque_on())))));
    row.extend(WheelPosition::ALL.map(|w| f64::from(world.wheel_slip(w))));
    let faults = bus.faults();
    let counts = faults.counts();
    row.push(faults.active().count() as f64);
    row.push((counts.instructions_corrupted + counts.replies_corrupted + counts.replies_dropped + counts.replies_delayed + counts.instructions_unheard) as f64);
    row.push(lidar.map_or(f64::NAN, |s| f64::from(s.ahead_m())));
    row.push(lidar.map_or(f64::NAN, |s| f64::from(s.nearest_m())));
    let contacts = WheelPosition::ALL.map(|w| world.contact_angles(w));
    row.extend(contacts.map(|c| c.map_or(f64::NAN, |(in_plane, _)| f64::from(in_plane))));
    row.extend(contacts.map(|c| c.map_or(f64::NAN, |(_, lateral)| f64::from(lateral))));
    row.push(control.map_or(f64::NAN, |c| c.transition_phase));
    row.push(control.map_or(f64::NAN, |c| c.relocation_leg));
    row
}

/// The terrain's height on a grid around `line` (x, z), for `path.png`'s shading: the line's
/// extent and half a metre round it (where a robot that leaves the line may go), at most
/// [`HEIGHT_GRID_CELLS`] cells on the longer side.
fn heights_around(line: impl Iterator<Item = [f32; 2]>, world: &RobotWorld) -> HeightGrid {
    const MARGIN_M: f32 = 0.5;
    let (mut x, mut z) = ((f32::INFINITY, f32::NEG_INFINITY), (f32::INFINITY, f32::NEG_INFINITY));
    for [px, pz] in line {
        x = (x.0.min(px - MARGIN_M), x.1.max(px + MARGIN_M));
        z = (z.0.min(pz - MARGIN_M), z.1.max(pz + MARGIN_M));
    }
    let cell = ((x.1 - x.0).max(z.1 - z.0) / HEIGHT_GRID_CELLS as f32).max(0.005);
    let (cols, rows) = (((x.1 - x.0) / cell).ceil() as usize + 1, ((z.1 - z.0) / cell).ceil() as usize + 1);
    let heights = (0..rows)
        .flat_map(|row| (0..cols).map(move |col| (x.0 + cell * col as f32, z.0 + cell * row as f32)))
        .map(|(px, pz)| world.surface_below(px, pz).map_or(f32::NAN, |(point, _)| point.y))
        .collect();
    HeightGrid { x_m: (x.0, x.0 + cell * (cols - 1) as f32), z_m: (z.0, z.0 + cell * (rows - 1) as f32), cols, rows, heights }
}
