//! Any byte stream, cut into chunks with gaps between them, through the frame decoder: it must
//! never panic, never return a packet longer than its LEN allows, and stay bounded.
#![no_main]

use std::time::Duration;

use climbsim::protocol::{DEFAULT_MAX_LEN, Decoder};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut decoder = Decoder::new(Duration::from_micros(1500), DEFAULT_MAX_LEN);
    let mut now = Duration::ZERO;
    // Each chunk: one byte of length (1–32) and one of gap (0–255 × 10 µs), then its bytes.
    let mut rest = data;
    while let [len, gap, tail @ ..] = rest {
        let take = usize::from(*len % 32 + 1).min(tail.len());
        now += Duration::from_micros(u64::from(*gap) * 10);
        for packet in decoder.push(now, &tail[..take]).into_iter().flatten() {
            assert!(packet.wire_len <= DEFAULT_MAX_LEN + 10, "packet longer than the decoder allows");
        }
        assert!(decoder.pending() <= DEFAULT_MAX_LEN + 10, "decoder buffer grows without bound");
        rest = &tail[take..];
    }
    let _ = decoder.flush();
});
