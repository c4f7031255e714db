//! Incremental framer for instruction (and status) packets.
//!
//! Framing is strictly by LEN: the Python SDK sends params unstuffed (reference §3), so an
//! `FF FF FD` inside a packet whose CRC has not been checked is never taken for a new header.
//! After a bad CRC or an impossible LEN the decoder drops one byte and hunts again, so a valid
//! packet hidden behind a false header is still found.

use std::time::Duration;

use thiserror::Error;

use super::crc16::crc16;
use super::stuffing::unstuff;
use super::{HEADER, PREFIX_LEN};

/// Default largest LEN accepted. DynamixelSDK's TX buffer is 1024 bytes, so no client sends more.
pub const DEFAULT_MAX_LEN: usize = 1024;
/// A pause longer than this between two bytes of a packet drops the partial packet (reference §1).
pub const DEFAULT_INTER_BYTE_TIMEOUT: Duration = Duration::from_micros(1500);

/// A packet whose CRC passed, with its parameters unstuffed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawPacket {
    pub id: u8,
    /// Instruction code (0x55 for a status packet).
    pub instruction: u8,
    /// Parameters after unstuffing (for a status packet: the error byte, then the params).
    pub params: Vec<u8>,
    /// Bytes the packet occupied on the wire, stuffing included (LEN + 7).
    pub wire_len: usize,
    /// The packet exactly as received (for traces).
    pub bytes: Vec<u8>,
}

impl RawPacket {
    /// A status packet's data, if its error byte reports no failure: `Err(None)` for a packet
    /// without an error byte, `Err(Some(error))` otherwise. The alert bit alone (a latched
    /// hardware error) does not fail the instruction.
    pub fn status_data(&self) -> Result<&[u8], Option<u8>> {
        match self.params.split_first() {
            Some((&error, data)) if error & !super::ALERT_BIT == 0 => Ok(data),
            Some((&error, _)) => Err(Some(error)),
            None => Err(None),
        }
    }
}

/// Something in the byte stream that was not a valid packet. None of these stop the decoder.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum FrameError {
    #[error("skipped {0} bytes outside any packet")]
    Garbage(usize),
    #[error("packet for ID {id} failed its CRC (received 0x{received:04X}, computed 0x{computed:04X})")]
    BadCrc { id: u8, received: u16, computed: u16 },
    #[error("header with impossible LEN {len} for ID {id}")]
    BadLength { id: u8, len: usize },
    #[error("header with reserved byte 0x{0:02X} instead of 0x00")]
    BadReserved(u8),
    #[error("dropped {0} bytes of a packet interrupted by an inter-byte gap")]
    InterByteTimeout(usize),
}

/// Outcome of looking at the front of the buffer.
enum Front {
    Packet(RawPacket),
    /// Drop this many bytes and report the error (if any).
    Skip(usize, Option<FrameError>),
    /// The frame at the front is not complete yet.
    NeedMore,
    Empty,
}

/// Sans-IO decoder: feed it bytes with their arrival time, take packets out.
#[derive(Debug)]
pub struct Decoder {
    buf: Vec<u8>,
    last_byte_at: Option<Duration>,
    inter_byte_timeout: Duration,
    max_len: usize,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new(DEFAULT_INTER_BYTE_TIMEOUT, DEFAULT_MAX_LEN)
    }
}

impl Decoder {
    pub fn new(inter_byte_timeout: Duration, max_len: usize) -> Self {
        Self { buf: Vec::with_capacity(256), last_byte_at: None, inter_byte_timeout, max_len }
    }

    /// Bytes held for an incomplete packet.
    pub fn pending(&self) -> usize {
        self.buf.len()
    }

    /// Feed `bytes` that arrived at `now` (any monotonic time base) and return every packet and
    /// framing error they complete, in stream order.
    pub fn push(&mut self, now: Duration, bytes: &[u8]) -> Vec<Result<RawPacket, FrameError>> {
        let mut out = Vec::new();
        if let Some(last) = self.last_byte_at
            && !self.buf.is_empty()
            && now.saturating_sub(last) > self.inter_byte_timeout
        {
            self.drain_stale(&mut out);
        }
        if !bytes.is_empty() {
            self.last_byte_at = Some(now);
        }
        self.buf.extend_from_slice(bytes);
        self.drain_complete(&mut out);
        out
    }

    /// End of stream (or a gap the caller has already seen): drop any partial packet, but still
    /// return complete packets that were hidden behind a false header.
    pub fn flush(&mut self) -> Vec<Result<RawPacket, FrameError>> {
        let mut out = Vec::new();
        self.drain_stale(&mut out);
        out
    }

    fn drain_complete(&mut self, out: &mut Vec<Result<RawPacket, FrameError>>) {
        loop {
            match self.front() {
                Front::Packet(packet) => {
                    self.buf.drain(..packet.wire_len);
                    out.push(Ok(packet));
                }
                Front::Skip(n, error) => {
                    self.buf.drain(..n);
                    out.extend(error.map(Err));
                }
                Front::NeedMore | Front::Empty => return,
            }
        }
    }

    /// Like `drain_complete`, but a frame that cannot complete is dropped byte by byte.
    fn drain_stale(&mut self, out: &mut Vec<Result<RawPacket, FrameError>>) {
        let mut dropped = 0;
        loop {
            match self.front() {
                Front::Packet(packet) => {
                    self.buf.drain(..packet.wire_len);
                    out.push(Ok(packet));
                }
                Front::Skip(n, Some(FrameError::Garbage(_)) | None) => {
                    self.buf.drain(..n);
                    dropped += n;
                }
                Front::Skip(n, Some(error)) => {
                    self.buf.drain(..n);
                    out.push(Err(error));
                }
                Front::NeedMore => {
                    self.buf.drain(..1);
                    dropped += 1;
                }
                Front::Empty => break,
            }
        }
        if dropped > 0 {
            out.push(Err(FrameError::InterByteTimeout(dropped)));
        }
    }

