//! The `climbsim` binary. Errors become one `climbsim: ...` line and an exit code that says what
//! happened: 0 passed, 1 a run failed, 2 bad input or environment, 130 interrupted
//! (`docs/exit-codes.md`). `anyhow` lives only here, the library has a `thiserror` enum per layer.

mod cli;

use clap::Parser;
use tracing_subscriber::EnvFilter;

fn main() -> std::process::ExitCode {
    use std::io::{IsTerminal as _, Write as _};
    tracing_subscriber::fmt()
        .with_env_filter(EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("warn")))
        .with_writer(std::io::stderr)
        // Colour only for a person at a terminal: escape codes in CI logs and files are noise.
        .with_ansi(std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none())
        .init();
    let cli = cli::Cli::parse();
    match cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            let _ = writeln!(std::io::stderr().lock(), "climbsim: {}", climbsim::runner::describe(error.as_ref()));
            // Anything that is not a run's verdict (bad input, an unusable path or program) is 2,
            // like a usage error.
            std::process::ExitCode::from(error.downcast_ref::<climbsim::runner::RunnerError>().map_or(2, climbsim::runner::RunnerError::exit_code))
        }
    }
}
