//! What a run shows in Foxglove, recorded (`run.mcap`; MCAP is also the ROS 2 bag format, and
//! Rerun opens it too) and live (Foxglove's WebSocket protocol), written with the Foxglove SDK,
//! which brings the well-known schemas, the MCAP writer and the WebSocket server. One set of
//! channels feeds both sinks.
//!
//! Topics (log time = simulated time since the run began):
//! - `/tf` (`foxglove.FrameTransforms`): `map` (z up) → `world` (rapier's y up) → `middle` →
//!   `front` (the rocker), the wheels in the section that carries them, each magnet in its
//!   wheel, at the capture rate;
//! - `/scene/terrain` (`foxglove.SceneUpdate`): the terrain coloured by height, the weld line's
//!   stripe and the obstacles, at the start and whenever the line moves;
//! - `/scene/robot`: the sections' boxes and the wheels, locked to their frames, at the start;
//! - `/scene/magnets`: an arrow per magnet as long as its pull, at the capture rate;
//! - `/camera/image` (`foxglove.CompressedImage`, PNG): every frame of the downward camera;
//! - `/lidar` (`foxglove.LaserScan`): every scan of the front LIDAR, when the robot has one;
//! - `/signals` (JSON): every column of `timeseries.csv` at the capture rate (the detector's
//!   `d_m` and `psi_rad` among them), and d and speed in mm and mm/min too, for plots;
//! - `/servos` (JSON): each servo's key registers, by name, at the capture rate;
//! - `/log` (`foxglove.Log`): events, faults starting and ending, and why a run failed;
//! - `/bus/packets` (JSON), when asked: every packet on the bus, hex and decoded;
//! - `/compare/robot` and `/compare/world` (JSON, `climbsim compare`): the registers each real
//!   read reply carried, and the world's answer to the same read, shaped as `/servos` is (raw
//!   values under the servo's name), so that one plot overlays the robot and the world.
//!
//! A live viewer that connects late still gets the scene: the server sends the latest terrain
//! and robot to each new subscriber.
//!
//! A recording is written as `<file>.tmp` and renamed when the run ends, interrupted or not, so
//! the named file is always complete.

mod live;
pub mod scene;

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use foxglove::messages::log::Level as LogLevel;
use foxglove::messages::{CameraCalibration, CompressedImage, FrameTransform, FrameTransforms, LaserScan, Log, Quaternion, SceneUpdate, Timestamp, Vector3};
use foxglove::{Channel, ChannelBuilder, Context, McapWriter, McapWriterHandle, PartialMetadata, RawChannel, Schema};
use thiserror::Error;

pub use live::LiveAddress;
use live::LiveServer;

use crate::bus::TransactionTap;
use crate::bus::transaction_json;
use crate::device::Servo;
use crate::scenario::CaptureSection;
use crate::sim::lidar::LidarScan;
use crate::sim::line::LineSample;
use crate::sim::{CAMERA_FRAME, PartFrame, RobotWorld};

/// The recording's file name in a run's output folder.
pub const MCAP_FILE: &str = "run.mcap";

/// Terrain meshes are cut to at most this many vertices a side (a 256 × 256 heightfield is sent
/// whole: about 3 MB once, far less compressed in the recording).
const TERRAIN_VERTICES_PER_SIDE: usize = 257;

/// A magnet pulling less than this (N) has its arrow drawn red.
const WEAK_MAGNET_N: f32 = crate::scenario::DEFAULT_ADHESION_FLOOR_N;

#[derive(Debug, Error)]
pub enum ViewError {
    #[error("cannot write {path}: {message}")]
    Write { path: PathBuf, message: String },
    #[error("cannot start the Foxglove WebSocket server on {address}: {message}")]
    Listen { address: String, message: String },
}

/// Where a run shows itself.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ViewOptions {
    /// Record into this file.
    pub mcap: Option<PathBuf>,
    /// Serve Foxglove's WebSocket protocol here.
    pub live: Option<LiveAddress>,
    /// Put every bus packet on `/bus/packets` too (`[capture] bus_packets`).
    pub packets: bool,
    /// Advertise `/compare/robot` and `/compare/world` (`climbsim compare`'s recording).
    pub compare: bool,
}

