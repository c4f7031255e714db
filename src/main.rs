//! The `climbsim` binary. Errors become one `climbsim: ...` line and an exit code that says what
//! happened: 0 passed, 1 a run failed, 2 bad input or environment, 130 interrupted
//! (`docs/exit-codes.md`). `anyhow` lives only here, the library has a `thiserror` enum per layer.

mod cli;

use clap::Parser;
use tracing_subscriber::filter::{LevelFilter, Targets};
use tracing_subscriber::layer::SubscriberExt as _;
use tracing_subscriber::util::SubscriberInitExt as _;

fn main() -> std::process::ExitCode {
    use std::io::{IsTerminal as _, Write as _};
    // RUST_LOG as a list of `target=level` (`climbsim=debug`, `warn,climbsim::bus=trace`):
    // `Targets`, not `EnvFilter`, whose span and field filters need a regex engine that was
    // 4 % of a fresh clone's build for a syntax nobody used here.
    let warnings_only = || Targets::new().with_default(LevelFilter::WARN);
    let (filter, bad_filter) = match std::env::var("RUST_LOG") {
        Ok(text) if !text.trim().is_empty() => match text.parse::<Targets>() {
            Ok(targets) => (targets, None),
            Err(error) => (warnings_only(), Some(format!("RUST_LOG={text:?} ignored ({error}): give target=level pairs, such as climbsim=debug"))),
        },
        _ => (warnings_only(), None),
    };
    tracing_subscriber::registry()
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                // Colour only for a person at a terminal: escape codes in CI logs and files are noise.
                .with_ansi(std::io::stderr().is_terminal() && std::env::var_os("NO_COLOR").is_none()),
        )
        .with(filter)
        .init();
    if let Some(warning) = bad_filter {
        tracing::warn!("{warning}");
    }
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
