//! `climbsim sweep`: a scenario over a grid of parameters, one shard of it, its listing, or the
//! merge of shards.

use std::path::PathBuf;

use anyhow::{Context as _, Result};

use climbsim::runner::sweep::{SweepPlan, grid_listing, merge, sweep};
use climbsim::runner::{Console as _, preflight_dir};
use climbsim::scenario::sweep::{Axis, Shard, grid};

use super::args::{PaceArgs, ROBOT_IN_CHECKOUT, load_robot};
use super::console::{Bar, Terminal};
use super::interrupt;

/// Run a scenario over a grid of parameters (in parallel), or merge sweeps' shards.
#[derive(Debug, clap::Args)]
pub struct SweepArgs {
    /// Scenario file (not with --merge).
    #[arg(required_unless_present = "merge")]
    pub scenario: Option<PathBuf>,
    /// A swept key and its values: `controller.zeta=0.3,0.5,0.7` (repeatable: a grid). Robot
    /// description and firmware profile keys too: `robot.wheel.friction=0.4,0.6,0.8`.
    #[arg(long = "set", value_name = "KEY=V1,V2,...")]
    pub set: Vec<String>,
    /// Runs at once (default: the number of CPUs).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Run only slice K of N of the grid (1-based), for CI matrices and job arrays; `auto/N`
    /// takes K from SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX (0-based).
    #[arg(long, value_name = "K/N")]
    pub shard: Option<String>,
    /// Print the grid points (of this shard) instead of running them.
    #[arg(long, conflicts_with = "merge")]
    pub list: bool,
    /// With --list: one JSON document (index, label, overrides, shard) for scripts.
    #[arg(long, requires = "list")]
    pub json: bool,
    /// Merge these sweeps' output folders (their sweep.json) instead of running.
    #[arg(long, num_args = 1.., conflicts_with_all = ["scenario", "set", "shard"])]
    pub merge: Vec<PathBuf>,
    /// With --merge: write the table even when grid points are missing or did not finish,
    /// and exit 0 (they are marked `not_run` / `interrupted` in it).
    #[arg(long, requires = "merge")]
    pub allow_incomplete: bool,
    /// Output folder (not needed with --list).
    #[arg(long, required_unless_present = "list")]
    pub out: Option<PathBuf>,
    /// Record `run.mcap` for every point too (off by default: a grid may have hundreds).
    #[arg(long)]
    pub mcap: bool,
    #[arg(long, env = "CLIMBSIM_ROBOT", default_value = ROBOT_IN_CHECKOUT)]
    pub robot: PathBuf,
    /// For an external controller: each point on its own port, at this speed.
    #[command(flatten)]
    pub pace: PaceArgs,
}

pub fn exec(args: SweepArgs) -> Result<()> {
    let SweepArgs { scenario, set, jobs, shard, list, json, merge: shards, allow_incomplete, out, mcap, robot, pace } = args;
    let axes = Axis::parse_all(&set)?;
    let shard = shard.as_deref().map(Shard::parse).transpose()?.unwrap_or(Shard::ALL);
    if list {
        if json {
            Terminal.say(&serde_json::to_string_pretty(&grid_listing(&axes, shard))?);
        } else {
            for point in shard.select(grid(&axes)) {
                Terminal.say(&point.label());
            }
        }
        return Ok(());
    }
    let out = out.context("--out is needed")?;
    interrupt::install()?;
    preflight_dir(&out, "--out")?;
    if !shards.is_empty() {
        return Ok(merge(&shards, &out, allow_incomplete, &Terminal)?);
    }
    let robot = load_robot(&robot)?;
    let scenario = scenario.context("a scenario file is needed")?;
    let jobs = jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, usize::from));
    let plan = SweepPlan { axes: &axes, jobs, shard, pace: pace.pace()?, record_mcap: mcap };
    Ok(sweep(&scenario, &plan, &robot, &out, interrupt::flag(), &Terminal, &Bar::new())?)
}
