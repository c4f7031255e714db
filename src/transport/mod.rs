//! Byte transports between a controller and the bus: a pseudo-terminal, TCP, an in-memory
//! duplex ([`memory`]), or CAN with ISO-TP ([`can`]). All of them run the same [`serve_stream`]
//! over any `AsyncRead + AsyncWrite`.

pub mod adapter;
mod busy_poll;
pub mod can;
mod echo;
mod handle;
pub mod latency;
pub mod memory;
mod pty;
pub mod rs485;
mod serial;
mod session;
pub mod stats;
mod tcp;

use std::time::Duration;

use thiserror::Error;

pub use adapter::{Adapter, AdapterModel};
pub use echo::{Echo, EchoFilter};
pub use handle::{BusHandle, Clock};
pub use pty::{PortStream, PtyError, PtyLine, VirtualPort, VirtualTimeStream};
pub use serial::{DeviceLine, DeviceSettings, DeviceStream, SerialDevice, SerialError, majority_baud};
pub use session::{serve_stream, serve_stream_through, sleep_until_precise};
pub use stats::{Answered, LineStats, LogHistogram, LoopKey, MasterTimeouts, PhysicsPace, ReportExtras, TimingReport};
pub use tcp::{TCP_INTER_BYTE_TIMEOUT, TcpLine, TcpServer, connect_forever, parse_tcp_addr, parse_tcp_server_addr};

#[derive(Debug, Error)]
pub enum TransportError {
    #[error(transparent)]
    Pty(#[from] PtyError),
    #[error("TCP: {0}")]
    Tcp(std::io::Error),
    #[error("bus I/O: {0}")]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Can(#[from] can::CanError),
    #[error(transparent)]
    Serial(#[from] SerialError),
}

/// What a transport knows about the line settings the controller chose.
pub trait LineSettings: Send + Sync {
    /// The baud the controller's port is set to, if the transport has such a thing.
    fn baud(&self) -> Option<u32>;

    /// Bytes the controller has written that the emulator has not read yet, where the transport
    /// can tell without reading (a pty). Lets a spinning wait notice a request sent early.
    fn waiting_from_controller(&self) -> Option<usize> {
        None
    }

    /// Reply bytes delivered that the controller has not read yet (a pty can tell).
    fn unread_by_controller(&self) -> Option<usize> {
        None
    }

    /// Block the calling thread until the controller has written something or `timeout` has
    /// passed, on a precise timer: Some(true) if bytes are waiting. None: the transport cannot,
    /// and the caller waits on the runtime's timer instead.
    fn wait_for_controller(&self, _timeout: Duration) -> Option<bool> {
        None
    }

    /// The wire between the controller and this transport is real (a serial device): replies
    /// are written when they start, not when a modelled wire would have delivered them.
    fn physical_wire(&self) -> bool {
        false
    }

    /// The replies of one transaction may go out in one write when nothing has to be waited for
    /// between them: a plain byte stream (a pty). Not where a write is a message (CAN's ISO-TP
    /// stream sends each write as one message, one status packet each).
    fn batches_replies(&self) -> bool {
        false
    }

    /// How long a begun packet may wait for its next bytes before it is dropped; None: the
    /// servos' own inter-byte timeout (a wire with a baud).
    fn inter_byte_timeout(&self) -> Option<Duration> {
        None
    }

    /// Called after every read of the controller's bytes (a TCP line re-arms its quick ACKs).
    fn read_done(&self) {}

    /// A transaction changed some servo's baud (`(id, bps)` of every servo): a transport with a
    /// baud of its own follows.
    fn servo_bauds_changed(&self, _servos: &[(u8, Option<u32>)]) {}
}

/// Bytes queued for reading on `fd` (FIONREAD).
pub(crate) fn queued_bytes(fd: i32) -> Option<usize> {
    let mut pending: libc::c_int = 0;
    // SAFETY: FIONREAD writes one c_int through the pointer, which is valid for the call.
    let rc = unsafe { libc::ioctl(fd, libc::FIONREAD, &mut pending) };
    (rc == 0).then_some(pending.max(0) as usize)
}

/// Block until `fd` is readable or `timeout` has passed; whether it is readable. ppoll(2)
/// sleeps on a high-resolution timer (tens of µs late, not the 1 ms of tokio's timer wheel);
/// a transport's own thread has nothing else to do meanwhile.
pub(crate) fn ppoll_readable(fd: i32, timeout: Duration) -> bool {
    let mut fds = [libc::pollfd { fd, events: libc::POLLIN, revents: 0 }];
    let timeout = libc::timespec { tv_sec: timeout.as_secs() as libc::time_t, tv_nsec: libc::c_long::from(timeout.subsec_nanos() as i32) };
    // SAFETY: one valid pollfd for the call's duration, a valid timespec, no signal mask.
    let rc = unsafe { libc::ppoll(fds.as_mut_ptr(), 1, &timeout, std::ptr::null()) };
    rc > 0 && fds[0].revents & libc::POLLIN != 0
}

/// A transport without a baud (TCP, in-memory): every servo hears every packet.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoLine;

impl LineSettings for NoLine {
    fn baud(&self) -> Option<u32> {
        None
    }
}
