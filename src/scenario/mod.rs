//! Scenario files (TOML): the world a run happens in (terrain, start pose, gravity, duration) and
//! what happens in it (weld line, camera, target speed, controller, scripted events, captured
//! signals, `[expect]` thresholds). `scenarios/README.md` documents every key; unknown keys are
//! rejected and errors name the file, line and key.
//!
//! One idea in one file (over 500 lines): the scenario file's schema, section by section; its
//! range checks live in [`validate`], its overrides in `overrides.rs`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rapier3d::prelude::Vector;
use serde::Deserialize;
use thiserror::Error;

pub mod sweep;
pub mod validate;

pub use crate::overrides::{Override, OverrideError, parse_value, split_values};

use crate::control::ReferenceConfig;
use crate::fault::{Fault, ScheduledFault};
use crate::sim::LineCameraSettings;
use crate::sim::lidar::LidarSettings;
use crate::sim::obstacles::ObstacleSpec;
use crate::sim::terrain::{TerrainError, TerrainSpec, UnrolledProfile, generate};
use crate::sim::{SolverSettings, StartPose, SurfaceFrame, WorldConfig};
use crate::source_location::{DataFileError, load_toml};

/// The most welds a scenario may have, `[line]` included (the relocation metrics keep a fixed
/// array of them per sample).
pub const MAX_WELDS: usize = 32;

/// The pull under which a magnet is "weak" unless a scenario states another
/// (`[capture] adhesion_floor_n`): a quarter of the robot's 80 N at contact.
pub const DEFAULT_ADHESION_FLOOR_N: f32 = 20.0;

#[derive(Debug, Error)]
pub enum ScenarioError {
    #[error(transparent)]
    File(#[from] DataFileError),
    #[error("scenario {path} with --set {set}: {message}")]
    Override { path: PathBuf, set: String, message: String },
    #[error("scenario {path}: terrain: {source}")]
    Terrain { path: PathBuf, source: TerrainError },
    #[error("scenario {path}: [[events]] at_s = {at_s}: {message}")]
    Event { path: PathBuf, at_s: f64, message: String },
    #[error("scenario {path}: [controller]: {message}")]
    Controller { path: PathBuf, message: String },
    /// A value out of its range (see [`validate`]), at its line in the file when it is written.
    #[error("scenario {path}{}: {problem}", .line.map_or(String::new(), |l| format!(":{l}")))]
    Invalid { path: PathBuf, line: Option<usize>, problem: validate::Problem },
}

fn default_gravity() -> [f32; 3] {
    [0.0, -9.81, 0.0]
}

fn default_true() -> bool {
    true
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldSection {
    /// Seed of every random choice (terrain noise).
    pub seed: u64,
    /// Gravity (m/s²) in the world frame (y up). Tilting it is how a slope or wall is simulated
    /// on flat steel; `[0, 0, 0]` turns it off as in the seed's experiments.
    #[serde(default = "default_gravity")]
    pub gravity_m_s2: [f32; 3],
    /// Length of a headless run (s).
    pub duration_s: f64,
    /// Magnets on at the start.
    #[serde(default = "default_true")]
    pub magnets: bool,
    /// Tread-on-terrain friction, if not the robot description's.
    #[serde(default)]
    pub friction: Option<f32>,
    /// Extra mass carried on the middle section (kg), e.g. a towed welding carriage.
    #[serde(default)]
    pub payload_kg: f32,
    /// rapier's solver effort, `{ iterations = 3, internal_iterations = 3, ticks_per_step = 2 }`
    /// by default (one physics step every two 1 ms firmware ticks): raise it, or step every tick,
    /// to check that a result does not depend on the solver.
    #[serde(default)]
    pub solver: SolverSettings,
}

/// Where the robot starts. Without a line: at (`x_m`, `z_m`) facing `yaw_deg` (0 = +x).
/// With a line: at the line's first point moved `x_m` along it and `line_offset_m` across it
/// (positive = the robot starts left of the line), heading along the line plus `yaw_deg` (the
/// initial heading error, positive = pointing left of the line). `z_m` must then be 0.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartSection {
    #[serde(default)]
    pub x_m: f32,
    #[serde(default)]
    pub z_m: f32,
    #[serde(default)]
    pub yaw_deg: f32,
    #[serde(default)]
    pub line_offset_m: f32,
}

fn default_smoothness() -> u32 {
    1
}
fn default_line_width_m() -> f32 {
    0.01
}

/// The painted weld line (seed §3.2): a polyline in (x, z), smoothed, draped on the terrain.
#[derive(Debug, Clone, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct LineSection {
    /// Two or more (x, z) points (m).
    pub points: Vec<[f32; 2]>,
    /// 1 = straight segments with sharp corners; higher = smoother corners (the seed's 1 vs 10).
    #[serde(default = "default_smoothness")]
    pub smoothness: u32,
    /// Painted width (m).
    #[serde(default = "default_line_width_m")]
    pub width_m: f32,
}

