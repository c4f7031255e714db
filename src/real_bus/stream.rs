//! One direction of a real bus as `climbsim tap` reads it: bytes in chunks, each chunk with the
//! time it was read, framed into packets that keep the times of their first and last byte, and
//! every byte that is not in a packet handed out raw (nothing is lost from the record).

use std::collections::VecDeque;
use std::time::Duration;

use crate::protocol::{Decoder, FrameError, RawPacket};

/// What a stretch of the stream turned out to be, in stream order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Piece {
    /// A packet whose CRC passed: when its first and last byte were read.
    Packet { packet: RawPacket, first: Duration, last: Duration },
    /// Bytes in no packet (noise, a cut packet, a failed CRC): when the first was read.
    Raw { bytes: Vec<u8>, first: Duration },
    /// What the framer said about bytes it dropped (the same bytes come as a [`Piece::Raw`]).
    FrameError(FrameError),
}

/// A direction's framer, with the arrival time of every byte it holds.
#[derive(Debug, Default)]
pub struct TimedStream {
    decoder: Decoder,
    /// Bytes fed and not yet handed out as a packet or raw; `held[0]` is stream offset `base`.
    held: Vec<u8>,
    base: u64,
    /// (stream offset of a chunk's first byte, when the chunk was read), oldest first; the
    /// first entry covers `base`.
    chunks: VecDeque<(u64, Duration)>,
}

impl TimedStream {
    /// Bytes read at `at`: the pieces they complete, in stream order.
    pub fn push(&mut self, at: Duration, bytes: &[u8]) -> Vec<Piece> {
        if bytes.is_empty() {
            return Vec::new();
        }
        self.chunks.push_back((self.base + self.held.len() as u64, at));
        self.held.extend_from_slice(bytes);
        let framed = self.decoder.push(at, bytes);
        self.settle(framed)
    }

    /// The stream has ended (or paused longer than a packet may): what is left comes out, a
    /// partial packet raw.
    pub fn flush(&mut self) -> Vec<Piece> {
        let framed = self.decoder.flush();
        let mut pieces = self.settle(framed);
        if !self.held.is_empty() {
            let first = self.time_of(self.base);
            let bytes = std::mem::take(&mut self.held);
            self.forget(bytes.len());
            pieces.push(Piece::Raw { bytes, first });
        }
        pieces
    }

    /// Hand out the framer's packets, with the raw bytes before each, and the raw bytes before
    /// what the framer still holds.
    fn settle(&mut self, framed: Vec<Result<RawPacket, FrameError>>) -> Vec<Piece> {
        let mut pieces = Vec::new();
        for item in framed {
            match item {
                Ok(packet) => {
                    // The framer hands out packets in stream order, each a contiguous run of
                    // the bytes it was fed: whatever precedes it here was dropped.
                    let at = find(&self.held, &packet.bytes).unwrap_or(0);
                    self.take_raw(at, &mut pieces);
                    let first = self.time_of(self.base);
                    let last = self.time_of(self.base + packet.bytes.len() as u64 - 1);
                    self.held.drain(..packet.bytes.len().min(self.held.len()));
                    self.forget(packet.bytes.len());
                    pieces.push(Piece::Packet { packet, first, last });
                }
                // Skipped noise says nothing its raw bytes do not.
                Err(FrameError::Garbage(_)) => {}
                Err(error) => pieces.push(Piece::FrameError(error)),
            }
        }
        let decided = self.held.len().saturating_sub(self.decoder.pending());
        self.take_raw(decided, &mut pieces);
        pieces
    }

    /// The first `count` held bytes, which no packet took, as a raw piece.
    fn take_raw(&mut self, count: usize, pieces: &mut Vec<Piece>) {
        if count == 0 {
            return;
        }
        let first = self.time_of(self.base);
        let bytes: Vec<u8> = self.held.drain(..count).collect();
        self.forget(bytes.len());
        pieces.push(Piece::Raw { bytes, first });
    }

