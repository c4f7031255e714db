//! CAN transport: Dynamixel packets carried in ISO-TP messages ([`isotp`]) over classic CAN
//! frames, one CAN ID pair per bus (the controller sends on `request`, the bus answers on
//! `response`). One Dynamixel packet is one ISO-TP message in each direction.
//!
//! Frames come and go through a [`CanFrameIo`]: an in-memory pipe ([`frame_pipe`], always built)
//! or a SocketCAN socket ([`SocketCanPort`], with the `can` feature on Linux). [`IsoTpChannel`]
//! runs an ISO-TP endpoint over one; [`serve_can`] puts the bus behind a channel by running the
//! same [`serve_stream`] as every other transport over a message-preserving stream.

pub mod isotp;
mod message_stream;
#[cfg(all(feature = "can", target_os = "linux"))]
mod socket;

use std::collections::VecDeque;
use std::future::Future;
use std::sync::Arc;

use thiserror::Error;
use tokio::sync::mpsc;
use tracing::{Instrument, debug, info_span, trace, warn};

use super::{BusHandle, Clock, NoLine, TransportError, serve_stream};
use isotp::{Endpoint, Event, FrameData, IsoTpError};

#[cfg(all(feature = "can", target_os = "linux"))]
pub use socket::SocketCanPort;

#[derive(Debug, Error)]
pub enum CanError {
    #[error("CAN interface {iface}: {source}")]
    Open { iface: String, source: std::io::Error },
    #[error("CAN I/O: {0}")]
    Io(#[from] std::io::Error),
    #[error("`{0}` is not a CAN ID (0x000-0x7FF standard, 0x800-0x1FFFFFFF extended)")]
    BadId(String),
    #[error("`{0}` is not REQUEST,RESPONSE (two CAN IDs, e.g. 0x7E0,0x7E8)")]
    BadIdPair(String),
    #[error("the request and response CAN IDs must differ")]
    SameIds,
}

/// An 11-bit standard or 29-bit extended CAN identifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CanId {
    Standard(u16),
    Extended(u32),
}

impl CanId {
    pub const STANDARD_MAX: u32 = 0x7FF;
    pub const EXTENDED_MAX: u32 = 0x1FFF_FFFF;

    /// Values up to 0x7FF are standard IDs, larger ones up to 0x1FFFFFFF extended.
    pub fn from_raw(raw: u32) -> Option<Self> {
        match raw {
            0..=Self::STANDARD_MAX => Some(Self::Standard(raw as u16)),
            0x800..=Self::EXTENDED_MAX => Some(Self::Extended(raw)),
            _ => None,
        }
    }

    pub fn raw(self) -> u32 {
        match self {
            Self::Standard(id) => u32::from(id),
            Self::Extended(id) => id,
        }
    }

    /// Hex (`0x7E0`) or decimal.
    pub fn parse(text: &str) -> Result<Self, CanError> {
        let text = text.trim();
        let raw = match text.strip_prefix("0x").or_else(|| text.strip_prefix("0X")) {
            Some(hex) => u32::from_str_radix(hex, 16),
            None => text.parse::<u32>(),
        };
        raw.ok().and_then(Self::from_raw).ok_or_else(|| CanError::BadId(text.to_owned()))
    }
}

impl std::fmt::Display for CanId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Standard(id) => write!(f, "{id:#05X}"),
            Self::Extended(id) => write!(f, "{id:#010X}"),
        }
    }
}

/// The CAN ID pair of one bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanIds {
    /// Controller to bus (instructions).
    pub request: CanId,
    /// Bus to controller (status packets).
    pub response: CanId,
}

impl Default for CanIds {
    /// 0x7E0/0x7E8: the conventional ISO-TP request/response pair (physical addressing of the
    /// first ECU in ISO 15765-4), which ISO-TP tools (`isotpsend`, python-can-isotp) know.
    fn default() -> Self {
        Self { request: CanId::Standard(0x7E0), response: CanId::Standard(0x7E8) }
    }
}

impl CanIds {
    /// `REQUEST,RESPONSE`, e.g. `0x7E0,0x7E8`.
    pub fn parse(text: &str) -> Result<Self, CanError> {
        let (request, response) = text.split_once(',').ok_or_else(|| CanError::BadIdPair(text.to_owned()))?;
        let ids = Self { request: CanId::parse(request)?, response: CanId::parse(response)? };
        if ids.request == ids.response {
            return Err(CanError::SameIds);
        }
        Ok(ids)
    }
}

