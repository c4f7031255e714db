//! What watches a run's world, split by job, each in its own file: the weld lines and ground
//! truth ([`welds`]), scripted events ([`events`]), the sensors ([`sensors`]: camera and
//! detector, LIDAR), the metrics ([`metrics`]: captured rows, the metric track and what is
//! measured over it — [`surfaces`], [`relocation`]), the Foxglove view ([`view_feed`]), and the
//! world watch ([`watch`]). [`Observer`] assembles them and runs them in three phases each tick,
//! in the spirit of Gazebo's systems: [`Observer::pre_update`] (events change the world),
//! [`Observer::update`] (sensors sense it), [`Observer::post_update`] (metrics record it, the
//! view shows it). A built-in controller acts between `update` and `post_update`
//! ([`super::lockstep`]); on the wall clock and in a replay the three run back to back
//! ([`Observer::on_tick`]).

pub mod capture;
pub mod events;
pub mod metrics;
pub mod relocation;
pub mod sensors;
pub mod surfaces;
pub mod view_feed;
pub mod watch;
pub mod welds;

use std::path::PathBuf;
use std::time::Duration;

use foxglove::messages::log::Level as LogLevel;
use rapier3d::prelude::Vector;
use serde_json::Value;

use crate::bus::{Bus, BusFaults, Timing};
use crate::control::planner::OccupancyGrid;
use crate::control::{ControlSample, LineError, Pose2, Relocation, RelocationConfig, WeldTask};
use crate::device::Servo;
use crate::report::{Summary, TimeSeries};
use crate::robot::RobotDescription;
use crate::runner::RunError;
use crate::runner::view::ViewOptions;
use crate::scenario::Scenario;
use crate::sim::lidar::LidarScan;
use crate::sim::{LineCamera, LineMeasurement, RobotWorld, SimError};

pub use capture::{COLUMNS, MetricTrack, summarise};
pub use sensors::robot_relative;
pub use welds::GroundTruth;

use events::{Effect, Events};
use metrics::{Metrics, RowInputs, TrackSample};
use relocation::RelocationTrack;
use sensors::Sensors;
use surfaces::SurfaceTrack;
use view_feed::ViewFeed;
use watch::{RunFailure, WorldWatch};
use welds::Welds;

/// What [`Observer::on_tick`] saw.
#[derive(Debug)]
pub struct TickObservation {
    /// The camera delivered a frame this tick.
    pub new_frame: bool,
    pub error: Option<RunError>,
    /// The world watch's verdict: the run should stop (see [`watch`]).
    pub failure: Option<RunFailure>,
}

/// Refuse a world the run cannot happen in: a start off the terrain, a fault on a servo the bus
/// does not have.
pub(crate) fn check_world(scenario: &Scenario, world: &RobotWorld, ids: &[u8]) -> Result<(), RunError> {
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
    scenario_path: PathBuf,
    welds: Welds,
    events: Events,
    sensors: Sensors,
    metrics: Metrics,
    /// The Foxglove view, once started.
    view: Option<ViewFeed>,
    watch: WorldWatch,
    /// With more than one weld: how the built-in controller is to relocate, and the map it is
    /// given (the metrics keep the true one).
    relocation: Option<(RelocationConfig, OccupancyGrid)>,
    /// The servos' names (robot description) by ID, for the view.
    servo_names: Vec<(u8, String)>,
}

impl Observer {
    /// The observer of `scenario`'s world: here the run's sensors and metrics are assembled.
    pub fn new(scenario: &Scenario, robot: &RobotDescription, world: &RobotWorld) -> Result<Self, RunError> {
        let path = scenario.path.clone();
        for name in scenario.capture.signals.iter().flatten() {
            if !COLUMNS.contains(&name.as_str()) {
                return Err(RunError::UnknownSignal { path, name: name.clone(), known: COLUMNS[1..].join(", ") });
            }
        }
        let welds = Welds::new(scenario, world)?;
        let sensors = Sensors::new(scenario, robot)?;
        let mut metrics = Metrics::new(scenario, &welds, world);
        metrics.add(Box::new(SurfaceTrack::new(scenario.capture.adhesion_floor_n as f32)));
        let relocation = if welds.lines().len() > 1 {
            let config = scenario.relocation.clone().unwrap_or_default();
            let (given, truth) = relocation::maps(world, welds.lines(), &config).map_err(|e| RunError::Relocation { path: path.clone(), message: e.to_string() })?;
            metrics.add(Box::new(RelocationTrack::new(truth, config.clearance_m as f32, welds.lines().len())));
            Some((config, given))
        } else {
            None
        };
        Ok(Self {
            scenario_path: path,
            events: Events::new(scenario),
            welds,
            sensors,
            metrics,
            view: None,
            watch: WorldWatch::new(),
            relocation,
            servo_names: robot.servo.iter().map(|s| (s.id, s.name.clone())).collect(),
        })
    }

