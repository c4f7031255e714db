//! Reply bytes a parked controller thread writes to the port for climbsim (the shim's side, and
//! why: `shim/src/outbox.rs`).
//!
//! climbsim passes the port's pty master to the processes it starts, under a fixed number
//! ([`abi::CONTROLLER_MASTER_FD`]). When it has replies to write and a thread that can write
//! them spins, it puts them in the block and waits until that thread has written them; if none
//! takes them within [`TAKEN_WITHIN`], it takes them back and writes them itself. Either way the
//! write is over when [`VirtualTime::write_through_controller`] returns: the hand-over that
//! follows, and everything the controller sees, are as before.

use std::os::fd::RawFd;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use tracing::warn;

use super::abi::{self, outbox};
use super::{VirtualTime, lock};

/// How long queued bytes may wait for a spinning thread to take them (it looks every few
/// hundred nanoseconds) before climbsim writes them itself.
const TAKEN_WITHIN: Duration = Duration::from_micros(20);

/// How long climbsim waits for a thread writing them before it looks whether that thread's
/// process is still there (a stopped one, by a debugger or SIGSTOP, is waited for).
const WRITTEN_WITHIN: Duration = Duration::from_millis(100);

impl VirtualTime {
    /// The port's master for the processes climbsim starts: climbsim's descriptor and the
    /// number it has in them (None: no port yet, or not a pty master). Announced in the block.
    pub fn master_for_controller(&self) -> Option<(RawFd, RawFd)> {
        let port = (*lock(&self.port))?;
        let mut number: libc::c_uint = 0;
        // SAFETY: TIOCGPTN writes one unsigned int through the pointer, valid for the call.
        if unsafe { libc::ioctl(port.master, libc::TIOCGPTN, &mut number) } != 0 {
            return None;
        }
        let header = &self.shared().header;
        header.port_pty_number.store(number, Ordering::Relaxed);
        header.port_master_fd.store(abi::CONTROLLER_MASTER_FD, Ordering::Release);
        Some((port.master, abi::CONTROLLER_MASTER_FD))
    }

    /// Have a parked controller thread write `data` to the port's master: how many bytes it
    /// wrote (None: no thread took them, or none can; climbsim writes them itself). Only while
    /// parked threads spin (a quiet machine): a thread asleep would have to be woken for it.
    pub fn write_through_controller(&self, data: &[u8]) -> Option<usize> {
        let header = &self.shared().header;
        if data.is_empty() || data.len() > abi::OUTBOX_BYTES || header.outbox_writers.load(Ordering::Acquire) == 0 || header.outbox_state.load(Ordering::Acquire) != outbox::EMPTY {
            return None;
        }
        for (cell, &byte) in header.outbox.iter().zip(data) {
            cell.store(byte, Ordering::Relaxed);
        }
        header.outbox_len.store(data.len() as u32, Ordering::Relaxed);
        header.outbox_written.store(0, Ordering::Relaxed);
        header.outbox_state.store(outbox::QUEUED, Ordering::Release);
        let queued = Instant::now();
        loop {
            match header.outbox_state.load(Ordering::Acquire) {
                outbox::QUEUED if queued.elapsed() > TAKEN_WITHIN => {
                    if header.outbox_state.compare_exchange(outbox::QUEUED, outbox::EMPTY, Ordering::AcqRel, Ordering::Relaxed).is_ok() {
                        lock(&self.stats).outbox_untaken += 1;
                        return None;
                    }
                }
                outbox::DONE => {
                    let written = (header.outbox_written.load(Ordering::Relaxed) as usize).min(data.len());
                    header.outbox_state.store(outbox::EMPTY, Ordering::Release);
                    lock(&self.stats).outbox_written += 1;
                    return Some(written);
                }
                outbox::CLAIMED if queued.elapsed() > WRITTEN_WITHIN => {
                    let claimer = header.outbox_claimer.load(Ordering::Relaxed);
                    // SAFETY: kill with signal 0 only asks whether the process exists.
                    if claimer > 0 && unsafe { libc::kill(claimer, 0) } != 0 {
                        // Killed within its write (a few microseconds): climbsim writes them.
                        warn!(claimer, "the controller process writing reply bytes for climbsim ended meanwhile");
                        header.outbox_state.store(outbox::EMPTY, Ordering::Release);
                        return None;
                    }
                    std::thread::sleep(Duration::from_millis(1));
                }
                _ => std::hint::spin_loop(),
            }
        }
    }
}