impl ViewOptions {
    /// What a run's `[capture]` asks for: `run.mcap` in its output folder (if it has one and
    /// `mcap` is on), bus packets if `bus_packets`, and the live server at `live`.
    pub fn of_run(capture: &CaptureSection, out_dir: Option<&Path>, live: Option<LiveAddress>) -> Self {
        Self { mcap: out_dir.filter(|_| capture.mcap).map(|dir| dir.join(MCAP_FILE)), live, packets: capture.bus_packets, compare: false }
    }

    pub fn is_off(&self) -> bool {
        self.mcap.is_none() && self.live.is_none()
    }
}

/// `/bus/packets`: one message per packet on the wire (see `bus::trace`).
const PACKET_SCHEMA: &str =
    r#"{"type":"object","properties":{"t":{"type":"number"},"dir":{"type":"string"},"id":{"type":"integer"},"from":{"type":"integer"},"hex":{"type":"string"},"decoded":{"type":"object"}}}"#;

/// The registers `/servos` shows, by control-table key.
const SERVO_REGISTERS: &[&str] =
    &["torque_enable", "goal_velocity", "present_velocity", "present_position", "present_current", "present_input_voltage", "present_temperature", "hardware_error_status"];

struct Recording {
    /// Taken when the recording is finished (closed and renamed).
    writer: Option<McapWriterHandle<BufWriter<File>>>,
    temporary: PathBuf,
    path: PathBuf,
}

impl Recording {
    /// Close the file and give it its final name.
    fn finish(mut self) -> Result<(), ViewError> {
        let error = |message: String| ViewError::Write { path: self.path.clone(), message };
        if let Some(writer) = self.writer.take() {
            writer.close().map_err(|e| error(e.to_string()))?;
        }
        std::fs::rename(&self.temporary, &self.path).map_err(|e| error(e.to_string()))
    }
}

impl Drop for Recording {
    /// Unfinished: the run failed to start, or failed before its outputs were written (the
    /// Foxglove port was taken, the controller could not start): no `run.mcap.tmp` is left.
    fn drop(&mut self) {
        if let Some(writer) = self.writer.take() {
            let _ = writer.close();
            let _ = std::fs::remove_file(&self.temporary);
        }
    }
}

/// The scene messages a late subscriber is sent (see [`live`]).
#[derive(Default)]
struct LatestScene {
    terrain: Option<SceneUpdate>,
    robot: Option<SceneUpdate>,
}

/// Channels of one run.
struct Channels {
    transforms: Channel<FrameTransforms>,
    terrain: Channel<SceneUpdate>,
    robot: Channel<SceneUpdate>,
    magnets: Channel<SceneUpdate>,
    image: Channel<CompressedImage>,
    calibration: Channel<CameraCalibration>,
    /// Only when the robot has a LIDAR: a channel is advertised to every viewer.
    lidar: Option<Channel<LaserScan>>,
    log: Channel<Log>,
    signals: Arc<RawChannel>,
    servos: Arc<RawChannel>,
    packets: Option<Arc<RawChannel>>,
    /// `/compare/robot` and `/compare/world`, when asked.
    compare: Option<[Arc<RawChannel>; 2]>,
}

/// Where [`View::readings`] go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReadingsTopic {
    /// `/servos`: a real bus's replies shown where the world's registers usually are (`tap
    /// --foxglove`: the shipped layout shows the real servos).
    Servos,
    /// `/compare/robot`: what the real servo answered.
    Robot,
    /// `/compare/world`: what the world answered to the same read.
    World,
}

/// One servo's read reply as registers: its name, ID and (key, raw value) pairs.
#[derive(Debug, Clone)]
pub struct ServoReadings<'a> {
    pub name: &'a str,
    pub id: u8,
    pub registers: Vec<(&'a str, i64)>,
}

