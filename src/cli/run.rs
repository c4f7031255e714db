//! `climbsim run SCENARIO`: one run, its outputs, its verdict.

use std::path::PathBuf;

use anyhow::{Result, bail};

use climbsim::embedded;
use climbsim::fault::ScheduledFault;
use climbsim::robot::RobotOverrides;
use climbsim::runner::external::{ExternalRun, run_external};
use climbsim::runner::lockstep::{LiveRun, run_builtin};
use climbsim::runner::outputs::judge;
use climbsim::runner::recording::RecordSpec;
use climbsim::runner::{Console as _, RunOutcome, RunnerError, default_out_dir, preflight_dir, preflight_file};
use climbsim::scenario::{ControllerSection, Override, Scenario};

use super::args::{FoxgloveArgs, PaceArgs, ROBOT_IN_CHECKOUT, TimingArg, built_in_unless_here, load_robot_with, parse_fault, refuse_recorded_cli_faults};
use super::console::Terminal;
use super::interrupt;

/// `run`'s scenario when none is given.
const DEFAULT_SCENARIO: &str = "scenarios/flat-line.toml";

/// Run a scenario and write its time series, summary, workbook and plots. A built-in
/// controller runs in lockstep, faster than real time; an external one (`command = [...]`)
/// is started with `DXL_PORT` and `CLIMBSIM_SENSORS` and runs on `--clock`: the wall clock
/// unless `--clock virtual` is given (simulated time).
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Scenario file (default: scenarios/flat-line.toml, the one built in outside the checkout).
    #[arg(default_value = DEFAULT_SCENARIO)]
    pub scenario: PathBuf,
    /// Output folder (default: results/<scenario name>).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override a key (repeatable): the scenario's (`controller.zeta=0.5`), the robot
    /// description's (`robot.wheel.friction=0.35`) or the firmware profile's
    /// (`profile.motor.coulomb_friction_nm=0.04`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Reply timing on the pty (external controllers only; default wire).
    #[arg(long, value_enum)]
    pub timing: Option<TimingArg>,
    /// Also create this symlink to the pty (external controllers only).
    #[arg(long)]
    pub link: Option<PathBuf>,
    #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
    pub robot: PathBuf,
    /// Inject a fault, as `serve --fault` (added to the scenario's events; repeatable).
    #[arg(long = "fault", value_name = "SPEC", value_parser = parse_fault)]
    pub faults: Vec<ScheduledFault>,
    /// Record the session (packets, world ticks, sensor reads) for `climbsim replay`
    /// (external controllers only: a built-in one is deterministic already).
    #[arg(long, value_name = "FILE")]
    pub record: Option<PathBuf>,
    #[command(flatten)]
    pub foxglove: FoxgloveArgs,
    #[command(flatten)]
    pub pace: PaceArgs,
}

pub fn exec(args: RunArgs) -> Result<()> {
    let RunArgs { scenario, out, set, timing, link, robot, faults, record, foxglove: FoxgloveArgs { address: foxglove }, pace } = args;
    interrupt::install()?;
    refuse_recorded_cli_faults(&faults, record.as_deref())?;
    let (overrides, robot_sets) = RobotOverrides::split(&parse_overrides(&set)?);
    let robot = load_robot_with(&robot, &robot_sets)?;
    // The default scenario is the checkout's, else the one built in (from any folder).
    let scenario = built_in_unless_here(&scenario, DEFAULT_SCENARIO, &embedded::SCENARIO);
    let mut loaded = Scenario::load_with(&scenario, &overrides)?;
    loaded.add_faults(faults);
    let out_dir = out.unwrap_or_else(|| default_out_dir(&scenario));
    // Every output path is checked before minutes of simulation, not after.
    preflight_dir(&out_dir, "--out")?;
    if let Some(path) = &record {
        preflight_file(path, "--record")?;
    }
    let mut outcome = match &loaded.controller {
        ControllerSection::Builtin(_) => {
            // Flags that only an external controller's wall-clock run uses are refused, not
            // silently ignored.
            let ignored = [
                (record.is_some(), "--record (a built-in controller's run is deterministic already: run it again)"),
                (link.is_some(), "--link (a built-in controller has no port)"),
                (timing.is_some(), "--timing (a built-in controller talks to the bus in lockstep)"),
                (!pace.is_default() && foxglove.is_none(), "--speed (a built-in controller runs in lockstep, as fast as the CPU allows; with --foxglove it keeps to --speed for the watcher)"),
            ];
            if let Some((_, flag)) = ignored.iter().find(|(given, _)| *given) {
                bail!("{}: the scenario's controller is built in, so {flag}", scenario.display());
            }
            let live = foxglove.map(|address| LiveRun { address, speed: pace.speed, console: &Terminal });
            run_builtin(&loaded, &robot, &out_dir, interrupt::flag(), live.as_ref())?
        }
        ControllerSection::External(external) => {
            let record = record.map(|path| RecordSpec { path, overrides: set.clone() });
            let options = ExternalRun { timing: timing.unwrap_or(TimingArg::Wire).into(), link: link.as_deref(), record: record.as_ref(), pace: pace.pace()?, announce: true, live: foxglove };
            run_external(&loaded, external, &robot, &options, &out_dir, interrupt::flag(), &Terminal)?
        }
    };
    let failures = judge(&mut outcome, &loaded, &out_dir)?;
    print_summary(&outcome, &out_dir);
    if !failures.is_empty() {
        return Err(RunnerError::Failed(format!("the run failed ({} in {}):\n  {}", failures.len(), out_dir.display(), failures.join("\n  "))).into());
    }
    Ok(())
}

/// `--set` values for a single run.
pub fn parse_overrides(sets: &[String]) -> Result<Vec<Override>> {
    sets.iter().map(|s| Override::parse(s).map_err(anyhow::Error::from)).collect()
}

/// Print the summary's headline metrics.
pub fn print_summary(outcome: &RunOutcome, out_dir: &std::path::Path) {
    Terminal.say(&format!("outputs: {}", out_dir.display()));
    for (key, value) in &outcome.summary {
        Terminal.say(&format!("  {key} = {value}"));
    }
}
