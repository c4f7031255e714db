//! A minimal Protocol 2.0 client over any [`BusLink`]: Write, Sync Read and Sync Write, with
//! the status checks a careful controller makes.

use thiserror::Error;

use crate::protocol::{RawPacket, encode_instruction, opcode};
use crate::sim::Lockstep;

/// Something that carries instruction bytes to the servos and returns their status packets.
pub trait BusLink {
    fn transact(&mut self, bytes: &[u8]) -> Vec<RawPacket>;
}

impl BusLink for Lockstep {
    fn transact(&mut self, bytes: &[u8]) -> Vec<RawPacket> {
        Lockstep::transact(self, bytes)
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum ControlError {
    #[error("servo {id} did not answer {what}")]
    NoReply { id: u8, what: &'static str },
    #[error("servo {id} answered {what} with status error 0x{error:02X}")]
    Status { id: u8, what: &'static str, error: u8 },
    #[error("servo {id} answered {what} with {got} data bytes, expected {expected}")]
    Length { id: u8, what: &'static str, got: usize, expected: usize },
    #[error("the robot description has no {0}")]
    MissingServo(&'static str),
    /// The description has no climbing robot for the reference controller to drive.
    #[error("{0}")]
    NotAClimber(String),
}

/// Reads and writes control-table items by address over a [`BusLink`].
pub struct ServoClient<'a, L: BusLink> {
    pub link: &'a mut L,
}

impl<'a, L: BusLink> ServoClient<'a, L> {
    pub fn new(link: &'a mut L) -> Self {
        Self { link }
    }

    /// Write `data` at `address` of servo `id` and check its status.
    pub fn write(&mut self, id: u8, address: u16, data: &[u8], what: &'static str) -> Result<(), ControlError> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(data);
        let reply = self.link.transact(&encode_instruction(id, opcode::WRITE, &params)).into_iter().find(|r| r.id == id);
        check(reply.as_ref(), id, what, 0).map(|_| ())
    }

    /// Sync Read `length` bytes at `address` from each of `ids`; the data in the order of `ids`.
    pub fn sync_read(&mut self, ids: &[u8], address: u16, length: u16, what: &'static str) -> Result<Vec<Vec<u8>>, ControlError> {
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(&length.to_le_bytes());
        params.extend_from_slice(ids);
        let replies = self.link.transact(&encode_instruction(crate::protocol::BROADCAST_ID, opcode::SYNC_READ, &params));
        ids.iter().map(|&id| check(replies.iter().find(|r| r.id == id), id, what, usize::from(length)).map(<[u8]>::to_vec)).collect()
    }

    /// Sync Write one `data` block per servo at `address` (every block the same length).
    pub fn sync_write(&mut self, address: u16, blocks: &[(u8, Vec<u8>)]) {
        let length = blocks.first().map_or(0, |(_, data)| data.len()) as u16;
        let mut params = address.to_le_bytes().to_vec();
        params.extend_from_slice(&length.to_le_bytes());
        for (id, data) in blocks {
            params.push(*id);
            params.extend_from_slice(data);
        }
        // Sync Write has no replies.
        self.link.transact(&encode_instruction(crate::protocol::BROADCAST_ID, opcode::SYNC_WRITE, &params));
    }
}

/// The data of a status reply, if it came, carries no error (see [`RawPacket::status_data`]) and
/// holds `expected` bytes.
fn check<'p>(reply: Option<&'p RawPacket>, id: u8, what: &'static str, expected: usize) -> Result<&'p [u8], ControlError> {
    let reply = reply.ok_or(ControlError::NoReply { id, what })?;
    let data = reply.status_data().map_err(|error| error.map_or(ControlError::NoReply { id, what }, |error| ControlError::Status { id, what, error }))?;
    if data.len() != expected {
        return Err(ControlError::Length { id, what, got: data.len(), expected });
    }
    Ok(data)
}
