//! Where the run library's lines go: stdout for what scripts read (ports, addresses, verdicts),
//! stderr for notes; and a sweep's progress bar.

use std::io::Write as _;

use climbsim::runner::Console;
use climbsim::runner::sweep::Progress;

/// stdout and stderr, each line flushed at once: a supervisor reads the port as it is said. A
/// reader that went away (`climbsim run … | head -1`) is no error: the lines it would have read
/// are dropped and the command carries on to its verdict and exit code.
pub struct Terminal;

impl Console for Terminal {
    fn say(&self, line: &str) {
        let mut stdout = std::io::stdout().lock();
        let _ = writeln!(stdout, "{line}");
        let _ = stdout.flush();
    }

    fn note(&self, line: &str) {
        let _ = writeln!(std::io::stderr().lock(), "{line}");
    }
}

/// A sweep's progress as a bar on stderr.
pub struct Bar(indicatif::ProgressBar);

impl Bar {
    pub fn new() -> Self {
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} runs, {elapsed} elapsed, ETA {eta} {msg}").unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()));
        Self(bar)
    }
}

impl Progress for Bar {
    fn start(&self, runs: usize) {
        self.0.set_length(runs as u64);
    }

    fn done_one(&self) {
        self.0.inc(1);
    }

    fn finish(&self) {
        self.0.finish_with_message("done");
    }
}
