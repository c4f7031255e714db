//! The transcript of a real bus (`climbsim tap --record FILE`): JSON lines, a [`RealHeader`]
//! and then [`RealRecord`]s in the order they were seen. Its format is not a simulated
//! session's (`--record`): `climbsim replay` refuses it by name, and `climbsim compare` reads it.
//!
//! Times are integer nanoseconds since the tap started, as read on its clock: an instruction's
//! `t` when its first byte was read from the controller and `end` when its last byte had been
//! handed to the servos' side; a reply's `t` and `end` when its first and last byte were read
//! from the servos' side.

use std::path::{Path, PathBuf};
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::transcript::{JsonLines, TranscriptError, nanos, read_json_lines, to_hex};

use super::pairing::{Event, Seen};

/// The `format` of a real bus's transcript.
pub const FORMAT: &str = crate::transcript::REAL_FORMAT;
/// The version this climbsim writes and reads.
pub const VERSION: u32 = 1;

/// Where and when the session was recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RealHeader {
    pub format: String,
    pub version: u32,
    pub climbsim: String,
    /// `tap`.
    pub mode: String,
    /// The serial device the servos are on.
    pub device: PathBuf,
    /// The port the controller opened.
    pub link: PathBuf,
    /// The line's rate at the start.
    pub baud: u32,
    /// The wall clock when the tap started (ns since the Unix epoch).
    pub started_unix_ns: u64,
}

impl RealHeader {
    pub fn new(device: &Path, link: &Path, baud: u32, started_unix_ns: u64) -> Self {
        Self {
            format: FORMAT.to_owned(),
            version: VERSION,
            climbsim: env!("CARGO_PKG_VERSION").to_owned(),
            mode: "tap".to_owned(),
            device: device.to_owned(),
            link: link.to_owned(),
            baud,
            started_unix_ns,
        }
    }
}

/// Which side sent bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Side {
    Controller,
    Servos,
}

impl Side {
    fn from_servos(servos: bool) -> Self {
        if servos { Self::Servos } else { Self::Controller }
    }
}

/// A status packet in a transaction.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct RealReply {
    pub id: u8,
    pub t: u64,
    pub end: u64,
    pub hex: String,
}

/// One line after the header.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "k", rename_all = "snake_case")]
pub enum RealRecord {
    /// An instruction, its replies, and the servos that should have answered and did not.
    Tx { t: u64, end: u64, baud: u32, hex: String, replies: Vec<RealReply>, missed: Vec<u8> },
    /// Bytes that are in no packet.
    Raw { from: Side, t: u64, hex: String },
    /// A status packet that answered nothing pending.
    Unpaired { t: u64, hex: String },
    /// A framing error (its bytes are in a `raw` line).
    FrameError { from: Side, t: u64, what: String },
    /// The controller set its port to another rate; the device followed.
    Baud { t: u64, baud: u32 },
    /// The session ended: why, and the bytes forwarded each way.
    End { t: u64, why: String, from_controller: u64, from_servos: u64 },
}

impl RealRecord {
    /// When it happened (ns since the session's start): an instruction's first byte, the
    /// other records' own instant.
    pub fn t(&self) -> u64 {
        match self {
            Self::Tx { t, .. } | Self::Raw { t, .. } | Self::Unpaired { t, .. } | Self::FrameError { t, .. } | Self::Baud { t, .. } | Self::End { t, .. } => *t,
        }
    }

    /// The record for something the pairing saw.
    pub fn from_event(event: &Event) -> Self {
        match event {
            Event::Transaction(seen) => Self::transaction(seen),
            Event::Raw { from_servos, at, bytes } => Self::Raw { from: Side::from_servos(*from_servos), t: nanos(*at), hex: to_hex(bytes) },
            Event::Unpaired { at, packet } => Self::Unpaired { t: nanos(*at), hex: to_hex(&packet.bytes) },
            Event::FrameError { from_servos, at, error } => Self::FrameError { from: Side::from_servos(*from_servos), t: nanos(*at), what: error.to_string() },
        }
    }

    fn transaction(seen: &Seen) -> Self {
        Self::Tx {
            t: nanos(seen.t),
            end: nanos(seen.end),
            baud: seen.baud,
            hex: to_hex(&seen.instruction.bytes),
            replies: seen.replies.iter().map(|r| RealReply { id: r.id, t: nanos(r.first), end: nanos(r.last), hex: to_hex(&r.bytes) }).collect(),
            missed: seen.missed.clone(),
        }
    }

    pub fn end(at: Duration, why: &str, from_controller: u64, from_servos: u64) -> Self {
        Self::End { t: nanos(at), why: why.to_owned(), from_controller, from_servos }
    }
}

/// A real bus's transcript read back.
pub type RealTranscript = JsonLines<RealHeader, RealRecord>;

/// Read a real bus's transcript (a torn last line is dropped, as `--record`'s are).
pub fn read(path: &Path) -> Result<RealTranscript, TranscriptError> {
    read_json_lines(path, FORMAT, VERSION, |record: &RealRecord| matches!(record, RealRecord::End { .. }))
}
