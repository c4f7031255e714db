//! Running a scenario: the world, the weld line and its camera, a controller, scripted events,
//! and the captured time series; then the seed's metrics over it.
//!
//! [`Observer`] is everything that watches the world (camera, detector, ground truth, capture,
//! events) and is shared by the two clocks: [`run_lockstep`] for the built-in controller (as
//! fast as the CPU allows, deterministic) and the real-time loop of `climbsim run` for an
//! external controller on the virtual port.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use rapier3d::prelude::Vector;
use serde_json::{Value, json};
use thiserror::Error;
use tracing::info_span;

use foxglove::messages::log::Level as LogLevel;

use crate::bus::{Bus, BusFaults, Timing};
use crate::device::Servo;
use crate::control::planner::OccupancyGrid;
use crate::control::{ControlError, ControlSample, Leg, LineError, Pose2, ReferenceController, Relocation, RelocationConfig, Senses, WallSighting, WeldTask};
use crate::report::{self, HeightGrid, PathView, Summary, TimeSeries};
use crate::robot::{RobotDescription, WheelPosition};
use crate::sim::detector::DetectorError;
use crate::sim::line::{LineError as WeldLineError, LineSample};
use crate::sim::lidar::{Lidar, LidarScan};
use crate::sim::terrain::UnrolledProfile;
use crate::sim::{magnet_frame, DetectorSettings, LineCamera, LineCameraSettings, LineDetector, LineMeasurement, Lockstep, RobotWorld, SimError, Surface, WeldLine};

pub use super::capture::{COLUMNS, MetricTrack, summarise};
use super::capture::Capture;
use super::relocation::{self, MAX_WELDS, RelocationSample, RelocationTrack, WeldView};
use super::surfaces::{SurfaceSample, SurfaceTrack};
use super::view::{LiveAddress, View, ViewOptions};
use super::watch::{self, WorldFailure, WorldWatch};
use super::{ControllerSection, Event, Scenario, ScenarioError, mm_min_to_m_s};

