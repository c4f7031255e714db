//! Range checks of every numeric scenario key after deserialisation: serde checks types, this
//! checks that a value is finite and physically sensible, so that a typo (`-1`, `1e30`, `nan`)
//! is a load error naming the key, its unit and the accepted range instead of a panic, a hang
//! or an hour of garbage. `docs/scenario-validation.md` gives every range and why.
//!
//! The terrain, line and camera constructors keep their own checks (power-of-two sizes, a line
//! of two distinct points, ...); this module adds what they cannot know (upper bounds that keep
//! memory and run time sane, cross-key rules such as an event inside the run).

use std::fmt;

use super::{ControllerSection, Scenario};
use crate::control::ReferenceConfig;
use crate::sim::terrain::TerrainSpec;

/// A key of the scenario file: table keys and array indices (`events[2].at_s`).
#[derive(Debug, Clone, PartialEq)]
pub enum KeyPart {
    Key(String),
    Index(usize),
}

/// One value out of range.
#[derive(Debug, Clone, PartialEq)]
pub struct Problem {
    pub key: Vec<KeyPart>,
    pub message: String,
}

impl Problem {
    /// The dotted key, as `--set` takes it (`world.duration_s`, `events[1].until_s`).
    pub fn key_text(&self) -> String {
        let mut text = String::new();
        for part in &self.key {
            match part {
                KeyPart::Key(k) if k.contains('.') => text.push_str(&format!("{}\"{k}\"", if text.is_empty() { "" } else { "." })),
                KeyPart::Key(k) => {
                    if !text.is_empty() {
                        text.push('.');
                    }
                    text.push_str(k);
                }
                KeyPart::Index(i) => text.push_str(&format!("[{i}]")),
            }
        }
        text
    }

    /// The 1-based line of the key in the scenario's `text` (of its nearest enclosing table when
    /// the key itself is not written, e.g. a default), if the text parses.
    pub fn line_in(&self, text: &str) -> Option<usize> {
        let root = toml::de::DeTable::parse(text).ok()?;
        let root = toml::de::DeValue::Table(root.into_inner());
        let mut current = &root;
        let mut span = None;
        for part in &self.key {
            let next = match part {
                KeyPart::Key(k) => current.get(k.as_str()),
                KeyPart::Index(i) => current.get(*i),
            };
            let Some(next) = next else { break };
            span = Some(next.span());
            current = next.get_ref();
        }
        span.map(|s| crate::source_location::line_col(text, s.start).0)
    }
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.key_text(), self.message)
    }
}

/// An accepted interval and its unit.
#[derive(Debug, Clone, Copy)]
pub struct Range {
    pub min: f64,
    /// Whether `min` itself is allowed.
    pub min_inclusive: bool,
    pub max: f64,
    pub unit: &'static str,
}

impl Range {
    const fn closed(min: f64, max: f64, unit: &'static str) -> Self {
        Self { min, min_inclusive: true, max, unit }
    }
    const fn above(min: f64, max: f64, unit: &'static str) -> Self {
        Self { min, min_inclusive: false, max, unit }
    }

    fn contains(&self, value: f64) -> bool {
        value.is_finite() && value <= self.max && (value > self.min || (self.min_inclusive && value == self.min))
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let unit = if self.unit.is_empty() { String::new() } else { format!(" {}", self.unit) };
        write!(f, "{}{}, {}]{unit}", if self.min_inclusive { "[" } else { "(" }, self.min, self.max)
    }
}