    /// Whether the world has a weld line (and so a camera image and line measurements).
    pub fn has_line(&self) -> bool {
        !self.welds.is_empty()
    }

    /// The target speed in force at `t_s` (zero before the speed step).
    pub fn target_speed_m_s(&self, t_s: f64) -> f64 {
        self.events.target_speed_m_s(t_s)
    }

    /// Phase one of a tick: apply the events due by `t_s`.
    pub fn pre_update(&mut self, t_s: f64, world: &mut RobotWorld) -> Result<(), RunError> {
        let effects = self.events.apply_due(t_s, world, &mut self.welds, &self.scenario_path)?;
        let at = Duration::from_secs_f64(t_s);
        for effect in effects {
            match effect {
                Effect::Note(message) => self.note(at, LogLevel::Info, message),
                Effect::WeldsMoved => {
                    if let Some(view) = &self.view {
                        view.welds_moved(at, world, &self.welds);
                    }
                }
            }
        }
        Ok(())
    }

    /// Phase two: the sensors that are due at `t` sense the world; the latest line measurement
    /// in the controller's convention (None while the line is not seen).
    pub fn update(&mut self, world: &RobotWorld, t: Duration) -> Option<LineError> {
        self.sensors.sense(world, &self.welds, t, self.view.as_ref().map(ViewFeed::view))
    }

    /// Phase three: the view's frame if one is due, the metric track's sample and a captured
    /// row if they are due at `t_s`. `control` is the built-in controller's view (an external
    /// controller's is unknown: its columns are NaN).
    pub fn post_update(&mut self, t_s: f64, bus: &Bus, control: Option<&ControlSample>) -> Result<(), RunError> {
        let (row_due, track_due) = self.metrics.due(t_s, self.view.is_some());
        let Some(world) = bus.plant::<RobotWorld>() else { return Ok(()) };
        if let Some(view) = &mut self.view {
            view.frame(t_s, bus, world);
        }
        if !row_due && !track_due {
            return Ok(());
        }
        let truth = self.welds.ground_truth(world);
        let target_m_s = self.events.target_speed_m_s(t_s);
        let seen = self.sensors.seen();
        if track_due {
            let camera_d_m = seen.map_or(f64::NAN, |l| l.d_err_m);
            self.metrics.record_track(&TrackSample { t_s, world, welds: &self.welds, truth: &truth }, camera_d_m, target_m_s);
        }
        if !row_due {
            return Ok(());
        }
        let row = metrics::row(&RowInputs { t_s, truth: &truth, target_m_s, seen, control, lidar: self.sensors.lidar_scan() }, world, bus);
        if let Some(view) = &mut self.view {
            view.signals(t_s, &row);
        }
        self.metrics.record_row(&row)
    }

    /// What every firmware tick of a wall-clock run (and of its replay) does after advancing the
    /// world: the three phases, and the world watch between sensing and recording. An error in
    /// one phase does not skip the others (the live run keeps going); the first is returned.
    pub fn on_tick(&mut self, bus: &mut Bus, now: Duration) -> TickObservation {
        let t_s = now.as_secs_f64();
        let Some(world) = bus.plant_mut::<RobotWorld>() else { return TickObservation { new_frame: false, error: None, failure: None } };
        let mut error = self.pre_update(t_s, world).err();
        let frames_before = self.sensors.frames_seen();
        self.update(world, now);
        let failed_before = self.watch.failure().is_some();
        let failure = self.watch.check(world, t_s).cloned();
        if let Some(failure) = failure.as_ref().filter(|_| !failed_before) {
            self.note(now, LogLevel::Error, failure.message.clone());
        }
        if let Err(capture) = self.post_update(t_s, bus, None) {
            error.get_or_insert(capture);
        }
        TickObservation { new_frame: self.sensors.frames_seen() != frames_before, error, failure }
    }

    /// Something for the view's `/log` (events, faults, failures); nothing without a view.
    pub fn note(&self, at: Duration, level: LogLevel, message: String) {
        if let Some(view) = &self.view {
            view.note(at, level, message);
        }
    }

