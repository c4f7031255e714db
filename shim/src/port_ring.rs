//! The controller's writes to the servo port, into the block's ring (`Shared::port_tx_ring`)
//! instead of the pty. Through the pty, each request woke the kernel's pty worker, and climbsim
//! waited with the world stopped until it had handed the bytes over; a controller's Sync Write
//! is what the world waits for at the end of every period. From the ring climbsim takes them
//! at once. What this does not see (stdio's writes, a process without the shim) still goes
//! through the pty, which climbsim reads too, as before.
//!
//! The stream stays in order: a counted write goes to the ring only when every counted byte
//! written through the pty (before the run, or by a build that had no ring) has been read.

use core::ffi::c_int;
use core::sync::atomic::Ordering;

use crate::abi::{PORT_TX_RING, Shared, call, state};
use crate::sys::iovec;
use crate::time::sim_now;
use crate::{active, charge, note_call, park};

/// Write `parts` (a write's buffer, or a writev's) to the port `fd` through the ring if the
/// stream's order allows it: the bytes written (or -1 with EAGAIN), or `None` for the kernel.
/// At most what the ring has room for: a larger write is a partial one, as the kernel's can be.
pub(crate) fn write(shared: &'static Shared, fd: c_int, parts: &[iovec]) -> Option<isize> {
    let wanted: usize = parts.iter().map(|part| part.iov_len).fold(0, usize::saturating_add);
    if wanted == 0 || shared.port_tx_pty_unread() > 0 {
        return None;
    }
    let mut room = ring_room(shared);
    while room == 0 {
        // A controller that wrote a whole ring without waiting once: climbsim takes the bytes
        // when every thread is parked, so this one yields until it has. (Through the pty, such
        // a write blocked in the kernel, where climbsim could not take it: the run failed.)
        // SAFETY: fcntl F_GETFL on the caller's descriptor.
        if unsafe { crate::sys::fcntl(fd, crate::sys::F_GETFL) } & crate::sys::O_NONBLOCK != 0 {
            crate::sys::set_errno(crate::sys::EAGAIN);
            return Some(-1);
        }
        park(shared, state::YIELDED, sim_now(shared), 0, 0);
        if active().is_none() {
            // The run ended meanwhile: nobody takes the ring now (what is in it goes to the
            // clean-up's servos first, then this, through the pty).
            return None;
        }
        room = ring_room(shared);
    }
    let count = wanted.min(room);
    let header = &shared.header;
    let start = header.port_tx_ring_written.load(Ordering::Acquire);
    let mut offset = start;
    let mut left = count;
    for part in parts {
        let take = part.iov_len.min(left);
        if take == 0 {
            continue;
        }
        // SAFETY: the caller's buffer, valid for `iov_len` bytes (write's contract).
        let bytes = unsafe { core::slice::from_raw_parts(part.iov_base.cast::<u8>(), take) };
        for &byte in bytes {
            shared.port_tx_ring[(offset % PORT_TX_RING as u64) as usize].store(byte, Ordering::Relaxed);
            offset += 1;
        }
        left -= take;
    }
    // The ring's count first: climbsim, seeing the stream's total grow, finds the bytes there.
    header.port_tx_ring_written.store(start + count as u64, Ordering::Release);
    note_call(shared, call::WRITE);
    header.port_tx_total.fetch_add(count as u64, Ordering::AcqRel);
    charge(shared, header.syscall_ns.load(Ordering::Relaxed));
    Some(count as isize)
}

/// Free bytes in the ring.
fn ring_room(shared: &Shared) -> usize {
    PORT_TX_RING.saturating_sub(usize::try_from(shared.port_tx_ring_unread()).unwrap_or(usize::MAX))
}
