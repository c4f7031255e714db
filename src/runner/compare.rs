//! `climbsim compare`: a real session (`climbsim tap`) re-enacted open-loop in a scenario's
//! world, and every real read reply set beside the world's answer to the same read.
//!
//! The world starts as the scenario says at the tap's start (t = 0) and ticks at the servos'
//! control period; each recorded instruction is handed to the bus at its recorded time (when
//! its first byte was read from the controller) and line rate, so the world's servos get the
//! same commands at the same instants as the real ones did. The world's answers are compared,
//! register by register ([`crate::real_bus::compare`]), and so is the reply latency: the real
//! one (the request's last byte handed to the servos' side to the reply's first byte read back)
//! against the wire model's (the request's end on the wire to the reply's start).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use foxglove::messages::log::Level as LogLevel;
use serde::Serialize;
use serde_json::json;
use thiserror::Error;
use tracing::info_span;

use super::RunError;
use super::observe::{Observer, scenario_bus};
use crate::bus::{Bus, Timing};
use crate::device::FirmwareProfile;
use crate::real_bus::compare::{Comparison, RegisterSeries, RegisterStats, Tolerances, fast_blocks, is_fast_read, read_spans, registers_in};
use crate::real_bus::{RealRecord, RealTranscript, Side};
use crate::report::{PlotLabels, PlotSeries, plot_series};
use crate::robot::{RobotDescription, RobotError, RobotOverrides};
use crate::runner::view::{LiveAddress, ReadingsTopic, ServoReadings, ViewOptions};
use crate::scenario::{Override, Scenario, ScenarioError};
use crate::transcript::{TranscriptError, packet_from_bytes, packet_from_hex};

