//! What a half-duplex line does when two drivers talk at once (sans-IO: times are inputs).
//!
//! The XM540-W270-R sits on RS-485, the -T on TTL; on both, one device drives the line at a time
//! and the protocol's turn-taking (instruction, Return Delay Time, status) keeps it that way. A
//! controller that sends before the last reply has left the wire, or two servos with one ID,
//! put two drivers on the line. Chosen model: the receivers see the bitwise AND of the two
//! bytes in flight (a 0 bit, the dominant low level of a TTL line, wins). On RS-485 the level
//! under contention is undefined; the AND is one deterministic choice, and like real contention
//! it breaks the CRC of both packets (unverified against a scope; listed in docs/serve-and-bus.md).

use std::time::Duration;

use super::Reply;

/// Two packets that start together: the second is ANDed over the first (extending it).
pub fn overlay(into: &mut Vec<u8>, other: &[u8]) {
    for (i, &b) in other.iter().enumerate() {
        match into.get_mut(i) {
            Some(existing) => *existing &= b,
            None => into.push(b),
        }
    }
}

/// The controller put `sent` on the wire starting at `at` while `replies` (not yet delivered)
/// were scheduled on it: every byte of `sent` that overlaps a reply byte in time is ANDed with
/// it, in both packets. Returns how many byte pairs collided (0: the line was free).
pub fn collide_in_time(sent: &mut [u8], at: Duration, replies: &mut [Reply], byte_time: Duration) -> usize {
    let tau = byte_time.as_secs_f64();
    if tau <= 0.0 {
        return 0;
    }
    let mut collided = 0;
    for reply in replies.iter_mut() {
        let reply_start = reply.start.as_secs_f64();
        let reply_len = reply.bytes.len();
        for (k, byte) in sent.iter_mut().enumerate() {
            // Controller byte k occupies [at + k·τ, at + (k+1)·τ); it meets the reply byte whose
            // slot contains its middle.
            let middle = at.as_secs_f64() + (k as f64 + 0.5) * tau;
            let slot = (middle - reply_start) / tau;
            if slot < 0.0 {
                continue;
            }
            let j = slot as usize;
            if j >= reply_len {
                continue;
            }
            let combined = *byte & reply.bytes[j];
            *byte = combined;
            reply.bytes[j] = combined;
            collided += 1;
        }
    }
    collided
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply(bytes: &[u8], start_us: u64, byte_us: u64) -> Reply {
        let start = Duration::from_micros(start_us);
        Reply { bytes: bytes.to_vec(), start, end: start + Duration::from_micros(byte_us * bytes.len() as u64), from: vec![1] }
    }

    const TAU: Duration = Duration::from_micros(100);

    #[test]
    fn bytes_sent_after_the_reply_left_the_wire_do_not_collide() {
        let mut replies = [reply(&[0xFF, 0x0F, 0xF0], 1_000, 100)];
        let mut sent = [0x00, 0x00];
        assert_eq!(collide_in_time(&mut sent, Duration::from_micros(1_300), &mut replies, TAU), 0);
        assert_eq!(replies[0].bytes, [0xFF, 0x0F, 0xF0]);
        assert_eq!(sent, [0x00, 0x00]);
    }

    #[test]
    fn bytes_sent_before_the_reply_starts_and_ending_in_time_do_not_collide() {
        // Return Delay Time gap: a short packet that fits before the reply's first byte.
        let mut replies = [reply(&[0x12, 0x34], 1_000, 100)];
        let mut sent = [0x00, 0x00];
        assert_eq!(collide_in_time(&mut sent, Duration::from_micros(790), &mut replies, TAU), 0);
    }

    #[test]
    fn overlapping_bytes_and_together_in_both_directions() {
        // The controller starts 1.5 bytes into the reply: its byte 0 meets reply byte 1 (middle
        // at 1 200 µs falls in slot 1), byte 1 meets reply byte 2, byte 2 is past the reply.
        let mut replies = [reply(&[0xFF, 0xF0, 0x3C], 1_000, 100)];
        let mut sent = [0x0F, 0xAA, 0x55];
        let hits = collide_in_time(&mut sent, Duration::from_micros(1_150), &mut replies, TAU);
        assert_eq!(hits, 2);
        assert_eq!(replies[0].bytes, [0xFF, 0x00, 0x28]);
        assert_eq!(sent, [0x00, 0x28, 0x55]);
    }

    #[test]
    fn a_packet_spanning_two_replies_hits_both() {
        let mut replies = [reply(&[0x00, 0x00], 1_000, 100), reply(&[0x00], 1_400, 100)];
        let mut sent = [0xFF; 6];
        let hits = collide_in_time(&mut sent, Duration::from_micros(1_000), &mut replies, TAU);
        assert_eq!(hits, 3);
        assert_eq!(sent, [0x00, 0x00, 0xFF, 0xFF, 0x00, 0xFF]);
    }

    #[test]
    fn overlay_extends_the_shorter_packet() {
        let mut into = vec![0xF0, 0xFF];
        overlay(&mut into, &[0x3C, 0x0F, 0x77]);
        assert_eq!(into, [0x30, 0x0F, 0x77]);
    }
}
