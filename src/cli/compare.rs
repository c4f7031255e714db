//! `climbsim compare TRANSCRIPT --scenario S`: a real session beside the world, register by
//! register; and what `fit` shares with it.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};

use climbsim::real_bus::compare::Tolerances;
use climbsim::real_bus::transcript::read;
use climbsim::report::diff::Tolerances as DiffTolerances;
use climbsim::runner::compare::{CompareOptions, CompareReport, compare};
use climbsim::runner::signals::compare_signals;
use climbsim::runner::{Console as _, Pace, RunnerError};

use super::args::ROBOT_IN_CHECKOUT;
use super::console::Terminal;
use super::interrupt;
use super::run::parse_overrides;

/// The world a real session is set beside, and how far apart they may be (`compare`, `fit`).
#[derive(Debug, clap::Args)]
pub struct AgainstArgs {
    /// The real session's transcript (`climbsim tap --record`).
    pub transcript: PathBuf,
    /// The scenario whose world the session is re-enacted in (it starts at the tap's start).
    #[arg(long)]
    pub scenario: PathBuf,
    /// Override a key (repeatable): the scenario's (`world.seed=2`), the robot description's
    /// (`robot.wheel.friction=0.35`) or the firmware profile's
    /// (`profile.motor.coulomb_friction_nm=0.04`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Robot description.
    #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
    pub robot: PathBuf,
    /// The RMS a register may differ by, in its unit: `present_position=0.5` for every servo,
    /// `3.present_position=0.5` for one (repeatable).
    #[arg(long = "tolerance", value_name = "KEY=ABS")]
    pub tolerance: Vec<String>,
    /// The RMS a register without an absolute tolerance may differ by, as a fraction of the
    /// real signal's span (never less than two steps of the register).
    #[arg(long, value_name = "R", default_value = "0.05")]
    pub rel: f64,
}

impl AgainstArgs {
    /// The compare options, with `out` (default results/`what`/<transcript name>).
    pub fn options(&self, what: &str, out: Option<PathBuf>) -> Result<CompareOptions> {
        if self.rel.is_nan() || self.rel < 0.0 {
            bail!("--rel must be a non-negative number");
        }
        let mut tolerances = Tolerances { rel: self.rel, ..Tolerances::default() };
        for text in &self.tolerance {
            let (key, value) = DiffTolerances::parse_abs(text).map_err(|e| anyhow::anyhow!("--tolerance {e}"))?;
            tolerances.abs.insert(key, value);
        }
        let robot = super::args::robot_path(&self.robot);
        super::args::load_robot(&robot)?;
        let out = out.unwrap_or_else(|| {
            let stem = self.transcript.file_stem().map_or_else(|| what.into(), |s| s.to_string_lossy().into_owned());
            PathBuf::from("results").join(what).join(stem)
        });
        Ok(CompareOptions { scenario: self.scenario.clone(), overrides: parse_overrides(&self.set)?, robot, tolerances, out })
    }
}

/// Re-enact a real session recorded by `climbsim tap` open-loop in a scenario's world (its
/// instructions at their recorded instants) and compare every real read reply with the world's
/// answer to the same read: per servo and register the bias, RMS, largest difference and lag,
/// and the reply latency against the wire model. Writes compare.json, compare.mcap and a plot
/// per register; exits 1 when a register's RMS is past its tolerance (by default 5 % of the
/// real signal's span, at least two steps).
#[derive(Debug, clap::Args)]
pub struct CompareArgs {
    #[command(flatten)]
    pub against: AgainstArgs,
    /// Output folder (default: results/compare/<transcript name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The real run's line offset as the controller measured it (CSV with `t_s` and `d_m`
    /// columns): the scenario is also run closed loop with its controller (on virtual time,
    /// with --robot and --set), and the seed's step metrics of the two are set side by side
    /// (signals.json, plots/line_offset.png). Informative: it does not change the exit code.
    #[arg(long, value_name = "FILE")]
    pub signals: Option<PathBuf>,
}

pub fn exec(args: CompareArgs) -> Result<()> {
    if args.signals.is_some() {
        interrupt::install()?;
    }
    let options = args.against.options("compare", args.out)?;
    let transcript = &args.against.transcript;
    let report = compare(&read(transcript)?, transcript, &options)?;
    refuse_unknown_tolerances(&options, &report)?;
    say_report(transcript, &options.scenario, &report);
    if let Some(file) = &args.signals {
        let signals = compare_signals(file, &options, Pace::virtual_time(), interrupt::flag())?;
        Terminal.note(&signals.table());
    }
    Terminal.say(&format!(
        "wrote {}: compare.json, compare.mcap (the world and both sides' readings, for Foxglove), plots/{}",
        options.out.display(),
        if args.signals.is_some() { ", signals.json, world-run/" } else { "" }
    ));
    verdict(&report)
}

/// A tolerance for a register the session never read is a typo that would loosen nothing.
pub fn refuse_unknown_tolerances(options: &CompareOptions, report: &CompareReport) -> Result<()> {
    if let Some(unknown) = options.tolerances.abs.keys().find(|key| !report.registers.iter().any(|r| &r.key == *key || &format!("{}.{}", r.id, r.key) == *key)) {
        let known: Vec<String> = report.registers.iter().map(|r| format!("{}.{}", r.id, r.key)).collect();
        bail!("--tolerance {unknown}=...: the session has no register `{unknown}` (it read: {})", known.join(", "));
    }
    Ok(())
}

pub fn say_report(transcript: &Path, scenario: &Path, report: &CompareReport) {
    let missed = if report.replies_the_world_missed > 0 { format!(", {} real replies the world did not give", report.replies_the_world_missed) } else { String::new() };
    Terminal.say(&format!("{}: {} instructions re-enacted in {}, {} read replies compared{missed}", transcript.display(), report.instructions, scenario.display(), report.replies_compared));
    Terminal.say(report.table().trim_end_matches('\n'));
}

/// Exit 1 (a failed comparison, not bad input) when a register is past its tolerance.
pub fn verdict(report: &CompareReport) -> Result<()> {
    let failures = report.failures();
    if !failures.is_empty() {
        let names: Vec<String> = failures.iter().map(|r| format!("servo {} {} (RMS {:.4} {} > {:.4})", r.id, r.key, r.rms, r.unit.as_deref().unwrap_or(""), r.tolerance)).collect();
        return Err(RunnerError::Failed(format!("the world differs from the robot past tolerance in {} of {} registers: {}", failures.len(), report.registers.len(), names.join("; "))).into());
    }
    Terminal.say("the world matches the robot within tolerance");
    Ok(())
}
