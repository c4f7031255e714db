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
//! themselves (a floor the wire model does not include). A timed echo, which returns the request
//! the predicted time after it read it (sleeping, then spinning its last 200 µs, as climbsim
//! does), is the floor of a timed reply: the same long sleeps on both sides of the pty, and the
//! wake-ups from them, with no emulator.
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

/// Where the client, the emulator and the echoes run.
#[derive(Clone, Copy)]
enum Placement {
    /// Wherever the scheduler puts them: on two vCPUs the emulator and the client usually sit
    /// on different ones, and each reply then wakes the client's halted vCPU.
    AsScheduled,
    /// All on one CPU (the first of this process's mask), as `taskset -c N` puts climbsim and a
    /// controller: each wake-up lands on a CPU that is already awake.
    OneCpu,
}

/// How a placement shows in rows, figures, JSON and file names.
struct PlacementTag {
    row: &'static str,
    figure: &'static str,
    json: &'static str,
    file: &'static str,
}

impl Placement {
    fn tag(self) -> PlacementTag {
        match self {
            Placement::AsScheduled => PlacementTag { row: "", figure: "", json: "as_scheduled", file: "" },
            Placement::OneCpu => PlacementTag { row: ", one CPU", figure: "_one_cpu", json: "one_cpu", file: "-one-cpu" },
        }
    }

    /// Pin this thread (and so everything it starts) for the placement; the guard restores the
    /// mask it had.
    fn pin(self) -> Option<Pinned> {
        match self {
            Placement::AsScheduled => None,
            Placement::OneCpu => Some(Pinned::to_first_cpu()),
        }
    }
}

/// This thread pinned to one CPU until dropped.
struct Pinned {
    before: libc::cpu_set_t,
}

impl Pinned {
    fn to_first_cpu() -> Self {
        // SAFETY: cpu_set_t is plain data; sched_{get,set}affinity read and write one set of the
        // size given, for the calling thread (pid 0).
        unsafe {
            let mut before: libc::cpu_set_t = std::mem::zeroed();
            assert_eq!(libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut before), 0, "sched_getaffinity");
            let first = (0..libc::CPU_SETSIZE as usize).find(|&cpu| libc::CPU_ISSET(cpu, &before)).expect("a CPU in the mask");
            let mut one: libc::cpu_set_t = std::mem::zeroed();
            libc::CPU_SET(first, &mut one);
            assert_eq!(libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &one), 0, "sched_setaffinity");
            Self { before }
        }
    }
}

impl Drop for Pinned {
    fn drop(&mut self) {
        // SAFETY: as in `to_first_cpu`, with the set saved there.
        let rc = unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &self.before) };
        assert_eq!(rc, 0, "restore the CPU mask");
    }
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let cases = [Case { name: "Read 4 B", request: encode_instruction(1, 0x02, &[132, 0, 4, 0]), reply_len: 15 }, Case { name: "Ping", request: encode_instruction(1, 0x01, &[]), reply_len: 14 }];
    let bauds = [(57_600u32, BaudRate::B57600), (1_000_000, BaudRate::B1000000), (4_000_000, BaudRate::B4000000)];
    let mut rows = Vec::new();
    let mut figures = Vec::new();
    println!();
    println!("request→reply over a real pty, --timing wire, Return Delay Time 500 µs{}", if full { "" } else { "  [smoke run, not a measurement]" });
    println!("| baud | packet | n | predicted µs | median µs | p99 µs | median − predicted µs | % | within 5 % or 50 µs |");
    println!("|---:|---|---:|---:|---:|---:|---:|---:|---|");
    for placement in [Placement::AsScheduled, Placement::OneCpu] {
        // Pinned here, before the emulator and the echoes start: they inherit the mask.
        let pinned = placement.pin();
        let tag = placement.tag();
        for (bps, baud) in bauds {
            measure_at(bps, baud, &tag, &cases, full, &mut rows, &mut figures);
        }
        drop(pinned);
    }
    if full {
        let json = serde_json::json!({ "bench": "timing_fidelity", "return_delay_us": RETURN_DELAY_S * 1e6, "rows": rows });
        let path = support::results_dir().join("timing_fidelity.json");
        std::fs::write(&path, serde_json::to_string_pretty(&json).expect("json") + "\n").expect("write results");
        println!("results: {}", path.display());
        support::history::record("timing_fidelity", &figures);
    }
}

