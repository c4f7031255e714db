//! ISO-TP (ISO 15765-2) segmentation for classic CAN, sans-IO: an [`Endpoint`] turns messages of
//! up to 4095 bytes into CAN frame payloads and back, with flow control. It reads no clock and
//! does no I/O: the caller passes the time (`now`, any monotonic `Duration`) into every call,
//! feeds it received frame payloads ([`Endpoint::on_frame`]), takes the payloads it wants sent
//! ([`Endpoint::poll_frame`]), wakes it at [`Endpoint::poll_deadline`] and collects what happened
//! with [`Endpoint::poll_event`]. CAN IDs are the caller's business (normal addressing: the whole
//! payload is ISO-TP).
//!
//! One idea in one file (over 500 lines): the endpoint's receiver and sender share its deadlines
//! and events, and each one's flow control goes out or comes in through the other.
//!
//! Both directions run independently (full duplex), one message at a time each way: further
//! messages to send wait in a queue. Malformed or unexpected frames are reported as
//! [`Event::Error`] and otherwise ignored or end the reception they broke, as §9.8.3 of the
//! standard prescribes; a new first or single frame always starts afresh.
//!
//! Timeouts modelled: N_Bs (the sender waits for a flow control frame) and N_Cr (the receiver
//! waits for the next consecutive frame). N_As/N_Ar (the CAN controller's transmit confirmation)
//! are not: the caller's frame I/O has no confirmations.

use std::collections::VecDeque;
use std::time::Duration;

use thiserror::Error;

/// Classic CAN: at most 8 data bytes per frame.
pub const CAN_MAX_DLEN: usize = 8;
/// Largest message the 12-bit length of a classic first frame can announce.
pub const MAX_MESSAGE_LEN: usize = 4095;
/// Largest message a single frame carries (classic CAN, normal addressing).
pub const SINGLE_FRAME_MAX: usize = 7;
/// Data bytes in a first frame.
const FIRST_FRAME_DATA: usize = 6;
/// Data bytes in a consecutive frame.
const CONSECUTIVE_FRAME_DATA: usize = 7;

const PCI_SINGLE: u8 = 0x0;
const PCI_FIRST: u8 = 0x1;
const PCI_CONSECUTIVE: u8 = 0x2;
const PCI_FLOW_CONTROL: u8 = 0x3;

/// The payload of one classic CAN frame: 0 to 8 bytes.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct FrameData {
    len: u8,
    bytes: [u8; CAN_MAX_DLEN],
}

impl FrameData {
    /// `None` if `data` is longer than 8 bytes.
    pub fn new(data: &[u8]) -> Option<Self> {
        let mut bytes = [0u8; CAN_MAX_DLEN];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(Self { len: data.len() as u8, bytes })
    }

    pub fn as_slice(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len)]
    }

    /// `data` followed by `padding` up to 8 bytes, or just `data` without padding.
    fn padded(data: &[u8], padding: Option<u8>) -> Self {
        debug_assert!(data.len() <= CAN_MAX_DLEN);
        let len = data.len().min(CAN_MAX_DLEN);
        let mut bytes = [padding.unwrap_or(0); CAN_MAX_DLEN];
        bytes[..len].copy_from_slice(&data[..len]);
        let len = if padding.is_some() { CAN_MAX_DLEN } else { len };
        Self { len: len as u8, bytes }
    }
}

impl std::fmt::Debug for FrameData {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "[")?;
        for (i, b) in self.as_slice().iter().enumerate() {
            if i > 0 {
                write!(f, " ")?;
            }
            write!(f, "{b:02X}")?;
        }
        write!(f, "]")
    }
}

/// Separation time between consecutive frames, in its one-byte flow control encoding:
/// 0x00–0x7F are 0–127 ms, 0xF1–0xF9 are 100–900 µs; every other value is reserved and a sender
/// must treat it as 0x7F (127 ms).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct StMin(u8);

impl StMin {
    /// No separation: consecutive frames back to back.
    pub const ZERO: Self = Self(0);

    pub const fn from_raw(raw: u8) -> Self {
        Self(raw)
    }

    pub const fn raw(self) -> u8 {
        self.0
    }