/// Longest run: a day of simulated time is far beyond any test, and bounds the time series.
pub const DURATION_S: Range = Range::above(0.0, 86_400.0, "s");
/// Gravity per axis: up to 10 g, far beyond Earth's 9.81, still stable at the 2 ms physics step
/// (a flat-line run at 10 g drives at its target speed).
pub const GRAVITY_M_S2: Range = Range::closed(-100.0, 100.0, "m/s²");
pub const FRICTION: Range = Range::closed(0.0, 10.0, "(friction coefficient)");
/// The robot weighs ~12 kg and its magnets hold a few hundred newtons: 200 kg is no longer a
/// payload it could carry, only a numerical stress.
pub const PAYLOAD_KG: Range = Range::closed(0.0, 200.0, "kg");
/// rapier's solver passes per physics step, each of `iterations` and `internal_iterations`.
/// 100 × 100 is ~1700× the default 3 × 2 and takes ~10 ms a step in release (measured, see
/// the docs), so a run still advances and an interrupt lands within one step; 1000 × 1000 took
/// over a second a step.
pub const SOLVER_ITERATIONS: std::ops::RangeInclusive<usize> = 1..=100;
/// Firmware ticks per physics step: the settings the solver-fidelity table vouches for.
pub const TICKS_PER_STEP: std::ops::RangeInclusive<usize> = 1..=2;
/// Start position and line offsets: the terrains are at most a few hundred metres across.
pub const POSITION_M: Range = Range::closed(-10_000.0, 10_000.0, "m");
/// Relocation's clearance in cells of its grid, at most.
pub const MAX_CLEARANCE_CELLS: f64 = 50.0;
/// An occupancy grid's cell: from a centimetre to a metre.
pub const GRID_CELL_M: Range = Range::closed(0.01, 1.0, "m");
/// Distances the LIDAR measures (the wall transition's triggers).
pub const LIDAR_DISTANCE_M: Range = Range::closed(0.0, 100.0, "m");
/// A magnet shaft turns within ±180° of straight down (one turn in position mode).
pub const MAGNET_TURN_DEG: Range = Range::closed(-180.0, 180.0, "°");
/// Wheel travel for the wall transition's release.
pub const TRAVEL_M: Range = Range::closed(0.0, 100.0, "m");
/// Yaw rate per radian of wall angle.
pub const SQUARE_GAIN: Range = Range::closed(0.0, 100.0, "(rad/s per rad)");
/// The LIDAR's window for the wall fit, either side of ahead.
pub const SQUARE_WINDOW_DEG: Range = Range::above(0.0, 180.0, "°");
pub const YAW_DEG: Range = Range::closed(-360.0, 360.0, "deg");
pub const LINE_OFFSET_M: Range = Range::closed(-10.0, 10.0, "m");
/// Smoothing subdivides every corner; beyond 100 the curve no longer changes but memory grows.
pub const LINE_SMOOTHNESS: std::ops::RangeInclusive<u32> = 1..=100;
pub const LINE_WIDTH_M: Range = Range::above(0.0, 1.0, "m");
/// Speeds up to 1 m/s (60 000 mm/min), ten times the robot's top speed; negative = reverse.
pub const SPEED_MM_MIN: Range = Range::closed(-60_000.0, 60_000.0, "mm/min");
/// The control period: at least one firmware tick (1 ms; 0 never advances the world), at most
/// one second.
pub const PERIOD_S: Range = Range::closed(0.001, 1.0, "s");
pub const ZETA: Range = Range::above(0.0, 100.0, "(damping ratio)");
pub const OMEGA_N_RAD_S: Range = Range::above(0.0, 1_000.0, "rad/s");
pub const INTEGRAL_POLE_RAD_S: Range = Range::closed(0.0, 1_000.0, "rad/s");
pub const MAX_YAW_RATE_RAD_S: Range = Range::above(0.0, 100.0, "rad/s");
/// PID gains on the speed error (m/s → m/s): finite and not negative (a negative gain is
/// positive feedback).
pub const PID_GAIN: Range = Range::closed(0.0, 1_000.0, "(m/s per m/s, ·s⁻¹ for ki, ·s for kd)");
pub const SPEED_WINDOW_S: Range = Range::above(0.0, 10.0, "s");
/// Terrain extents: a 10 km square is already far beyond any deck; beyond it f32 positions
/// lose millimetres.
pub const TERRAIN_SIZE_M: Range = Range::above(0.0, 10_000.0, "m");
pub const TERRAIN_HEIGHT_M: Range = Range::closed(-1_000.0, 1_000.0, "m");
/// Mesh facets of a pipe or fillet: each one is a few triangles; 100 000 keeps the mesh small.
pub const MESH_SEGMENTS: std::ops::RangeInclusive<u32> = 0..=100_000;
pub const CAMERA_FRAME_RATE_HZ: Range = Range::above(0.0, 1_000.0, "Hz");
pub const CAMERA_SIZE_M: Range = Range::above(0.0, 10.0, "m");
pub const CAMERA_ASPECT: Range = Range::above(0.0, 100.0, "(width / height)");
pub const CAMERA_NOISE: Range = Range::closed(0.0, 255.0, "gray levels");
/// Rows per second of `timeseries.csv`: above 0 (a rate of 0 never captures), at most one row
/// per firmware tick (1 kHz), the fastest any run advances; a lockstep run allows only its
/// control rate, which the run itself checks.
/// An obstacle's sizes: anything larger is terrain (see `sim::obstacles`).
pub const OBSTACLE_SIZE_M: Range = Range::above(0.0, crate::sim::obstacles::MAX_OBSTACLE_M as f64, "m");
pub const CAPTURE_RATE_HZ: Range = Range::above(0.0, 1_000.0, "Hz");
pub const ON_LINE_TOLERANCE_M: Range = Range::closed(0.0, 10.0, "m");
/// A magnet pulls up to a few hundred newtons; 10 kN leaves room for any robot.
pub const ADHESION_FLOOR_N: Range = Range::closed(0.0, 10_000.0, "N");

