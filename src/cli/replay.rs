//! `climbsim replay TRANSCRIPT`: a `--record`ed session re-enacted without its controller.

use std::path::PathBuf;

use anyhow::{Context as _, Result};

use climbsim::runner::replay::{ReplaySources, replay};
use climbsim::runner::write_outputs;
use climbsim::transcript::Transcript;

use climbsim::runner::Console as _;

use super::console::Terminal;
use super::run::print_summary;

/// Re-enact a `--record` transcript without its controller: the same scenario, world ticks
/// and instruction packets in lockstep, deterministically; writes the same outputs as `run`.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// The transcript.
    pub transcript: PathBuf,
    /// Output folder (default: results/replay/<transcript name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Scenario file (default: the recorded path).
    #[arg(long)]
    pub scenario: Option<PathBuf>,
    /// Robot description (default: the recorded path).
    #[arg(long)]
    pub robot: Option<PathBuf>,
    /// Replay even if the scenario, robot description or firmware profile differs from the
    /// recording's.
    #[arg(long)]
    pub force: bool,
}

pub fn exec(args: ReplayArgs) -> Result<()> {
    let ReplayArgs { transcript, out, scenario, robot, force } = args;
    replay_command(&transcript, out, &ReplaySources { scenario, robot, force })
}

/// `climbsim replay FILE`.
pub fn replay_command(transcript: &std::path::Path, out: Option<PathBuf>, sources: &ReplaySources) -> Result<()> {
    let transcript = Transcript::read(transcript)?;
    let out_dir = out.unwrap_or_else(|| {
        let stem = transcript.path.file_stem().map_or_else(|| "replay".into(), |s| s.to_string_lossy().into_owned());
        PathBuf::from("results").join("replay").join(stem)
    });
    let replayed = replay(&transcript, sources, &out_dir)?;
    write_outputs(&replayed.outcome, &out_dir).with_context(|| format!("writing outputs to {}", out_dir.display()))?;
    print_summary(&replayed.outcome, &out_dir);
    let stats = &replayed.stats;
    Terminal.say(&format!(
        "replayed {} ticks and {} packets ({} sensor reads recorded) to t = {:.3} s{}",
        stats.ticks,
        stats.packets,
        stats.sensor_reads,
        replayed.outcome.sim_s,
        if stats.complete { "" } else { " (the transcript has no end line: its prefix)" }
    ));
    if let Some(line) = stats.first_reply_mismatch_line {
        Terminal.say(&format!("{} packets were answered differently from the recording (first at line {line})", stats.reply_mismatches));
    }
    Ok(())
}
