//! `climbsim replay`: re-enact a recorded session ([`crate::transcript`]) without its controller.
//!
//! The world and bus are rebuilt from the same scenario (same seed, overrides, baud, timing) and
//! driven in lockstep through the transcript's records in their recorded order: each `tick`
//! advances the bus to its time and runs the observer (events, camera, capture) exactly as the
//! pacer did; each `rx` hands the packet to the bus at its recorded arrival time and line baud,
//! so `Bus::handle` advances the plant to the same instruction end and the servos see the same
//! `now`. The sequence of calls on the bus is the live run's, so the replay reproduces it to the
//! bit wherever the model is unchanged, and anything that differs is a change in the model.
//!
//! The recorded replies and wire-end times are compared with the replay's as it goes: a
//! mismatch means the model (or the scenario, when forced) answers differently now.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde_json::json;
use thiserror::Error;
use tracing::{info_span, warn};

use super::RunError;
use super::observe::{require_line, scenario_bus};
use super::outputs::{RunOutcome, settings_json};
use super::view::ViewOptions;
use crate::bus::Timing;
use crate::robot::{RobotDescription, RobotError, RobotOverrides};
use crate::scenario::{Override, Scenario, ScenarioError};
use crate::transcript::{Record, Transcript, TranscriptError, crc64_hex, packet_from_hex, to_hex};

#[derive(Debug, Error)]
pub enum ReplayError {
    #[error(transparent)]
    Transcript(#[from] TranscriptError),
    #[error(transparent)]
    Run(#[from] RunError),
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    #[error(transparent)]
    Robot(#[from] RobotError),
    #[error("cannot read {}: {source}", path.display())]
    Read { path: PathBuf, source: std::io::Error },
    #[error("cannot create {}: {source}", path.display())]
    CreateDir { path: PathBuf, source: std::io::Error },
    #[error(
        "{what} {} differs from the copy in the recording {}: first at line {line}: recorded `{recorded}`, now `{now}` (pass --force to replay with the current file anyway)",
        path.display(), transcript.display()
    )]
    Differs { what: &'static str, path: PathBuf, transcript: PathBuf, line: usize, recorded: String, now: String },
    #[error(
        "firmware profile {} differs from the one recorded in {} (CRC-64 {recorded}, now {now}; pass --force to replay anyway)",
        path.display(), transcript.display()
    )]
    ProfileDiffers { path: PathBuf, transcript: PathBuf, recorded: String, now: String },
    #[error("{}:1: the recorded --set `{set}` does not parse: {message}", path.display())]
    Override { path: PathBuf, set: String, message: String },
    #[error("{}:1: unknown timing `{timing}` (wire or off)", path.display())]
    Timing { path: PathBuf, timing: String },
    #[error("{}:{line}: {message}", path.display())]
    Packet { path: PathBuf, line: usize, message: String },
    /// A record's time cannot be a session's: before the tick before it, or after its end.
    #[error("{}:{line}: {message}", path.display())]
    Time { path: PathBuf, line: usize, message: String },
    #[error("{}: the transcript has no world ticks: nothing to replay", path.display())]
    NoTicks { path: PathBuf },
}

/// What the replay saw besides the run's outputs.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplayStats {
    pub ticks: u64,
    pub packets: u64,
    pub sensor_reads: u64,
    /// Packets whose replies differ from the recorded ones, and the first one's line.
    pub reply_mismatches: u64,
    pub first_reply_mismatch_line: Option<usize>,
    /// Packets whose end on the modelled wire differs from the recorded one.
    pub wire_end_mismatches: u64,
    /// The transcript ended cleanly (else a prefix was replayed).
    pub complete: bool,
}

/// A replay's outputs (as a run's) and what it checked.
pub struct Replayed {
    pub outcome: RunOutcome,
    pub stats: ReplayStats,
}

/// Where the scenario and robot description come from, and whether differences from the
/// recorded copies are accepted.
#[derive(Debug, Clone, Default)]
pub struct ReplaySources {
    /// The scenario file (default: the recorded path).
    pub scenario: Option<PathBuf>,
    /// The robot description (default: the recorded path).
    pub robot: Option<PathBuf>,
    pub force: bool,
}

/// How far past the scenario's end a `run`'s records may go: the world stops at the end, but
/// the controller is stopped only after it (at most its 3 s of grace after SIGTERM), and its
/// last packets are still recorded.
const PAST_THE_END: Duration = Duration::from_secs(5);

