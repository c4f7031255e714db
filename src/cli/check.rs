//! `climbsim check PATH...`: every scenario against its `[expect]`; JUnit for CI.

use std::path::PathBuf;

use anyhow::Result;

use climbsim::robot::RobotOverrides;
use climbsim::runner::check::{CheckOptions, check};
use climbsim::runner::{preflight_dir, preflight_file};

use super::args::{ClockArg, PaceArgs, ROBOT_IN_CHECKOUT, load_robot_with};
use super::console::Terminal;
use super::interrupt;

/// Run scenarios and test their `[expect]` thresholds; exit non-zero if any fails.
#[derive(Debug, clap::Args)]
pub struct CheckArgs {
    /// Scenario files, or folders (their `*.toml` files that have an `[expect]` section).
    #[arg(required = true)]
    pub paths: Vec<PathBuf>,
    /// Also write JUnit XML here.
    #[arg(long)]
    pub junit: Option<PathBuf>,
    /// Root of the runs' output folders.
    #[arg(long, default_value = "results/check")]
    pub out: PathBuf,
    #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
    pub robot: PathBuf,
    /// Override a key in every scenario checked (repeatable), as `run --set` does: the
    /// scenario's (`world.duration_s=5`, `controller={ kind = "external", command = [...] }`),
    /// the robot description's (`robot.wheel.friction=0.35`) or the firmware profile's.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Scenarios checked at once. Runs on virtual time or in lockstep give the same verdicts
    /// side by side; wall-clock runs compete for the CPU, and their pace shows it.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..))]
    pub jobs: u16,
    /// An external controller runs on virtual time unless `--clock wall` (or `--speed N`) is
    /// given; built-in ones always run in lockstep, as fast as the CPU allows.
    #[command(flatten)]
    pub pace: PaceArgs,
}

pub fn exec(args: CheckArgs) -> Result<()> {
    let CheckArgs { paths, junit, out, robot, set, jobs, pace } = args;
    interrupt::install()?;
    let (overrides, robot_sets) = RobotOverrides::split(&super::run::parse_overrides(&set)?);
    let robot = load_robot_with(&robot, &robot_sets)?;
    preflight_dir(&out, "--out")?;
    if let Some(path) = &junit {
        preflight_file(path, "--junit")?;
    }
    let options = CheckOptions { out_root: &out, junit: junit.as_deref(), pace: pace.pace_defaulting_to(ClockArg::Virtual)?, jobs: usize::from(jobs), overrides: &overrides };
    Ok(check(&paths, &robot, &options, interrupt::flag(), &Terminal)?)
}
