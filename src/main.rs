//! The `climbsim` binary. Errors become one `climbsim: ...` line and exit code 1; `anyhow` lives
//! only here, the library has a `thiserror` enum per layer.

mod cli;

use clap::Parser;
use tracing_subscriber::EnvFilter;

fn main() -> std::process::ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("warn")))
        .with_writer(std::io::stderr)
        .init();
    let cli = cli::Cli::parse();
    match cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("climbsim: {error:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