/// Every case at `bps` against a fresh emulator (and baseline), with both echoes as floors, in
/// interleaved blocks: prints the rows and adds them to `rows` and `figures`.
fn measure_at(bps: u32, baud: BaudRate, tag: &PlacementTag, cases: &[Case], full: bool, rows: &mut Vec<serde_json::Value>, figures: &mut Vec<support::history::Figure>) {
    let bps_text = bps.to_string();
    let report = support::scratch_dir("timing-fidelity").join(format!("timing-{bps}{}.json", tag.file));
    let report_text = report.display().to_string();
    let mut emulator = Emulator::start(&["--baud", &bps_text, "--report", &report_text]);
    let port = support::open_raw_port(emulator.port(), baud);
    let mut baseline = support::start_baseline(&["--baud", &bps_text]);
    let baseline_port = baseline.as_ref().map(|b| support::open_raw_port(b.port(), baud));
    let echo = support::PtyEcho::start(baud);
    let mut buf = [0u8; 64];
    for case in cases {
        // Round trips take 0.6–5.5 ms: a few seconds per case when measuring.
        let (warmup, n) = if full { (50, if bps < 100_000 { 500 } else { 2_000 }) } else { (5, 20) };
        let predicted = ((case.request.len() + case.reply_len) as f64 * BITS_PER_BYTE / f64::from(bps) + RETURN_DELAY_S) * 1e6;
        // The request echoed the predicted time after it was read: the least a timed reply
        // can cost on this host, with the same long sleeps on both sides of the pty.
        let timed_echo = support::PtyEcho::delayed(baud, std::time::Duration::from_secs_f64(predicted / 1e6));
        let ports: Vec<&std::fs::File> = std::iter::once(&port).chain(baseline_port.as_ref()).chain([echo.client(), timed_echo.client()]).collect();
        // The two echoes (last) return the request itself.
        let expect = |index: usize| if index + 2 >= ports.len() { case.request.len() } else { case.reply_len };
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
        drop(ports);
        timed_echo.stop();
        let short = if case.name == "Ping" { "ping" } else { "read4" };
        let mut timed_us = samples.pop().expect("timed echo samples");
        let timed_median = support::median(&mut timed_us);
        let timed_error = timed_median - predicted;
        let mut echo_us = samples.pop().expect("echo samples");
        let echo_median = support::median(&mut echo_us);
        println!("|   | pty echo of the request, same blocks (the host's round trip){} | {n} | | {echo_median:.1} | | | | |", tag.row);
        println!(
            "|   | the request echoed {predicted:.1} µs after it was read, same blocks (the host's floor for a timed reply){} | {n} | {predicted:.1} | {timed_median:.1} | | {timed_error:+.1} | {:+.2} | |",
            tag.row,
            100.0 * timed_error / predicted
        );
        rows.push(serde_json::json!({ "baud": bps, "placement": tag.json, "packet": format!("{} (pty echo floor)", case.name), "n": n, "median_us": echo_median }));
        rows.push(serde_json::json!({ "baud": bps, "placement": tag.json, "packet": format!("{} (timed echo floor)", case.name), "n": n, "predicted_us": predicted, "median_us": timed_median, "error_us": timed_error }));
        figures.push(support::history::figure(format!("{bps}_{short}_echo_floor{}", tag.figure), echo_median, "us"));
        figures.push(support::history::figure(format!("{bps}_{short}_timed_echo_error{}", tag.figure), timed_error, "us"));
        for (index, mut us) in samples.into_iter().enumerate() {
            let median = support::median(&mut us);
            let p99 = us[(us.len() * 99 / 100).min(us.len() - 1)];
            let error = median - predicted;
            let percent = 100.0 * error / predicted;
            let met = error.abs() <= 50.0 || percent.abs() <= 5.0;
            let name = if index == 0 { format!("{}{}", case.name, tag.row) } else { format!("{} (baseline){}", case.name, tag.row) };
            println!("| {bps} | {name} | {n} | {predicted:.1} | {median:.1} | {p99:.1} | {error:+.1} | {percent:+.2} | {} |", if met { "yes" } else { "NO" });
            let which = if index == 0 { "" } else { "_baseline" };
            figures.push(support::history::figure(format!("{bps}_{short}_error{which}{}", tag.figure), error, "us"));
            rows.push(serde_json::json!({
                "baud": bps, "placement": tag.json, "packet": name, "n": n, "predicted_us": predicted, "median_us": median,
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
    println!(
        "|   | emulator's hand-over after the due time (all {bps} bps replies){} | {} | | p50 {:.1} | p99 {:.1} | | | |",
        tag.row,
        lateness["count"],
        lateness["p50_us"].as_f64().unwrap_or(f64::NAN),
        lateness["p99_us"].as_f64().unwrap_or(f64::NAN)
    );
    rows.push(serde_json::json!({ "baud": bps, "placement": tag.json, "emulator_handover_lateness_us": lateness }));
}