#[derive(Debug, Error)]
pub enum CompareError {
    #[error(transparent)]
    Transcript(#[from] TranscriptError),
    #[error(transparent)]
    Run(#[from] RunError),
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    Robot(#[from] RobotError),
    #[error("{}:{line}: {message}", path.display())]
    Record { path: PathBuf, line: usize, message: String },
    #[error("{}: no read replies to compare (the session has no Read, Sync Read or Bulk Read, fast or not, that a servo answered)", path.display())]
    NothingToCompare { path: PathBuf },
    #[error("cannot write {}: {source}", path.display())]
    Write { path: PathBuf, source: std::io::Error },
    #[error(transparent)]
    Plot(crate::report::ReportError),
    /// The world's run of `--signals` failed.
    #[error(transparent)]
    Runner(#[from] super::RunnerError),
    #[error("{}: {message}", path.display())]
    Signals { path: PathBuf, message: String },
    /// `fit` was given no session to fit against.
    #[error("fit needs at least one session")]
    NoSession,
}

/// What to compare the session with.
#[derive(Debug, Clone)]
pub struct CompareOptions {
    pub scenario: PathBuf,
    /// `--set`: the scenario's keys, and the robot description's and profile's (`robot.…`,
    /// `profile.…`).
    pub overrides: Vec<Override>,
    pub robot: PathBuf,
    pub tolerances: Tolerances,
    /// Where `compare.json` goes ([`compare`]; [`reenact`] writes nothing).
    pub out: PathBuf,
}

/// Reply latency of one servo, real and modelled (µs, medians).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LatencyComparison {
    pub id: u8,
    pub replies: usize,
    pub real_median_us: f64,
    pub model_median_us: f64,
}

/// The comparison's result (`compare.json`).
#[derive(Debug, Clone, Serialize)]
pub struct CompareReport {
    pub transcript: PathBuf,
    pub scenario: PathBuf,
    pub robot: PathBuf,
    pub overrides: Vec<String>,
    /// Instructions re-enacted, and read replies compared.
    pub instructions: u64,
    pub replies_compared: u64,
    /// Real replies the world did not give (a servo it does not have, a different answer).
    pub replies_the_world_missed: u64,
    pub registers: Vec<RegisterStats>,
    pub latency: Vec<LatencyComparison>,
    /// Each register's samples, real and simulated (plotted, not in the JSON).
    #[serde(skip)]
    pub series: Vec<RegisterSeries>,
}

impl CompareReport {
    /// The registers past their tolerance.
    pub fn failures(&self) -> Vec<&RegisterStats> {
        self.registers.iter().filter(|r| !r.passed).collect()
    }

    /// A table for the terminal.
    pub fn table(&self) -> String {
        let mut out = String::from("   ID  register                 unit      samples        bias         RMS     max |Δ|   lag ms   tolerance\n");
        for r in &self.registers {
            out.push_str(&format!(
                "  {:>3}  {:<24} {:<8} {:>8}  {:>10.4}  {:>10.4}  {:>10.4}  {:>7.1}  {:>10.4}{}\n",
                r.id,
                r.key,
                r.unit.as_deref().unwrap_or("-"),
                r.samples,
                r.bias,
                r.rms,
                r.max_abs,
                r.lag_ms,
                r.tolerance,
                if r.passed { "" } else { "  EXCEEDED" }
            ));
        }
        for l in &self.latency {
            out.push_str(&format!("  servo {:>3}: reply latency median {:.0} µs real, {:.0} µs in the wire model ({} replies)\n", l.id, l.real_median_us, l.model_median_us, l.replies));
        }
        out
    }
}

/// The recording of a comparison in its output folder: the world re-enacting the session, as a
/// run records it, with `/compare/robot` and `/compare/world` (see [`crate::runner::view`]).
pub const COMPARE_MCAP: &str = "compare.mcap";

/// Re-enact `transcript` in the scenario's world and compare; writes `compare.json`, the plots
/// and `compare.mcap` into `options.out`.
pub fn compare(transcript: &RealTranscript, path: &Path, options: &CompareOptions) -> Result<CompareReport, CompareError> {
    std::fs::create_dir_all(&options.out).map_err(|source| CompareError::Write { path: options.out.clone(), source })?;
    let report = reenact(transcript, path, options, Some(&options.out.join(COMPARE_MCAP)))?;
    write_report(&report, &options.out)?;
    Ok(report)
}

/// Write `compare.json` (the report and whether it passed) into `out`, and a plot per register
/// (the robot's and the world's values over time) into `out/plots`.
pub fn write_report(report: &CompareReport, out: &Path) -> Result<(), CompareError> {
    std::fs::create_dir_all(out).map_err(|source| CompareError::Write { path: out.to_owned(), source })?;
    let json_path = out.join("compare.json");
    let mut value = serde_json::to_value(report).unwrap_or_else(|_| json!({}));
    value["passed"] = json!(report.failures().is_empty());
    let text = serde_json::to_string_pretty(&value).unwrap_or_default() + "\n";
    std::fs::write(&json_path, text).map_err(|source| CompareError::Write { path: json_path, source })?;
    let plots = out.join("plots");
    std::fs::create_dir_all(&plots).map_err(|source| CompareError::Write { path: plots.clone(), source })?;
    for series in &report.series {
        let t: Vec<f64> = series.samples.iter().map(|s| s.0).collect();
        let (real, sim): (Vec<f64>, Vec<f64>) = series.samples.iter().map(|s| (s.1, s.2)).unzip();
        let title = format!("servo {} {}: the robot and the world", series.id, series.key);
        let y = format!("{} ({})", series.key, series.unit.as_deref().unwrap_or("raw"));
        let labels = PlotLabels { title: &title, x: "t (s, since the tap started)", y: &y };
        let lines = [PlotSeries { label: "robot", x: &t, y: &real }, PlotSeries { label: "world", x: &t, y: &sim }];
        plot_series(&plots, &format!("servo{}_{}", series.id, series.key), &labels, &lines).map_err(CompareError::Plot)?;
    }
    Ok(())
}

/// Re-enact `transcript` in the scenario's world and compare, writing nothing but the recording
/// (`recording`, if given: an MCAP of the world, its bus packets and both sides' readings).
pub fn reenact(transcript: &RealTranscript, path: &Path, options: &CompareOptions, recording: Option<&Path>) -> Result<CompareReport, CompareError> {
    let _span = info_span!("compare", transcript = %path.display(), scenario = %options.scenario.display()).entered();
    let mut world = Reenactor::new(path, options, recording, None)?;
    for (line, record) in &transcript.records {
        world.instruction(*line, record)?;
    }
    world.finish()
}

/// A real session re-enacted in a scenario's world one instruction at a time, as the
/// instructions come: from a transcript ([`reenact`]), or live, beside the real servos, from
/// `climbsim tap --scenario` (the same records in the same order give the same report).
pub struct Reenactor {
    /// The transcript's path (for errors, and the report).
    transcript: PathBuf,
    options: CompareOptions,
    bus: Bus,
    observer: Observer,
    /// The servos' profile decodes the replies; their control period is the world's tick.
    profile: Arc<FirmwareProfile>,
    tick: Duration,
    next_tick: Duration,
    comparison: Comparison,
    instructions: u64,
    compared: u64,
    missed: u64,
    /// Per servo: reply latencies (µs), real and in the wire model.
    latencies: BTreeMap<u8, (Vec<f64>, Vec<f64>)>,
    /// The last instruction's time: they come in order.
    last: Duration,
    /// Where a live viewer sees the world, when it is served live.
    live_url: Option<String>,
}

impl Reenactor {
    /// The scenario's world at the session's start (`transcript` names the session), recorded
    /// into `recording` and served live at `live` if given.
    pub fn new(transcript: &Path, options: &CompareOptions, recording: Option<&Path>, live: Option<LiveAddress>) -> Result<Self, CompareError> {
        let (overrides, robot_sets) = RobotOverrides::split(&options.overrides);
        let scenario = Scenario::load_with(&options.scenario, &overrides)?;
        let robot = RobotDescription::load_with(&options.robot, &robot_sets)?;
        let (mut bus, mut observer) = scenario_bus(&scenario, &robot, Timing::Wire, None)?;
        let live_url = observer.start_view(&ViewOptions { mcap: recording.map(Path::to_owned), live, packets: true, compare: true }, &mut bus)?;
        let Some(servo) = bus.servos().first() else { return Err(CompareError::NothingToCompare { path: transcript.to_owned() }) };
        let (profile, tick) = (Arc::clone(servo.profile()), servo.control_period());
        let wheels = robot.servo.iter().filter(|servo| servo.role == Some(crate::parts::ServoRole::WheelDrive)).map(|servo| servo.id);
        Ok(Self {
            transcript: transcript.to_owned(),
            options: options.clone(),
            bus,
            observer,
            profile,
            tick,
            next_tick: tick,
            comparison: Comparison::new(wheels),
            instructions: 0,
            compared: 0,
            missed: 0,
            latencies: BTreeMap::new(),
            last: Duration::ZERO,
            live_url,
        })
    }

    /// Where a live viewer sees the world (`ws://…`), when it is served live.
    pub fn live_url(&self) -> Option<&str> {
        self.live_url.as_deref()
    }

    fn record_error(&self, line: usize, message: String) -> CompareError {
        CompareError::Record { path: self.transcript.clone(), line, message }
    }

    /// The next record of the session (at `line` of its transcript): an instruction is handed to
    /// the world at its recorded instant, after the world has ticked up to it, and the world's
    /// answers are set beside the real ones. Other records are skipped.
    pub fn instruction(&mut self, line: usize, record: &RealRecord) -> Result<(), CompareError> {
        self.log_real_bus(record);
        let RealRecord::Tx { t, end, baud, hex, replies, .. } = record else { return Ok(()) };
        let at = Duration::from_nanos(*t);
        if at < self.last {
            return Err(self.record_error(line, format!("t = {:.6} s is before the instruction before it ({:.6} s): a tap writes them in order", at.as_secs_f64(), self.last.as_secs_f64())));
        }
        self.last = at;
        while self.next_tick <= at {
            self.bus.advance(self.next_tick);
            if let Some(error) = self.observer.on_tick(&mut self.bus, self.next_tick).error {
                return Err(CompareError::Run(error));
            }
            self.next_tick += self.tick;
        }
        let packet = packet_from_hex(hex).map_err(|message| self.record_error(line, message))?;
        let (spans, fast) = (read_spans(&packet), is_fast_read(&packet));
        let transaction = self.bus.handle(packet, at, Some(*baud));
        self.instructions += 1;
        let profile = Arc::clone(&self.profile);
        // Both sides' readings of this instruction, for the recording.
        let mut readings = (Vec::new(), Vec::new());
        if fast {
            // One combined reply each, split per servo; no per-servo latency to set beside the
            // wire model's.
            let real = replies.first().map(|r| packet_from_hex(&r.hex)).transpose().map_err(|message| self.record_error(line, format!("a reply: {message}")))?;
            let sim = transaction.replies.first().map(|r| packet_from_bytes(&r.bytes)).transpose().map_err(|message| self.record_error(line, format!("the world's reply: {message}")))?;
            let (Some(real), Some(sim)) = (real, sim) else {
                self.missed += u64::from(!replies.is_empty());
                return Ok(());
            };
            let simulated = fast_blocks(&sim, &spans);
            let at_s = replies.first().map_or(0.0, |r| Duration::from_nanos(r.t).as_secs_f64());
            for (id, address, real_data) in fast_blocks(&real, &spans) {
                let Some(&(_, _, sim_data)) = simulated.iter().find(|(of, _, _)| *of == id) else {
                    self.missed += 1;
                    continue;
                };
                let name = self.observer.view().and(self.observer.servo_name(id));
                add_pair(&mut self.comparison, &mut readings, &profile, name, (id, address, at_s), (real_data, sim_data));
                self.compared += 1;
            }
        }
        for reply in replies.iter().filter(|_| !fast) {
            let real = packet_from_hex(&reply.hex).map_err(|message| self.record_error(line, format!("a reply: {message}")))?;
            let Some(sim) = transaction.replies.iter().find(|r| r.from == [reply.id]) else {
                self.missed += 1;
                self.log(at, LogLevel::Warning, format!("the world did not answer {} where the robot did", self.servo(reply.id)));
                continue;
            };
            let entry = self.latencies.entry(reply.id).or_default();
            entry.0.push(Duration::from_nanos(reply.t.saturating_sub(*end)).as_secs_f64() * 1e6);
            entry.1.push(sim.start.saturating_sub(transaction.instruction_end).as_secs_f64() * 1e6);
            let Some(&(_, address, _)) = spans.iter().find(|(id, _, _)| *id == reply.id) else { continue };
            let sim_packet = packet_from_bytes(&sim.bytes).map_err(|message| self.record_error(line, format!("the world's reply: {message}")))?;
            if let (Ok(real_data), Ok(sim_data)) = (real.status_data(), sim_packet.status_data()) {
                let name = self.observer.view().and(self.observer.servo_name(reply.id));
                add_pair(&mut self.comparison, &mut readings, &profile, name, (reply.id, address, Duration::from_nanos(reply.t).as_secs_f64()), (real_data, sim_data));
                self.compared += 1;
            }
        }
        if let Some(view) = self.observer.view() {
            view.readings(ReadingsTopic::Robot, at, &readings.0);
            view.readings(ReadingsTopic::World, at, &readings.1);
        }
        Ok(())
    }

    /// What the real bus said besides its readings ([`real_bus_note`]), on the view's log
    /// beside the world's own lines, when there is a view.
    fn log_real_bus(&self, record: &RealRecord) {
        if self.observer.view().is_none() {
            return;
        }
        if let Some((level, note)) = real_bus_note(record, |id| self.servo(id)) {
            self.log(Duration::from_nanos(record.t()), level, format!("the robot: {note}"));
        }
    }

    /// A line on the view's log at `at`, when there is a view.
    fn log(&self, at: Duration, level: LogLevel, message: String) {
        if let Some(view) = self.observer.view() {
            view.log(at, level, message);
        }
    }

    /// A servo as the log names it: its name in the robot description, and its ID.
    fn servo(&self, id: u8) -> String {
        self.observer.servo_name(id).map_or_else(|| format!("ID {id}"), |name| format!("{name} ({id})"))
    }

    /// The session is over: the recording gets its final name, and the comparison is made.
    pub fn finish(mut self) -> Result<CompareReport, CompareError> {
        if self.compared == 0 {
            return Err(CompareError::NothingToCompare { path: self.transcript });
        }
        self.observer.finish_view()?;
        let latency = std::mem::take(&mut self.latencies)
            .into_iter()
            .map(|(id, (mut real, mut model))| LatencyComparison { id, replies: real.len(), real_median_us: median(&mut real), model_median_us: median(&mut model) })
            .collect();
        let options = &self.options;
        Ok(CompareReport {
            transcript: self.transcript.clone(),
            scenario: options.scenario.clone(),
            robot: options.robot.clone(),
            overrides: options.overrides.iter().map(|o| o.to_string()).collect(),
            instructions: self.instructions,
            replies_compared: self.compared,
            replies_the_world_missed: self.missed,
            registers: self.comparison.stats(&self.profile, &options.tolerances),
            latency,
            series: self.comparison.series().cloned().collect(),
        })
    }
}

/// What a real bus's record says besides its readings, as a log line: the servos that did not
/// answer, a framing error, a status packet that answered nothing (`servo` names a servo). What
/// `tap --foxglove` shows as the session goes, and the world's view of it beside its own lines.
pub(super) fn real_bus_note(record: &RealRecord, servo: impl Fn(u8) -> String) -> Option<(LogLevel, String)> {
    match record {
        RealRecord::Tx { missed, .. } if !missed.is_empty() => {
            let missed: Vec<String> = missed.iter().map(|id| servo(*id)).collect();
            Some((LogLevel::Warning, format!("no reply from {}", missed.join(", "))))
        }
        RealRecord::Unpaired { hex, .. } => {
            let from = packet_from_hex(hex).map_or_else(|_| "a servo".to_owned(), |packet| servo(packet.id));
            Some((LogLevel::Warning, format!("a status packet from {from} that answered nothing pending (late?)")))
        }
        RealRecord::FrameError { from, what, .. } => {
            let side = match from {
                Side::Controller => "controller",
                Side::Servos => "servos",
            };
            Some((LogLevel::Error, format!("from the {side}: {what}")))
        }
        _ => None,
    }
}

/// One servo's answer to a read, as the robot and the world gave it: compared register by
/// register, and kept for the recording under the servo's `name` when there is one (a view).
fn add_pair<'a>(
    comparison: &mut Comparison,
    readings: &mut (Vec<ServoReadings<'a>>, Vec<ServoReadings<'a>>),
    profile: &'a FirmwareProfile,
    name: Option<&'a str>,
    (id, address, t_s): (u8, u16, f64),
    (real, sim): (&[u8], &[u8]),
) {
    comparison.add(profile, id, address, t_s, real, sim);
    if let Some(name) = name {
        readings.0.push(ServoReadings { name, id, registers: registers_in(profile, address, real) });
        readings.1.push(ServoReadings { name, id, registers: registers_in(profile, address, sim) });
    }
}

fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}
