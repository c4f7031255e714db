//! Timing fidelity (issue #5): at 57600 bps, 1 Mbps and 4 Mbps, the measured median
//! request→reply time of a real client on the pty against the wire-time prediction
//! (request + reply bytes) × 10 / baud + Return Delay Time. Target: within 5 % or 50 µs.
//! Reported, not asserted.
//!
//! For each baud a fresh `climbsim serve --baud B` (default `--timing wire`, Return Delay Time
//! 250 × 2 µs = 500 µs) is started; the client opens the pty raw at that baud, writes a Read of
//! Present Position (ID 1, 4 bytes: 14-byte instruction, 15-byte status) and a Ping (10 → 14
//! bytes), and times from the write to the reply's last byte. Results: a table on stdout and
//! `target/bench-results/timing_fidelity.json`.
//!
//! `cargo bench --bench timing_fidelity` measures; without `--bench` a short smoke pass.

#[path = "../tests/support/mod.rs"]
mod support;


use climbsim::protocol::encode_instruction;
use nix::sys::termios::BaudRate;
use support::Emulator;

const RETURN_DELAY_S: f64 = 500e-6;
const BITS_PER_BYTE: f64 = 10.0;

struct Case {
    name: &'static str,
    request: Vec<u8>,
    reply_len: usize,
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let cases = [
        Case { name: "Read 4 B", request: encode_instruction(1, 0x02, &[132, 0, 4, 0]), reply_len: 15 },
        Case { name: "Ping", request: encode_instruction(1, 0x01, &[]), reply_len: 14 },
    ];
    let bauds = [(57_600u32, BaudRate::B57600), (1_000_000, BaudRate::B1000000), (4_000_000, BaudRate::B4000000)];
    let mut rows = Vec::new();
    println!();
    println!("request→reply over a real pty, --timing wire, Return Delay Time 500 µs{}", if full { "" } else { "  [smoke run, not a measurement]" });
    println!("| baud | packet | n | predicted µs | median µs | p99 µs | median − predicted µs | % | within 5 % or 50 µs |");
    println!("|---:|---|---:|---:|---:|---:|---:|---:|---|");
    for (bps, baud) in bauds {
        let bps_text = bps.to_string();
        let report = support::scratch_dir("timing-fidelity").join(format!("timing-{bps}.json"));
        let report_text = report.display().to_string();
        let mut emulator = Emulator::start(&["--baud", &bps_text, "--report", &report_text]);
        let port = support::open_raw_port(emulator.port(), baud);
        let mut buf = [0u8; 64];
        for case in &cases {
            // Round trips take 0.6–5.5 ms: a few seconds per case when measuring.
            let (warmup, n) = if full { (50, if bps < 100_000 { 500 } else { 2_000 }) } else { (5, 20) };
            for _ in 0..warmup {
                support::round_trip(&port, &case.request, case.reply_len, &mut buf);
            }
            let mut us: Vec<f64> = (0..n).map(|_| support::round_trip(&port, &case.request, case.reply_len, &mut buf) as f64 / 1e3).collect();
            assert_eq!(buf[4], 1, "reply from ID 1");
            let median = support::median(&mut us);
            let p99 = us[(us.len() * 99 / 100).min(us.len() - 1)];
            let predicted = ((case.request.len() + case.reply_len) as f64 * BITS_PER_BYTE / f64::from(bps) + RETURN_DELAY_S) * 1e6;
            let error = median - predicted;
            let percent = 100.0 * error / predicted;
            let met = error.abs() <= 50.0 || percent.abs() <= 5.0;
            println!("| {bps} | {} | {n} | {predicted:.1} | {median:.1} | {p99:.1} | {error:+.1} | {percent:+.2} | {} |", case.name, if met { "yes" } else { "NO" });
            rows.push(serde_json::json!({
                "baud": bps, "packet": case.name, "n": n, "predicted_us": predicted, "median_us": median,
                "p99_us": p99, "error_us": error, "error_pct": percent, "target_met": met,
            }));
        }
        drop(port);
        assert!(emulator.stop(), "climbsim did not exit 0 on SIGTERM");
        // The emulator's own part of the error: how long after the wire model's due time it
        // handed replies to the pty (the rest is the pty and the client waking up).
        let timing: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).expect("timing report")).expect("report JSON");
        let lateness = &timing["delivery_lateness_us"];
        println!("|   | emulator's hand-over after the due time (all {bps} bps replies) | {} | | p50 {:.1} | p99 {:.1} | | | |", lateness["count"], lateness["p50_us"].as_f64().unwrap_or(f64::NAN), lateness["p99_us"].as_f64().unwrap_or(f64::NAN));
        rows.push(serde_json::json!({ "baud": bps, "emulator_handover_lateness_us": lateness }));
    }
    if full {
        let json = serde_json::json!({ "bench": "timing_fidelity", "return_delay_us": RETURN_DELAY_S * 1e6, "rows": rows });
        let path = support::results_dir().join("timing_fidelity.json");
        std::fs::write(&path, serde_json::to_string_pretty(&json).expect("json") + "\n").expect("write results");
        println!("results: {}", path.display());
    }
}
