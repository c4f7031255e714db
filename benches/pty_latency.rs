//! Round-trip latency over a real pseudo-terminal: climbsim (`serve --timing off`) against a raw
//! pty echo, the floor any pty-based emulator sits on. Target: median(climbsim) ≤ 1.25 ×
//! median(echo). Reported, not asserted.
//!
//! `CLIMBSIM_BASELINE=<another climbsim binary>` adds it as a third path, interleaved with the
//! other two, for an A/B of two builds under the same machine conditions.
//!
//! (a) echo: a thread does a blocking read on a pty master and writes the same bytes back; the
//!     client, on the slave (raw, 57600 nominal), writes a 14-byte packet (exactly a Read request,
//!     `encode_instruction(1, 0x02, &[132, 0, 4, 0])`) and reads until 14 bytes came back.
//! (b) climbsim: the client opens the emulator's pty (raw, 57600, the servos' baud), writes that
//!     Read of Present Position (ID 1, 4 bytes) and reads until the 15-byte status reply arrived.
//!
//! Both use the same blocking client code. After a warm-up, the two alternate in blocks so they
//! share machine conditions. Results: a table on stdout and `target/bench-results/pty_latency.json`.
//!
//! `cargo bench --bench pty_latency` runs the full measurement; without `--bench` (e.g.
//! `cargo test --benches`) it runs a short smoke pass and writes nothing.

#[path = "../tests/support/mod.rs"]
mod support;

use std::fs::File;
use std::time::Instant;

use climbsim::protocol::{crc16, encode_instruction};
use nix::sys::termios::BaudRate;
use support::Emulator;

const READ: u8 = 0x02;
const REPLY_LEN: usize = 15; // 11 + 4 data bytes
/// The target for median(climbsim) / median(echo).
const TARGET_RATIO: f64 = 1.25;

/// One timed path: a client port and how many bytes come back.
struct TimedPath<'a> {
    client: &'a File,
    expect: usize,
    is_echo: bool,
}

impl<'a> TimedPath<'a> {
    fn echo(client: &'a File) -> Self {
        Self { client, expect: 14, is_echo: true }
    }

    fn climbsim(client: &'a File) -> Self {
        Self { client, expect: REPLY_LEN, is_echo: false }
    }

    fn round_trip(&self, request: &[u8], buf: &mut [u8]) -> u64 {
        let ns = support::round_trip(self.client, request, self.expect, buf);
        if self.is_echo {
            assert_eq!(&buf[..self.expect], request, "echo returned other bytes");
        } else {
            // Spot-check: every reply is the full, valid status packet.
            check_reply(&buf[..REPLY_LEN]);
        }
        ns
    }
}

struct Config {
    full: bool,
    warmup: usize,
    blocks: usize,
    per_block: usize,
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let cfg = if full { Config { full, warmup: 2_000, blocks: 40, per_block: 500 } } else { Config { full, warmup: 50, blocks: 4, per_block: 50 } };
    let request = encode_instruction(1, READ, &[132, 0, 4, 0]);
    assert_eq!(request.len(), 14, "a Read request is 14 bytes");

    // (a) Raw pty echo.
    let echo = support::PtyEcho::start(BaudRate::B57600);
    let echo_client = echo.client();

    // (b) climbsim, and (c) a baseline build of it if one is given (an A/B in one run).
    let mut emulator = Emulator::start(&["--timing", "off"]);
    let sim_client = support::open_raw_port(emulator.port(), BaudRate::B57600);
    let baseline_bin = support::baseline_binary();
    let mut baseline = support::start_baseline(&["--timing", "off"]);
    let baseline_client = baseline.as_ref().map(|emulator| support::open_raw_port(emulator.port(), BaudRate::B57600));

    let mut buf = [0u8; 64];
    // Check every path answers what it should before timing anything.
    support::round_trip(echo_client, &request, request.len(), &mut buf);
    assert_eq!(&buf[..request.len()], &request[..], "echo returned other bytes");
    let mut paths: Vec<TimedPath> = vec![TimedPath::echo(echo_client), TimedPath::climbsim(&sim_client)];
    if let Some(client) = &baseline_client {
        paths.push(TimedPath::climbsim(client));
    }
    for path in &paths {
        path.round_trip(&request, &mut buf);
    }

    for _ in 0..cfg.warmup {
        for path in &paths {
            path.round_trip(&request, &mut buf);
        }
    }
    let mut samples: Vec<Vec<u64>> = vec![Vec::with_capacity(cfg.blocks * cfg.per_block); paths.len()];
    let started = Instant::now();
    for block in 0..cfg.blocks {
        // Rotate which one goes first in a block, so none always follows another.
        for turn in 0..paths.len() {
            let index = (block + turn) % paths.len();
            for _ in 0..cfg.per_block {
                samples[index].push(paths[index].round_trip(&request, &mut buf));
            }
        }
    }
    let wall = started.elapsed();

    drop(paths);
    drop(sim_client);
    drop(baseline_client);
    let exit_ok = emulator.stop() && baseline.as_mut().is_none_or(|b| b.stop());
    echo.stop();