struct Checker {
    prefix: Vec<KeyPart>,
}

impl Checker {
    fn at(parts: &[&str]) -> Self {
        Self { prefix: parts.iter().map(|p| KeyPart::Key((*p).to_owned())).collect() }
    }

    fn problem(&self, key: &[KeyPart], message: String) -> Problem {
        Problem { key: self.prefix.iter().chain(key).cloned().collect(), message }
    }

    fn range(&self, key: &str, value: f64, range: Range) -> Result<(), Problem> {
        self.range_at(&[KeyPart::Key(key.to_owned())], value, range)
    }

    fn range_at(&self, key: &[KeyPart], value: f64, range: Range) -> Result<(), Problem> {
        if range.contains(value) {
            return Ok(());
        }
        // The value carries the unit's symbol only (`-1 s`, not the range's explanation).
        let unit = match range.unit.split(' ').next() {
            Some(symbol) if !symbol.is_empty() && !symbol.starts_with('(') => format!(" {symbol}"),
            _ => String::new(),
        };
        Err(self.problem(key, format!("{value}{unit} is outside {range}")))
    }

    fn count<T: PartialOrd + fmt::Display + Copy>(&self, key: &str, value: T, range: &std::ops::RangeInclusive<T>, what: &str) -> Result<(), Problem> {
        if range.contains(&value) {
            return Ok(());
        }
        Err(self.problem(&[KeyPart::Key(key.to_owned())], format!("{value} is outside [{}, {}] {what}", range.start(), range.end())))
    }
}

fn key(k: &str) -> KeyPart {
    KeyPart::Key(k.to_owned())
}

/// The first out-of-range value of `scenario`, if any.
pub fn check(scenario: &Scenario) -> Result<(), Problem> {
    check_world(scenario)?;
    check_terrain(&scenario.terrain)?;
    check_line_and_start(scenario)?;
    check_camera(scenario)?;
    let speed = Checker::at(&["speed"]);
    speed.range("target_mm_min", scenario.speed.target_mm_min, SPEED_MM_MIN)?;
    speed.range("step_at_s", scenario.speed.step_at_s, Range::closed(0.0, crate::fault::MAX_FAULT_TIME_S, "s"))?;
    if let ControllerSection::Builtin(config) = &scenario.controller {
        check_controller(config)?;
        if config.wall_transition.is_some() && scenario.lidar.is_none() {
            return Err(Checker::at(&["controller"]).problem(&[key("wall_transition")], "the wall transition watches the front LIDAR: add a [lidar] table".to_owned()));
        }
    }
    check_events(scenario)?;
    check_obstacles(scenario)?;
    if let Some(lidar) = &scenario.lidar {
        use crate::sim::lidar::LidarError;
        lidar.validate().map_err(|error| match error {
            LidarError::Beams(_) => Checker::at(&["lidar"]).problem(&[key("beams")], format!("{error}")),
            LidarError::Invalid { field, value, reason } => Checker::at(&["lidar"]).problem(&[key(field)], format!("{value} {reason}")),
        })?;
    }
    let capture = Checker::at(&["capture"]);
    capture.range("rate_hz", scenario.capture.rate_hz, CAPTURE_RATE_HZ)?;
    capture.range("on_line_tolerance_m", scenario.capture.on_line_tolerance_m, ON_LINE_TOLERANCE_M)?;
    capture.range("adhesion_floor_n", scenario.capture.adhesion_floor_n, ADHESION_FLOOR_N)?;
    let expect = Checker::at(&["expect"]);
    for (metric, threshold) in &scenario.expect {
        for (bound, value) in [("min", threshold.min), ("max", threshold.max)] {
            if let Some(value) = value.filter(|v| !v.is_finite()) {
                return Err(expect.problem(&[key(metric), key(bound)], format!("{value} is not a finite number")));
            }
        }
        if let (Some(min), Some(max)) = (threshold.min, threshold.max)
            && min > max
        {
            return Err(expect.problem(&[key(metric)], format!("min {min} is above max {max}")));
        }
    }
    Ok(())
}