/// A run as Foxglove sees it.
pub struct View {
    /// Channels and sinks belong to a context of their own: runs of a sweep record side by side.
    _context: Arc<Context>,
    recording: Option<Recording>,
    live: Option<LiveServer>,
    channels: Arc<Channels>,
    latest: Arc<Mutex<LatestScene>>,
    columns: Vec<&'static str>,
    /// Signals also published in the scenarios' units, for plots: (column index, name, factor).
    in_scenario_units: Vec<(usize, String, f64)>,
    /// JSON reused message after message.
    json: String,
    tyre_radius_m: f32,
    camera_distance_m: f32,
}

/// What a view needs to know of the run it shows.
#[derive(Debug, Clone, Copy)]
pub struct Setup<'a> {
    /// The values of each [`View::signals`] row.
    pub columns: &'a [&'static str],
    /// The servos of [`View::servos`], in bus order.
    pub servo_names: &'a [String],
    /// `/lidar` exists only with a LIDAR.
    pub has_lidar: bool,
    /// The wheels' outer radius: the magnets' arrows start outside the tyre.
    pub tyre_radius_m: f32,
    /// How far below the camera the ground is at the start: its calibration's focal length makes
    /// its orthographic image the right size there.
    pub camera_distance_m: f32,
}

/// The signals `/signals` also carries in the units scenarios are written in (`d_mm`,
/// `speed_mm_min`, …): Foxglove plots what is published.
const SIGNALS_IN_SCENARIO_UNITS: &[&str] = &["d_m", "d_true_m", "speed_m_s", "target_speed_m_s"];

fn nanos(t: Duration) -> u64 {
    u64::try_from(t.as_nanos()).unwrap_or(u64::MAX)
}

fn timestamp(t: Duration) -> Timestamp {
    Timestamp::new(u32::try_from(t.as_secs()).unwrap_or(u32::MAX), t.subsec_nanos())
}

/// A JSON schema for the signals: one number per column.
fn signals_schema(columns: &[&str]) -> Vec<u8> {
    let properties: serde_json::Map<String, serde_json::Value> = columns.iter().map(|&name| (name.to_owned(), serde_json::json!({ "type": "number" }))).collect();
    serde_json::json!({ "type": "object", "properties": properties }).to_string().into_bytes()
}

/// A JSON schema for `/servos`: an object per servo name, its ID and a number per register.
fn servos_schema(names: &[String]) -> Vec<u8> {
    let mut registers: serde_json::Map<String, serde_json::Value> = SERVO_REGISTERS.iter().map(|&key| (key.to_owned(), serde_json::json!({ "type": "number" }))).collect();
    registers.insert("id".to_owned(), serde_json::json!({ "type": "integer" }));
    let servo = serde_json::json!({ "type": "object", "properties": registers });
    let properties: serde_json::Map<String, serde_json::Value> = names.iter().map(|name| (name.clone(), servo.clone())).collect();
    serde_json::json!({ "type": "object", "properties": properties }).to_string().into_bytes()
}

fn json_channel(context: &Arc<Context>, topic: &str, schema_name: &str, schema: Vec<u8>) -> Result<Arc<RawChannel>, String> {
    ChannelBuilder::new(topic).context(context).message_encoding("json").schema(Schema::new(schema_name, "jsonschema", schema)).build_raw().map_err(|e| e.to_string())
}

