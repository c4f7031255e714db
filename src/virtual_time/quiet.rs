//! Whether the machine is quiet enough for the scheduler and the controller to spin while they
//! wait for each other. A spin saves a futex's sleep and wake-up when the other side has a CPU
//! of its own; where more threads want to run than there are CPUs (a sweep's other runs, a
//! loaded CI machine), it takes the CPU from the very thread it waits for, and a run gets
//! several times slower. The kernel's count of runnable threads (the fourth field of
//! /proc/loadavg, read at most every few milliseconds) tells which.

use std::time::{Duration, Instant};

/// How often /proc/loadavg is read (about 10 µs a read).
const EVERY: Duration = Duration::from_millis(5);

#[derive(Debug)]
pub(super) struct Quiet {
    cpus: usize,
    checked: Option<Instant>,
    quiet: bool,
}

impl Quiet {
    pub(super) fn new() -> Self {
        Self { cpus: std::thread::available_parallelism().map_or(1, usize::from), checked: None, quiet: false }
    }

    /// No more threads runnable than there are CPUs (the controller's and climbsim's own
    /// included), as of the last look.
    pub(super) fn now(&mut self) -> bool {
        if self.checked.is_none_or(|at| at.elapsed() >= EVERY) {
            self.checked = Some(Instant::now());
            self.quiet = runnable().is_some_and(|running| running <= self.cpus);
        }
        self.quiet
    }
}

/// Threads runnable now, machine-wide (None where /proc cannot tell).
fn runnable() -> Option<usize> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    parse_runnable(&text)
}

/// "0.52 0.58 0.59 3/412 12345": the fourth field's first number.
fn parse_runnable(text: &str) -> Option<usize> {
    text.split_whitespace().nth(3)?.split('/').next()?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_runnable_count_and_nothing_from_garbage() {
        assert_eq!(parse_runnable("0.52 0.58 0.59 3/412 12345\n"), Some(3));
        assert_eq!(parse_runnable("0.52 0.58"), None);
        assert_eq!(parse_runnable("a b c x/y z"), None);
    }
}
