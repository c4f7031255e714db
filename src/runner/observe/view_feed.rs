//! What a run shows in Foxglove ([`crate::runner::view`]): the scene at the start, the robot's
//! frames, magnet pulls and servos' registers at [`VIEW_RATE_HZ`], faults as they start and end,
//! the captured signals, events and failures in the log.

use std::path::Path;
use std::time::Duration;

use foxglove::messages::log::Level as LogLevel;

use crate::bus::Bus;
use crate::device::Servo;
use crate::robot::WheelPosition;
use crate::runner::RunError;
use crate::runner::view::{Setup, View, ViewOptions};
use crate::sim::{RobotWorld, magnet_frame};

use super::capture::COLUMNS;
use super::welds::Welds;

/// How often the view gets the robot's frames and the servos' registers (Foxglove's 3D panel
/// looks smooth from about 30 Hz).
pub const VIEW_RATE_HZ: f64 = 50.0;

pub struct ViewFeed {
    view: View,
    /// When the view's next frame is due (simulated seconds).
    next_frame_s: f64,
    /// Which scheduled faults were acting at the last frame (for the log).
    faults_acting: Vec<bool>,
    /// The servos' names (robot description) by ID.
    servo_names: Vec<(u8, String)>,
}

impl ViewFeed {
    /// Start the view (a recording, a live server, or both): the terrain, the welds and the
    /// robot's shapes are sent at once.
    pub fn start(options: &ViewOptions, world: &RobotWorld, welds: &Welds, servo_names: Vec<(u8, String)>, has_lidar: bool, scenario_path: &Path) -> Result<Self, RunError> {
        let names: Vec<String> = servo_names.iter().map(|(_, name)| name.clone()).collect();
        let camera = world.camera_pose().translation;
        let camera_distance_m = world.surface_below(camera.x, camera.z).map_or(world.climber().camera.position_m[1], |(ground, _)| camera.y - ground.y);
        let setup = Setup { columns: COLUMNS, servo_names: &names, has_lidar, tyre_radius_m: world.climber().wheel.outer_radius_m, camera_distance_m };
        let view = View::start(options, &setup)?;
        view.terrain(Duration::ZERO, world, &welds.samples());
        view.robot(Duration::ZERO, world);
        view.log(Duration::ZERO, LogLevel::Info, format!("{}: the run starts", scenario_path.display()));
        Ok(Self { view, next_frame_s: 0.0, faults_acting: Vec::new(), servo_names })
    }

    pub fn view(&self) -> &View {
        &self.view
    }

    /// What the bus hands every transaction to, for the view's `/bus/packets` (if it shows
    /// them).
    pub fn packet_tap(&self) -> Option<crate::bus::TransactionTap> {
        self.view.packet_tap()
    }

    pub fn live_url(&self) -> Option<String> {
        self.view.live_url()
    }

    /// A line for the view's `/log`.
    pub fn note(&self, at: Duration, level: LogLevel, message: String) {
        self.view.log(at, level, message);
    }

    /// The welds moved: show them again.
    pub fn welds_moved(&self, at: Duration, world: &RobotWorld, welds: &Welds) {
        self.view.terrain(at, world, &welds.samples());
    }

    /// One captured row on `/signals`.
    pub fn signals(&mut self, t_s: f64, row: &[f64]) {
        self.view.signals(Duration::from_secs_f64(t_s), row);
    }

    /// The view's frame at `t_s` if one is due: the robot's frames and magnet pulls, the
    /// servos' registers, and faults that started or ended since the last one.
    pub fn frame(&mut self, t_s: f64, bus: &Bus, world: &RobotWorld) {
        if t_s < self.next_frame_s {
            return;
        }
        self.next_frame_s = (t_s * VIEW_RATE_HZ).floor() / VIEW_RATE_HZ + 1.0 / VIEW_RATE_HZ;
        let at = Duration::from_secs_f64(t_s);
        let pulls: Vec<(String, f32)> = WheelPosition::ALL.iter().zip(world.adhesion()).map(|(&w, a)| (magnet_frame(w), a.force_n)).collect();
        self.view.transforms(at, &world.part_frames(), &pulls);
        let servos: Vec<(&str, &Servo)> = self.servo_names.iter().filter_map(|(id, name)| bus.servos().iter().find(|s| s.id() == *id).map(|s| (name.as_str(), s))).collect();
        self.view.servos(at, &servos);
        let faults = bus.faults();
        for (index, (fault, &acting)) in faults.scheduled().iter().zip(faults.acting()).enumerate() {
            if acting != self.faults_acting.get(index).copied().unwrap_or(false) {
                let what = serde_json::to_string(&fault.fault).unwrap_or_else(|_| fault.fault.kind().to_owned());
                let message = if acting { format!("fault starts: {what}") } else { format!("fault ends: {what}") };
                self.view.log(at, if acting { LogLevel::Warning } else { LogLevel::Info }, message);
            }
        }
        self.faults_acting = faults.acting().to_vec();
    }

    /// Close the view: the recording gets its final name, the live server stops.
    pub fn finish(self) -> Result<(), RunError> {
        Ok(self.view.finish()?)
    }
}