impl View {
    /// Start showing a run (see [`Setup`]). Nothing is sent until [`View::terrain`] and
    /// [`View::robot`].
    pub fn start(options: &ViewOptions, setup: &Setup<'_>) -> Result<Self, ViewError> {
        let Setup { columns, servo_names, has_lidar, tyre_radius_m, camera_distance_m } = *setup;
        let in_scenario_units: Vec<(usize, String, f64)> = SIGNALS_IN_SCENARIO_UNITS
            .iter()
            .filter_map(|&name| Some((columns.iter().position(|c| *c == name)?, crate::report::units::in_shown_unit(name)?)))
            .map(|(index, (name, factor))| (index, name, factor))
            .collect();
        let mut schema_names: Vec<&str> = columns.to_vec();
        schema_names.extend(in_scenario_units.iter().map(|(_, name, _)| name.as_str()));
        let context = Context::new();
        let recording = options.mcap.as_ref().map(|path| start_recording(&context, path)).transpose()?;
        let error = |message: String| ViewError::Write { path: options.mcap.clone().unwrap_or_default(), message };
        let channels = Arc::new(Channels {
            transforms: ChannelBuilder::new("/tf").context(&context).build(),
            terrain: ChannelBuilder::new("/scene/terrain").context(&context).build(),
            robot: ChannelBuilder::new("/scene/robot").context(&context).build(),
            magnets: ChannelBuilder::new("/scene/magnets").context(&context).build(),
            image: ChannelBuilder::new("/camera/image").context(&context).build(),
            calibration: ChannelBuilder::new("/camera/calibration").context(&context).build(),
            lidar: has_lidar.then(|| ChannelBuilder::new("/lidar").context(&context).build()),
            log: ChannelBuilder::new("/log").context(&context).build(),
            signals: json_channel(&context, "/signals", "climbsim.Signals", signals_schema(&schema_names)).map_err(error)?,
            servos: json_channel(&context, "/servos", "climbsim.Servos", servos_schema(servo_names)).map_err(error)?,
            packets: options.packets.then(|| json_channel(&context, "/bus/packets", "climbsim.BusPacket", PACKET_SCHEMA.as_bytes().to_vec())).transpose().map_err(error)?,
            compare: options
                .compare
                .then(|| {
                    Ok::<_, String>([
                        json_channel(&context, "/compare/robot", "climbsim.Servos", servos_schema(servo_names))?,
                        json_channel(&context, "/compare/world", "climbsim.Servos", servos_schema(servo_names))?,
                    ])
                })
                .transpose()
                .map_err(error)?,
        });
        let latest = Arc::new(Mutex::new(LatestScene::default()));
        let live = options.live.as_ref().map(|address| LiveServer::start(&context, address, Arc::clone(&channels), Arc::clone(&latest))).transpose()?;
        Ok(Self { _context: context, recording, live, channels, latest, columns: columns.to_vec(), in_scenario_units, json: String::new(), tyre_radius_m, camera_distance_m })
    }

    /// Where a live viewer connects (`ws://…`), when the view is live.
    pub fn live_url(&self) -> Option<String> {
        self.live.as_ref().map(LiveServer::url)
    }

    /// The terrain and the weld line at `t` (at the start, and again when the line moves).
    pub fn terrain(&self, t: Duration, world: &RobotWorld, lines: &[&[LineSample]]) {
        let update = scene::terrain_and_line(timestamp(t), &world.terrain_mesh(TERRAIN_VERTICES_PER_SIDE), lines, &world.obstacle_shapes());
        self.channels.terrain.log_with_time(&update, nanos(t));
        self.latest.lock().unwrap_or_else(PoisonError::into_inner).terrain = Some(update);
    }

    /// The robot's shapes, each locked to its frame.
    pub fn robot(&self, t: Duration, world: &RobotWorld) {
        let update = scene::robot(timestamp(t), &world.part_shapes());
        self.channels.robot.log_with_time(&update, nanos(t));
        self.latest.lock().unwrap_or_else(PoisonError::into_inner).robot = Some(update);
    }