    /// Write the captured rows into `out_dir/timeseries.csv` as they come instead of keeping
    /// them.
    pub fn stream_to(&mut self, out_dir: &std::path::Path) -> Result<(), RunError> {
        self.metrics.stream_to(out_dir)
    }

    /// Keep no captured rows and no metric track (`serve SCENARIO`, which writes no outputs).
    pub fn discard_rows(&mut self) {
        self.metrics.discard_rows();
    }

    /// Show the run in Foxglove (see [`crate::runner::view`]): a recording, a live server, or
    /// both. The terrain, the line and the robot's shapes are sent at once; the robot's frames,
    /// the servos' registers and the signals with the capture. The live server's URL, if any.
    pub fn start_view(&mut self, options: &ViewOptions, bus: &mut Bus) -> Result<Option<String>, RunError> {
        if options.is_off() {
            return Ok(None);
        }
        let Some(world) = bus.plant::<RobotWorld>() else { return Ok(None) };
        let view = ViewFeed::start(options, world, &self.welds, self.servo_names.clone(), self.sensors.has_lidar(), &self.scenario_path)?;
        bus.set_transaction_tap(view.packet_tap());
        let url = view.live_url();
        self.view = Some(view);
        Ok(url)
    }

    /// The built-in controller's relocation between the welds, on the map it is given; None with
    /// a single weld.
    pub fn relocation_plan(&self) -> Option<Relocation> {
        let (config, given) = self.relocation.as_ref()?;
        let tasks = self.welds.lines().iter().map(|w| WeldTask { points: w.smoothed().to_vec() }).collect();
        Some(Relocation::new(config.clone(), tasks, given.clone()))
    }

    /// The weld list as the sensor server's `/welds` serves it.
    pub fn welds_json(&self) -> Value {
        self.welds.to_json()
    }

    /// The detector's output on the newest frame, in the detector's own convention (where the
    /// line is relative to the robot); [`robot_relative`] gives the run's.
    pub fn latest(&self) -> Option<&LineMeasurement> {
        self.sensors.latest()
    }

    /// The LIDAR's latest scan, if the robot has one and it has scanned.
    pub fn lidar_scan(&self) -> Option<&LidarScan> {
        self.sensors.lidar_scan()
    }

    pub fn camera(&self) -> &LineCamera {
        self.sensors.camera()
    }

    /// The robot's true pose relative to the nearest weld (d and ψ are NaN without a line).
    pub fn ground_truth(&self, world: &RobotWorld) -> GroundTruth {
        self.welds.ground_truth(world)
    }

    /// Why the world watch stopped believing in this run (see [`watch`]), once it has.
    pub fn world_failure(&self) -> Option<&RunFailure> {
        self.watch.failure()
    }

    /// The view, once started.
    pub fn view(&self) -> Option<&crate::runner::view::View> {
        self.view.as_ref().map(ViewFeed::view)
    }

    /// A servo's name in the robot description.
    pub fn servo_name(&self, id: u8) -> Option<&str> {
        self.servo_names.iter().find(|(of, _)| *of == id).map(|(_, name)| name.as_str())
    }

    /// Close the view: the recording gets its final name, the live server stops.
    pub fn finish_view(&mut self) -> Result<(), RunError> {
        match self.view.take() {
            Some(view) => view.finish(),
            None => Ok(()),
        }
    }

    /// End the run's watching: the view closes, a streamed `timeseries.csv` is completed
    /// (flushed and renamed), rows kept in memory are returned, with the metric track.
    pub fn finish(mut self) -> Result<(Option<TimeSeries>, MetricTrack), RunError> {
        self.finish_view()?;
        self.metrics.finish()
    }

    /// The seed's metrics over the metric track, and every track metric's keys.
    pub fn summary(&self, on_line_tolerance_m: f64) -> Summary {
        self.metrics.summary(on_line_tolerance_m)
    }
}

/// The robot's pose in plan, as relocation takes it (the simulator's own: a stand-in for a real
/// robot's localisation) and the sensor server's `/state` gives it.
pub fn plan_pose(world: &RobotWorld) -> Pose2 {
    let pose = world.chassis_pose();
    let forward = pose.rotation * Vector::X;
    Pose2 { x: f64::from(pose.translation.x), z: f64::from(pose.translation.z), heading_rad: f64::from((-forward.z).atan2(forward.x)) }
}