fn default_target_mm_min() -> f64 {
    250.0
}

/// The speed task (seed §5): the welding speed to hold, from t = `step_at_s` (0 before it).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedSection {
    #[serde(default = "default_target_mm_min")]
    pub target_mm_min: f64,
    #[serde(default)]
    pub step_at_s: f64,
}

impl Default for SpeedSection {
    fn default() -> Self {
        Self { target_mm_min: default_target_mm_min(), step_at_s: 0.0 }
    }
}

/// Millimetres per minute to metres per second.
pub fn mm_min_to_m_s(mm_min: f64) -> f64 {
    mm_min / 60_000.0
}

/// Who drives the robot.
#[derive(Debug, Clone, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum ControllerSection {
    /// The in-process reference controller, in lockstep (as fast as the CPU allows).
    Builtin(ReferenceConfig),
    /// A program started with the serial port's path in `DXL_PORT` and the sensor server's URL
    /// in `CLIMBSIM_SENSORS`; the world then runs in real time.
    External(ExternalController),
}

impl Default for ControllerSection {
    fn default() -> Self {
        Self::Builtin(ReferenceConfig::default())
    }
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExternalController {
    /// Program and arguments; a relative program path is resolved against the scenario's folder.
    /// `{name}` in an argument is replaced by `params.name`.
    pub command: Vec<String>,
    /// The program ends by itself (a scripted task): exiting with status 0 then ends the run
    /// there; a non-zero exit, a signal, or still running at the scenario's end (it had not
    /// finished) fails it. Without this, a controller that
    /// ends before the scenario does fails the run, whatever its exit status.
    #[serde(default)]
    pub ends_by_itself: bool,
    /// Values for the program: each is `{name}` in `command` and `CLIMBSIM_PARAM_<NAME>` in its
    /// environment, so sweeps (`--set controller.params.zeta=0.5,1.0`) reach an unchanged program.
    #[serde(default)]
    pub params: BTreeMap<String, toml::Value>,
}

impl ExternalController {
    /// `params` as the text a program receives (strings without quotes).
    pub fn param_text(&self) -> BTreeMap<String, String> {
        self.params.iter().map(|(name, value)| (name.clone(), value.as_str().map_or_else(|| value.to_string(), str::to_owned))).collect()
    }

