//! The sensor server's ledger: where the server listens (how the shim knows which connections
//! to follow) and the counts of request and response bytes on each connection. Handed to the
//! sensor server, which knows nothing else of virtual time; time waits until climbsim has read
//! every request byte the shim counted, and a thread waiting on a connection is let go once its
//! response is there.

use std::sync::Arc;
use std::sync::atomic::Ordering;

use super::abi::{self, Shared};
use super::block::Block;

/// The sensor connections' ledger (see the module doc).
pub struct SensorLedger {
    block: Arc<Block>,
}

impl SensorLedger {
    pub(super) fn new(block: Arc<Block>) -> Self {
        Self { block }
    }

    fn shared(&self) -> &Shared {
        self.block.shared()
    }

    /// The sensor server controllers connect to: connections to it are followed.
    pub fn attach_server(&self, address: std::net::SocketAddrV4) {
        let header = &self.shared().header;
        header.sensor_ip.store(u32::from_ne_bytes(address.ip().octets()), Ordering::Relaxed);
        header.sensor_port.store(u32::from(address.port()), Ordering::Release);
    }

    /// The followed connection whose controller end is `client_port`, if any.
    fn conn(&self, client_port: u16) -> Option<&abi::Conn> {
        self.shared().live_conns().iter().find(|c| c.client_port.load(Ordering::Acquire) == u32::from(client_port))
    }

    /// The sensor server has read (and, a request being whole, answered) `bytes` more from
    /// the connection from `client_port`.
    pub fn request_read(&self, client_port: u16, bytes: usize) {
        if let Some(conn) = self.conn(client_port) {
            conn.read.fetch_add(bytes as u64, Ordering::AcqRel);
        }
    }

    /// The sensor server wrote `bytes` of response to `client_port` (`closed`: and then closed
    /// its end, which the controller reads as one more "byte", the end of the stream).
    pub fn response_written(&self, client_port: u16, bytes: usize, closed: bool) {
        if let Some(conn) = self.conn(client_port) {
            conn.resp_written.fetch_add(bytes as u64 + u64::from(closed), Ordering::AcqRel);
        }
    }

    /// A response waits on one of the connections the thread in slot `slot` waits on.
    pub(super) fn response_waiting(&self, slot: usize) -> bool {
        self.shared().response_waiting_for(slot)
    }

    /// Whether request bytes a controller sent wait for climbsim (by the shim's count).
    pub(super) fn unread_by_climbsim(&self) -> bool {
        self.shared().requests_unread()
    }
}
