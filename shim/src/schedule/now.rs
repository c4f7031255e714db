//! The time now, as the shim itself reads it: simulated time from the block (and what each
//! clock id reads at a simulated instant), and the host's monotonic and CPU-time clocks
//! through libc (never through the shim's own interposers).
//! Below every other module that parks or charges, which read these.

use core::sync::atomic::Ordering;

use crate::abi::{Shared, mode};
use crate::sys::{self, clockid_t, time_t, timespec};

/// TAI runs 37 s ahead of UTC (since 2017).
const TAI_OFFSET_NS: u64 = 37_000_000_000;

/// What `clock` reads at simulated time `now`, if it is one the shim answers.
pub(crate) fn clock_at(shared: &Shared, clock: clockid_t, now: u64) -> Option<u64> {
    let header = &shared.header;
    let epoch = header.clock.realtime_epoch_ns.load(Ordering::Relaxed);
    let base = header.clock.monotonic_base_ns.load(Ordering::Relaxed);
    match clock {
        sys::CLOCK_REALTIME | sys::CLOCK_REALTIME_COARSE | sys::CLOCK_REALTIME_ALARM => Some(epoch + now),
        sys::CLOCK_TAI => Some(epoch + TAI_OFFSET_NS + now),
        sys::CLOCK_MONOTONIC | sys::CLOCK_MONOTONIC_RAW | sys::CLOCK_MONOTONIC_COARSE | sys::CLOCK_BOOTTIME | sys::CLOCK_BOOTTIME_ALARM => Some(base + now),
        _ => None,
    }
}

/// Simulated time (ns since the run's start) at which `clock` reads `reading`.
pub(crate) fn sim_time_of(shared: &Shared, clock: clockid_t, reading: u64) -> Option<u64> {
    let zero = clock_at(shared, clock, 0)?;
    Some(reading.saturating_sub(zero))
}

/// Simulated time now (ns since the run's start). After the run's end it goes on at the wall
/// clock's rate from where it stopped.
pub(crate) fn sim_now(shared: &Shared) -> u64 {
    let header = &shared.header;
    let now = header.clock.now_ns.load(Ordering::Acquire);
    let ended_at = match crate::schedule::block::orphaned_at() {
        Some(at) => at,
        None if header.mode.load(Ordering::Acquire) == mode::VIRTUAL => return now,
        None => header.clock.ending_wall_ns.load(Ordering::Acquire),
    };
    now.saturating_add(real_monotonic_ns().saturating_sub(ended_at))
}

pub(crate) use crate::sys::{real_monotonic_ns, thread_cpu_ns, to_ns};

pub(crate) fn from_ns(ns: u64) -> timespec {
    timespec { tv_sec: (ns / 1_000_000_000) as time_t, tv_nsec: (ns % 1_000_000_000) as i64 }
}

/// A spin's limit on the host's monotonic clock, read once every [`SpinLimit::EVERY`] turns of
/// the loop: the shim reads the host's clocks with a system call once the vDSO is patched, and
/// what a spin must do quickly is test its own condition.
pub(crate) struct SpinLimit {
    until: u64,
    turns: u32,
    passed: bool,
}

impl SpinLimit {
    /// Turns of a spin between two clock reads: a turn (a `pause`) is 22 ns on the reference
    /// machine, so a limit is overrun by 6 µs at most, and the reads (160 ns each) are 3 % of a
    /// spin (every 32 turns they were 19 %, and a Python check took 4 % longer than with the
    /// vDSO read every turn).
    const EVERY: u32 = 256;

    /// A limit at `until`, the host's clock reading `now` (which the caller has just read: a
    /// limit already past spins no turn).
    pub(crate) fn until(until: u64, now: u64) -> SpinLimit {
        SpinLimit { until, turns: 0, passed: now >= until }
    }

    /// Whether the limit has passed, as last read (once it has, for good).
    pub(crate) fn passed(&mut self) -> bool {
        self.turns = self.turns.wrapping_add(1);
        if !self.passed && self.turns.is_multiple_of(Self::EVERY) {
            self.passed = real_monotonic_ns() >= self.until;
        }
        self.passed
    }
}