    /// `command` with every `{name}` replaced by its parameter; an error names a placeholder
    /// without a parameter or a parameter that is not a plain value.
    pub fn substituted_command(&self) -> Result<Vec<String>, String> {
        if self.command.is_empty() {
            return Err("command is empty: name the program and its arguments".into());
        }
        for (name, value) in &self.params {
            if matches!(value, toml::Value::Array(_) | toml::Value::Table(_)) {
                return Err(format!("params.{name}: a parameter is a number, string or boolean, not {}", value.type_str()));
            }
        }
        let text = self.param_text();
        self.command.iter().map(|arg| substitute(arg, &text)).collect()
    }
}

/// Replace `{name}` (letters, digits, `_`) in `arg` by `params[name]`.
fn substitute(arg: &str, params: &BTreeMap<String, String>) -> Result<String, String> {
    let mut out = String::with_capacity(arg.len());
    let mut rest = arg;
    while let Some(open) = rest.find('{') {
        out.push_str(&rest[..open]);
        let after = &rest[open + 1..];
        let name_len = after.find(|c: char| !(c.is_ascii_alphanumeric() || c == '_')).unwrap_or(after.len());
        if name_len == 0 || !after[name_len..].starts_with('}') {
            // Not a placeholder (e.g. JSON in an argument): keep the brace.
            out.push('{');
            rest = after;
            continue;
        }
        let name = &after[..name_len];
        let value = params
            .get(name)
            .ok_or_else(|| format!("command argument `{arg}` uses {{{name}}}, but [controller] params has no `{name}` (it has: {})", params.keys().cloned().collect::<Vec<_>>().join(", ")))?;
        out.push_str(value);
        rest = &after[name_len + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// A scripted change at `at_s`. Each key present takes effect.
#[derive(Debug, Clone, Deserialize, serde::Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Event {
    pub at_s: f64,
    /// New target speed (a speed step).
    #[serde(default)]
    pub set_speed_mm_min: Option<f64>,
    /// Shift the whole line sideways (m, positive to the left of its direction): a distance step.
    #[serde(default)]
    pub line_offset_m: Option<f64>,
    /// Magnets on or off.
    #[serde(default)]
    pub magnets: Option<bool>,
    /// A fault that starts at `at_s` (see [`crate::fault::Fault`]).
    #[serde(default)]
    pub fault: Option<Fault>,
    /// When the fault ends (it lasts to the end of the run without).
    #[serde(default)]
    pub until_s: Option<f64>,
}

impl Event {
    /// The event's fault with its window, if it has one.
    pub fn scheduled_fault(&self) -> Option<ScheduledFault> {
        self.fault.clone().map(|fault| ScheduledFault { at_s: self.at_s, until_s: self.until_s, fault })
    }
}

fn default_capture_hz() -> f64 {
    50.0
}
fn default_adhesion_floor_n() -> f64 {
    f64::from(DEFAULT_ADHESION_FLOOR_N)
}

fn default_on_line_m() -> f64 {
    0.002
}

/// What the time series records and how metrics are taken.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureSection {
    /// Rows per second of `timeseries.csv`.
    #[serde(default = "default_capture_hz")]
    pub rate_hz: f64,
    /// |distance error| within which the robot counts as on the line (m).
    #[serde(default = "default_on_line_m")]
    pub on_line_tolerance_m: f64,
    /// The columns `timeseries.csv` and the workbook keep (besides `t_s`); all when absent.
    /// Metrics are taken from the full series either way.
    #[serde(default)]
    pub signals: Option<Vec<String>>,
    /// Record `run.mcap` (Foxglove) beside the other outputs of `run` and `check` (sweeps
    /// record only with `--mcap`).
    #[serde(default = "default_true")]
    pub mcap: bool,
    /// Also put every bus packet (hex and decoded) on the recording's and the live view's
    /// `/bus/packets` topic.
    #[serde(default)]
    pub bus_packets: bool,
    /// The stated pull (N) no magnet should stay under for long: `adhesion.longest_below_s`
    /// measures how long one did (the view draws such a magnet's arrow red).
    #[serde(default = "default_adhesion_floor_n")]
    pub adhesion_floor_n: f64,
}

impl Default for CaptureSection {
    fn default() -> Self {
        Self { rate_hz: default_capture_hz(), on_line_tolerance_m: default_on_line_m(), signals: None, mcap: true, bus_packets: false, adhesion_floor_n: default_adhesion_floor_n() }
    }
}

impl Threshold {
    fn describe(&self) -> String {
        match (self.min, self.max) {
            (Some(min), Some(max)) => format!("[{min}, {max}]"),
            (Some(min), None) => format!(">= {min}"),
            (None, Some(max)) => format!("<= {max}"),
            (None, None) => "any value".to_owned(),
        }
    }
}

/// Bounds on one summary metric for `climbsim check`.
#[derive(Debug, Clone, Copy, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Threshold {
    #[serde(default)]
    pub min: Option<f64>,
    #[serde(default)]
    pub max: Option<f64>,
}

/// The servo bus as the robot was configured before the run.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSection {
    /// Every servo's Baud Rate at power-on (bps), if not the robot description's factory
    /// 57600: a controller that needs a faster bus than the factory one is run on a robot that
    /// was set up for it (`DXL_BAUD` tells the program).
    #[serde(default)]
    pub baud_bps: Option<u32>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    pub world: WorldSection,
    #[serde(default)]
    pub bus: BusSection,
    pub terrain: TerrainSpec,
    #[serde(default)]
    pub line: Option<LineSection>,
    /// More welds after `[line]`, in order (`[[welds]]`): the robot relocates from the end of one
    /// to the start of the next.
    #[serde(default)]
    pub welds: Vec<LineSection>,
    /// How the built-in controller relocates between welds.
    #[serde(default)]
    pub relocation: Option<crate::control::RelocationConfig>,
    /// Boxes and cylinders standing on the terrain (`[[obstacles]]`).
    #[serde(default)]
    pub obstacles: Vec<ObstacleSpec>,
    /// The front LIDAR's settings; without `[lidar]` the robot has none.
    #[serde(default)]
    pub lidar: Option<LidarSettings>,
    /// The downward line camera (the robot description's mount and defaults if absent).
    #[serde(default)]
    pub camera: Option<LineCameraSettings>,
    #[serde(default)]
    pub start: Option<StartSection>,
    #[serde(default)]
    pub speed: SpeedSection,
    #[serde(default)]
    pub controller: ControllerSection,
    #[serde(default)]
    pub events: Vec<Event>,
    #[serde(default)]
    pub capture: CaptureSection,
    /// Summary metric name (as in `summary.json`) → bounds.
    #[serde(default)]
    pub expect: BTreeMap<String, Threshold>,
    #[serde(skip)]
    pub path: PathBuf,
    /// The `--set KEY=VALUE` overrides applied, in order (`settings.json` records them).
    #[serde(skip)]
    pub overrides: Vec<String>,
}

