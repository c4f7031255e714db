//! The servo port's bytes from the controller: the shim copies what it sees written into the
//! block's ring (`abi::Shared::port_tx_ring`), the rest comes through the pty; climbsim counts
//! what it has read of both, and time waits until it has read all the shim counted.

use std::os::fd::RawFd;
use std::sync::atomic::Ordering;

use super::abi;
use super::{PortFds, VirtualTime, lock};

/// How long the run's end waits for writers into the ring that are under way.
const RING_WRITERS_FINISH_WITHIN: std::time::Duration = std::time::Duration::from_millis(100);

impl VirtualTime {
    /// The servo port the controller opens: its writes are counted, its reads waited for.
    pub fn attach_port(&self, master: RawFd, slave: RawFd) {
        let mut stat: libc::stat = unsafe { std::mem::zeroed() };
        // SAFETY: fstat of climbsim's own descriptor into a valid struct.
        if unsafe { libc::fstat(slave, &mut stat) } == 0 {
            self.shared().header.port.rdev.store(stat.st_rdev, Ordering::Release);
        }
        *lock(&self.port) = Some(PortFds { master, slave });
    }

    /// climbsim has read `bytes` more from the port (and so time-stamped them).
    pub fn port_read(&self, bytes: usize) {
        self.shared().header.port.tx_read.fetch_add(bytes as u64, Ordering::AcqRel);
    }

    /// Take what the controller wrote to the port through the block's ring (see
    /// `abi::Shared::port_tx_ring`) into `out`, counted as read; how many bytes (0: none is
    /// there, the pty may have some).
    pub fn take_port_ring(&self, out: &mut [u8]) -> usize {
        let shared = self.shared();
        let header = &shared.header;
        let start = header.port.tx_ring_read.load(Ordering::Acquire);
        // Never more than a ring's worth: the count is the shim's, which climbsim does not trust.
        let unread = shared.port_tx_ring_unread().min(abi::PORT_TX_RING as u64);
        let count = usize::try_from(unread).unwrap_or(usize::MAX).min(out.len());
        for (index, byte) in out[..count].iter_mut().enumerate() {
            *byte = shared.port_tx_ring_at(start.wrapping_add(index as u64)).load(Ordering::Relaxed);
        }
        header.port.tx_ring_read.store(start.wrapping_add(count as u64), Ordering::Release);
        self.port_read(count);
        count
    }

    /// Everything left in the port's ring once the run has ended (the shim writes to the pty
    /// then), counted as read. Writers already under way finish first (a few microseconds; at
    /// most [`RING_WRITERS_FINISH_WITHIN`], for one killed in its write).
    pub fn take_port_ring_rest(&self) -> Vec<u8> {
        let shared = self.shared();
        let since = std::time::Instant::now();
        while shared.header.port.tx_ring_writers.load(Ordering::SeqCst) != 0 && since.elapsed() < RING_WRITERS_FINISH_WITHIN {
            std::thread::yield_now();
        }
        let unread = shared.port_tx_ring_unread().min(abi::PORT_TX_RING as u64);
        let mut rest = vec![0; usize::try_from(unread).unwrap_or(abi::PORT_TX_RING)];
        let taken = self.take_port_ring(&mut rest);
        rest.truncate(taken);
        rest
    }
}
