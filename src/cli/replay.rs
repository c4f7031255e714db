//! `--record FILE` (on `run` and `serve`), `climbsim replay` and `climbsim diff`.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};

use climbsim::bus::{Bus, Timing};
use climbsim::report::diff::{self, Tolerances};
use climbsim::robot::RobotDescription;
use climbsim::scenario::Scenario;
use climbsim::scenario::replay::{ReplaySources, replay};
use climbsim::scenario::run::write_outputs;
use climbsim::sensor_server::SensorFeed;
use climbsim::transcript::{BusSettings, Header, Recorder, RobotCopy, ScenarioCopy, Transcript, crc64_hex, nanos};
use climbsim::transport::{BusHandle, PhysicsPace};

/// What `--record` needs besides the loaded scenario: the file, and the `--set` overrides as
/// given (the replay applies them to the scenario file again).
#[derive(Debug, Clone)]
pub struct RecordSpec {
    pub path: PathBuf,
    pub overrides: Vec<String>,
}

/// Create the transcript for a session of `scenario` on `bus` and write its header.
pub fn start_recording(spec: &RecordSpec, mode: &str, scenario: &Scenario, robot: &RobotDescription, bus: &Bus, baud_override: Option<u32>) -> Result<Arc<Recorder>> {
    let read = |path: &Path| std::fs::read_to_string(path).with_context(|| format!("--record: cannot read {}", path.display()));
    let profile_path = robot.profile_path();
    let tick = bus.servos().first().map_or(Duration::from_millis(1), |s| s.control_period());
    let header = Header::new(
        mode,
        ScenarioCopy { path: scenario.path.clone(), overrides: spec.overrides.clone(), text: read(&scenario.path)? },
        RobotCopy { path: robot.path.clone(), text: read(&robot.path)?, profile_crc64: crc64_hex(read(&profile_path)?.as_bytes()), profile_path },
        scenario.world.seed,
        BusSettings {
            baud: baud_override.unwrap_or(robot.bus.baud_bps),
            baud_override,
            timing: match bus.timing() {
                Timing::Wire => "wire",
                Timing::Off => "off",
            }
            .to_owned(),
            tick_ns: nanos(tick),
        },
    );
    let recorder = Recorder::create(&spec.path, &header).with_context(|| format!("--record {}", spec.path.display()))?;
    Ok(Arc::new(recorder))
}

/// Record what the sensor server serves into the handle's transcript, if it has one.
pub fn record_sensor_reads(handle: &Arc<BusHandle>, feed: &SensorFeed) {
    let Some(recorder) = handle.recorder().cloned() else { return };
    let clock = handle.clock();
    feed.on_read(Box::new(move |path, status, content_type, body| recorder.sensor_read(clock.now(), path, status, content_type, body)));
}

/// Write the transcript's `end` line; say where it is.
pub fn finish_recording(handle: &BusHandle, pace: &PhysicsPace) -> Result<()> {
    let Some(recorder) = handle.recorder() else { return Ok(()) };
    recorder.finish(handle.clock().now(), pace.ticks, pace.overruns)?;
    eprintln!("climbsim: recorded the session in {}", recorder.path().display());
    Ok(())
}

/// `climbsim replay FILE`.
pub fn replay_command(transcript: &Path, out: Option<PathBuf>, sources: &ReplaySources) -> Result<()> {
    let transcript = Transcript::read(transcript)?;
    let out_dir = out.unwrap_or_else(|| {
        let stem = transcript.path.file_stem().map_or_else(|| "replay".into(), |s| s.to_string_lossy().into_owned());
        PathBuf::from("results").join("replay").join(stem)
    });
    let replayed = replay(&transcript, sources)?;
    write_outputs(&replayed.outcome, &out_dir).with_context(|| format!("writing outputs to {}", out_dir.display()))?;
    super::batch::print_summary(&replayed.outcome, &out_dir);
    let stats = &replayed.stats;
    println!(
        "replayed {} ticks and {} packets ({} sensor reads recorded) to t = {:.3} s{}",
        stats.ticks,
        stats.packets,
        stats.sensor_reads,
        replayed.outcome.sim_s,
        if stats.complete { "" } else { " (the transcript has no end line: its prefix)" }
    );
    if let Some(line) = stats.first_reply_mismatch_line {
        println!("{} packets were answered differently from the recording (first at line {line})", stats.reply_mismatches);
    }
    Ok(())
}

/// `climbsim diff A B`: print the table; fail if any key exceeds its tolerance.
pub fn diff_command(a: &Path, b: &Path, tolerances: &[String], rel: Option<f64>) -> Result<()> {
    let mut given = Tolerances { rel, ..Tolerances::default() };
    for text in tolerances {
        let (key, value) = Tolerances::parse_abs(text).map_err(|e| anyhow::anyhow!("--tolerance {e}"))?;
        given.abs.insert(key, value);
    }
    if rel.is_some_and(|r| r.is_nan() || r < 0.0) {
        anyhow::bail!("--rel must be a non-negative number");
    }
    let (run_a, run_b) = (diff::load_run(a)?, diff::load_run(b)?);
    let report = diff::compare(&run_a, &run_b, &given);
    // A tolerance for a key neither run has is a typo that would otherwise loosen nothing.
    if let Some(unknown) = given.abs.keys().find(|key| !report.rows.iter().any(|row| &row.key == *key)) {
        let known: Vec<&str> = report.rows.iter().map(|row| row.key.as_str()).collect();
        anyhow::bail!("--tolerance {unknown}=...: neither {} nor {} has a column or metric `{unknown}` (they have: {})", a.display(), b.display(), known.join(", "));
    }
    if report.rows.is_empty() {
        anyhow::bail!("{} and {} have nothing in common to compare (a time series or a summary each)", a.display(), b.display());
    }
    println!("A: {}\nB: {}", a.display(), b.display());
    print!("{}", report.table());
    let failures = report.failures();
    if failures > 0 {
        // A difference is the comparison's verdict (exit 1), not bad input (exit 2).
        return Err(super::Verdict::Failed(format!("{failures} of {} keys differ by more than their tolerance", report.rows.len())).into());
    }
    println!("no differences beyond tolerance");
    Ok(())
}