impl Scenario {
    pub fn load(path: &Path) -> Result<Self, ScenarioError> {
        let mut scenario: Self = load_toml("scenario", path)?;
        scenario.path = path.to_owned();
        scenario.check_ranges(&[])?;
        scenario.check_events()?;
        Ok(scenario)
    }

    /// Every numeric key in its range ([`validate::check`]). A value an override set is blamed
    /// on the `--set`; one written in the file on its line there.
    fn check_ranges(&self, overrides: &[Override]) -> Result<(), ScenarioError> {
        let Err(problem) = validate::check(self) else { return Ok(()) };
        let key = problem.key_text();
        if let Some(set) = overrides.iter().find(|o| key == o.key || key.starts_with(&format!("{}.", o.key)) || key.starts_with(&format!("{}[", o.key))) {
            return Err(ScenarioError::Override { path: self.path.clone(), set: set.to_string(), message: problem.to_string() });
        }
        // The text was read a moment ago; if it cannot be now, the error still names the key.
        let line = std::fs::read_to_string(&self.path).ok().and_then(|text| problem.line_in(&text));
        Err(ScenarioError::Invalid { path: self.path.clone(), line, problem })
    }

    /// What serde cannot check in `[[events]]` (a fault's ranges and window) and in an external
    /// controller (its command's placeholders).
    fn check_events(&self) -> Result<(), ScenarioError> {
        if let ControllerSection::External(external) = &self.controller {
            external.substituted_command().map_err(|message| ScenarioError::Controller { path: self.path.clone(), message })?;
        }
        for event in &self.events {
            let fail = |message: String| ScenarioError::Event { path: self.path.clone(), at_s: event.at_s, message };
            match event.scheduled_fault() {
                Some(fault) => fault.validate().map_err(|e| fail(e.to_string()))?,
                None if event.until_s.is_some() => return Err(fail("until_s needs a fault in the same event".into())),
                None => {}
            }
        }
        Ok(())
    }