/// A classic CAN data frame: an ID and 0 to 8 data bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CanFrame {
    pub id: CanId,
    pub data: FrameData,
}

impl CanFrame {
    /// `None` if `data` is longer than 8 bytes.
    pub fn new(id: CanId, data: &[u8]) -> Option<Self> {
        Some(Self { id, data: FrameData::new(data)? })
    }
}

/// Sends and receives classic CAN frames. Both futures must be cancel-safe: a cancelled `recv`
/// loses no frame, and a cancelled `send` either sent the frame or did not.
pub trait CanFrameIo {
    fn send(&mut self, frame: CanFrame) -> impl Future<Output = std::io::Result<()>> + Send;
    /// The next frame; `None` once the other end has gone.
    fn recv(&mut self) -> impl Future<Output = std::io::Result<Option<CanFrame>>> + Send;
}

/// One end of an in-memory CAN frame pipe: what one end sends, the other receives.
#[derive(Debug)]
pub struct MemoryCanPort {
    tx: mpsc::Sender<CanFrame>,
    rx: mpsc::Receiver<CanFrame>,
}

/// Two connected [`MemoryCanPort`]s, each direction buffering `capacity` frames.
pub fn frame_pipe(capacity: usize) -> (MemoryCanPort, MemoryCanPort) {
    let (a_tx, b_rx) = mpsc::channel(capacity);
    let (b_tx, a_rx) = mpsc::channel(capacity);
    (MemoryCanPort { tx: a_tx, rx: a_rx }, MemoryCanPort { tx: b_tx, rx: b_rx })
}

impl CanFrameIo for MemoryCanPort {
    async fn send(&mut self, frame: CanFrame) -> std::io::Result<()> {
        self.tx.send(frame).await.map_err(|_| std::io::Error::new(std::io::ErrorKind::BrokenPipe, "the other end of the CAN pipe is gone"))
    }

    async fn recv(&mut self) -> std::io::Result<Option<CanFrame>> {
        Ok(self.rx.recv().await)
    }
}

/// An ISO-TP endpoint on a [`CanFrameIo`]: it transmits on `tx_id` and listens to `rx_id`;
/// frames with other IDs are ignored. Time comes from its own monotonic clock.
pub struct IsoTpChannel<F> {
    io: F,
    tx_id: CanId,
    rx_id: CanId,
    endpoint: Endpoint,
    clock: Clock,
    /// A frame taken from the endpoint but not yet sent (a `send` was cancelled).
    unsent: Option<CanFrame>,
    received: VecDeque<Vec<u8>>,
}

impl<F: CanFrameIo> IsoTpChannel<F> {
    pub fn new(io: F, tx_id: CanId, rx_id: CanId, config: isotp::Config) -> Self {
        Self { io, tx_id, rx_id, endpoint: Endpoint::new(config), clock: Clock::default(), unsent: None, received: VecDeque::new() }
    }

    /// The bus's end: answers on `ids.response`, listens to `ids.request`.
    pub fn bus_side(io: F, ids: CanIds, config: isotp::Config) -> Self {
        Self::new(io, ids.response, ids.request, config)
    }

    /// A controller's end: sends on `ids.request`, listens to `ids.response`.
    pub fn controller_side(io: F, ids: CanIds, config: isotp::Config) -> Self {
        Self::new(io, ids.request, ids.response, config)
    }

    /// Queue a message; it goes out while [`recv`](Self::recv) or [`send`](Self::send) runs.
    pub fn queue(&mut self, message: Vec<u8>) -> Result<(), IsoTpError> {
        self.endpoint.send(message)
    }

    /// Queue a message and run the link until everything queued has been sent or given up on
    /// (given-up messages are logged). Messages that arrive meanwhile are kept for `recv`.
    pub async fn send(&mut self, message: Vec<u8>) -> Result<(), CanError> {
        self.endpoint.send(message).map_err(|e| CanError::Io(std::io::Error::new(std::io::ErrorKind::InvalidInput, e)))?;
        while !self.endpoint.tx_idle() || self.unsent.is_some() {
            if !self.step().await? {
                return Err(CanError::Io(std::io::ErrorKind::BrokenPipe.into()));
            }
        }
        Ok(())
    }

