//! Reply bytes a parked thread writes to the port for climbsim (`abi::outbox`; climbsim's side:
//! `src/virtual_time/outbox.rs`).
//!
//! A write to a pty wakes the kernel's worker that hands the bytes to the other side, on the
//! CPU it last ran on: the controller's, whose own writes to the port wake it there. Woken from
//! climbsim's CPU, that costs a write of the eight replies of a Sync Read 26 µs on a VM (the
//! interrupt to the other CPU), against 5 µs for the controller's own writes. A thread that
//! spins while it waits for its turn is on the controller's CPU and has nothing to do: it
//! writes them, with the port's master that climbsim passed to the processes it started.
//! Nothing the controller sees changes: climbsim waits until they are written and handed over,
//! as when it writes them itself, and the shim counts and hides them the same way.

use core::ffi::{c_int, c_long};
use core::sync::atomic::{AtomicI64, Ordering};

use crate::abi::{Shared, outbox};
use crate::native;
use crate::sys::nr;

/// TIOCGPTN: the number of a pty master's slave.
const TIOCGPTN: c_long = 0x8004_5430;

/// Whether `Header::port_master_fd` is the port's master in this process, as last found:
/// the process's id times two, plus one if it is (0: not looked yet). A forked child looks again.
static FOUND: AtomicI64 = AtomicI64::new(0);

fn remember(pid: i32, is_master: bool) {
    FOUND.store(i64::from(pid) * 2 + i64::from(is_master), Ordering::Relaxed);
}

/// The port's master in this process, if climbsim passed it and it still is that.
fn master(shared: &Shared) -> Option<c_int> {
    let fd = shared.header.port_master_fd.load(Ordering::Relaxed);
    if fd < 0 {
        return None;
    }
    let mut number: u32 = u32::MAX;
    // Straight to the kernel, as every call the shim makes from a parked thread: through libc
    // the first call looks the symbol up (dlsym), which can make calls the filter traps, and a
    // trapped call inside a park let two threads run at once (seen: a lock hand-over test whose
    // clock moved half as far in one run of six).
    // TIOCGPTN writes one unsigned int through the pointer, valid for the call; on a descriptor
    // that is not a pty master it fails without touching it.
    let rc = native::call3(nr::IOCTL as c_long, c_long::from(fd), TIOCGPTN, (&mut number as *mut u32) as c_long);
    (rc == 0 && number == shared.header.port_pty_number.load(Ordering::Relaxed)).then_some(fd)
}

/// Whether this process can write to the port's master (looked at once per process; the
/// write looks again).
pub(crate) fn can_write(shared: &Shared) -> bool {
    let pid = crate::pid();
    let found = FOUND.load(Ordering::Relaxed);
    if found != 0 && found / 2 == i64::from(pid) {
        return found % 2 == 1;
    }
    let is_master = master(shared).is_some();
    remember(pid, is_master);
    is_master
}

/// Write the bytes climbsim queued, if no other thread has taken them. Called by a thread that
/// spins while parked.
pub(crate) fn write_if_queued(shared: &Shared) {
    let header = &shared.header;
    if header.outbox_state.load(Ordering::Acquire) != outbox::QUEUED
        || header.outbox_state.compare_exchange(outbox::QUEUED, outbox::CLAIMED, Ordering::AcqRel, Ordering::Relaxed).is_err()
    {
        return;
    }
    header.outbox_claimer.store(crate::pid(), Ordering::Relaxed);
    let len = (header.outbox_len.load(Ordering::Relaxed) as usize).min(header.outbox.len());
    let written = match master(shared) {
        // `len` bytes of the block, which climbsim does not touch while they are claimed
        // (AtomicU8 has u8's layout); the master is non-blocking (climbsim's). A failed write
        // returns a negative errno, and errno is not touched.
        Some(fd) => native::call3(nr::WRITE as c_long, c_long::from(fd), header.outbox.as_ptr() as c_long, len as c_long).max(0),
        None => {
            // The descriptor is no longer the port's: climbsim writes them itself.
            remember(crate::pid(), false);
            0
        }
    };
    header.outbox_written.store(written as u32, Ordering::Relaxed);
    header.outbox_state.store(outbox::DONE, Ordering::Release);
}
