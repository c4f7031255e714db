//! Decode + handle + encode of one Sync Read of 8 IDs × 4 bytes (Present Position), the hot
//! path of a controller's read cycle, without any I/O. Target: < 5 µs.
//!
//! Timed by hand (the other benches are too): a second's warm-up, then 41 blocks of about 50 ms
//! each, the median and the 10th–90th percentiles of the blocks' time per iteration. (Criterion
//! did this once; it and its dependencies were a tenth of the dependencies' compile time in
//! every `cargo test`, which builds all dev-dependencies, for this one bench.)
//! `cargo bench --bench codec`; results on stdout and in target/bench-results/codec.json.

#[path = "../tests/support/mod.rs"]
mod support;

use std::hint::black_box;
use std::time::{Duration, Instant};

use climbsim::bus::Timing;
use climbsim::protocol::{Decoder, encode_instruction, opcode};
use climbsim::robot::RobotDescription;

const WARM_UP: Duration = Duration::from_secs(1);
const BLOCKS: usize = 41;
const BLOCK: Duration = Duration::from_millis(50);

fn main() {
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot description");
    let mut bus = robot.bench_bus(Timing::Off, None).expect("bench bus");
    let request = encode_instruction(0xFE, opcode::SYNC_READ, &[132, 0, 4, 0, 1, 2, 3, 4, 5, 6, 7, 8]);
    let mut decoder = Decoder::default();
    let now = Duration::from_secs(1);
    bus.advance(now);
    let mut once = || {
        let mut reply_bytes = 0;
        for packet in decoder.push(now, black_box(&request)) {
            let transaction = bus.handle(packet.expect("valid packet"), now, None);
            reply_bytes += transaction.replies.iter().map(|r| r.bytes.len()).sum::<usize>();
        }
        assert_eq!(reply_bytes, 8 * 15);
        black_box(reply_bytes);
    };
    // Warm up, and find how many iterations fill a block.
    let started = Instant::now();
    let mut warm_up_iterations = 0u64;
    while started.elapsed() < WARM_UP {
        once();
        warm_up_iterations += 1;
    }
    let per_block = ((warm_up_iterations as f64 * BLOCK.as_secs_f64() / started.elapsed().as_secs_f64()) as u64).max(1);
    let mut us_per_iteration: Vec<f64> = (0..BLOCKS)
        .map(|_| {
            let block = Instant::now();
            for _ in 0..per_block {
                once();
            }
            block.elapsed().as_secs_f64() * 1e6 / per_block as f64
        })
        .collect();
    us_per_iteration.sort_by(f64::total_cmp);
    let (p10, median, p90) = (us_per_iteration[BLOCKS / 10], support::median(&mut us_per_iteration), us_per_iteration[BLOCKS * 9 / 10]);
    println!("sync_read_8x4_decode_handle_encode: {median:.3} µs median ({p10:.3}–{p90:.3} µs, 10th–90th percentile of {BLOCKS} blocks of {per_block} iterations)");
    let json = serde_json::json!({ "bench": "codec", "median_us": median, "p10_us": p10, "p90_us": p90, "blocks": BLOCKS, "iterations_per_block": per_block });
    let path = support::results_dir().join("codec.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json).expect("json") + "\n").expect("write results");
}
