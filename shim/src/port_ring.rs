//! The controller's writes to the servo port, into the block's ring (`Shared::port_tx_ring`)
//! instead of the pty. Through the pty, each request woke the kernel's pty worker, and climbsim
//! waited with the world stopped until it had handed the bytes over; a controller's Sync Write
//! is what the world waits for at the end of every period. From the ring climbsim takes them
//! at once. What this does not see (stdio's writes, a process without the shim) still goes
//! through the pty, which climbsim reads too, as before.
//!
//! One writer at a time: the thread has its turn (its first followed call claims it), and
//! signals are held while it copies and publishes, so that a handler that writes the port (a
//! SIGTERM or SIGALRM handler's torque-off) cannot take the same offsets. climbsim counts the
//! writers in flight (`Header::port.tx_ring_writers`): at the run's end it waits for them
//! before it takes what is left for the clean-up's servos.

use core::ffi::{c_int, c_long};
use core::sync::atomic::Ordering;

use crate::abi::{PORT_TX_RING, Parked, Shared, Wait, call, mode};
use crate::native;
use crate::schedule::park::{charge, note_call, park};
use crate::schedule::slot::my_slot;
use crate::sys::{iovec, nr};
use crate::time::sim_now;

/// Write `parts` (a write's buffer, or a writev's) to the port `fd` through the ring: the bytes
/// written (or -1 with EAGAIN), or `None` for the kernel (the run has ended). A blocking write
/// waits for room until all of it is in, as a terminal's does; a non-blocking one takes what
/// fits after one yield to climbsim, else EAGAIN.
pub(crate) fn write(shared: &'static Shared, fd: c_int, parts: &[iovec]) -> Option<isize> {
    let wanted: usize = parts.iter().map(|part| part.iov_len).fold(0, usize::saturating_add);
    if wanted == 0 {
        return None;
    }
    // The turn first (a thread the shim has not seen yet claims its slot and waits for it).
    note_call(shared, call::WRITE);
    let header = &shared.header;
    let mut writer = Writer::enter(shared)?;
    let mut written = 0;
    let mut blocking = None;
    loop {
        let room = ring_room(shared);
        if room > 0 {
            let count = (wanted - written).min(room);
            copy_in(shared, parts, written, count);
            header.port.tx_total.fetch_add(count as u64, Ordering::AcqRel);
            written += count;
        }
        // SAFETY: fcntl F_GETFL on the caller's descriptor.
        let is_blocking = *blocking.get_or_insert_with(|| unsafe { crate::sys::fcntl(fd, crate::sys::F_GETFL) } & crate::sys::O_NONBLOCK == 0);
        if written == wanted || (written > 0 && !is_blocking) {
            break;
        }
        if room == 0 && !is_blocking && writer.yielded {
            charge(shared, header.clock.syscall_ns.load(Ordering::Relaxed));
            crate::epoll::port_was_full(shared);
            crate::sys::set_errno(crate::sys::EAGAIN);
            return Some(-1);
        }
        // A controller that wrote a whole ring without waiting once: climbsim takes the bytes
        // when every thread is parked, so this one yields until it has. (Through the pty, a
        // write larger than the terminal's buffer blocked in the kernel, out of climbsim's
        // reach: the run failed.)
        if !writer.yield_to_climbsim() {
            // The run ended, or the thread cannot park: the rest goes to the kernel.
            return if written > 0 { Some(written as isize) } else { None };
        }
    }
    charge(shared, header.clock.syscall_ns.load(Ordering::Relaxed));
    Some(written as isize)
}

/// Copy `count` bytes of `parts`, from byte `skip` on, to the ring's end, and publish them.
fn copy_in(shared: &Shared, parts: &[iovec], skip: usize, count: usize) {
    let _held = SignalsHeld::new();
    let header = &shared.header;
    let start = header.port.tx_ring_written.load(Ordering::Acquire);
    let (mut offset, mut skip, mut left) = (start, skip, count);
    for part in parts {
        if left == 0 {
            break;
        }
        if skip >= part.iov_len {
            skip -= part.iov_len;
            continue;
        }
        let take = (part.iov_len - skip).min(left);
        // SAFETY: the caller's buffer, valid for `iov_len` bytes (write's contract); `skip +
        // take` stays within it.
        let bytes = unsafe { core::slice::from_raw_parts(part.iov_base.cast::<u8>().add(skip), take) };
        for &byte in bytes {
            shared.port_tx_ring_at(offset).store(byte, Ordering::Relaxed);
            offset = offset.wrapping_add(1);
        }
        skip = 0;
        left -= take;
    }
    // Published before the stream's total grows: climbsim, seeing it, finds the bytes here.
    header.port.tx_ring_written.store(start.wrapping_add(count as u64), Ordering::Release);
}

/// Free bytes in the ring.
fn ring_room(shared: &Shared) -> usize {
    PORT_TX_RING.saturating_sub(usize::try_from(shared.port_tx_ring_unread()).unwrap_or(usize::MAX))
}

/// A writer in flight (`Header::port.tx_ring_writers`), entered only while the run is on.
struct Writer {
    shared: &'static Shared,
    /// Whether it has yielded to climbsim (so that climbsim took what the ring held).
    yielded: bool,
}

impl Writer {
    fn enter(shared: &'static Shared) -> Option<Self> {
        let header = &shared.header;
        header.port.tx_ring_writers.fetch_add(1, Ordering::SeqCst);
        // Counted before the look: climbsim sets ENDING, then waits for the count to fall.
        if header.mode.load(Ordering::SeqCst) != mode::VIRTUAL {
            header.port.tx_ring_writers.fetch_sub(1, Ordering::SeqCst);
            return None;
        }
        Some(Self { shared, yielded: false })
    }

    /// Park until climbsim lets this thread go again (it takes the ring's bytes first); whether
    /// the run goes on.
    fn yield_to_climbsim(&mut self) -> bool {
        if my_slot().is_none() {
            return false;
        }
        park(self.shared, Parked::Yielded, sim_now(self.shared), Wait::Time);
        self.yielded = true;
        self.shared.header.mode.load(Ordering::SeqCst) == mode::VIRTUAL && crate::schedule::block::active().is_some()
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        self.shared.header.port.tx_ring_writers.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Every signal but the synchronous faults (and SIGSYS, which the shim's own trap needs) held
/// for the guard's life.
struct SignalsHeld(u64);

impl SignalsHeld {
    fn new() -> Self {
        const SIG_BLOCK: c_long = 0;
        let faults = [4u32, 5, 7, 8, 11, 31].iter().fold(0u64, |mask, signo| mask | 1 << (signo - 1));
        let hold: u64 = !faults;
        let mut before = 0u64;
        native::call4(nr::RT_SIGPROCMASK, SIG_BLOCK, &hold as *const u64 as c_long, &mut before as *mut u64 as c_long, 8);
        Self(before)
    }
}

impl Drop for SignalsHeld {
    fn drop(&mut self) {
        const SIG_SETMASK: c_long = 2;
        native::call4(nr::RT_SIGPROCMASK, SIG_SETMASK, &self.0 as *const u64 as c_long, 0, 8);
    }
}
