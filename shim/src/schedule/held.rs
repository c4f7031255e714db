//! Reply bytes climbsim wrote to the port ahead of their time (`abi::HeldRun`).
//!
//! A Sync Read's eight replies are written in one go when the request is handled, each marked
//! with the instant its last byte arrives on the modelled wire. Until then the shim hides it: a
//! read returns only what is visible, a poll or select does not report the port readable for
//! bytes that are not, FIONREAD counts only visible bytes, and tcflush discards only those. So a
//! controller that spins on the port moves from reply to reply by itself, without a hand-over to
//! climbsim for each, and still sees every byte at its wire-model instant.

use core::cell::Cell;
use core::ffi::c_int;
use core::sync::atomic::{Ordering, fence};

use crate::abi::{NEVER, Shared};
use crate::schedule::now::sim_now;

/// The port's stream at one instant.
#[derive(Clone, Copy)]
pub(crate) struct Stream {
    /// Bytes visible (offset in the stream).
    pub visible: u64,
    /// Bytes written.
    pub written: u64,
    /// Bytes the controller has taken.
    pub taken: u64,
    /// When more bytes become visible ([`NEVER`]: none are held).
    pub next_due: u64,
}

impl Stream {
    /// Bytes written that may not be seen yet.
    pub fn hidden(&self) -> u64 {
        self.written.saturating_sub(self.visible)
    }

    /// Visible bytes the controller has not read.
    pub fn unread(&self) -> u64 {
        self.visible.saturating_sub(self.taken)
    }

    /// The port must look empty: it holds bytes, and none of them is visible and unread.
    pub fn looks_empty(&self) -> bool {
        self.hidden() > 0 && self.unread() == 0
    }
}

/// The port's stream at simulated time `now`.
pub(crate) fn stream_at(shared: &Shared, now: u64) -> Stream {
    let header = &shared.header;
    // A sequence lock: climbsim rewrites the runs only while every thread is parked, but a thread
    // that polls real descriptors meanwhile may look. A climbsim that died mid-write leaves the
    // count odd: after a while, everything written counts as visible.
    for _ in 0..10_000 {
        let seq = header.port.held_seq.load(Ordering::Acquire);
        if seq & 1 == 1 {
            core::hint::spin_loop();
            continue;
        }
        let written = header.port.rx_written.load(Ordering::Acquire);
        let (visible, next_due) = header.port_visible_at(written, now);
        fence(Ordering::Acquire);
        if header.port.held_seq.load(Ordering::Relaxed) == seq {
            let taken = header.port.rx_taken.load(Ordering::Acquire);
            return Stream { visible, written, taken, next_due };
        }
    }
    let written = header.port.rx_written.load(Ordering::Acquire);
    Stream { visible: written, written, taken: header.port.rx_taken.load(Ordering::Acquire), next_due: NEVER }
}

pub(crate) fn stream_now(shared: &Shared) -> Stream {
    stream_at(shared, sim_now(shared))
}

/// The controller read (or discarded) `bytes` of the port's stream.
pub(crate) fn took(shared: &Shared, bytes: isize) {
    if bytes > 0 {
        shared.header.port.rx_taken.fetch_add(bytes as u64, Ordering::AcqRel);
    }
}

/// A thread about to block on the port: climbsim's horizon must not let another thread move
/// the clock past the instant the next held reply shows (this one has to be let go then).
pub(crate) fn bound_horizon(shared: &Shared) {
    let next_due = stream_now(shared).next_due;
    if next_due != NEVER {
        shared.header.clock.horizon_ns.fetch_min(next_due, Ordering::AcqRel);
    }
}

thread_local! {
    /// A wait's result had the port hidden (see [`take_masked`]).
    static MASKED: Cell<bool> = const { Cell::new(false) };
}

/// Whether a result was masked since the last call: the kernel reported the port readable for
/// bytes that are not visible yet, so a real wait on it returns at once.
pub(crate) fn take_masked() -> bool {
    MASKED.with(|m| m.replace(false))
}

/// The port is readable for the kernel (`kernel_ready`) but must look empty now.
pub(crate) fn hide(shared: &Shared, kernel_ready: bool) -> bool {
    if !kernel_ready || !stream_now(shared).looks_empty() {
        return false;
    }
    MASKED.with(|m| m.set(true));
    true
}

/// A poll's result without the port's readiness where nothing visible is there to read.
pub(crate) fn mask_poll(shared: &Shared, fds: *mut crate::sys::pollfd, count: crate::sys::nfds_t, ready: c_int, port_fd: Option<c_int>) -> c_int {
    let Some(port_fd) = port_fd.filter(|_| ready > 0) else { return ready };
    const POLLRDNORM: i16 = 0x40;
    let mut ready = ready;
    for index in 0..count as usize {
        // SAFETY: the caller's array of `count` pollfds.
        let entry = unsafe { &mut *fds.add(index) };
        let readable = entry.revents & (crate::sys::POLLIN | POLLRDNORM) != 0;
        if entry.fd == port_fd && hide(shared, readable) {
            entry.revents &= !(crate::sys::POLLIN | POLLRDNORM);
            if entry.revents == 0 {
                ready -= 1;
            }
        }
    }
    ready
}

/// A select's result without the port in the read set where nothing visible is there to read.
pub(crate) fn mask_select(shared: &Shared, read: *mut crate::sys::fd_set, ready: c_int, port_fd: Option<c_int>) -> c_int {
    let Some(fd) = port_fd.filter(|&fd| ready > 0 && !read.is_null() && (0..1024).contains(&fd)) else { return ready };
    let (word, bit) = (fd as usize / 64, 1u64 << (fd % 64));
    // SAFETY: the caller's read set (1024 bits), not null.
    let set = unsafe { &mut (*read).bits[word] };
    if hide(shared, *set & bit != 0) {
        *set &= !bit;
        return ready - 1;
    }
    ready
}
