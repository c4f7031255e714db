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
    /// What to write.
    pub what: ExportWhat,
    /// Where to write it (made if missing).
    pub dir: PathBuf,
    /// Overwrite files that are there.
    #[arg(long)]
    pub force: bool,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ExportWhat {
    Robot,
    Profile,
    Layout,
    Controller,
    /// `run`'s default scenario (flat-line.toml).
    Scenario,
    All,
}

pub fn exec(args: ExportArgs) -> Result<()> {
    let what = match args.what {
        ExportWhat::Robot => Export::Robot,
        ExportWhat::Profile => Export::Profile,
        ExportWhat::Layout => Export::Layout,
        ExportWhat::Controller => Export::Controller,
        ExportWhat::Scenario => Export::Scenario,
        ExportWhat::All => Export::All,
    };
    for path in export(what, &args.dir, args.force)? {
        Terminal.say(&format!("wrote {}", path.display()));
    }
    Ok(())
}