    /// Add faults given on the command line (`--fault`) as events, after the file's.
    pub fn add_faults(&mut self, faults: Vec<ScheduledFault>) {
        self.events.extend(faults.into_iter().map(|f| Event { at_s: f.at_s, set_speed_mm_min: None, line_offset_m: None, magnets: None, fault: Some(f.fault), until_s: f.until_s }));
    }

    /// The faults the events schedule, in file order.
    pub fn faults(&self) -> Vec<ScheduledFault> {
        self.events.iter().filter_map(Event::scheduled_fault).collect()
    }

    /// Load with `--set` overrides applied. Without overrides this is [`Scenario::load`] (whose
    /// errors carry line and column); with them the file is edited as a TOML table first, so an
    /// error names the key and the overrides instead.
    pub fn load_with(path: &Path, overrides: &[Override]) -> Result<Self, ScenarioError> {
        if overrides.is_empty() {
            return Self::load(path);
        }
        // Parse once as the plain file so that syntax errors keep their line and column.
        let mut table: toml::Table = load_toml("scenario", path)?;
        let set = overrides.iter().map(ToString::to_string).collect::<Vec<_>>().join(" ");
        let fail = |message: String| ScenarioError::Override { path: path.to_owned(), set: set.clone(), message };
        for o in overrides {
            o.apply(&mut table).map_err(|e| fail(e.to_string()))?;
        }
        let mut scenario = Self::deserialize(table).map_err(|e| fail(e.to_string()))?;
        scenario.path = path.to_owned();
        scenario.overrides = overrides.iter().map(ToString::to_string).collect();
        scenario.check_ranges(overrides)?;
        scenario.check_events()?;
        Ok(scenario)
    }

    /// The thresholds of `[expect]` that `summary` breaks, one message each; a metric the run
    /// did not produce (or produced as null) fails its threshold.
    pub fn failed_expectations(&self, summary: &BTreeMap<String, serde_json::Value>) -> Vec<String> {
        let mut failures = Vec::new();
        for (key, threshold) in &self.expect {
            let Some(value) = summary.get(key).and_then(serde_json::Value::as_f64) else {
                failures.push(format!("{key}: {} (expected {})", missing_metric(key, summary), threshold.describe()));
                continue;
            };
            if threshold.min.is_some_and(|min| value < min) || threshold.max.is_some_and(|max| value > max) {
                failures.push(format!("{key} = {value} is outside {}", threshold.describe()));
            }
        }
        failures
    }

    /// Where the robot starts (see [`StartSection`]).
    pub fn start_pose(&self) -> StartPose {
        let given = self.start.clone().unwrap_or_default();
        let Some(line) = self.line.as_ref().filter(|l| l.points.len() >= 2) else {
            return StartPose { x_m: given.x_m, z_m: given.z_m, yaw_deg: given.yaw_deg, ..StartPose::default() };
        };
        let ([x0, z0], [x1, z1]) = (line.points[0], line.points[1]);
        let length = (x1 - x0).hypot(z1 - z0).max(f32::EPSILON);
        let (ux, uz) = ((x1 - x0) / length, (z1 - z0) / length);
        // y up, z to the robot's right: the line's left is up × along = (uz, −ux), and a heading
        // along (ux, uz) is a yaw (about +y) of atan2(−uz, ux).
        let (left_x, left_z) = (uz, -ux);
        let (x_m, z_m) = (x0 + given.x_m * ux + given.line_offset_m * left_x, z0 + given.x_m * uz + given.line_offset_m * left_z);
        let yaw_deg = (-uz).atan2(ux).to_degrees() + given.yaw_deg;
        // A line painted on a wall terrain is in the unrolled sheet's coordinates: the start is
        // where the sheet puts that point, floor or wall, heading along the sheet.
        let on_surface = UnrolledProfile::of(&self.terrain).and_then(|sheet| {
            let (point, normal) = sheet.point(x_m, z_m)?;
            let along = sheet.along(x_m)?;
            let (sin, cos) = yaw_deg.to_radians().sin_cos();
            // Heading 0 runs along the sheet's u, a positive heading turns toward −z (left).
            Some(SurfaceFrame { point, normal, forward: along * cos - Vector::Z * sin })
        });
        StartPose { x_m, z_m, yaw_deg, on_surface, ..StartPose::default() }
    }

