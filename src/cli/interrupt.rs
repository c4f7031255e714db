//! SIGINT and SIGTERM for every command: the first asks the run in progress (or `serve`) to stop
//! and write what it has (complete files covering the run so far); a later one, more than
//! [`SAME_REQUEST_NS`] after the first, ends the process at once. Signals close behind the first
//! are the same request: `timeout` sends its SIGTERM to the command and then to the process
//! group, and a terminal's Ctrl-C reaches a wrapper script and its child alike. (A `serve` ended
//! by a second signal leaves its `--link` and unwritten `--report`/`--record` behind, as any
//! program killed mid-shutdown does.)

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use anyhow::{Context, Result};
use nix::sys::signal::{SaFlags, SigAction, SigHandler, SigSet, Signal, sigaction};

static REQUESTED: AtomicBool = AtomicBool::new(false);
/// CLOCK_MONOTONIC (ns) of the first signal.
static FIRST_AT_NS: AtomicU64 = AtomicU64::new(0);
/// Signals within this long of the first are the same request (1 s).
pub const SAME_REQUEST_NS: u64 = 1_000_000_000;

fn monotonic_ns() -> u64 {
    let mut now = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime is async-signal-safe and writes only `now`.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut now) };
    (now.tv_sec as u64).saturating_mul(1_000_000_000).saturating_add(now.tv_nsec as u64)
}

extern "C" fn on_signal(_signal: libc::c_int) {
    // Only async-signal-safe work here: atomics, clock_gettime, and _exit on a later signal.
    let now = monotonic_ns();
    if !REQUESTED.swap(true, Ordering::SeqCst) {
        FIRST_AT_NS.store(now, Ordering::SeqCst);
        return;
    }
    if now.saturating_sub(FIRST_AT_NS.load(Ordering::SeqCst)) > SAME_REQUEST_NS {
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(130) }
    }
}

/// Route SIGINT and SIGTERM to the flag.
pub fn install() -> Result<()> {
    let action = SigAction::new(SigHandler::Handler(on_signal), SaFlags::SA_RESTART, SigSet::empty());
    for signal in [Signal::SIGINT, Signal::SIGTERM] {
        // SAFETY: the handler only touches an atomic and calls _exit.
        unsafe { sigaction(signal, &action) }.with_context(|| format!("cannot handle {signal}"))?;
    }
    Ok(())
}

/// Set once a stop was asked for.
pub fn flag() -> &'static AtomicBool {
    &REQUESTED
}
