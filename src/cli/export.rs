//! `climbsim export`: the files climbsim has built in, written out to edit.

use std::path::PathBuf;

use anyhow::Result;

use climbsim::embedded::{Export, export};
use climbsim::runner::Console as _;

use super::console::Terminal;

/// Write out the files climbsim has built in and uses when none is given: the robot
/// description (with its firmware profile beside it), the firmware profile, the Foxglove layout,
/// the reference controller (Python, the official SDK), `run`'s default scenario, or all of them. Edit them and pass them
/// back (`--robot DIR/robot.toml`; a scenario's `[controller] command`). Existing files are
/// not overwritten without --force.
#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    /// What to write: robot, profile, layout, controller, scenario or all.
    pub what: Export,
    /// Where to write it (made if missing).
    pub dir: PathBuf,
    /// Overwrite files that are there.
    #[arg(long)]
    pub force: bool,
}

pub fn exec(args: ExportArgs) -> Result<()> {
    for path in export(args.what, &args.dir, args.force)? {
        Terminal.say(&format!("wrote {}", path.display()));
    }
    Ok(())
}