    /// Run the link until a message arrives; `None` once the frame I/O has closed. Cancel-safe.
    pub async fn recv(&mut self) -> Result<Option<Vec<u8>>, CanError> {
        loop {
            if let Some(message) = self.received.pop_front() {
                return Ok(Some(message));
            }
            if !self.step().await? {
                return Ok(None);
            }
        }
    }

    /// Apply timeouts, send what is due, then wait for one frame or the next deadline. False
    /// once the frame I/O has closed. Every await is cancel-safe: state lives in `self`.
    async fn step(&mut self) -> Result<bool, CanError> {
        let now = self.clock.now();
        self.endpoint.handle_timeout(now);
        if self.unsent.is_none() {
            self.unsent = self.endpoint.poll_frame(now).map(|data| CanFrame { id: self.tx_id, data });
        }
        self.drain_events();
        if let Some(frame) = self.unsent {
            let sent = self.io.send(frame).await;
            self.unsent = None;
            if let Err(error) = sent {
                // A full transmit queue or a bus-off: this message is lost, the next may pass.
                warn!(%error, id = %frame.id, "CAN frame not sent; ISO-TP message dropped");
                self.endpoint.abort_tx();
                if error.kind() == std::io::ErrorKind::BrokenPipe {
                    return Ok(false);
                }
            }
            return Ok(true);
        }
        if !self.received.is_empty() {
            return Ok(true);
        }
        let deadline = self.endpoint.poll_deadline().map(|at| self.clock.instant(at));
        tokio::select! {
            frame = self.io.recv() => match frame? {
                None => return Ok(false),
                Some(frame) if frame.id == self.rx_id => {
                    trace!(id = %frame.id, data = ?frame.data, "CAN frame in");
                    self.endpoint.on_frame(self.clock.now(), frame.data.as_slice());
                    self.drain_events();
                }
                Some(frame) => trace!(id = %frame.id, "CAN frame for another ID ignored"),
            },
            () = sleep_until(deadline), if deadline.is_some() => {}
        }
        Ok(true)
    }

    fn drain_events(&mut self) {
        while let Some(event) = self.endpoint.poll_event() {
            match event {
                Event::Received(message) => {
                    trace!(bytes = message.len(), "ISO-TP message in");
                    self.received.push_back(message);
                }
                Event::Sent(bytes) => trace!(bytes, "ISO-TP message out"),
                // Malformed or stray frames: dropped, the next first or single frame resyncs.
                Event::Error(error) => debug!(%error, "ISO-TP"),
            }
        }
    }
}

async fn sleep_until(deadline: Option<std::time::Instant>) {
    match deadline {
        Some(at) => tokio::time::sleep_until(at.into()).await,
        None => std::future::pending().await,
    }
}

/// Requests received but not yet taken by the bus; more are dropped (and logged).
const INBOUND_CAPACITY: usize = 64;

/// Serve the bus on a CAN link until the frame I/O closes: every ISO-TP message on
/// `ids.request` goes to the bus as bytes, every reply packet goes back as one ISO-TP message on
/// `ids.response`.
pub async fn serve_can<F: CanFrameIo>(io: F, ids: CanIds, config: isotp::Config, handle: Arc<BusHandle>) -> Result<(), TransportError> {
    let mut channel = IsoTpChannel::bus_side(io, ids, config);
    let (stream, mut ends) = message_stream::pair(INBOUND_CAPACITY);
    let session = serve_stream(stream, handle, &NoLine);
    let link = async move {
        loop {
            tokio::select! {
                message = channel.recv() => match message? {
                    None => return Ok::<_, TransportError>(()),
                    Some(message) => match ends.to_bus.try_send(message) {
                        Ok(()) => {}
                        Err(mpsc::error::TrySendError::Full(_)) => warn!("CAN: {INBOUND_CAPACITY} requests wait for the bus; one dropped"),
                        Err(mpsc::error::TrySendError::Closed(_)) => return Ok(()),
                    },
                },
                reply = ends.from_bus.recv() => match reply {
                    None => return Ok(()),
                    Some(reply) => {
                        if let Err(error) = channel.queue(reply) {
                            warn!(%error, "CAN: reply not sent");
                        }
                    }
                },
            }
        }
    };
    let span = info_span!("can", request = %ids.request, response = %ids.response);
    // When the link ends its half of the stream is dropped and the session reads end-of-file.
    async { tokio::try_join!(session, link).map(|_| ()) }.instrument(span).await
}