    /// The robot's frames at `t` (under `world`), and each magnet's pull as an arrow.
    pub fn transforms(&self, t: Duration, frames: &[PartFrame], magnet_pulls: &[(String, f32)]) {
        // Foxglove's 3D panel has z up; rapier's world has y up: +90° about x turns one into the other.
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let mut transforms = Vec::with_capacity(frames.len() + 1);
        transforms.push(FrameTransform {
            timestamp: Some(timestamp(t)),
            parent_frame_id: "map".to_owned(),
            child_frame_id: "world".to_owned(),
            translation: Some(Vector3 { x: 0.0, y: 0.0, z: 0.0 }),
            rotation: Some(Quaternion { x: half, y: 0.0, z: 0.0, w: half }),
        });
        transforms.extend(frames.iter().map(|frame| FrameTransform {
            timestamp: Some(timestamp(t)),
            parent_frame_id: frame.parent.clone(),
            child_frame_id: frame.name.clone(),
            translation: Some(scene::vector3(frame.pose.translation)),
            rotation: Some(scene::quaternion(frame.pose.rotation)),
        }));
        self.channels.transforms.log_with_time(&FrameTransforms { transforms }, nanos(t));
        self.channels.magnets.log_with_time(&scene::magnet_arrows(timestamp(t), magnet_pulls, WEAK_MAGNET_N, self.tyre_radius_m), nanos(t));
        if let Some(live) = &self.live {
            live.broadcast_time(nanos(t));
        }
    }

    /// A camera frame taken at `t`, PNG-encoded, `width` × `height` pixels seeing `2 ×
    /// half_height_m` forward, and its calibration.
    pub fn image(&self, t: Duration, png: Vec<u8>, (width, height): (u32, u32), half_height_m: f32) {
        let message = CompressedImage { timestamp: Some(timestamp(t)), frame_id: CAMERA_FRAME.to_owned(), data: png.into(), format: "png".to_owned() };
        self.channels.image.log_with_time(&message, nanos(t));
        self.channels.calibration.log_with_time(&scene::camera_calibration(timestamp(t), (width, height), half_height_m, self.camera_distance_m), nanos(t));
    }

    /// A LIDAR scan, in the middle section's frame at its mount.
    pub fn lidar(&self, scan: &LidarScan) {
        let message = LaserScan {
            timestamp: Some(timestamp(scan.t)),
            frame_id: "middle".to_owned(),
            pose: Some(scene::pose(&scan.mount)),
            start_angle: f64::from(scan.start_angle_rad),
            end_angle: f64::from(scan.end_angle_rad()),
            ranges: scan.ranges_m.iter().map(|&r| f64::from(r)).collect(),
            intensities: Vec::new(),
        };
        if let Some(channel) = &self.channels.lidar {
            channel.log_with_time(&message, nanos(scan.t));
        }
    }

    /// Something that happened at `t`: an event, a fault, a failure.
    pub fn log(&self, t: Duration, level: LogLevel, message: String) {
        let message = Log { timestamp: Some(timestamp(t)), level: level as i32, message, name: "climbsim".to_owned(), file: String::new(), line: 0 };
        self.channels.log.log_with_time(&message, nanos(t));
    }

    /// One row of signals (the values of the columns given to [`View::start`]); NaN and
    /// infinite values are left out (JSON has no number for them).
    pub fn signals(&mut self, t: Duration, row: &[f64]) {
        // Written by hand into a reused buffer: the column names are plain identifiers, and a
        // finite f64's Display is a valid JSON number (no exponent, no NaN).
        use std::fmt::Write as _;
        let json = &mut self.json;
        json.clear();
        json.push('{');
        for (&name, &value) in self.columns.iter().zip(row).filter(|(_, v)| v.is_finite()) {
            if json.len() > 1 {
                json.push(',');
            }
            let _ = write!(json, "\"{name}\":{value}");
        }
        for (index, name, factor) in &self.in_scenario_units {
            if let Some(value) = row.get(*index).map(|v| v * factor).filter(|v| v.is_finite()) {
                if json.len() > 1 {
                    json.push(',');
                }
                let _ = write!(json, "\"{name}\":{value}");
            }
        }
        json.push('}');
        self.channels.signals.log_with_meta(json.as_bytes(), PartialMetadata { log_time: Some(nanos(t)) });
    }