    /// The encoding of `duration`, if it has one exactly: whole milliseconds up to 127 ms, or
    /// 100–900 µs in steps of 100 µs.
    pub fn from_duration(duration: Duration) -> Option<Self> {
        let micros = duration.as_micros();
        if micros.is_multiple_of(1000) && micros / 1000 <= 0x7F {
            return Some(Self((micros / 1000) as u8));
        }
        if micros.is_multiple_of(100) && (100..=900).contains(&micros) {
            return Some(Self(0xF0 + (micros / 100) as u8));
        }
        None
    }

    /// The separation a sender keeps.
    pub fn duration(self) -> Duration {
        match self.0 {
            ms @ 0x00..=0x7F => Duration::from_millis(u64::from(ms)),
            hundreds @ 0xF1..=0xF9 => Duration::from_micros(100 * u64::from(hundreds - 0xF0)),
            _ => Duration::from_millis(0x7F),
        }
    }
}

/// Flow status of a flow control frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlowStatus {
    ContinueToSend,
    Wait,
    Overflow,
}

impl FlowStatus {
    fn code(self) -> u8 {
        match self {
            Self::ContinueToSend => 0,
            Self::Wait => 1,
            Self::Overflow => 2,
        }
    }
}

/// What an endpoint does and tolerates.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Config {
    /// Pad every frame sent to 8 bytes with this byte; `None` sends the shortest frames.
    /// Received frames are accepted either way if they hold the bytes they announce.
    pub padding: Option<u8>,
    /// Block size sent in our flow control: consecutive frames the peer may send before it waits
    /// for the next flow control frame (0: all of them).
    pub block_size: u8,
    /// Separation time sent in our flow control.
    pub st_min: StMin,
    /// N_Bs: how long we wait for the peer's flow control before giving up on a message.
    pub n_bs: Duration,
    /// N_Cr: how long we wait for the peer's next consecutive frame before dropping a message.
    pub n_cr: Duration,
    /// WFTmax: flow control WAIT frames accepted in a row before giving up on a message.
    pub max_wait_frames: u8,
    /// Longest message we accept (at most [`MAX_MESSAGE_LEN`]); longer first frames get OVFLW.
    pub max_rx_len: usize,
    /// Messages waiting to be sent beyond which [`Endpoint::send`] refuses more.
    pub max_tx_queue: usize,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            padding: Some(0xCC),
            block_size: 0,
            st_min: StMin::ZERO,
            n_bs: Duration::from_millis(1000),
            n_cr: Duration::from_millis(1000),
            max_wait_frames: 10,
            max_rx_len: MAX_MESSAGE_LEN,
            max_tx_queue: 1024,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum IsoTpError {
    #[error("empty CAN frame")]
    EmptyFrame,
    #[error("unknown PCI type {0:#X}")]
    UnknownPci(u8),
    #[error("{kind} frame of {dlc} bytes is too short")]
    Truncated { kind: &'static str, dlc: usize },
    #[error("single frame announcing {len} bytes in a {dlc}-byte CAN frame")]
    BadSingleFrameLen { len: usize, dlc: usize },
    #[error("first frame announcing {0} bytes, which a single frame carries")]
    FirstFrameTooShort(u32),
    #[error("first frame with the 32-bit length escape announcing {0} bytes, which the 12-bit length covers")]
    NeedlessEscape(u32),
    #[error("first frame announcing {len} bytes, more than the {max} accepted: flow control OVFLW sent")]
    RxOverflow { len: u32, max: usize },
    #[error("reception of a {expected}-byte message ({received} received) interrupted by a new {by} frame")]
    RxInterrupted { expected: usize, received: usize, by: &'static str },
    #[error("consecutive frame without a first frame")]
    UnexpectedConsecutive,
    #[error("consecutive frame with sequence number {got}, expected {expected}: message dropped")]
    WrongSequence { expected: u8, got: u8 },
    #[error("no consecutive frame within N_Cr ({0:?}): {1}-byte message dropped")]
    RxTimeout(Duration, usize),
    #[error("flow control frame while not waiting for one")]
    UnexpectedFlowControl,
    #[error("flow control with invalid flow status {0:#X}: message not sent")]
    InvalidFlowStatus(u8),
    #[error("no flow control within N_Bs ({0:?}): message not sent")]
    TxTimeout(Duration),
    #[error("the receiver has no room for a {0}-byte message (flow control OVFLW)")]
    TxOverflow(usize),
    #[error("more than {0} flow control WAIT frames in a row: message not sent")]
    TxTooManyWaits(u8),
    #[error("a message of {0} bytes cannot be sent (1 to 4095)")]
    TxMessageLen(usize),
    #[error("{0} messages already wait to be sent")]
    TxQueueFull(usize),
}

/// What happened, in order: see [`Endpoint::poll_event`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// A complete message arrived.
    Received(Vec<u8>),
    /// The last frame of a message of this length was handed out by `poll_frame`.
    Sent(usize),
    /// A frame was malformed or unexpected, or a timeout struck; see [`IsoTpError`].
    Error(IsoTpError),
}

#[derive(Debug)]
enum Rx {
    Idle,
    Receiving { data: Vec<u8>, expected: usize, next_sn: u8, block_left: u8, deadline: Duration },
}

#[derive(Debug)]
enum Tx {
    Idle,
    /// A first frame or a block went out; the peer's flow control is due by `deadline`.
    AwaitFlowControl {
        message: Vec<u8>,
        offset: usize,
        next_sn: u8,
        deadline: Duration,
        waits: u8,
    },
    /// Consecutive frames go out, the next at `next_at`; `block_left` is `None` without a limit.
    Sending {
        message: Vec<u8>,
        offset: usize,
        next_sn: u8,
        block_left: Option<u8>,
        st_min: Duration,
        next_at: Duration,
    },
}

/// One end of an ISO-TP link; see the module documentation.
#[derive(Debug)]
pub struct Endpoint {
    config: Config,
    rx: Rx,
    tx: Tx,
    queue: VecDeque<Vec<u8>>,
    /// Flow control frames waiting to go out; they go before any data frame.
    control: VecDeque<FrameData>,
    events: VecDeque<Event>,
}

impl Endpoint {
    pub fn new(config: Config) -> Self {
        Self { config, rx: Rx::Idle, tx: Tx::Idle, queue: VecDeque::new(), control: VecDeque::new(), events: VecDeque::new() }
    }

    pub fn config(&self) -> &Config {
        &self.config
    }

    /// Queue `message` to be sent after those already queued.
    pub fn send(&mut self, message: Vec<u8>) -> Result<(), IsoTpError> {
        if message.is_empty() || message.len() > MAX_MESSAGE_LEN {
            return Err(IsoTpError::TxMessageLen(message.len()));
        }
        if self.queue.len() >= self.config.max_tx_queue {
            return Err(IsoTpError::TxQueueFull(self.queue.len()));
        }
        self.queue.push_back(message);
        Ok(())
    }

    /// True when nothing is being sent or waits to be sent.
    pub fn tx_idle(&self) -> bool {
        matches!(self.tx, Tx::Idle) && self.queue.is_empty() && self.control.is_empty()
    }

    /// Drop the message being sent (the caller could not put its frames on the bus).
    pub fn abort_tx(&mut self) {
        self.tx = Tx::Idle;
    }

    /// The next thing that happened, oldest first.
    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// The earliest time at which the endpoint wants [`Endpoint::poll_frame`] or
    /// [`Endpoint::handle_timeout`] called again, if it waits for anything.
    pub fn poll_deadline(&self) -> Option<Duration> {
        let rx = match &self.rx {
            Rx::Receiving { deadline, .. } => Some(*deadline),
            Rx::Idle => None,
        };
        let tx = match &self.tx {
            Tx::AwaitFlowControl { deadline, .. } => Some(*deadline),
            Tx::Sending { next_at, .. } => Some(*next_at),
            Tx::Idle => None,
        };
        [rx, tx].into_iter().flatten().min()
    }

    /// Apply the timeouts due at `now`.
    pub fn handle_timeout(&mut self, now: Duration) {
        if let Rx::Receiving { deadline, data, .. } = &self.rx
            && now >= *deadline
        {
            self.events.push_back(Event::Error(IsoTpError::RxTimeout(self.config.n_cr, data.len())));
            self.rx = Rx::Idle;
        }
        if let Tx::AwaitFlowControl { deadline, .. } = &self.tx
            && now >= *deadline
        {
            self.events.push_back(Event::Error(IsoTpError::TxTimeout(self.config.n_bs)));
            self.tx = Tx::Idle;
        }
    }

    /// The next frame payload to put on the bus at `now`, if any is due.
    pub fn poll_frame(&mut self, now: Duration) -> Option<FrameData> {
        if let Some(frame) = self.control.pop_front() {
            return Some(frame);
        }
        let padding = self.config.padding;
        match std::mem::replace(&mut self.tx, Tx::Idle) {
            Tx::Idle => {
                let message = self.queue.pop_front()?;
                if message.len() <= SINGLE_FRAME_MAX {
                    let mut data = [0u8; CAN_MAX_DLEN];
                    data[0] = (PCI_SINGLE << 4) | message.len() as u8;
                    data[1..=message.len()].copy_from_slice(&message);
                    self.events.push_back(Event::Sent(message.len()));
                    return Some(FrameData::padded(&data[..=message.len()], padding));
                }
                let len = message.len();
                let mut data = [0u8; CAN_MAX_DLEN];
                data[0] = (PCI_FIRST << 4) | ((len >> 8) as u8 & 0x0F);
                data[1] = len as u8;
                data[2..].copy_from_slice(&message[..FIRST_FRAME_DATA]);
                let deadline = now + self.config.n_bs;
                self.tx = Tx::AwaitFlowControl { message, offset: FIRST_FRAME_DATA, next_sn: 1, deadline, waits: 0 };
                Some(FrameData::padded(&data, padding))
            }
            waiting @ Tx::AwaitFlowControl { .. } => {
                self.tx = waiting;
                None
            }
            Tx::Sending { message, offset, next_sn, block_left, st_min, next_at } => {
                if now < next_at {
                    self.tx = Tx::Sending { message, offset, next_sn, block_left, st_min, next_at };
                    return None;
                }
                let end = (offset + CONSECUTIVE_FRAME_DATA).min(message.len());
                let mut data = [0u8; CAN_MAX_DLEN];
                data[0] = (PCI_CONSECUTIVE << 4) | next_sn;
                data[1..=end - offset].copy_from_slice(&message[offset..end]);
                let frame = FrameData::padded(&data[..=end - offset], padding);
                let next_sn = (next_sn + 1) & 0x0F;
                if end == message.len() {
                    self.events.push_back(Event::Sent(message.len()));
                } else if block_left == Some(1) {
                    let deadline = now + self.config.n_bs;
                    self.tx = Tx::AwaitFlowControl { message, offset: end, next_sn, deadline, waits: 0 };
                } else {
                    let block_left = block_left.map(|n| n - 1);
                    self.tx = Tx::Sending { message, offset: end, next_sn, block_left, st_min, next_at: now + st_min };
                }
                Some(frame)
            }
        }
    }

    /// A frame payload arrived (on the peer's CAN ID) at `now`.
    pub fn on_frame(&mut self, now: Duration, data: &[u8]) {
        let Some(&pci) = data.first() else {
            return self.error(IsoTpError::EmptyFrame);
        };
        match pci >> 4 {
            PCI_SINGLE => self.on_single(data),
            PCI_FIRST => self.on_first(now, data),
            PCI_CONSECUTIVE => self.on_consecutive(now, data),
            PCI_FLOW_CONTROL => self.on_flow_control(now, data),
            other => self.error(IsoTpError::UnknownPci(other)),
        }
    }

    fn error(&mut self, error: IsoTpError) {
        self.events.push_back(Event::Error(error));
    }

    /// A new single or first frame: whatever reception was under way is abandoned.
    fn interrupt_rx(&mut self, by: &'static str) {
        if let Rx::Receiving { data, expected, .. } = std::mem::replace(&mut self.rx, Rx::Idle) {
            self.error(IsoTpError::RxInterrupted { expected, received: data.len(), by });
        }
    }

    fn on_single(&mut self, data: &[u8]) {
        let len = usize::from(data[0] & 0x0F);
        // SF_DL 0 is the CAN FD escape; on classic CAN it, like a length the frame does not
        // hold, makes the frame invalid: ignored, and the reception under way goes on.
        if len == 0 || len > SINGLE_FRAME_MAX || len >= data.len() {
            return self.error(IsoTpError::BadSingleFrameLen { len, dlc: data.len() });
        }
        self.interrupt_rx("single");
        self.events.push_back(Event::Received(data[1..=len].to_vec()));
    }

    fn on_first(&mut self, now: Duration, data: &[u8]) {
        // A classic first frame fills the CAN frame.
        if data.len() < CAN_MAX_DLEN {
            return self.error(IsoTpError::Truncated { kind: "first", dlc: data.len() });
        }
        let short_len = (u32::from(data[0] & 0x0F) << 8) | u32::from(data[1]);
        let (len, payload) = if short_len == 0 {
            // Escape: a 32-bit length follows (ISO 15765-2:2016), meant for messages > 4095.
            (u32::from_be_bytes([data[2], data[3], data[4], data[5]]), &data[6..])
        } else {
            (short_len, &data[2..])
        };
        if short_len == 0 && len as usize <= MAX_MESSAGE_LEN {
            return self.error(IsoTpError::NeedlessEscape(len));
        }
        if len as usize <= SINGLE_FRAME_MAX {
            return self.error(IsoTpError::FirstFrameTooShort(len));
        }
        self.interrupt_rx("first");
        if len as usize > self.config.max_rx_len {
            self.queue_flow_control(FlowStatus::Overflow);
            return self.error(IsoTpError::RxOverflow { len, max: self.config.max_rx_len });
        }
        let expected = len as usize;
        let mut message = Vec::with_capacity(expected);
        message.extend_from_slice(payload);
        self.rx = Rx::Receiving { data: message, expected, next_sn: 1, block_left: self.config.block_size, deadline: now + self.config.n_cr };
        self.queue_flow_control(FlowStatus::ContinueToSend);
    }

    fn on_consecutive(&mut self, now: Duration, frame: &[u8]) {
        let Rx::Receiving { data, expected, next_sn, block_left, deadline } = &mut self.rx else {
            return self.error(IsoTpError::UnexpectedConsecutive);
        };
        let sn = frame[0] & 0x0F;
        if sn != *next_sn {
            let error = IsoTpError::WrongSequence { expected: *next_sn, got: sn };
            self.rx = Rx::Idle;
            return self.error(error);
        }
        let want = (*expected - data.len()).min(CONSECUTIVE_FRAME_DATA);
        if frame.len() < 1 + want {
            self.rx = Rx::Idle;
            return self.error(IsoTpError::Truncated { kind: "consecutive", dlc: frame.len() });
        }
        data.extend_from_slice(&frame[1..=want]);
        if data.len() == *expected {
            let message = std::mem::take(data);
            self.rx = Rx::Idle;
            self.events.push_back(Event::Received(message));
            return;
        }
        *next_sn = (sn + 1) & 0x0F;
        *deadline = now + self.config.n_cr;
        if self.config.block_size > 0 {
            *block_left -= 1;
            if *block_left == 0 {
                *block_left = self.config.block_size;
                self.queue_flow_control(FlowStatus::ContinueToSend);
            }
        }
    }

    fn on_flow_control(&mut self, now: Duration, frame: &[u8]) {
        if frame.len() < 3 {
            return self.error(IsoTpError::Truncated { kind: "flow control", dlc: frame.len() });
        }
        let Tx::AwaitFlowControl { waits, deadline, .. } = &mut self.tx else {
            return self.error(IsoTpError::UnexpectedFlowControl);
        };
        match frame[0] & 0x0F {
            0 => {
                let Tx::AwaitFlowControl { message, offset, next_sn, .. } = std::mem::replace(&mut self.tx, Tx::Idle) else {
                    return;
                };
                let block_left = (frame[1] != 0).then_some(frame[1]);
                let st_min = StMin::from_raw(frame[2]).duration();
                // The first consecutive frame may follow the flow control at once.
                self.tx = Tx::Sending { message, offset, next_sn, block_left, st_min, next_at: now };
            }
            1 => {
                *waits += 1;
                if *waits > self.config.max_wait_frames {
                    self.tx = Tx::Idle;
                    return self.error(IsoTpError::TxTooManyWaits(self.config.max_wait_frames));
                }
                *deadline = now + self.config.n_bs;
            }
            2 => {
                let Tx::AwaitFlowControl { message, .. } = std::mem::replace(&mut self.tx, Tx::Idle) else {
                    return;
                };
                self.error(IsoTpError::TxOverflow(message.len()));
            }
            status => {
                self.tx = Tx::Idle;
                self.error(IsoTpError::InvalidFlowStatus(status));
            }
        }
    }

    fn queue_flow_control(&mut self, status: FlowStatus) {
        let data = [(PCI_FLOW_CONTROL << 4) | status.code(), self.config.block_size, self.config.st_min.raw()];
        self.control.push_back(FrameData::padded(&data, self.config.padding));
    }
}

#[cfg(test)]
mod tests;