fn check_world(scenario: &Scenario) -> Result<(), Problem> {
    let world = &scenario.world;
    let c = Checker::at(&["world"]);
    c.range("duration_s", world.duration_s, DURATION_S)?;
    for (i, g) in world.gravity_m_s2.iter().enumerate() {
        c.range_at(&[key("gravity_m_s2"), KeyPart::Index(i)], f64::from(*g), GRAVITY_M_S2)?;
    }
    if let Some(friction) = world.friction {
        c.range("friction", f64::from(friction), FRICTION)?;
    }
    c.range("payload_kg", f64::from(world.payload_kg), PAYLOAD_KG)?;
    let solver = Checker::at(&["world", "solver"]);
    solver.count("iterations", world.solver.iterations.get(), &SOLVER_ITERATIONS, "solver iterations per step")?;
    solver.count("internal_iterations", world.solver.internal_iterations.get(), &SOLVER_ITERATIONS, "solver passes per iteration")?;
    solver.count("ticks_per_step", world.solver.ticks_per_step.get(), &TICKS_PER_STEP, "firmware ticks per physics step")?;
    Ok(())
}

fn check_terrain(terrain: &TerrainSpec) -> Result<(), Problem> {
    let c = Checker::at(&["terrain"]);
    let size = |name: &str, v: f32| c.range(name, f64::from(v), TERRAIN_SIZE_M);
    let height = |name: &str, v: f32| c.range(name, f64::from(v), TERRAIN_HEIGHT_M);
    let position = |name: &str, v: f32| c.range(name, f64::from(v), POSITION_M);
    match *terrain {
        TerrainSpec::Flat { size_m } => size("size_m", size_m),
        TerrainSpec::Perlin { size_m, max_height_m, noise_scale, .. } => {
            size("size_m", size_m)?;
            height("max_height_m", max_height_m)?;
            c.range("noise_scale", f64::from(noise_scale), Range::above(0.0, 1e6, "cm"))
        }
        TerrainSpec::Slope { size_m, slope_x_deg, slope_z_deg, .. } => {
            size("size_m", size_m)?;
            c.range("slope_x_deg", f64::from(slope_x_deg), Range::closed(-89.0, 89.0, "deg"))?;
            c.range("slope_z_deg", f64::from(slope_z_deg), Range::closed(-89.0, 89.0, "deg"))
        }
        TerrainSpec::Bump { size_m, height_m, radius_m, x_m, z_m, .. } => {
            size("size_m", size_m)?;
            height("height_m", height_m)?;
            size("radius_m", radius_m)?;
            position("x_m", x_m)?;
            position("z_m", z_m)
        }
        TerrainSpec::Step { size_m, height_m, x_m, z_from_m, .. } => {
            size("size_m", size_m)?;
            height("height_m", height_m)?;
            position("x_m", x_m)?;
            position("z_from_m", z_from_m)
        }
        TerrainSpec::Pipe { radius_m, length_m, segments, .. } => {
            size("radius_m", radius_m)?;
            size("length_m", length_m)?;
            c.count("segments", segments, &MESH_SEGMENTS, "mesh segments")
        }
        TerrainSpec::Wall { wall_distance_m, wall_height_m, width_m, fillet_radius_m, segments } => {
            size("wall_distance_m", wall_distance_m)?;
            size("wall_height_m", wall_height_m)?;
            size("width_m", width_m)?;
            c.range("fillet_radius_m", f64::from(fillet_radius_m), Range::closed(0.0, TERRAIN_SIZE_M.max, "m"))?;
            c.count("segments", segments, &MESH_SEGMENTS, "mesh segments")
        }
        TerrainSpec::Heightmap { size_m, max_height_m, .. } => {
            size("size_m", size_m)?;
            height("max_height_m", max_height_m)
        }
    }
}