/// Refuse records whose times no session could have written: world ticks out of order (they
/// only ever go forward), and any record after the session's end (a `run`: the scenario's
/// duration and [`PAST_THE_END`]; any session with an `end` line: that line's time). Without
/// this an edited time sends the replay computing for days.
fn check_times(transcript: &Transcript, duration: Duration) -> Result<(), ReplayError> {
    let end_line = transcript.records.iter().find_map(|(_, record)| match record {
        Record::End { t, .. } => Some(Duration::from_nanos(*t)),
        _ => None,
    });
    let limit = match (transcript.header.mode.as_str(), end_line) {
        ("run", Some(end)) => Some(end.min(duration + PAST_THE_END)),
        ("run", None) => Some(duration + PAST_THE_END),
        (_, end) => end,
    };
    let error = |line: usize, message: String| ReplayError::Time { path: transcript.path.clone(), line, message };
    let mut last_tick: Option<(usize, Duration)> = None;
    for (line, record) in &transcript.records {
        let t = match record {
            Record::Tick { t } | Record::Rx { t, .. } | Record::Sensor { t, .. } | Record::End { t, .. } => Duration::from_nanos(*t),
        };
        if let Some(limit) = limit.filter(|limit| t > *limit) {
            return Err(error(*line, format!("t = {:.6} s is after the session's end at {:.6} s", t.as_secs_f64(), limit.as_secs_f64())));
        }
        if let Record::Tick { .. } = record {
            if let Some((before, previous)) = last_tick.filter(|(_, previous)| t <= *previous) {
                return Err(error(*line, format!("tick at t = {:.6} s is not after the tick at line {before} (t = {:.6} s): ticks only go forward", t.as_secs_f64(), previous.as_secs_f64())));
            }
            last_tick = Some((*line, t));
        }
    }
    if last_tick.is_none() {
        return Err(ReplayError::NoTicks { path: transcript.path.clone() });
    }
    Ok(())
}