    fn front(&self) -> Front {
        let buf = &self.buf;
        if buf.is_empty() {
            return Front::Empty;
        }
        let Some(start) = find_header(buf) else {
            // Keep a trailing FF or FF FF: it may be the start of the next header.
            let keep = trailing_header_prefix(buf);
            return if keep == buf.len() { Front::NeedMore } else { Front::Skip(buf.len() - keep, Some(FrameError::Garbage(buf.len() - keep))) };
        };
        if start > 0 {
            return Front::Skip(start, Some(FrameError::Garbage(start)));
        }
        if buf.len() < PREFIX_LEN {
            return Front::NeedMore;
        }
        let reserved = buf[3];
        if reserved == 0xFD {
            // FF FF FD FD is stuffed data from the middle of some packet, not a header.
            return Front::Skip(1, None);
        }
        if reserved != 0x00 {
            return Front::Skip(1, Some(FrameError::BadReserved(reserved)));
        }
        let id = buf[4];
        let len = usize::from(u16::from_le_bytes([buf[5], buf[6]]));
        if !(3..=self.max_len).contains(&len) {
            return Front::Skip(1, Some(FrameError::BadLength { id, len }));
        }
        let total = PREFIX_LEN + len;
        if buf.len() < total {
            return Front::NeedMore;
        }
        let received = u16::from_le_bytes([buf[total - 2], buf[total - 1]]);
        let computed = crc16(&buf[..total - 2]);
        if received != computed {
            return Front::Skip(1, Some(FrameError::BadCrc { id, received, computed }));
        }
        // Unstuff from the instruction byte on, as it was stuffed (reference §3).
        let mut body = unstuff(&buf[PREFIX_LEN..total - 2]);
        let instruction = body.remove(0);
        Front::Packet(RawPacket { id, instruction, params: body, wire_len: total, bytes: buf[..total].to_vec() })
    }
}

fn find_header(buf: &[u8]) -> Option<usize> {
    buf.windows(HEADER.len()).position(|w| w == HEADER)
}

fn trailing_header_prefix(buf: &[u8]) -> usize {
    if buf.ends_with(&HEADER[..2]) {
        2
    } else if buf.ends_with(&HEADER[..1]) {
        1
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PING_1: [u8; 10] = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x03, 0x00, 0x01, 0x19, 0x4E];
    const T0: Duration = Duration::ZERO;

    fn packets(results: Vec<Result<RawPacket, FrameError>>) -> Vec<RawPacket> {
        results.into_iter().filter_map(Result::ok).collect()
    }

    #[test]
    fn decodes_ping_fed_one_byte_at_a_time() {
        let mut decoder = Decoder::default();
        let mut got = Vec::new();
        for &b in &PING_1 {
            got.extend(packets(decoder.push(T0, &[b])));
        }
        assert_eq!(got, vec![RawPacket { id: 1, instruction: 0x01, params: vec![], wire_len: 10, bytes: PING_1.to_vec() }]);
        assert_eq!(decoder.pending(), 0);
    }

    #[test]
    fn resyncs_after_garbage_and_bad_crc() {
        let mut stream = vec![0x00, 0x13, 0xFF];
        let mut corrupt = PING_1;
        corrupt[8] ^= 0x01;
        stream.extend_from_slice(&corrupt);
        stream.extend_from_slice(&PING_1);
        let results = Decoder::default().push(T0, &stream);
        assert!(results.iter().any(|r| matches!(r, Err(FrameError::BadCrc { id: 1, .. }))));
        assert_eq!(packets(results).len(), 1);
    }

    #[test]
    fn frames_unstuffed_python_sdk_write_by_len() {
        // Reference §3: the Python SDK writes 0x00FDFFFF to 116 unstuffed.
        let bytes = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x09, 0x00, 0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00, 0xC9, 0x07];
        let got = packets(Decoder::default().push(T0, &bytes));
        assert_eq!(got.len(), 1);
        assert_eq!((got[0].id, got[0].instruction, got[0].wire_len), (1, 0x03, 16));
        assert_eq!(got[0].params, [0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00]);
    }

    #[test]
    fn drops_partial_packet_after_gap() {
        let mut decoder = Decoder::default();
        assert!(decoder.push(T0, &PING_1[..5]).is_empty());
        let results = decoder.push(Duration::from_millis(2), &PING_1);
        assert!(matches!(results[0], Err(FrameError::InterByteTimeout(5))), "{results:?}");
        assert_eq!(packets(results).len(), 1);
    }

    #[test]
    fn keeps_partial_packet_within_gap() {
        let mut decoder = Decoder::default();
        assert!(decoder.push(T0, &PING_1[..5]).is_empty());
        let got = packets(decoder.push(Duration::from_micros(1400), &PING_1[5..]));
        assert_eq!(got.len(), 1);
    }

    #[test]
    fn flush_finds_packet_behind_false_header_with_long_len() {
        let mut stream = vec![0xFF, 0xFF, 0xFD, 0x00, 0x07, 0x00, 0x02];
        stream.extend_from_slice(&PING_1);
        let mut decoder = Decoder::default();
        assert!(packets(decoder.push(T0, &stream)).is_empty());
        assert_eq!(packets(decoder.flush()).len(), 1);
    }

    #[test]
    fn stuffed_marker_is_not_a_header() {
        let stream = [0xFF, 0xFF, 0xFD, 0xFD, 0x01];
        let results = Decoder::default().push(T0, &stream);
        assert!(packets(results).is_empty());
    }
}
