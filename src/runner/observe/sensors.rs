//! The robot's sensors as a run sees them: the downward camera with its line detector, and the
//! front LIDAR when the scenario has a `[lidar]`. Each renders or scans when it is due.

use std::time::Duration;

use crate::control::LineError;
use crate::robot::RobotDescription;
use crate::runner::RunError;
use crate::runner::view::View;
use crate::scenario::Scenario;
use crate::sim::lidar::{Lidar, LidarScan};
use crate::sim::{DetectorSettings, LineCamera, LineCameraSettings, LineDetector, LineMeasurement, RobotWorld};

use super::welds::Welds;

pub struct Sensors {
    camera: LineCamera,
    detector: LineDetector,
    /// The detector's output on the newest frame (None before the first frame).
    latest: Option<LineMeasurement>,
    frames_seen: u64,
    lidar: Option<Lidar>,
}

impl Sensors {
    pub fn new(scenario: &Scenario, robot: &RobotDescription) -> Result<Self, RunError> {
        let path = &scenario.path;
        let climber = robot.climber()?;
        let settings = scenario.camera.clone().unwrap_or_else(|| LineCameraSettings::from_mount(&climber.camera));
        let camera = LineCamera::new(settings).map_err(|e| RunError::Camera { path: path.clone(), message: e.to_string() })?;
        let detector = LineDetector::new(DetectorSettings::default())?;
        let lidar = scenario.lidar.clone().map(|settings| Lidar::new(settings, climber.lidar.position_m)).transpose().map_err(|e| RunError::Lidar { path: path.clone(), message: e.to_string() })?;
        Ok(Self { camera, detector, latest: None, frames_seen: 0, lidar })
    }

    /// Scan with the LIDAR and render the camera if they are due at `t`, run the detector on any
    /// new frame, and show what is new in `view`; the latest line measurement in the
    /// controller's convention (None while the line is not seen).
    pub fn sense(&mut self, world: &RobotWorld, welds: &Welds, t: Duration, view: Option<&View>) -> Option<LineError> {
        if let Some(scan) = self.lidar.as_mut().and_then(|lidar| lidar.scan(world, t))
            && let Some(view) = view
        {
            view.lidar(scan);
        }
        // Without a weld line there is nothing for the camera and its detector to find.
        if welds.is_empty() {
            return None;
        }
        let half_height_m = self.camera.settings().orthographic_size_m;
        if let Some(frame) = self.camera.render(world.camera_pose(), welds.lines(), t) {
            self.latest = Some(self.detector.detect(frame));
            self.frames_seen += 1;
            if let Some(view) = view {
                // The recording's chunks are compressed again (zstd): the fastest PNG will do.
                match frame.to_png_with(png::Compression::Fastest) {
                    Ok(png) => view.image(frame.t, png, (frame.width, frame.height), half_height_m),
                    Err(error) => tracing::warn!(%error, "camera frame not recorded"),
                }
            }
        }
        self.seen()
    }

    /// The newest frame's line measurement in the run's one convention (None while the line is
    /// not seen).
    pub fn seen(&self) -> Option<LineError> {
        self.latest.filter(|m| m.valid).map(|m| robot_relative(&m))
    }

    /// The detector's output on the newest frame, in the detector's own convention (where the
    /// line is relative to the robot); [`robot_relative`] gives the run's.
    pub fn latest(&self) -> Option<&LineMeasurement> {
        self.latest.as_ref()
    }

    /// Whether the robot has a LIDAR (the scenario's `[lidar]`).
    pub fn has_lidar(&self) -> bool {
        self.lidar.is_some()
    }

    /// The LIDAR's latest scan, if the robot has one and it has scanned.
    pub fn lidar_scan(&self) -> Option<&LidarScan> {
        self.lidar.as_ref().and_then(Lidar::latest)
    }

    /// Frames the camera has delivered so far.
    pub fn frames_seen(&self) -> u64 {
        self.frames_seen
    }

    pub fn camera(&self) -> &LineCamera {
        &self.camera
    }
}

/// A line measurement in the run's one convention, that of the ground truth and the controller:
/// where the robot is relative to the line (+ = robot left of the line, pointing left of it).
/// The detector says where the line is relative to the robot, the opposite sign.
pub fn robot_relative(measurement: &LineMeasurement) -> LineError {
    LineError { d_err_m: -f64::from(measurement.d_m), psi_err_rad: -f64::from(measurement.psi_rad) }
}
