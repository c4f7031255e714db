//! `climbsim check PATH...`: every scenario against its `[expect]`; JUnit for CI.

use std::path::PathBuf;

use anyhow::Result;

use climbsim::runner::check::check;
use climbsim::runner::{preflight_dir, preflight_file};

use super::args::{ClockArg, PaceArgs, ROBOT_IN_CHECKOUT, load_robot};
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
    let CheckArgs { paths, junit, out, robot, jobs, pace } = args;
    interrupt::install()?;
    let robot = load_robot(&robot)?;
    preflight_dir(&out, "--out")?;
    if let Some(path) = &junit {
        preflight_file(path, "--junit")?;
    }
    Ok(check(&paths, &robot, &out, junit.as_deref(), pace.pace_defaulting_to(ClockArg::Virtual)?, usize::from(jobs), interrupt::flag(), &Terminal)?)
}