fn check_line_and_start(scenario: &Scenario) -> Result<(), Problem> {
    let start = scenario.start.clone().unwrap_or_default();
    let s = Checker::at(&["start"]);
    s.range("x_m", f64::from(start.x_m), POSITION_M)?;
    s.range("z_m", f64::from(start.z_m), POSITION_M)?;
    s.range("yaw_deg", f64::from(start.yaw_deg), YAW_DEG)?;
    s.range("line_offset_m", f64::from(start.line_offset_m), LINE_OFFSET_M)?;
    let Some(line) = &scenario.line else {
        if !scenario.welds.is_empty() {
            return Err(Checker::at(&[]).problem(&[key("welds")], "[[welds]] come after the first weld, [line]: add one".to_owned()));
        }
        return Ok(());
    };
    check_line_section(&Checker::at(&["line"]), line)?;
    if scenario.welds.len() + 1 > crate::scenario::MAX_WELDS {
        return Err(Checker::at(&[]).problem(&[key("welds")], format!("{} welds with [line]; at most {}", scenario.welds.len() + 1, crate::scenario::MAX_WELDS)));
    }
    for (i, weld) in scenario.welds.iter().enumerate() {
        check_line_section(&Checker { prefix: vec![key("welds"), KeyPart::Index(i)] }, weld)?;
    }
    if let Some(r) = &scenario.relocation {
        let c = Checker::at(&["relocation"]);
        c.range("speed_mm_min", r.speed_mm_min, Range::above(0.0, SPEED_MM_MIN.max, "mm/min"))?;
        c.range("cell_m", r.cell_m, GRID_CELL_M)?;
        c.range("clearance_m", r.clearance_m, TRAVEL_M)?;
        // Growing the map costs (clearance / cell)² per blocked cell, at every plan.
        if r.clearance_m > MAX_CLEARANCE_CELLS * r.cell_m {
            return Err(c.problem(&[key("clearance_m")], format!("{} m is more than {MAX_CLEARANCE_CELLS} cells of {} m; use a coarser cell_m", r.clearance_m, r.cell_m)));
        }
        c.range("approach_m", r.approach_m, TRAVEL_M)?;
        c.range("arrive_tolerance_m", r.arrive_tolerance_m, Range::above(0.0, 10.0, "m"))?;
        c.range("lookahead_m", r.lookahead_m, Range::above(0.0, 10.0, "m"))?;
        c.range("max_slope_deg", r.max_slope_deg, Range::closed(0.0, 90.0, "°"))?;
        c.range("map_margin_m", r.map_margin_m, TRAVEL_M)?;
    }
    // The start is placed along the first segment (see `Scenario::start_pose`): beyond its ends
    // the robot starts off the line, and past the line's end there is nothing to follow.
    if let [[x0, z0], [x1, z1], ..] = line.points[..] {
        let first = f64::from((x1 - x0).hypot(z1 - z0));
        s.range("x_m", f64::from(start.x_m), Range::closed(0.0, first, "m (along the line's first segment)"))?;
    }
    Ok(())
}

fn check_line_section(c: &Checker, line: &super::LineSection) -> Result<(), Problem> {
    for (i, point) in line.points.iter().enumerate() {
        for (j, v) in point.iter().enumerate() {
            c.range_at(&[key("points"), KeyPart::Index(i), KeyPart::Index(j)], f64::from(*v), POSITION_M)?;
        }
    }
    c.count("smoothness", line.smoothness, &LINE_SMOOTHNESS, "(1 = sharp corners)")?;
    c.range("width_m", f64::from(line.width_m), LINE_WIDTH_M)
}

fn check_camera(scenario: &Scenario) -> Result<(), Problem> {
    let Some(camera) = &scenario.camera else { return Ok(()) };
    let c = Checker::at(&["camera"]);
    c.range("orthographic_size_m", f64::from(camera.orthographic_size_m), CAMERA_SIZE_M)?;
    c.range("aspect", f64::from(camera.aspect), CAMERA_ASPECT)?;
    c.range("frame_rate_hz", f64::from(camera.frame_rate_hz), CAMERA_FRAME_RATE_HZ)?;
    c.range("noise_std", f64::from(camera.noise_std), CAMERA_NOISE)
}

