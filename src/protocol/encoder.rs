//! Packet encoders: status replies (what the emulated servos send) and instructions (what a
//! controller sends; used by tests, benches and the in-process controller).

use super::crc16::{RunningCrc, crc16};
use super::stuffing::stuff;
use super::{BROADCAST_ID, HEADER, STATUS_INSTRUCTION};

/// Stuffing covers the instruction byte through the last parameter (reference §3).
fn frame(id: u8, instruction: u8, body: &[u8]) -> Vec<u8> {
    let mut unstuffed = Vec::with_capacity(body.len() + 1);
    unstuffed.push(instruction);
    unstuffed.extend_from_slice(body);
    let stuffed = stuff(&unstuffed);
    // LEN = stuffed instruction + body + CRC. Callers keep bodies far below the 16-bit limit
    // (reads are bounded by the control table).
    let len = stuffed.len() + 2;
    debug_assert!(len <= usize::from(u16::MAX), "packet body of {len} bytes cannot be framed");
    let mut out = Vec::with_capacity(len + 7);
    out.extend_from_slice(&HEADER);
    out.push(0x00);
    out.push(id);
    out.extend_from_slice(&(len as u16).to_le_bytes());
    out.extend_from_slice(&stuffed);
    let crc = crc16(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// A status packet from `id` with `error` and `params`, stuffed as the spec requires.
pub fn encode_status(id: u8, error: u8, params: &[u8]) -> Vec<u8> {
    let mut body = Vec::with_capacity(params.len() + 1);
    body.push(error);
    body.extend_from_slice(params);
    frame(id, STATUS_INSTRUCTION, &body)
}

/// An instruction packet, stuffed as the spec requires (unlike the Python SDK, see reference §3).
pub fn encode_instruction(id: u8, instruction: u8, params: &[u8]) -> Vec<u8> {
    frame(id, instruction, params)
}

/// Builds the one combined Fast Sync/Bulk Read reply (reference §6): `FF FF FD 00 FE LEN 55`, then
/// per device `ERR ID data CRC`, where each CRC runs over everything sent before it. Never stuffed.
pub struct FastReplyBuilder {
    bytes: Vec<u8>,
    crc: RunningCrc,
}

impl FastReplyBuilder {
    /// `data_lens` are the data lengths of every device listed in the instruction, in order; LEN is
    /// fixed by them before any device has answered, as on the real bus. `None` when the combined
    /// packet would not fit the 16-bit LEN field.
    pub fn new(data_lens: impl IntoIterator<Item = usize>) -> Option<Self> {
        let len: usize = 1 + data_lens.into_iter().map(|n| n + 4).sum::<usize>();
        let len = u16::try_from(len).ok()?;
        let mut bytes = Vec::with_capacity(usize::from(len) + 7);
        bytes.extend_from_slice(&HEADER);
        bytes.push(0x00);
        bytes.push(BROADCAST_ID);
        bytes.extend_from_slice(&len.to_le_bytes());
        bytes.push(STATUS_INSTRUCTION);
        let mut crc = RunningCrc::new();
        crc.update(&bytes);
        Some(Self { bytes, crc })
    }

    /// Append one device's block.
    pub fn push_block(&mut self, error: u8, id: u8, data: &[u8]) {
        let start = self.bytes.len();
        self.bytes.push(error);
        self.bytes.push(id);
        self.bytes.extend_from_slice(data);
        self.crc.update(&self.bytes[start..]);
        let crc = self.crc.value();
        self.bytes.extend_from_slice(&crc.to_le_bytes());
        self.crc.update(&crc.to_le_bytes());
    }

    /// Bytes so far. When a listed device did not add its block, the packet is short of its LEN,
    /// exactly as a real bus would leave it.
    pub fn into_bytes(self) -> Vec<u8> {
        self.bytes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ping_reply_matches_reference() {
        assert_eq!(encode_status(1, 0, &[0x60, 0x04, 0x30]), [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x07, 0x00, 0x55, 0x00, 0x60, 0x04, 0x30, 0xEA, 0xDA]);
    }

    #[test]
    fn status_reply_is_stuffed() {
        // Reference §3 worked example: data FF FF FD 00.
        assert_eq!(encode_status(1, 0, &[0xFF, 0xFF, 0xFD, 0x00]), [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x09, 0x00, 0x55, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00, 0xD8, 0x9C]);
    }

    #[test]
    fn fast_sync_read_reply_matches_emanual() {
        let mut builder = FastReplyBuilder::new([4, 4, 4]).unwrap();
        builder.push_block(0, 3, &[0xA6, 0, 0, 0]);
        builder.push_block(0, 7, &[0x1F, 0x08, 0, 0]);
        builder.push_block(0, 4, &[0xFF, 0x03, 0, 0]);
        let expected = [
            0xFF, 0xFF, 0xFD, 0x00, 0xFE, 0x19, 0x00, 0x55, 0x00, 0x03, 0xA6, 0x00, 0x00, 0x00, 0x84, 0x08, 0x00, 0x07, 0x1F, 0x08, 0x00, 0x00, 0x16, 0xCA, 0x00, 0x04, 0xFF, 0x03, 0x00, 0x00, 0xD1,
            0x9E,
        ];
        assert_eq!(builder.into_bytes(), expected);
    }
}