#[derive(Debug, Error)]
pub enum RunError {
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    View(#[from] super::view::ViewError),
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error("scenario {path}: [line]: {source}")]
    Line { path: PathBuf, source: WeldLineError },
    #[error("scenario {path}: [camera]: {message}")]
    Camera { path: PathBuf, message: String },
    #[error("scenario {path}: {message}")]
    Lidar { path: PathBuf, message: String },
    #[error("scenario {path}: [relocation]: {message}")]
    Relocation { path: PathBuf, message: String },
    #[error("scenario {path} has no [line]: a run needs a weld line to follow")]
    NoLine { path: PathBuf },
    #[error("scenario {path}: [capture] signals: no signal `{name}` (known: {known})")]
    UnknownSignal { path: PathBuf, name: String, known: String },
    /// A capture faster than the run produces new states would repeat rows, or lag behind.
    #[error("scenario {path}: [capture] rate_hz = {rate_hz} Hz is more than this run can capture: {max_hz} Hz ({why})")]
    CaptureRate { path: PathBuf, rate_hz: f64, max_hz: f64, why: String },
    #[error("line detector: {0}")]
    Detector(#[from] DetectorError),
    #[error("controller: {0}")]
    Control(#[from] ControlError),
    #[error("scenario {path} has an external controller; run it with `climbsim run` (real time)")]
    NeedsRealTime { path: PathBuf },
    #[error(transparent)]
    Report(#[from] report::ReportError),
    #[error("scenario {path}: {message}")]
    Start { path: PathBuf, message: String },
    #[error("scenario {path}: {source}")]
    Fault { path: PathBuf, source: crate::fault::FaultError },
}

/// Servo IDs with per-servo fault columns.
const FAULT_COLUMN_IDS: std::ops::RangeInclusive<u8> = 1..=8;
/// Wheel servo IDs with a torque column.
const TORQUE_COLUMN_IDS: std::ops::RangeInclusive<u8> = 1..=4;

/// The robot's pose relative to the line: what a perfect sensor would say.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GroundTruth {
    /// Distance from the line (m), positive when the robot is left of it.
    pub d_err_m: f64,
    /// Heading relative to the line (rad), positive when the robot points left of it.
    pub psi_err_rad: f64,
    /// Ground speed along the body's forward axis (m/s).
    pub speed_m_s: f64,
    /// How far along the line the robot's nearest point is (m; NaN without a line).
    pub arc_m: f64,
    /// Which weld (0 = `[line]`, then `[[welds]]` in order) these are measured against: the
    /// nearest.
    pub weld: Option<usize>,
}

/// What [`Observer::on_tick`] saw.
#[derive(Debug)]
pub struct TickObservation {
    /// The camera delivered a frame this tick.
    pub new_frame: bool,
    pub error: Option<RunError>,
    /// The world watch's verdict: the run should stop (see [`watch`]).
    pub failure: Option<WorldFailure>,
}

/// Refuse a world the run cannot happen in: a start off the terrain, a fault on a servo the bus
/// does not have.
fn check_world(scenario: &Scenario, world: &RobotWorld, ids: &[u8]) -> Result<(), RunError> {
    watch::check_start(world).map_err(|message| RunError::Start { path: scenario.path.clone(), message })?;
    crate::fault::check_ids(&scenario.faults(), ids).map_err(|source| RunError::Fault { path: scenario.path.clone(), source })
}

/// The bus of `scenario`'s world (servos at `baud`, the scenario's or the robot's), and its
/// observer (camera and detector when the scenario has a weld line, capture, view): what `serve
/// SCENARIO`, `run` with an external controller and `replay` all drive. `RobotWorld::new` has already updated
/// the query structures, so the line drapes at once.
pub fn scenario_bus(scenario: &Scenario, robot: &RobotDescription, timing: Timing, baud: Option<u32>) -> Result<(Bus, Observer), RunError> {
    // `serve --baud` over the scenario's `[bus] baud_bps` over the robot description's.
    let baud = baud.or(scenario.bus.baud_bps);
    let servos = robot.servos(baud).map_err(SimError::from)?;
    let world = RobotWorld::new(robot, scenario.world_config()?, &servos).map_err(SimError::from)?;
    check_world(scenario, &world, &servos.iter().map(Servo::id).collect::<Vec<_>>())?;
    let observer = Observer::new(scenario, robot, &world)?;
    let mut bus = robot.bus_of(servos, Box::new(world), timing, baud).map_err(SimError::from)?;
    bus.set_faults(BusFaults::new(scenario.faults(), scenario.world.seed));
    Ok((bus, observer))
}

/// A run (lockstep, wall clock or replayed) follows a weld line: refuse a scenario without one.
/// (`serve` watches any world.)
pub fn require_line(scenario: &Scenario) -> Result<(), RunError> {
    match scenario.line {
        Some(_) => Ok(()),
        None => Err(RunError::NoLine { path: scenario.path.clone() }),
    }
}

/// Everything that watches the world during a run.
pub struct Observer {
    /// The weld lines: `[line]`, then `[[welds]]` (none: the world is still watched, the view
    /// and the robot's state).
    welds: Vec<WeldLine>,
    /// Their control points as given, for line-offset events (the lines are rebuilt and draped
    /// again).
    weld_points: Vec<Vec<[f32; 2]>>,
    /// The terrain laid flat when the line is painted on a wall terrain (see [`UnrolledProfile`]).
    sheet: Option<UnrolledProfile>,
    camera: LineCamera,
    detector: LineDetector,
    /// The detector's output on the newest frame (None before the first frame).
    latest: Option<LineMeasurement>,
    /// The front LIDAR, when the scenario has a `[lidar]`.
    lidar: Option<Lidar>,
    frames_seen: u64,
    capture: Capture,
    target_speed_m_s: f64,
    speed_step_at_s: f64,
    events: Vec<Event>,
    next_event: usize,
    scenario_path: PathBuf,
    watch: WorldWatch,
    /// The Foxglove view (recording, live server), if the run has one.
    view: Option<View>,
    /// When the view's next frame is due (simulated seconds): at [`VIEW_RATE_HZ`] whatever the
    /// capture rate.
    next_view_s: f64,
    /// Which scheduled faults were acting at the last capture (for the view's log).
    faults_acting: Vec<bool>,
    /// The servos' names (robot description) by ID.
    servo_names: Vec<(u8, String)>,
    /// Transitions, adhesion and slides (see [`SurfaceTrack`]).
    surfaces: SurfaceTrack,
    /// With more than one weld: how the robot is to relocate, the map it is given, and the
    /// metrics of its moves.
    relocation: Option<(RelocationConfig, OccupancyGrid, RelocationTrack)>,
}

/// How often the view gets the robot's frames and the servos' registers (Foxglove's 3D panel
/// looks smooth from about 30 Hz).
pub const VIEW_RATE_HZ: f64 = 50.0;

impl Observer {
    pub fn new(scenario: &Scenario, robot: &RobotDescription, world: &RobotWorld) -> Result<Self, RunError> {
        let path = scenario.path.clone();
        for name in scenario.capture.signals.iter().flatten() {
            if !COLUMNS.contains(&name.as_str()) {
                return Err(RunError::UnknownSignal { path, name: name.clone(), known: COLUMNS[1..].join(", ") });
            }
        }
        let sheet = UnrolledProfile::of(&scenario.terrain);
        let sections: Vec<&super::LineSection> = scenario.line.iter().chain(&scenario.welds).collect();
        let welds = sections.iter().map(|l| build_line(&l.points, l.smoothness, l.width_m, 0.0, surface(&sheet, world))).collect::<Result<Vec<_>, _>>().map_err(|source| RunError::Line { path: path.clone(), source })?;
        let settings = scenario.camera.clone().unwrap_or_else(|| LineCameraSettings::from_mount(&robot.camera));
        let camera = LineCamera::new(settings).map_err(|e| RunError::Camera { path: path.clone(), message: e.to_string() })?;
        let detector = LineDetector::new(DetectorSettings::default())?;
        let lidar = scenario.lidar.clone().map(|settings| Lidar::new(settings, robot.lidar.position_m)).transpose().map_err(|e| RunError::Lidar { path: path.clone(), message: e.to_string() })?;
        let mut events = scenario.events.clone();
        events.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        let relocation = if welds.len() > 1 {
            let config = scenario.relocation.clone().unwrap_or_default();
            let (given, truth) = relocation::maps(world, &welds, &config).map_err(|e| RunError::Relocation { path: path.clone(), message: e.to_string() })?;
            let track = RelocationTrack::new(truth, config.clearance_m as f32, welds.len());
            Some((config, given, track))
        } else {
            None
        };
        let mut capture = Capture::new(scenario.capture.rate_hz, scenario.capture.signals.as_deref());
        if !welds.is_empty() {
            capture.set_lines(welds.iter().map(|w| w.smoothed().to_vec()).collect());
            // On a wall terrain the picture is the sheet laid flat, in the line's own
            // coordinates: no heights from above.
            match &sheet {
                Some(_) => capture.set_view(PathView::LaidFlat),
                None => capture.set_heights(heights_around(welds.iter().flat_map(|w| w.smoothed().iter().copied()), world)),
            }
        }
        Ok(Self {
            welds,
            weld_points: sections.iter().map(|l| l.points.clone()).collect(),
            sheet,
            camera,
            detector,
            latest: None,
            lidar,
            frames_seen: 0,
            capture,
            target_speed_m_s: mm_min_to_m_s(scenario.speed.target_mm_min),
            speed_step_at_s: scenario.speed.step_at_s,
            events,
            next_event: 0,
            scenario_path: path,
            watch: WorldWatch::new(),
            view: None,
            next_view_s: 0.0,
            faults_acting: Vec::new(),
            servo_names: robot.servo.iter().map(|s| (s.id, s.name.clone())).collect(),
            surfaces: SurfaceTrack::new(scenario.capture.adhesion_floor_n as f32),
            relocation,
        })
    }

    /// Whether the world has a weld line (and so a camera image and line measurements).
    pub fn has_line(&self) -> bool {
        !self.welds.is_empty()
    }

    /// The target speed in force at `t_s` (zero before the speed step).
    pub fn target_speed_m_s(&self, t_s: f64) -> f64 {
        if t_s >= self.speed_step_at_s { self.target_speed_m_s } else { 0.0 }
    }

    /// Apply the events due by `t_s`.
    pub fn apply_events(&mut self, t_s: f64, world: &mut RobotWorld) -> Result<(), RunError> {
        while let Some(event) = self.events.get(self.next_event).filter(|e| e.at_s <= t_s).cloned() {
            self.next_event += 1;
            let _span = info_span!("event", at_s = event.at_s).entered();
            let at = Duration::from_secs_f64(t_s);
            if let Some(speed) = event.set_speed_mm_min {
                self.target_speed_m_s = mm_min_to_m_s(speed);
                self.note(at, LogLevel::Info, format!("event at {} s: target speed {speed} mm/min", event.at_s));
            }
            if let Some(on) = event.magnets {
                world.set_magnets_on(on);
                self.note(at, LogLevel::Info, format!("event at {} s: magnets {}", event.at_s, if on { "on" } else { "off" }));
            }
            if let Some(offset) = event.line_offset_m {
                // Validation refuses a line offset without a line; every weld moves.
                let moved = self
                    .welds
                    .iter()
                    .zip(&self.weld_points)
                    .map(|(line, points)| build_line(points, line.smoothness(), line.width_m(), offset, surface(&self.sheet, world)))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|source| RunError::Line { path: self.scenario_path.clone(), source })?;
                self.note(at, LogLevel::Info, format!("event at {} s: the line moves {} mm to the left", event.at_s, offset * 1000.0));
                self.welds = moved;
                if let Some(view) = &self.view {
                    view.terrain(at, world, &self.weld_samples());
                }
            }
        }
        Ok(())
    }

    /// Something for the view's `/log` (events, faults, failures); nothing without a view.
    pub fn note(&self, at: Duration, level: LogLevel, message: String) {
        if let Some(view) = &self.view {
            view.log(at, level, message);
        }
    }

    /// Write the captured rows into `out_dir/timeseries.csv` as they come (see
    /// [`Capture::stream_to`]) instead of keeping them.
    pub fn stream_to(&mut self, out_dir: &std::path::Path) -> Result<(), RunError> {
        Ok(self.capture.stream_to(out_dir)?)
    }

    /// Show the run in Foxglove (see [`super::view`]): a recording, a live server, or both. The
    /// terrain, the line and the robot's shapes are sent at once; the robot's frames, the
    /// servos' registers and the signals with the capture. The live server's URL, if any.
    pub fn start_view(&mut self, options: &ViewOptions, bus: &mut Bus) -> Result<Option<String>, RunError> {
        if options.is_off() {
            return Ok(None);
        }
        let Some(world) = bus.plant::<RobotWorld>() else { return Ok(None) };
        let names: Vec<String> = self.servo_names.iter().map(|(_, name)| name.clone()).collect();
        let view = View::start(options, COLUMNS, &names)?;
        view.terrain(Duration::ZERO, world, &self.weld_samples());
        view.robot(Duration::ZERO, world);
        view.log(Duration::ZERO, LogLevel::Info, format!("{}: the run starts", self.scenario_path.display()));
        let url = view.live_url();
        bus.set_transaction_tap(view.packet_tap());
        self.view = Some(view);
        Ok(url)
    }

    /// Keep no captured rows and no metric track (`serve SCENARIO`, which writes no outputs).
    pub fn discard_rows(&mut self) {
        self.capture.discard();
    }

    /// Scan with the LIDAR and render the camera if they are due at `t`, run the detector on any
    /// new frame; the latest line measurement in the controller's convention (None while the
    /// line is not seen).
    pub fn sense(&mut self, world: &RobotWorld, t: Duration) -> Option<LineError> {
        if let Some(scan) = self.lidar.as_mut().and_then(|lidar| lidar.scan(world, t))
            && let Some(view) = &self.view
        {
            view.lidar(scan);
        }
        // Without a weld line there is nothing for the camera and its detector to find.
        if self.welds.is_empty() {
            return None;
        }
        if let Some(frame) = self.camera.render(world.camera_pose(), &self.welds, t) {
            self.latest = Some(self.detector.detect(frame));
            self.frames_seen += 1;
            if let Some(view) = &self.view {
                // The recording's chunks are compressed again (zstd): the fastest PNG will do.
                match frame.to_png_with(png::Compression::Fastest) {
                    Ok(png) => view.image(frame.t, png),
                    Err(error) => tracing::warn!(%error, "camera frame not recorded"),
                }
            }
        }
        self.latest.filter(|m| m.valid).map(|m| robot_relative(&m))
    }

    /// The robot seen from each weld, in plan (for the relocation metrics).
    fn weld_views(&self, world: &RobotWorld) -> [Option<WeldView>; MAX_WELDS] {
        let pose = world.chassis_pose();
        let centre = pose.translation;
        let forward = pose.rotation * Vector::X;
        let mut views = [None; MAX_WELDS];
        for (view, line) in views.iter_mut().zip(&self.welds) {
            let p = line.nearest(centre);
            let (d_m, psi_rad) = p.relative_pose(centre, forward);
            *view = Some(WeldView {
                distance_m: (p.point.x - centre.x).hypot(p.point.z - centre.z),
                inside: p.arc_length_m > 1e-3 && p.arc_length_m < line.length_m() - 1e-3,
                d_m,
                psi_rad,
            });
        }
        views
    }

    /// The built-in controller's relocation between the welds, on the map it is given; None with
    /// a single weld.
    pub fn relocation_plan(&self) -> Option<Relocation> {
        let (config, given, _) = self.relocation.as_ref()?;
        let tasks = self.welds.iter().map(|w| WeldTask { points: w.smoothed().to_vec() }).collect();
        Some(Relocation::new(config.clone(), tasks, given.clone()))
    }

    /// Every weld's draped samples (for the view's stripes).
    fn weld_samples(&self) -> Vec<&[LineSample]> {
        self.welds.iter().map(WeldLine::samples).collect()
    }

    /// The welds, `[line]` first.
    pub fn welds(&self) -> &[WeldLine] {
        &self.welds
    }

    /// The weld list as the sensor server's `/welds` serves it.
    pub fn welds_json(&self) -> Value {
        let welds: Vec<Value> = self
            .welds
            .iter()
            .zip(&self.weld_points)
            .enumerate()
            .map(|(index, (line, points))| json!({ "index": index, "points": points, "smoothed": line.smoothed(), "length_m": line.length_m() }))
            .collect();
        json!({ "welds": welds })
    }

    /// The detector's output on the newest frame, in the detector's own convention (where the
    /// line is relative to the robot); [`robot_relative`] gives the run's.
    pub fn latest(&self) -> Option<&LineMeasurement> {
        self.latest.as_ref()
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

    /// The robot's true pose relative to the line (d and ψ are NaN without a line).
    pub fn ground_truth(&self, world: &RobotWorld) -> GroundTruth {
        let pose = world.chassis_pose();
        let centre = pose.translation;
        let forward = pose.rotation * Vector::X;
        let speed_m_s = f64::from(world.chassis_velocity().dot(forward));
        // Against the weld nearest the robot (the one it follows, or is about to).
        let nearest = self.welds.iter().enumerate().map(|(k, line)| (k, line.nearest(centre))).min_by(|(_, a), (_, b)| (a.point - centre).length().total_cmp(&(b.point - centre).length()));
        let Some((weld, projection)) = nearest else { return GroundTruth { d_err_m: f64::NAN, psi_err_rad: f64::NAN, speed_m_s, arc_m: f64::NAN, weld: None } };
        let (d, psi) = projection.relative_pose(centre, forward);
        GroundTruth {
            d_err_m: f64::from(d),
            psi_err_rad: f64::from(psi),
            speed_m_s,
            arc_m: f64::from(projection.arc_length_m),
            weld: Some(weld),
        }
    }

    /// Record a row if one is due at `t_s`, and the metric track's sample if one is due.
    /// `control` is the built-in controller's view (an external controller's is unknown: its
    /// columns are NaN).
    pub fn capture(&mut self, t_s: f64, bus: &Bus, control: Option<&ControlSample>) -> Result<(), RunError> {
        let (row_due, track_due) = (self.capture.row_due(t_s), self.capture.track_due(t_s));
        let Some(world) = bus.plant::<RobotWorld>() else { return Ok(()) };
        if self.view.is_some() && t_s >= self.next_view_s {
            self.next_view_s = (t_s * VIEW_RATE_HZ).floor() / VIEW_RATE_HZ + 1.0 / VIEW_RATE_HZ;
            self.show(t_s, bus, world);
        }
        if !row_due && !track_due {
            return Ok(());
        }
        let truth = self.ground_truth(world);
        let target = self.target_speed_m_s(t_s);
        let seen = self.latest.filter(|m| m.valid).map(|m| robot_relative(&m));
        // The camera's measurement in the same convention as the ground truth (NaN when the line
        // is not seen).
        let (d_m, psi_rad) = seen.map_or((f64::NAN, f64::NAN), |l| (l.d_err_m, l.psi_err_rad));
        let position = world.chassis_pose().translation;
        if track_due {
            self.capture.record_track(t_s, truth.d_err_m, d_m, truth.speed_m_s, target);
            let [x, z] = self.sheet.as_ref().map_or([position.x, position.z], |sheet| sheet.unroll(position));
            self.capture.record_position(t_s, x, z);
            let adhesion = world.adhesion();
            self.surfaces.push(&SurfaceSample {
                t_s,
                pull_n: adhesion.each_ref().map(|a| a.force_n),
                normal: adhesion.each_ref().map(|a| a.contact.map(|(_, n)| n)),
                d_true_m: truth.d_err_m,
                arc_m: truth.arc_m,
            });
            if self.relocation.is_some() {
                let sample = RelocationSample { t_s, position: [position.x, position.z], nearest: self.weld_views(world) };
                if let Some((_, _, track)) = &mut self.relocation {
                    track.push(&sample);
                }
            }
        }
        if !row_due {
            return Ok(());
        }
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
        let scan = self.lidar_scan();
        row.push(scan.map_or(f64::NAN, |s| f64::from(s.ahead_m())));
        row.push(scan.map_or(f64::NAN, |s| f64::from(s.nearest_m())));
        let contacts = WheelPosition::ALL.map(|w| world.contact_angles(w));
        row.extend(contacts.map(|c| c.map_or(f64::NAN, |(in_plane, _)| f64::from(in_plane))));
        row.extend(contacts.map(|c| c.map_or(f64::NAN, |(_, lateral)| f64::from(lateral))));
        row.push(control.map_or(f64::NAN, |c| c.transition_phase));
        row.push(control.map_or(f64::NAN, |c| c.relocation_leg));
        if let Some(view) = &mut self.view {
            view.signals(Duration::from_secs_f64(t_s), &row);
        }
        self.capture.record_row(&row)?;
        Ok(())
    }

    /// The view's frame at `t_s`: the robot's frames and magnet pulls, the servos' registers,
    /// and faults that started or ended since the last one.
    fn show(&mut self, t_s: f64, bus: &Bus, world: &RobotWorld) {
        let Some(view) = &mut self.view else { return };
        let at = Duration::from_secs_f64(t_s);
        let pulls: Vec<(String, f32)> = WheelPosition::ALL.iter().zip(world.adhesion()).map(|(&w, a)| (magnet_frame(w), a.force_n)).collect();
        view.transforms(at, &world.part_frames(), &pulls);
        let servos: Vec<(&str, &Servo)> = self.servo_names.iter().filter_map(|(id, name)| bus.servos().iter().find(|s| s.id() == *id).map(|s| (name.as_str(), s))).collect();
        view.servos(at, &servos);
        let faults = bus.faults();
        for (index, (fault, &acting)) in faults.scheduled().iter().zip(faults.acting()).enumerate() {
            if acting != self.faults_acting.get(index).copied().unwrap_or(false) {
                let what = serde_json::to_string(&fault.fault).unwrap_or_else(|_| fault.fault.kind().to_owned());
                let message = if acting { format!("fault starts: {what}") } else { format!("fault ends: {what}") };
                view.log(at, if acting { LogLevel::Warning } else { LogLevel::Info }, message);
            }
        }
        self.faults_acting = faults.acting().to_vec();
    }

    /// What every firmware tick of a wall-clock run (and of its replay) does after advancing the
    /// world: apply due events, render and detect, capture a row. An error in one step does not
    /// skip the others (the live run keeps going); the first is returned.
    pub fn on_tick(&mut self, bus: &mut Bus, now: Duration) -> TickObservation {
        let t_s = now.as_secs_f64();
        let Some(world) = bus.plant_mut::<RobotWorld>() else { return TickObservation { new_frame: false, error: None, failure: None } };
        let mut error = self.apply_events(t_s, world).err();
        let frames_before = self.frames_seen;
        self.sense(world, now);
        let failed_before = self.watch.failure().is_some();
        let failure = self.watch.check(world, t_s).cloned();
        if let Some(failure) = failure.as_ref().filter(|_| !failed_before) {
            self.note(now, LogLevel::Error, failure.message.clone());
        }
        if let Err(capture) = self.capture(t_s, bus, None) {
            error.get_or_insert(capture);
        }
        TickObservation { new_frame: self.frames_seen != frames_before, error, failure }
    }

    /// Close the view: the recording gets its final name, the live server stops.
    pub fn finish_view(&mut self) -> Result<(), RunError> {
        match self.view.take() {
            Some(view) => Ok(view.finish()?),
            None => Ok(()),
        }
    }

    /// Why the world watch stopped believing in this run (see [`watch`]), once it has.
    pub fn world_failure(&self) -> Option<&WorldFailure> {
        self.watch.failure()
    }

    /// End the capture: a streamed `timeseries.csv` is completed (flushed and renamed), rows kept
    /// in memory are returned, with the metric track.
    pub fn finish(mut self) -> Result<(Option<TimeSeries>, MetricTrack), RunError> {
        self.finish_view()?;
        let series = self.capture.finish()?;
        Ok((series, self.capture.into_track()))
    }

    /// The seed's metrics over the metric track (the same whatever `[capture] rate_hz`).
    pub fn summary(&self, on_line_tolerance_m: f64) -> Summary {
        let mut summary = summarise(self.capture.track(), self.speed_step_at_s, on_line_tolerance_m);
        summary.extend(self.surfaces.summary());
        if let Some((_, _, track)) = &self.relocation {
            summary.extend(track.summary());
        }
        summary
    }
}

/// The robot's pose in plan, as relocation takes it (the simulator's own: a stand-in for a real
/// robot's localisation) and the sensor server's `/state` gives it.
pub fn plan_pose(world: &RobotWorld) -> Pose2 {
    let pose = world.chassis_pose();
    let forward = pose.rotation * Vector::X;
    Pose2 { x: f64::from(pose.translation.x), z: f64::from(pose.translation.z), heading_rad: f64::from((-forward.z).atan2(forward.x)) }
}

/// A line measurement in the run's one convention, that of the ground truth and the controller:
/// where the robot is relative to the line (+ = robot left of the line, pointing left of it).
/// The detector says where the line is relative to the robot, the opposite sign.
pub fn robot_relative(measurement: &LineMeasurement) -> LineError {
    LineError { d_err_m: -f64::from(measurement.d_m), psi_err_rad: -f64::from(measurement.psi_rad) }
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
    let heights = (0..rows).flat_map(|row| (0..cols).map(move |col| (x.0 + cell * col as f32, z.0 + cell * row as f32))).map(|(px, pz)| world.surface_below(px, pz).map_or(f32::NAN, |(point, _)| point.y)).collect();
    HeightGrid { x_m: (x.0, x.0 + cell * (cols - 1) as f32), z_m: (z.0, z.0 + cell * (rows - 1) as f32), cols, rows, heights }
}

/// The longer side of `path.png`'s height grid, in cells.
const HEIGHT_GRID_CELLS: usize = 160;

fn build_line(points: &[[f32; 2]], smoothness: u32, width_m: f32, offset_m: f64, surface: &dyn Surface) -> Result<WeldLine, WeldLineError> {
    let shifted = offset_points(points, offset_m as f32);
    let mut line = WeldLine::new(&shifted, smoothness, width_m)?;
    line.drape(surface)?;
    Ok(line)
}

/// What a line is painted on: a wall terrain's unrolled sheet (so it can go up the wall), or
/// whatever is below its points.
fn surface<'a>(sheet: &'a Option<UnrolledProfile>, world: &'a RobotWorld) -> &'a dyn Surface {
    match sheet {
        Some(sheet) => sheet,
        None => world,
    }
}

/// The control points moved `offset` to the left of the line's direction (per segment, joined
/// at each corner along the mean of its segments' left normals).
fn offset_points(points: &[[f32; 2]], offset: f32) -> Vec<[f32; 2]> {
    if offset == 0.0 || points.len() < 2 {
        return points.to_vec();
    }
    let left = |a: [f32; 2], b: [f32; 2]| {
        let (dx, dz) = (b[0] - a[0], b[1] - a[1]);
        let length = dx.hypot(dz).max(f32::EPSILON);
        // Up × along, with z to the right: (dz, −dx) / length.
        [dz / length, -dx / length]
    };
    (0..points.len())
        .map(|i| {
            let before = (i > 0).then(|| left(points[i - 1], points[i]));
            let after = (i + 1 < points.len()).then(|| left(points[i], points[i + 1]));
            let n = match (before, after) {
                (Some(a), Some(b)) => {
                    let (x, z) = (a[0] + b[0], a[1] + b[1]);
                    let length = x.hypot(z).max(f32::EPSILON);
                    [x / length, z / length]
                }
                (Some(n), None) | (None, Some(n)) => n,
                (None, None) => [0.0, 0.0],
            };
            [points[i][0] + offset * n[0], points[i][1] + offset * n[1]]
        })
        .collect()
}

/// Why a run failed other than by its thresholds (`summary.json`'s `failures`, one line each;
/// empty for a run that went as far as it should).
pub fn failures(summary: &Summary) -> Vec<String> {
    summary.get("failures").and_then(Value::as_array).map_or_else(Vec::new, |lines| lines.iter().map(|l| l.as_str().map_or_else(|| l.to_string(), str::to_owned)).collect())
}

/// Record `failure` in `summary` (`failures` and `failure_at_s`).
pub fn record_failure(summary: &mut Summary, failure: &WorldFailure) {
    let mut lines = failures(summary);
    lines.push(failure.message.clone());
    summary.insert("failures".to_owned(), json!(lines));
    summary.insert("failure_at_s".to_owned(), json!(failure.at_s));
}

/// A finished run.
pub struct RunOutcome {
    /// The captured rows when the run kept them in memory ([`run_lockstep`], replay); `None`
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
    let camera = scenario.camera.clone().unwrap_or_else(|| LineCameraSettings::from_mount(&robot.camera));
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
        "friction": f32_json(scenario.world.friction.unwrap_or(robot.wheel.friction)),
        "magnets": scenario.world.magnets,
        "bus_baud_bps": scenario.bus.baud_bps.unwrap_or(robot.bus.baud_bps),
        "capture": {
            "rate_hz": scenario.capture.rate_hz,
            "on_line_tolerance_m": scenario.capture.on_line_tolerance_m,
            "signals": scenario.capture.signals,
            "metric_period_s": super::capture::METRIC_PERIOD_S,
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

/// Run a scenario with the built-in controller in lockstep, as fast as the CPU allows; the
/// captured rows are kept in the outcome.
pub fn run_lockstep(scenario: &Scenario, robot: &RobotDescription) -> Result<RunOutcome, RunError> {
    run_lockstep_until(scenario, robot, &AtomicBool::new(false), None, None)
}

/// A built-in controller's run shown live in Foxglove: where the server listens, and at what
/// multiple of real time the run goes (a lockstep run is otherwise as fast as the CPU allows,
/// too fast to watch).
#[derive(Debug, Clone)]
pub struct LiveRun {
    pub address: LiveAddress,
    pub speed: f64,
    /// Told the server's URL once it listens, before the run starts.
    pub announce: fn(&str),
}

/// [`run_lockstep`], ending early when `stop` is set (e.g. by SIGINT): the outcome then covers
/// the run up to that moment and its summary says where it stopped (`interrupted_at_s`). With
/// `out_dir`, the captured rows go into its `timeseries.csv` as they come (complete when this
/// returns, interrupted or not) and the outcome holds none: [`write_outputs`] into the same
/// folder then writes the rest.
pub fn run_lockstep_until(scenario: &Scenario, robot: &RobotDescription, stop: &AtomicBool, out_dir: Option<&std::path::Path>, live: Option<&LiveRun>) -> Result<RunOutcome, RunError> {
    let ControllerSection::Builtin(config) = &scenario.controller else {
        return Err(RunError::NeedsRealTime { path: scenario.path.clone() });
    };
    require_line(scenario)?;
    // Rows are captured once per control period: a faster capture would repeat them.
    let control_hz = 1.0 / config.period().as_secs_f64();
    if scenario.capture.rate_hz > control_hz * (1.0 + 1e-9) {
        let why = format!("a built-in controller's run captures once per control period, {} s; lower rate_hz or controller.period_s", config.period().as_secs_f64());
        return Err(RunError::CaptureRate { path: scenario.path.clone(), rate_hz: scenario.capture.rate_hz, max_hz: (control_hz * 1e6).round() / 1e6, why });
    }
    let _span = info_span!("scenario", path = %scenario.path.display()).entered();
    let started = Instant::now();
    let mut sim = Lockstep::new(robot, scenario.world_config()?)?;
    check_world(scenario, sim.world(), &sim.bus().servos().iter().map(Servo::id).collect::<Vec<_>>())?;
    // The world advances one physics step (the servos' firmware tick) at a time, so that an
    // interrupt and the world watch act within a step, not a control period.
    let tick = sim.bus().servos().first().map_or(Duration::from_millis(1), Servo::control_period);
    let mut watch = WorldWatch::new();
    let mut failure = None;
    sim.bus_mut().set_faults(BusFaults::new(scenario.faults(), scenario.world.seed));
    let mut controller_errors = 0u64;
    let mut last_sample = ControlSample::default();
    // The servos' own profile, not a second parse of the file.
    let profile = sim.bus().servos().first().map(|s| std::sync::Arc::clone(s.profile())).ok_or(ControlError::MissingServo("servo on the bus"))?;
    // Runs start one firmware tick in, with the world settled for a step (the recorded figures
    // come from such runs). Draping does not need it: RobotWorld::new already made the terrain
    // queryable.
    sim.run(Duration::from_millis(1));
    let mut observer = Observer::new(scenario, robot, sim.world())?;
    if let Some(out_dir) = out_dir {
        observer.stream_to(out_dir)?;
    }
    let view = ViewOptions::of_run(&scenario.capture, out_dir, live.map(|l| l.address.clone()));
    if let (Some(url), Some(live)) = (observer.start_view(&view, sim.bus_mut())?, live) {
        (live.announce)(&url);
    }
    let mut controller = ReferenceController::new(robot, &profile, config.clone(), observer.target_speed_m_s(0.0))?;
    if let Some(relocation) = observer.relocation_plan() {
        controller = controller.with_relocation(relocation);
    }
    let relocating = controller.relocation().is_some();
    controller.start(&mut sim)?;
    let period = config.period();
    let wall_window_rad = config.wall_transition.as_ref().map_or(0.0, |t| t.square_window_deg.to_radians() as f32);
    let end = Duration::from_secs_f64(scenario.world.duration_s);
    let mut interrupted = false;
    while sim.now() < end {
        if stop.load(Ordering::Relaxed) {
            interrupted = true;
            break;
        }
        let now = sim.now();
        let t_s = now.as_secs_f64();
        observer.apply_events(t_s, sim.world_mut())?;
        controller.set_target_speed(observer.target_speed_m_s(t_s));
        let line = observer.sense(sim.world(), now);
        let wall = observer.lidar_scan().map(|scan| WallSighting {
            ahead_m: f64::from(scan.ahead_m()),
            angle_rad: scan.wall_angle_rad(wall_window_rad).map(f64::from),
        });
        let returns = if relocating { observer.lidar_scan().map(LidarScan::returns_in_plan).unwrap_or_default() } else { Vec::new() };
        let pose = relocating.then(|| plan_pose(sim.world()));
        let senses = Senses { line, wall, pose, lidar_returns: &returns };
        let sample = match controller.tick(&mut sim, now, &senses) {
            Ok(sample) => *sample,
            // With faults on the bus a lost or corrupted reply is expected: the controller skips
            // the period (its wheels keep the last command) and tries again next period, as a
            // real one that times out would. Without faults a failed read is still a bug.
            Err(error) if !sim.bus().faults().is_empty() => {
                controller_errors += 1;
                tracing::debug!(%error, t_s, "control period skipped");
                last_sample
            }
            Err(error) => return Err(error.into()),
        };
        last_sample = sample;
        observer.capture(t_s, sim.bus(), Some(&sample))?;
        let period_end = sim.now() + period;
        while sim.now() < period_end && !interrupted && failure.is_none() {
            sim.run(tick.min(period_end - sim.now()));
            interrupted = stop.load(Ordering::Relaxed);
            failure = watch.check(sim.world(), sim.now().as_secs_f64()).cloned();
        }
        if interrupted || failure.is_some() {
            break;
        }
        if let Some(live) = live {
            // Keep to `speed` × real time for the person watching.
            let due = Duration::from_secs_f64(sim.now().as_secs_f64() / live.speed);
            if let Some(ahead) = due.checked_sub(started.elapsed()) {
                std::thread::sleep(ahead);
            }
        }
    }
    if let Some(failure) = &failure {
        observer.note(sim.now(), LogLevel::Error, failure.message.clone());
    }
    let wall_s = started.elapsed().as_secs_f64();
    let sim_s = sim.now().as_secs_f64();
    let mut summary = observer.summary(scenario.capture.on_line_tolerance_m);
    summary.insert("realtime_factor".to_owned(), json!(sim_s / wall_s.max(1e-9)));
    if interrupted {
        summary.insert("interrupted_at_s".to_owned(), json!(sim_s));
    }
    if let Some(failure) = &failure {
        record_failure(&mut summary, failure);
    }
    summary.extend(fault_summary(sim.bus()));
    if !sim.bus().faults().is_empty() {
        summary.insert("faults.control_periods_skipped".to_owned(), json!(controller_errors));
    }
    if let Some(relocation) = controller.relocation() {
        summary.insert("relocation.replans".to_owned(), json!(relocation.replans()));
        if let Leg::Stuck { reason } = relocation.leg() {
            summary.insert("relocation.stuck".to_owned(), json!(reason));
        }
    }
    let (series, track) = observer.finish()?;
    Ok(RunOutcome { series, track, summary, settings: settings_json(scenario, robot), sim_s, wall_s })
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
