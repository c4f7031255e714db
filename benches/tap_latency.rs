//! What `climbsim tap` adds to a transaction's round trip at 1 Mbps: the same client, the same
//! "real" servos (`climbsim serve --device` on the far end of a null-modem pty pair), once on
//! the pair's near end directly and once through `tap` on that end. Blocks of the two
//! alternate, so they share machine conditions; the added latency is the difference of the
//! medians. Target: ≤ 30 µs. Reported, not asserted.
//!
//! The transaction: a Read of Present Position from ID 1 (14 bytes out, 15 back), the client
//! blocking on its raw port as in `pty_latency`. `cargo bench --bench tap_latency` measures
//! (6 blocks of 500 each way) and writes `target/bench-results/tap_latency.json`; without
//! `--bench` it runs a smoke pass of one short block each way and writes nothing.

#[path = "../tests/support/mod.rs"]
mod support;

use std::time::{Duration, Instant};

use climbsim::protocol::encode_instruction;
use nix::sys::termios::BaudRate;
use support::null_modem::NullModem;
use support::tap::TapProcess;

const REPLY_LEN: usize = 15;
const TARGET_ADDED_US: f64 = 30.0;

fn block(port: &std::path::Path, count: usize, samples: &mut Vec<f64>) {
    let client = support::open_raw_port(port, BaudRate::B1000000);
    let request = encode_instruction(1, 0x02, &[132, 0, 4, 0]);
    let mut buf = [0u8; 64];
    for _ in 0..count {
        let ns = support::round_trip(&client, &request, REPLY_LEN, &mut buf);
        assert_eq!(&buf[..5], &[0xFF, 0xFF, 0xFD, 0x00, 0x01], "a status from ID 1");
        samples.push(ns as f64 / 1e3);
    }
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (blocks, per_block) = if full { (6, 500) } else { (1, 20) };
    let dir = support::scratch_dir("tap-latency");
    let cable = NullModem::new();
    let _servos = support::Options::default().stderr_log().start(&["--device", cable.b().to_str().expect("utf-8"), "--baud", "1000000"]);
    let (mut direct, mut tapped) = (Vec::new(), Vec::new());
    let started = Instant::now();
    for _ in 0..blocks {
        block(cable.a(), per_block, &mut direct);
        let mut tap = TapProcess::start(cable.a(), &dir, &["--baud", "1000000"]);
        block(&tap.port, per_block, &mut tapped);
        tap.interrupt();
        assert!(tap.wait(Duration::from_secs(10)).success(), "{}", tap.stderr());
    }
    let (direct_median, tapped_median) = (support::median(&mut direct), support::median(&mut tapped));
    let added = tapped_median - direct_median;
    println!(
        "tap_latency: Read of 4 bytes at 1 Mbps, {} round trips each way in {blocks} blocks, {:.1} s{}",
        direct.len(),
        started.elapsed().as_secs_f64(),
        if full { "" } else { "  [smoke run, not a measurement]" }
    );
    println!("  direct on the pty pair      median {direct_median:8.1} µs");
    println!("  through climbsim tap        median {tapped_median:8.1} µs");
    println!("  added by tap                {added:8.1} µs (target ≤ {TARGET_ADDED_US} µs: {})", if added <= TARGET_ADDED_US { "met" } else { "NOT met" });
    if full {
        let json = serde_json::json!({
            "bench": "tap_latency",
            "round_trips_each": direct.len(),
            "direct_median_us": direct_median,
            "tap_median_us": tapped_median,
            "added_us": added,
            "target_added_us": TARGET_ADDED_US,
        });
        let path = support::results_dir().join("tap_latency.json");
        std::fs::write(&path, serde_json::to_string_pretty(&json).expect("json") + "\n").expect("write results");
    }
}