fn check_controller(config: &ReferenceConfig) -> Result<(), Problem> {
    let c = Checker::at(&["controller"]);
    c.range("period_s", config.period_s, PERIOD_S)?;
    c.range("zeta", config.zeta, ZETA)?;
    c.range("omega_n", config.omega_n, OMEGA_N_RAD_S)?;
    c.range("integral_pole_rad_s", config.integral_pole_rad_s, INTEGRAL_POLE_RAD_S)?;
    c.range("max_yaw_rate_rad_s", config.max_yaw_rate_rad_s, MAX_YAW_RATE_RAD_S)?;
    c.range("kp", config.kp, PID_GAIN)?;
    c.range("ki", config.ki, PID_GAIN)?;
    c.range("kd", config.kd, PID_GAIN)?;
    c.range("speed_window_s", config.speed_window_s, SPEED_WINDOW_S)?;
    if let Some(t) = &config.wall_transition {
        let c = Checker::at(&["controller", "wall_transition"]);
        c.range("detect_m", t.detect_m, LIDAR_DISTANCE_M)?;
        c.range("magnets_at_m", t.magnets_at_m, LIDAR_DISTANCE_M)?;
        c.range("front_magnet_deg", t.front_magnet_deg, MAGNET_TURN_DEG)?;
        c.range("release_after_m", t.release_after_m, TRAVEL_M)?;
        c.range("square_gain", t.square_gain, SQUARE_GAIN)?;
        c.range("square_window_deg", t.square_window_deg, SQUARE_WINDOW_DEG)?;
    }
    Ok(())
}

fn check_obstacles(scenario: &Scenario) -> Result<(), Problem> {
    use crate::sim::obstacles::ObstacleSpec;
    for (i, obstacle) in scenario.obstacles.iter().enumerate() {
        let c = Checker { prefix: vec![key("obstacles"), KeyPart::Index(i)] };
        let [x, z] = obstacle.at_m();
        c.range_at(&[key("at_m"), KeyPart::Index(0)], f64::from(x), POSITION_M)?;
        c.range_at(&[key("at_m"), KeyPart::Index(1)], f64::from(z), POSITION_M)?;
        match obstacle {
            ObstacleSpec::Box { size_m, yaw_deg, .. } => {
                for (axis, size) in size_m.iter().enumerate() {
                    c.range_at(&[key("size_m"), KeyPart::Index(axis)], f64::from(*size), OBSTACLE_SIZE_M)?;
                }
                c.range("yaw_deg", f64::from(*yaw_deg), YAW_DEG)?;
            }
            ObstacleSpec::Cylinder { radius_m, length_m, yaw_deg, .. } => {
                c.range("radius_m", f64::from(*radius_m), OBSTACLE_SIZE_M)?;
                c.range("length_m", f64::from(*length_m), OBSTACLE_SIZE_M)?;
                c.range("yaw_deg", f64::from(*yaw_deg), YAW_DEG)?;
            }
        }
    }
    Ok(())
}

fn check_events(scenario: &Scenario) -> Result<(), Problem> {
    // An event after the end never happens; allowed, so that `--set world.duration_s=` can
    // shorten any scenario for a quick look.
    let run = Range::closed(0.0, crate::fault::MAX_FAULT_TIME_S, "s");
    for (i, event) in scenario.events.iter().enumerate() {
        let c = Checker { prefix: vec![key("events"), KeyPart::Index(i)] };
        c.range("at_s", event.at_s, run)?;
        if let Some(until) = event.until_s {
            c.range("until_s", until, Range::closed(event.at_s, f64::MAX, "s (at or after at_s)"))?;
        }
        if let Some(speed) = event.set_speed_mm_min {
            c.range("set_speed_mm_min", speed, SPEED_MM_MIN)?;
        }
        if let Some(offset) = event.line_offset_m {
            c.range("line_offset_m", offset, LINE_OFFSET_M)?;
            if scenario.line.is_none() {
                return Err(c.problem(&[key("line_offset_m")], "moves the weld line, but the scenario has no [line]".to_owned()));
            }
        }
    }
    Ok(())
}
