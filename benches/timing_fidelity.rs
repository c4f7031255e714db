//! Timing fidelity (issue #5): at 57600 bps, 1 Mbps and 4 Mbps, the measured median
//! request→reply time of a real client on the pty against the wire-time prediction
//! (request + reply bytes) × 10 / baud + Return Delay Time. Target: within 5 % or 50 µs.
//! Reported, not asserted.
//!
//! For each baud a fresh `climbsim serve --baud B` (default `--timing wire`, Return Delay Time
//! 250 × 2 µs = 500 µs) is started; the client opens the pty raw at that baud, writes a Read of
//! Present Position (ID 1, 4 bytes: 14-byte instruction, 15-byte status) and a Ping (10 → 14
//! bytes), and times from the write to the reply's last byte. Results: a table on stdout and
//! `target/bench-results/timing_fidelity.json`. A raw pty echo of the same request, timed in
//! blocks interleaved with the emulator's, shows what the host's pty and wake-ups cost by
//! themselves (a floor the wire model does not include).
//!
//! `cargo bench --bench timing_fidelity` measures; without `--bench` a short smoke pass.
//! `CLIMBSIM_BASELINE=<another climbsim binary>` also times that build, in blocks interleaved
//! with this one's, for an A/B under the same machine conditions (rows marked "baseline").

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
    let mut figures = Vec::new();
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
        let mut baseline = support::start_baseline(&["--baud", &bps_text]);
        let baseline_port = baseline.as_ref().map(|b| support::open_raw_port(b.port(), baud));
        let echo = support::PtyEcho::start(baud);
        let mut buf = [0u8; 64];
        for case in &cases {
            // Round trips take 0.6–5.5 ms: a few seconds per case when measuring.
            let (warmup, n) = if full { (50, if bps < 100_000 { 500 } else { 2_000 }) } else { (5, 20) };
            let ports: Vec<&std::fs::File> = std::iter::once(&port).chain(baseline_port.as_ref()).chain([echo.client()]).collect();
            // The echo (last) returns the request itself.
            let expect = |index: usize| if index == ports.len() - 1 { case.request.len() } else { case.reply_len };
            for (index, port) in ports.iter().enumerate() {
                for _ in 0..warmup {
                    support::round_trip(port, &case.request, expect(index), &mut buf);
                }
            }
            let mut samples: Vec<Vec<f64>> = vec![Vec::with_capacity(n); ports.len()];
            const BLOCK: usize = 50;
            while samples[0].len() < n {
                for (index, port) in ports.iter().enumerate() {
                    let expect = expect(index);
                    for _ in 0..BLOCK.min(n - samples[index].len()) {
                        samples[index].push(support::round_trip(port, &case.request, expect, &mut buf) as f64 / 1e3);
                        assert_eq!(buf[4], 1, "reply from ID 1");
                    }
                }
            }
            let predicted = ((case.request.len() + case.reply_len) as f64 * BITS_PER_BYTE / f64::from(bps) + RETURN_DELAY_S) * 1e6;
            let mut echo_us = samples.pop().expect("echo samples");
            let echo_median = support::median(&mut echo_us);
            println!("|   | pty echo of the request, same blocks (the host's floor) | {n} | | {echo_median:.1} | | | | |");
            rows.push(serde_json::json!({ "baud": bps, "packet": format!("{} (pty echo floor)", case.name), "n": n, "median_us": echo_median }));
            let short = if case.name == "Ping" { "ping" } else { "read4" };
            figures.push(support::history::figure(format!("{bps}_{short}_echo_floor"), echo_median, "us"));
            for (index, mut us) in samples.into_iter().enumerate() {
                let median = support::median(&mut us);
                let p99 = us[(us.len() * 99 / 100).min(us.len() - 1)];
                let error = median - predicted;
                let percent = 100.0 * error / predicted;
                let met = error.abs() <= 50.0 || percent.abs() <= 5.0;
                let name = if index == 0 { case.name.to_owned() } else { format!("{} (baseline)", case.name) };
                println!("| {bps} | {name} | {n} | {predicted:.1} | {median:.1} | {p99:.1} | {error:+.1} | {percent:+.2} | {} |", if met { "yes" } else { "NO" });
                let which = if index == 0 { "" } else { "_baseline" };
                figures.push(support::history::figure(format!("{bps}_{short}_error{which}"), error, "us"));
                rows.push(serde_json::json!({
                    "baud": bps, "packet": name, "n": n, "predicted_us": predicted, "median_us": median,
                    "p99_us": p99, "error_us": error, "error_pct": percent, "target_met": met,
                }));
            }
        }
        drop(port);
        drop(baseline_port);
        echo.stop();
        assert!(emulator.stop(), "climbsim did not exit 0 on SIGTERM");
        assert!(baseline.as_mut().is_none_or(|b| b.stop()), "the baseline did not exit 0 on SIGTERM");
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
        support::history::record("timing_fidelity", &figures);
    }
}
