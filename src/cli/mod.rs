//! The command line: one module per subcommand, each a clap `Args` struct and an `exec` that
//! parses what clap could not, calls the run library ([`climbsim::runner`]) and prints. No run
//! logic lives here.

mod args;
mod check;
mod compare;
mod console;
mod diff;
mod export;
mod fit;
mod interrupt;
mod replay;
mod run;
mod serve;
mod sweep;
mod tap;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(name = "climbsim", version, about = "Hardware-in-the-loop simulator for a magnetic wall-climbing welding robot")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

// Parsed once at start: the size of the largest variant (serve's flags) costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub enum Command {
    Serve(serve::ServeArgs),
    Run(run::RunArgs),
    Check(check::CheckArgs),
    Replay(replay::ReplayArgs),
    Diff(diff::DiffArgs),
    Sweep(sweep::SweepArgs),
    Tap(tap::TapArgs),
    Compare(compare::CompareArgs),
    Fit(fit::FitArgs),
    Export(export::ExportArgs),
    Init(export::InitArgs),
}

pub fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Serve(args) => serve::exec(args),
        Command::Run(args) => run::exec(args),
        Command::Check(args) => check::exec(args),
        Command::Replay(args) => replay::exec(args),
        Command::Diff(args) => diff::exec(args),
        Command::Sweep(args) => sweep::exec(args),
        Command::Tap(args) => tap::exec(args),
        Command::Compare(args) => compare::exec(args),
        Command::Fit(args) => fit::exec(args),
        Command::Export(args) => export::exec(args),
        Command::Init(args) => export::exec_init(args),
    }
}