    /// `count` bytes from `base` on have been handed out.
    fn forget(&mut self, count: usize) {
        self.base += count as u64;
        // Drop the chunks that end before the new base (keep the one that covers it).
        while self.chunks.len() > 1 && self.chunks[1].0 <= self.base {
            self.chunks.pop_front();
        }
    }

    /// When the byte at stream `offset` was read.
    fn time_of(&self, offset: u64) -> Duration {
        self.chunks.iter().take_while(|(start, _)| *start <= offset).last().or(self.chunks.front()).map_or(Duration::ZERO, |(_, at)| *at)
    }
}

fn find(haystack: &[u8], needle: &[u8]) -> Option<usize> {
    if needle.is_empty() || needle.len() > haystack.len() {
        return None;
    }
    haystack.windows(needle.len()).position(|window| window == needle)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::encode_instruction;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn packets(pieces: &[Piece]) -> Vec<(u8, Duration, Duration)> {
        pieces.iter().filter_map(|p| if let Piece::Packet { packet, first, last } = p { Some((packet.id, *first, *last)) } else { None }).collect()
    }

    #[test]
    fn a_packet_split_over_two_reads_keeps_its_first_and_last_byte_times() {
        let ping = encode_instruction(1, 0x01, &[]);
        let mut stream = TimedStream::default();
        assert!(stream.push(ms(1), &ping[..4]).is_empty());
        let pieces = stream.push(ms(2), &ping[4..]);
        assert_eq!(packets(&pieces), vec![(1, ms(1), ms(2))]);
    }

    #[test]
    fn noise_between_packets_comes_out_raw_in_order_and_nothing_is_lost() {
        let one = encode_instruction(1, 0x01, &[]);
        let two = encode_instruction(2, 0x01, &[]);
        let mut bytes = vec![0x00, 0x13];
        bytes.extend_from_slice(&one);
        bytes.extend_from_slice(&[0xAA, 0xBB, 0xCC]);
        bytes.extend_from_slice(&two);
        let mut stream = TimedStream::default();
        let mut pieces = stream.push(ms(5), &bytes[..9]);
        pieces.extend(stream.push(ms(6), &bytes[9..]));
        pieces.extend(stream.flush());
        let mut rebuilt = Vec::new();
        let mut order = Vec::new();
        for piece in &pieces {
            match piece {
                Piece::Packet { packet, .. } => {
                    rebuilt.extend_from_slice(&packet.bytes);
                    order.push(format!("packet {}", packet.id));
                }
                Piece::Raw { bytes, .. } => {
                    rebuilt.extend_from_slice(bytes);
                    order.push(format!("raw {}", bytes.len()));
                }
                Piece::FrameError(_) => {}
            }
        }
        assert_eq!(rebuilt, bytes, "every byte is in a packet or raw, once, in order");
        assert_eq!(order, ["raw 2", "packet 1", "raw 3", "packet 2"]);
        assert_eq!(packets(&pieces), vec![(1, ms(5), ms(6)), (2, ms(6), ms(6))]);
    }

    #[test]
    fn a_packet_with_a_bad_crc_comes_out_raw_and_a_cut_one_at_the_end() {
        let mut bad = encode_instruction(3, 0x02, &[0x84, 0x00, 0x04, 0x00]);
        let n = bad.len();
        bad[n - 1] ^= 0xFF;
        let good = encode_instruction(4, 0x01, &[]);
        let mut stream = TimedStream::default();
        let mut pieces = stream.push(ms(1), &bad);
        pieces.extend(stream.push(ms(2), &good));
        pieces.extend(stream.push(ms(3), &good[..5]));
        pieces.extend(stream.flush());
        assert_eq!(packets(&pieces), vec![(4, ms(2), ms(2))]);
        let raw: Vec<usize> = pieces.iter().filter_map(|p| if let Piece::Raw { bytes, .. } = p { Some(bytes.len()) } else { None }).collect();
        assert_eq!(raw.iter().sum::<usize>(), bad.len() + 5, "{pieces:?}");
        assert!(pieces.iter().any(|p| matches!(p, Piece::FrameError(FrameError::BadCrc { id: 3, .. }))));
    }
}