    /// The servos' key registers at `t`, as the controller would read them (raw register
    /// values), each servo under its name.
    pub fn servos(&mut self, t: Duration, servos: &[(&str, &Servo)]) {
        use std::fmt::Write as _;
        let json = &mut self.json;
        json.clear();
        json.push('{');
        for (index, (name, servo)) in servos.iter().enumerate() {
            if index > 0 {
                json.push(',');
            }
            let _ = write!(json, "\"{name}\":{{\"id\":{}", servo.id());
            let profile = servo.profile();
            for &key in SERVO_REGISTERS {
                if let Some(item) = profile.find(key) {
                    let _ = write!(json, ",\"{key}\":{}", servo.table().get(item));
                }
            }
            json.push('}');
        }
        json.push('}');
        self.channels.servos.log_with_meta(json.as_bytes(), PartialMetadata { log_time: Some(nanos(t)) });
    }

    /// The registers read replies carried at `t` (one message for the replies of one
    /// instruction), shaped as [`View::servos`] shapes them, on `topic` (nothing if the view has
    /// no such topic).
    pub fn readings(&self, topic: ReadingsTopic, t: Duration, servos: &[ServoReadings<'_>]) {
        use std::fmt::Write as _;
        let channel = match topic {
            ReadingsTopic::Servos => Some(&self.channels.servos),
            ReadingsTopic::Robot => self.channels.compare.as_ref().map(|[robot, _]| robot),
            ReadingsTopic::World => self.channels.compare.as_ref().map(|[_, world]| world),
        };
        let Some(channel) = channel.filter(|_| !servos.is_empty()) else { return };
        let mut json = String::from("{");
        for (index, servo) in servos.iter().enumerate() {
            // The name comes from the robot description: escaped as JSON; the keys are the
            // profile's identifiers.
            let _ = write!(json, "{}{}:{{\"id\":{}", if index > 0 { "," } else { "" }, serde_json::Value::from(servo.name), servo.id);
            for (key, value) in &servo.registers {
                let _ = write!(json, ",\"{key}\":{value}");
            }
            json.push('}');
        }
        json.push('}');
        channel.log_with_meta(json.as_bytes(), PartialMetadata { log_time: Some(nanos(t)) });
    }

    /// A line of JSON on `/bus/packets` at `t` (a real bus's record: `climbsim tap`), if the
    /// view shows packets.
    pub fn packet_line(&self, t: Duration, json: &str) {
        if let Some(channel) = &self.channels.packets {
            channel.log_with_meta(json.as_bytes(), PartialMetadata { log_time: Some(nanos(t)) });
        }
    }

    /// Tell a live viewer that time is `t` now (a view without a world to move).
    pub fn time(&self, t: Duration) {
        if let Some(live) = &self.live {
            live.broadcast_time(nanos(t));
        }
    }

    /// What puts every transaction of a bus on `/bus/packets` (the instruction, then each reply,
    /// as `--trace-bus` writes them, at their times on the wire), if the view was asked for
    /// packets.
    pub fn packet_tap(&self) -> Option<TransactionTap> {
        let channel = self.channels.packets.clone()?;
        Some(Box::new(move |transaction| {
            for line in transaction_json(transaction) {
                let at = line["t"].as_f64().map_or(0, |t| nanos(Duration::from_secs_f64(t.max(0.0))));
                channel.log_with_meta(line.to_string().as_bytes(), PartialMetadata { log_time: Some(at) });
            }
        }))
    }

    /// Close the recording and give it its final name; stop the live server.
    pub fn finish(mut self) -> Result<(), ViewError> {
        if let Some(live) = self.live.take() {
            live.stop();
        }
        match self.recording.take() {
            Some(recording) => recording.finish(),
            None => Ok(()),
        }
    }
}

fn start_recording(context: &Arc<Context>, path: &Path) -> Result<Recording, ViewError> {
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".tmp");
    let temporary = PathBuf::from(temporary);
    let error = |message: String| ViewError::Write { path: path.to_owned(), message };
    // A leftover of a killed run would make `create_new` fail.
    let _ = std::fs::remove_file(&temporary);
    let writer = McapWriter::new().context(context).create_new_buffered_file(&temporary).map_err(|e| error(e.to_string()))?;
    Ok(Recording { writer: Some(writer), temporary, path: path.to_owned() })
}
