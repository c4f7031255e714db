//! Dynamixel Protocol 2.0 wire format, sans-IO.
//!
//! Nothing here reads a clock or touches a file descriptor: the [`Decoder`] is fed byte chunks
//! together with the time they arrived, and the encoders return byte vectors. That keeps framing,
//! CRC and stuffing testable with byte vectors alone (see the golden tests at the bottom of each
//! file and `tests/protocol_golden.rs`).

mod crc16;
mod decoder;
mod encoder;
mod instruction;
mod stuffing;

pub use crc16::crc16;
pub use decoder::{DEFAULT_INTER_BYTE_TIMEOUT, DEFAULT_MAX_LEN, Decoder, FrameError, RawPacket};
pub use encoder::{FastReplyBuilder, encode_instruction, encode_status};
pub use instruction::{BulkReadEntry, BulkWriteEntry, Instruction, ParamError, SyncWriteEntry, opcode};
pub use stuffing::{stuff, unstuff};

/// `FF FF FD`: the three header bytes every packet starts with.
pub const HEADER: [u8; 3] = [0xFF, 0xFF, 0xFD];
/// Highest usable device ID (0xFD would collide with the header, 0xFE is broadcast).
pub const MAX_ID: u8 = 252;
/// Broadcast ID.
pub const BROADCAST_ID: u8 = 0xFE;
/// Instruction code of a status (reply) packet.
pub const STATUS_INSTRUCTION: u8 = 0x55;
/// Bytes before the LEN-counted part: header (3) + reserved (1) + ID (1) + LEN (2).
pub const PREFIX_LEN: usize = 7;
/// Alert bit of the status error byte: Hardware Error Status is non-zero.
pub const ALERT_BIT: u8 = 0x80;