    let mut samples = samples.into_iter();
    let echo_stats = Stats::of(&mut samples.next().expect("echo samples"));
    let sim_stats = Stats::of(&mut samples.next().expect("climbsim samples"));
    let baseline_stats = samples.next().map(|mut s| Stats::of(&mut s));
    let ratio = sim_stats.median_ns as f64 / echo_stats.median_ns as f64;

    println!();
    println!(
        "pty round-trip latency ({} round trips each, interleaved in {} blocks, {:.1} s){}",
        echo_stats.n,
        cfg.blocks,
        wall.as_secs_f64(),
        if cfg.full { "" } else { "  [smoke run, not a measurement]" }
    );
    println!("| path                                     |     n | min µs | median µs | p90 µs | p99 µs | max µs |");
    println!("|------------------------------------------|------:|-------:|----------:|-------:|-------:|-------:|");
    echo_stats.row("raw pty echo (14 B out, 14 B back)");
    sim_stats.row("climbsim --timing off (14 B, 15 B reply)");
    if let Some(stats) = &baseline_stats {
        stats.row("baseline (CLIMBSIM_BASELINE), same");
    }
    println!();
    let met = ratio <= TARGET_RATIO;
    println!("ratio median(climbsim) / median(echo) = {ratio:.2}  (target ≤ {TARGET_RATIO}: {})", if met { "met" } else { "NOT met" });
    println!("climbsim overhead over the echo floor (median) = {:.1} µs", (sim_stats.median_ns as f64 - echo_stats.median_ns as f64) / 1e3);
    let baseline_ratio = baseline_stats.as_ref().map(|b| sim_stats.median_ns as f64 / b.median_ns as f64);
    if let (Some(stats), Some(ab)) = (&baseline_stats, baseline_ratio) {
        println!("baseline: ratio to echo {:.2}; median(climbsim) / median(baseline) = {ab:.3}", stats.median_ns as f64 / echo_stats.median_ns as f64);
    }

    if cfg.full {
        let json = serde_json::json!({
            "bench": "pty_latency",
            "round_trips_each": echo_stats.n,
            "blocks": cfg.blocks,
            "warmup_each": cfg.warmup,
            "request_bytes": request.len(),
            "echo": echo_stats.json(),
            "climbsim_timing_off": sim_stats.json(),
            "baseline": baseline_stats.as_ref().map(Stats::json),
            "baseline_binary": baseline_bin.map(|p| p.display().to_string()),
            "ratio_median": ratio,
            "ratio_to_baseline": baseline_ratio,
            "target_ratio_max": TARGET_RATIO,
            "target_met": met,
            "emulator_exit_ok": exit_ok,
            "nominal_baud": 57600,
        });
        let path = support::results_dir().join("pty_latency.json");
        std::fs::write(&path, serde_json::to_string_pretty(&json).expect("json") + "\n").expect("write results");
        println!("results: {}", path.display());
        use support::history::figure;
        let mut figures = vec![figure("echo_median", echo_stats.median_ns as f64 / 1e3, "us"), figure("climbsim_median", sim_stats.median_ns as f64 / 1e3, "us"), figure("ratio_to_echo", ratio, "x")];
        figures.extend(baseline_ratio.map(|r| figure("ratio_to_baseline", r, "x")));
        support::history::record("pty_latency", &figures);
    }
    assert!(exit_ok, "climbsim did not exit 0 on SIGTERM");
}

fn check_reply(reply: &[u8]) {
    assert_eq!(&reply[..9], &[0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x08, 0x00, 0x55, 0x00], "status header of the Present Position reply: {reply:02X?}");
    let crc = u16::from_le_bytes([reply[13], reply[14]]);
    assert_eq!(crc, crc16(&reply[..13]), "CRC of the reply {reply:02X?}");
}

struct Stats {
    n: usize,
    min_ns: u64,
    median_ns: u64,
    p90_ns: u64,
    p99_ns: u64,
    max_ns: u64,
    mean_ns: f64,
}

impl Stats {
    fn of(samples: &mut [u64]) -> Self {
        samples.sort_unstable();
        let pct = |p: f64| samples[((samples.len() - 1) as f64 * p).round() as usize];
        Self {
            n: samples.len(),
            min_ns: samples[0],
            median_ns: pct(0.5),
            p90_ns: pct(0.9),
            p99_ns: pct(0.99),
            max_ns: *samples.last().unwrap(),
            mean_ns: samples.iter().sum::<u64>() as f64 / samples.len() as f64,
        }
    }

    fn row(&self, name: &str) {
        let us = |ns: u64| ns as f64 / 1e3;
        println!("| {name:<40} | {:>5} | {:>6.1} | {:>9.1} | {:>6.1} | {:>6.1} | {:>6.0} |", self.n, us(self.min_ns), us(self.median_ns), us(self.p90_ns), us(self.p99_ns), us(self.max_ns));
    }

    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "n": self.n,
            "min_us": self.min_ns as f64 / 1e3,
            "median_us": self.median_ns as f64 / 1e3,
            "p90_us": self.p90_ns as f64 / 1e3,
            "p99_us": self.p99_ns as f64 / 1e3,
            "max_us": self.max_ns as f64 / 1e3,
            "mean_us": self.mean_ns / 1e3,
        })
    }
}
