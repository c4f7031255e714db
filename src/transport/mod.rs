//! Byte transports between a controller and the bus: a pseudo-terminal, TCP, an in-memory
//! duplex ([`memory`]), or CAN with ISO-TP ([`can`]). All of them run the same [`serve_stream`]
//! over any `AsyncRead + AsyncWrite`.

pub mod can;
pub mod memory;
mod pty;
mod tcp;

use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use thiserror::Error;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tracing::{debug, info_span, trace, warn, Instrument};

use crate::bus::{Bus, Timing, TraceWriter, Transaction};
use crate::protocol::{DEFAULT_MAX_LEN, Decoder, FrameError, RawPacket};

pub use pty::{PortStream, PtyError, PtyLine, VirtualPort};
pub use tcp::{TcpServer, parse_tcp_addr};

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
}

/// The emulator's monotonic time base: every timestamp is a `Duration` since `origin`.
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    origin: Instant,
}

impl Default for Clock {
    fn default() -> Self {
        Self { origin: Instant::now() }
    }
}

impl Clock {
    pub fn now(&self) -> Duration {
        self.origin.elapsed()
    }
    pub fn instant(&self, at: Duration) -> Instant {
        self.origin + at
    }
}

/// The bus and what every transport shares with it.
pub struct BusHandle {
    bus: Mutex<Bus>,
    trace: Mutex<Option<TraceWriter>>,
    clock: Clock,
}

impl BusHandle {
    pub fn new(bus: Bus, trace: Option<TraceWriter>) -> Arc<Self> {
        Arc::new(Self { bus: Mutex::new(bus), trace: Mutex::new(trace), clock: Clock::default() })
    }

    pub fn clock(&self) -> Clock {
        self.clock
    }

    /// Run `f` with the bus locked. A panic elsewhere never leaves the bus unusable: the state is
    /// plain data, so a poisoned lock is taken over.
    pub fn with_bus<R>(&self, f: impl FnOnce(&mut Bus) -> R) -> R {
        let mut bus = self.bus.lock().unwrap_or_else(PoisonError::into_inner);
        f(&mut bus)
    }

    fn handle(&self, packet: RawPacket, received_at: Duration, line_baud: Option<u32>) -> Transaction {
        let transaction = self.with_bus(|bus| bus.handle(packet, received_at, line_baud));
        let mut trace = self.trace.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(writer) = trace.as_mut()
            && let Err(error) = writer.record(&transaction)
        {
            warn!(%error, "bus trace write failed; tracing stopped");
            *trace = None;
        }
        transaction
    }
}

/// What a transport knows about the line settings the controller chose.
pub trait LineSettings: Send + Sync {
    /// The baud the controller's port is set to, if the transport has such a thing.
    fn baud(&self) -> Option<u32>;
}

/// A transport without a baud (TCP, in-memory): every servo hears every packet.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoLine;

impl LineSettings for NoLine {
    fn baud(&self) -> Option<u32> {
        None
    }
}

/// Sleep until `deadline` with microsecond precision: the timer wheel gets us close (it has 1 ms
/// resolution), a spin finishes the job.
pub async fn sleep_until_precise(deadline: Instant) {
    const SPIN_MARGIN: Duration = Duration::from_micros(1500);
    let now = Instant::now();
    if deadline > now + SPIN_MARGIN {
        tokio::time::sleep_until((deadline - SPIN_MARGIN).into()).await;
    }
    while Instant::now() < deadline {
        std::hint::spin_loop();
    }
}

/// Serve one controller connection until it closes: decode instructions, hand them to the bus,
/// write the replies when the wire model says they have arrived.
pub async fn serve_stream<S>(mut stream: S, handle: Arc<BusHandle>, line: &dyn LineSettings) -> Result<(), TransportError>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let (gap, timing) = handle.with_bus(|bus| (bus.inter_byte_timeout(), bus.timing()));
    let mut decoder = Decoder::new(gap, DEFAULT_MAX_LEN);
    let clock = handle.clock();
    let mut buf = vec![0u8; 4096];
    loop {
        // A partial packet waits for at most the inter-byte gap: if the line stays quiet that
        // long, drop it (and find any packet that was hidden behind a false header).
        let read = if decoder.pending() > 0 {
            tokio::time::timeout(gap, stream.read(&mut buf)).await.ok()
        } else {
            Some(stream.read(&mut buf).await)
        };
        let now = clock.now();
        let results = match read {
            None => decoder.flush(),
            Some(read) => match read? {
                0 => return Ok(()),
                n => decoder.push(now, &buf[..n]),
            },
        };
        for result in results {
            match result {
                Ok(packet) => {
                    let span = info_span!("packet", id = packet.id, instruction = packet.instruction);
                    let transaction = span.in_scope(|| handle.handle(packet, now, line.baud()));
                    write_replies(&mut stream, &transaction, timing, clock).instrument(span).await?;
                }
                // A bad CRC gets no reply (no error 0x03): ROBOTIS's own slave code drops such
                // packets; unverified on XM firmware (reference §7), listed in the README.
                Err(error) => log_frame_error(&error),
            }
        }
    }
}

async fn write_replies<S: AsyncWrite + Unpin>(stream: &mut S, transaction: &Transaction, timing: Timing, clock: Clock) -> std::io::Result<()> {
    for reply in &transaction.replies {
        if timing == Timing::Wire {
            sleep_until_precise(clock.instant(reply.end)).await;
        }
        stream.write_all(&reply.bytes).await?;
        trace!(from = ?reply.from, bytes = reply.bytes.len(), "reply written");
    }
    stream.flush().await
}

fn log_frame_error(error: &FrameError) {
    match error {
        FrameError::Garbage(_) => trace!(%error, "framing"),
        _ => debug!(%error, "framing"),
    }
}
