//! The futex calls climbsim makes on the block's words: its own sleeps, and the wake-ups of the
//! controller's threads.

use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Duration;

use super::abi::Slot;

/// Sleep while `word` holds `expected`, at most `timeout` (a shared futex: the word may be in
/// the block, which the controller's processes map too).
pub(super) fn futex_wait(word: &AtomicU32, expected: u32, timeout: Duration) {
    let timeout = libc::timespec { tv_sec: timeout.as_secs() as libc::time_t, tv_nsec: libc::c_long::from(timeout.subsec_nanos() as i32) };
    // SAFETY: a shared futex wait on a valid, aligned word in our mapping, with a valid timeout.
    unsafe { libc::syscall(libc::SYS_futex, word.as_ptr(), libc::FUTEX_WAIT, expected, &timeout as *const libc::timespec, 0usize, 0u32) };
}

/// Wake every sleeper on `word`.
pub(super) fn futex_wake(word: &AtomicU32) {
    // SAFETY: a shared futex wake on a valid, aligned word in our mapping.
    unsafe { libc::syscall(libc::SYS_futex, word.as_ptr(), libc::FUTEX_WAKE, i32::MAX) };
}

/// Wake a thread that was given the turn, or let go at the run's end.
pub(super) fn wake(slot: &Slot) {
    slot.wake_word.fetch_add(1, Ordering::AcqRel);
    futex_wake(&slot.wake_word);
}