    /// The world this scenario describes (terrain generated from its seed).
    pub fn world_config(&self) -> Result<WorldConfig, ScenarioError> {
        let base = self.path.parent().unwrap_or(Path::new("."));
        let terrain = generate(&self.terrain, self.world.seed, base).map_err(|source| ScenarioError::Terrain { path: self.path.clone(), source })?;
        let start = self.start_pose();
        let [gx, gy, gz] = self.world.gravity_m_s2;
        Ok(WorldConfig {
            gravity: Vector::new(gx, gy, gz),
            terrain,
            start,
            friction: self.world.friction,
            magnets_on: self.world.magnets,
            payload_kg: self.world.payload_kg,
            solver: self.world.solver,
            obstacles: self.obstacles.clone(),
        })
    }
}

/// Why `key` has no number in `summary`: a step metric of a response that never settled or
/// never rose says so; anything else was not measured in this run.
fn missing_metric(key: &str, summary: &BTreeMap<String, serde_json::Value>) -> String {
    let Some((signal, metric)) = key.split_once('.') else { return "not measured in this run".to_owned() };
    let settled = summary.get(&format!("{signal}.settled")).and_then(serde_json::Value::as_bool);
    match (metric, settled) {
        ("settling_time_s", Some(false)) => format!("never settled ({signal} stayed outside its settling band to the end)"),
        ("rise_time_s", _) if summary.contains_key(key) => format!("never rose ({signal} did not reach the upper rise level of its step)"),
        _ if summary.contains_key(key) => "no value: the run did not produce one (null in summary.json)".to_owned(),
        _ => "not measured in this run".to_owned(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn external(command: &[&str], params: &str) -> ExternalController {
        let params: toml::Table = params.parse().expect("toml");
        ExternalController { command: command.iter().map(|s| (*s).to_owned()).collect(), ends_by_itself: false, params: params.into_iter().collect() }
    }

    #[test]
    fn a_missing_metric_says_why() {
        let summary: BTreeMap<String, serde_json::Value> =
            [("distance.settled", serde_json::json!(false)), ("distance.settling_time_s", serde_json::Value::Null), ("speed.rise_time_s", serde_json::Value::Null)]
                .into_iter()
                .map(|(k, v)| (k.to_owned(), v))
                .collect();
        assert!(missing_metric("distance.settling_time_s", &summary).starts_with("never settled"));
        assert!(missing_metric("speed.rise_time_s", &summary).starts_with("never rose"));
        assert_eq!(missing_metric("faults.replies_dropped", &summary), "not measured in this run");
    }

    #[test]
    fn command_placeholders_take_the_params() {
        let controller = external(&["./ctl.py", "--zeta", "{zeta}", "--name={name}", "{\"json\": 1}", "{}"], "zeta = 0.5\nname = \"a b\"");
        assert_eq!(controller.substituted_command().expect("substituted"), ["./ctl.py", "--zeta", "0.5", "--name=a b", "{\"json\": 1}", "{}"]);
        assert_eq!(controller.param_text()["name"], "a b");
    }

    #[test]
    fn unknown_placeholders_and_empty_commands_are_errors() {
        let error = external(&["ctl", "{omega}"], "zeta = 1").substituted_command().expect_err("unknown");
        assert!(error.contains("{omega}") && error.contains("zeta"), "{error}");
        assert!(external(&[], "").substituted_command().is_err());
        assert!(external(&["ctl"], "gains = [1, 2]").substituted_command().expect_err("array").contains("params.gains"));
    }
}
