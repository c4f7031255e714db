//! `climbsim export`: the files climbsim has built in, written out to edit; `climbsim init`: a
//! controller repository's skeleton.

use std::path::PathBuf;

use anyhow::Result;

use climbsim::embedded::{Export, export, init};
use climbsim::runner::Console as _;

use super::console::Terminal;

/// Write out the files climbsim has built in and uses when none is given: the robot
/// description (with its firmware profile beside it), the firmware profile, the Foxglove
/// layouts (a run's, and a real session's beside the world's), the reference controller
/// (Python, the official SDK), `run`'s default scenario, or all of them. Edit them and pass
/// them back (`--robot DIR/robot.toml`; a scenario's `[controller] command`). Existing files
/// are not overwritten without --force.
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

/// Start a controller repository in DIR: a scenario, a sample controller, a pytest test and CI.
///
/// A scenario on the built-in robot (scenarios/line-follow.toml), a sample controller on the official Python SDK
/// (controller/line_follower.py, climbsim's reference line follower), a pytest test on
/// climbsim's plugin (tests/test_climbsim.py), a CI workflow that installs climbsim with pip
/// and runs `climbsim check scenarios/ --junit` (.github/workflows/climbsim.yml), and what they
/// need (requirements.txt, pytest.ini, README.md, .gitignore). Files of your own in DIR are left
/// alone; the skeleton's are not overwritten without --force.
#[derive(Debug, clap::Args)]
pub struct InitArgs {
    /// The repository's folder (made if missing).
    #[arg(default_value = ".")]
    pub dir: PathBuf,
    /// Overwrite the skeleton's files that are there.
    #[arg(long)]
    pub force: bool,
}

pub fn exec_init(args: InitArgs) -> Result<()> {
    for path in init(&args.dir, args.force)? {
        Terminal.say(&format!("wrote {}", path.display()));
    }
    Terminal.say(&format!("next: cd {} && pip install -r requirements.txt && pytest", args.dir.display()));
    Ok(())
}
