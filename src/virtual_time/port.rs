//! The servo port as the scheduler holds it: its device (how the shim knows the controller's
//! descriptor for it) and the count of the controller's bytes climbsim has read (time waits
//! until it has read all the shim counted).

use std::os::fd::RawFd;
use std::sync::atomic::Ordering;

use super::{PortFds, VirtualTime, lock};

impl VirtualTime {
    /// The servo port the controller opens: its writes are counted, its reads waited for.
    pub fn attach_port(&self, master: RawFd, slave: RawFd) {
        let mut stat: libc::stat = unsafe { std::mem::zeroed() };
        // SAFETY: fstat of climbsim's own descriptor into a valid struct.
        if unsafe { libc::fstat(slave, &mut stat) } == 0 {
            self.shared().header.port_rdev.store(stat.st_rdev, Ordering::Release);
        }
        *lock(&self.port) = Some(PortFds { master, slave });
    }

    /// climbsim has read `bytes` more from the port (and so time-stamped them).
    pub fn port_read(&self, bytes: usize) {
        self.shared().header.port_tx_read.fetch_add(bytes as u64, Ordering::AcqRel);
    }
}