/// Re-enact `transcript` (see the module documentation), writing its time series and its
/// Foxglove recording (if the scenario records one) into `out_dir` as they come.
pub fn replay(transcript: &Transcript, sources: &ReplaySources, out_dir: &Path) -> Result<Replayed, ReplayError> {
    let header = &transcript.header;
    let scenario_path = sources.scenario.clone().unwrap_or_else(|| header.scenario.path.clone());
    let robot_path = sources.robot.clone().unwrap_or_else(|| header.robot.path.clone());
    let _span = info_span!("replay", transcript = %transcript.path.display(), scenario = %scenario_path.display()).entered();
    let started = Instant::now();

    let scenario_text = read_text(&scenario_path)?;
    let robot_text = read_text(&robot_path)?;
    if !sources.force {
        same_text("scenario", &scenario_path, &transcript.path, &header.scenario.text, &scenario_text)?;
        same_text("robot description", &robot_path, &transcript.path, &header.robot.text, &robot_text)?;
    }
    let overrides = header
        .scenario
        .overrides
        .iter()
        .map(|set| Override::parse(set).map_err(|e| ReplayError::Override { path: transcript.path.clone(), set: set.clone(), message: e.to_string() }))
        .collect::<Result<Vec<_>, _>>()?;
    let (overrides, robot_sets) = RobotOverrides::split(&overrides);
    let scenario = Scenario::load_with(&scenario_path, &overrides)?;
    let robot = RobotDescription::load_with(&robot_path, &robot_sets)?;
    let profile_path = robot.profile_path();
    let profile_crc = crc64_hex(read_text(&profile_path)?.as_bytes());
    if !sources.force && profile_crc != header.robot.profile_crc64 {
        return Err(ReplayError::ProfileDiffers { path: profile_path, transcript: transcript.path.clone(), recorded: header.robot.profile_crc64.clone(), now: profile_crc });
    }
    if scenario.world.seed != header.seed {
        warn!(recorded = header.seed, now = scenario.world.seed, "the scenario's seed differs from the recording's");
    }
    let timing = match header.bus.timing.as_str() {
        "wire" => Timing::Wire,
        "off" => Timing::Off,
        other => return Err(ReplayError::Timing { path: transcript.path.clone(), timing: other.to_owned() }),
    };

    check_times(transcript, Duration::from_secs_f64(scenario.world.duration_s))?;
    let (mut bus, mut observer) = scenario_bus(&scenario, &robot, timing, header.bus.baud_override)?;
    require_line(&scenario)?;
    std::fs::create_dir_all(out_dir).map_err(|source| ReplayError::CreateDir { path: out_dir.to_owned(), source })?;
    observer.stream_to(out_dir)?;
    observer.start_view(&ViewOptions::of_run(&scenario.capture, Some(out_dir), None), &mut bus)?;
    let mut stats = ReplayStats { complete: transcript.complete, ..ReplayStats::default() };
    let mut last_t = Duration::ZERO;
    let packet_error = |line: usize, message: String| ReplayError::Packet { path: transcript.path.clone(), line, message };
    for (line, record) in &transcript.records {
        match record {
            Record::Tick { t } => {
                let at = Duration::from_nanos(*t);
                bus.advance(at);
                if let Some(error) = observer.on_tick(&mut bus, at).error {
                    return Err(error.into());
                }
                stats.ticks += 1;
                last_t = last_t.max(at);
            }
            Record::Rx { t, baud, hex, end, replies } => {
                let packet = packet_from_hex(hex).map_err(|message| packet_error(*line, message))?;
                let at = Duration::from_nanos(*t);
                let transaction = bus.handle(packet, at, *baud);
                stats.packets += 1;
                if end.is_some_and(|end| Duration::from_nanos(end) != transaction.instruction_end) {
                    stats.wire_end_mismatches += 1;
                }
                if let Some(recorded) = replies {
                    let now: Vec<String> = transaction.replies.iter().map(|r| to_hex(&r.bytes)).collect();
                    if &now != recorded {
                        stats.reply_mismatches += 1;
                        if stats.first_reply_mismatch_line.is_none() {
                            warn!(line, ?recorded, ?now, "the replay answered this packet differently from the recording");
                            stats.first_reply_mismatch_line = Some(*line);
                        }
                    }
                }
                last_t = last_t.max(at);
            }
            Record::Sensor { .. } => stats.sensor_reads += 1,
            Record::End { .. } => {}
        }
    }
    if !transcript.complete {
        warn!(path = %transcript.path.display(), "the transcript has no `end` line (a killed run?): replayed the prefix it holds");
    }

    let sim_s = last_t.as_secs_f64();
    let mut summary = observer.summary(scenario.capture.on_line_tolerance_m);
    summary.insert("physics_ticks".to_owned(), json!(stats.ticks));
    summary.insert("replay.packets".to_owned(), json!(stats.packets));
    summary.insert("replay.reply_mismatches".to_owned(), json!(stats.reply_mismatches));
    summary.insert("replay.wire_end_mismatches".to_owned(), json!(stats.wire_end_mismatches));
    summary.insert("replay.complete".to_owned(), json!(stats.complete));
    let mut settings = settings_json(&scenario, &robot);
    settings["replay_of"] = json!(transcript.path.display().to_string());
    settings["overrides"] = json!(header.scenario.overrides);
    let (series, track) = observer.finish()?;
    let outcome = RunOutcome { series, track, summary, settings, sim_s, wall_s: started.elapsed().as_secs_f64() };
    Ok(Replayed { outcome, stats })
}

fn read_text(path: &Path) -> Result<String, ReplayError> {
    std::fs::read_to_string(path).map_err(|source| ReplayError::Read { path: path.to_owned(), source })
}

/// Refuse a file whose text is not the recorded copy, naming the first line that differs.
fn same_text(what: &'static str, path: &Path, transcript: &Path, recorded: &str, now: &str) -> Result<(), ReplayError> {
    if recorded == now {
        return Ok(());
    }
    let (mut old, mut new) = (recorded.lines(), now.lines());
    let mut line = 1;
    loop {
        match (old.next(), new.next()) {
            (Some(a), Some(b)) if a == b => line += 1,
            (a, b) => {
                let show = |l: Option<&str>| l.map_or_else(|| "<end of file>".to_owned(), str::to_owned);
                return Err(ReplayError::Differs { what, path: path.to_owned(), transcript: transcript.to_owned(), line, recorded: show(a), now: show(b) });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_first_differing_line_is_named() {
        let error = same_text("scenario", Path::new("s.toml"), Path::new("t.jsonl"), "a\nb = 1\nc\n", "a\nb = 2\nc\n").expect_err("differs");
        let text = error.to_string();
        assert!(text.contains("line 2") && text.contains("`b = 1`") && text.contains("`b = 2`") && text.contains("s.toml"), "{text}");
        let error = same_text("scenario", Path::new("s.toml"), Path::new("t.jsonl"), "a\n", "a\nb\n").expect_err("longer");
        assert!(error.to_string().contains("line 2: recorded `<end of file>`"), "{error}");
        assert!(same_text("scenario", Path::new("s.toml"), Path::new("t.jsonl"), "a\n", "a\n").is_ok());
    }
}
