//! Control-loop rate a `dynamixel2` (0.9.1) controller reaches against climbsim over a real pty.
//!
//! One cycle = one Sync Read of 8 IDs × 8 bytes at address 128 (Present Velocity + Present
//! Position) + one Sync Write of 8 × Goal Velocity (address 104, 4 bytes), with all servos in
//! velocity mode (Operating Mode 1) and torque on. dynamixel2's `sync_write` does not wait for
//! anything (there is no reply); the next Sync Read queues behind it on the wire.
//!
//! 1. `serve --timing off`, client at 57600: cycles/s for ~3 s. Target ≥ 20 000 cycles/s.
//!    `CLIMBSIM_BASELINE=<another climbsim binary>` interleaves it, in quarter-second slices, for
//!    an A/B of two builds under the same machine conditions.
//! 2. `serve --timing wire --baud 4000000`, client at 4 Mbps: measured cycles/s against the wire
//!    model's prediction, with the default Return Delay Time (250 = 500 µs per reply) and again
//!    after writing Return Delay Time = 0 to all servos (EEPROM, torque off first).
//!    Target: measured within 10 % of the prediction.
//!
//! Model (climbsim's `--timing wire`): an instruction occupies bytes × 10 / baud from when it
//! arrives or the wire frees, whichever is later; each reply starts Return Delay Time after the
//! end of what precedes it and lasts bytes × 10 / baud. So one cycle is predicted to take
//! `(sync-read bytes + 8 × reply bytes + sync-write bytes) × 10 / baud + 8 × RDT`; what the
//! measurement adds on top is the client's turnaround (last reply in → Sync Write out).
//!
//! Results: a table on stdout and `target/bench-results/loop_rate.json`. Without `--bench` (e.g.
//! `cargo test --benches`) it runs a short smoke pass and writes nothing.

#[path = "../tests/support/mod.rs"]
mod support;

use std::time::{Duration, Instant};

use climbsim::protocol::{encode_instruction, encode_status};
use dynamixel2::instructions::SyncWriteData;
use support::Emulator;

type Bus = dynamixel2::Bus<Vec<u8>, Vec<u8>>;

const IDS: [u8; 8] = [1, 2, 3, 4, 5, 6, 7, 8];
const A_RETURN_DELAY: u16 = 9;
const A_OPERATING_MODE: u16 = 11;
const A_TORQUE: u16 = 64;
const A_GOAL_VELOCITY: u16 = 104;
const A_PRESENT_VELOCITY: u16 = 128;
const READ_LEN: u16 = 8;
const SYNC_READ: u8 = 0x82;
const SYNC_WRITE: u8 = 0x83;
const WIRE_BAUD: u32 = 4_000_000;
/// Cycles per second to reach at `--timing off`.
const TARGET_RATE: f64 = 20_000.0;
const BITS_PER_BYTE: f64 = 10.0;
/// Small goal velocities (0.229 rev/min units): wheels turning, magnet shafts still. None is
/// negative on purpose: dynamixel2 0.9.1 mis-unstuffs `FF FF FF FD FD` (its unstuffing state
/// machine resets on the third `FF`), which a negative Present Velocity (`.. FF FF FF`) followed by
/// a Present Position whose low byte is 0xFD puts on the wire; the crate then reports 9 parameters
/// instead of 8. The emulator's reply is correct; a real servo would send the same bytes.
const GOALS: [i32; 8] = [10, 10, 10, 10, 0, 0, 0, 0];

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (run_for, warm_for) = if full { (Duration::from_secs(3), Duration::from_millis(300)) } else { (Duration::from_millis(200), Duration::from_millis(20)) };
    let goals: Vec<SyncWriteData<u32>> = IDS.iter().zip(GOALS).map(|(&id, v)| SyncWriteData { motor_id: id, data: v as u32 }).collect();

    // Wire bytes of one cycle, from the codec that builds the real packets.
    let mut sync_read_params = vec![];
    sync_read_params.extend_from_slice(&A_PRESENT_VELOCITY.to_le_bytes());
    sync_read_params.extend_from_slice(&READ_LEN.to_le_bytes());
    sync_read_params.extend_from_slice(&IDS);
    let sync_read_bytes = encode_instruction(0xFE, SYNC_READ, &sync_read_params).len();
    let reply_bytes = encode_status(1, 0, &[0; READ_LEN as usize]).len();
    let mut sync_write_params = vec![];
    sync_write_params.extend_from_slice(&A_GOAL_VELOCITY.to_le_bytes());
    sync_write_params.extend_from_slice(&4u16.to_le_bytes());
    for g in &goals {
        sync_write_params.push(g.motor_id);
        sync_write_params.extend_from_slice(&g.data.to_le_bytes());
    }
    let sync_write_bytes = encode_instruction(0xFE, SYNC_WRITE, &sync_write_params).len();
    let cycle_bytes = sync_read_bytes + IDS.len() * reply_bytes + sync_write_bytes;

    // 1. Timing off: this build, two pty floors (a thread answering each Sync Read with eight
    // canned replies at once: no bus, no servos; one sleeps in read(2), one spins for the next
    // request as climbsim does), and a baseline build if one is given, all interleaved.
    let sync_read = encode_instruction(0xFE, SYNC_READ, &sync_read_params);
    let canned: Vec<u8> = IDS.iter().flat_map(|&id| encode_status(id, 0, &[0; READ_LEN as usize])).collect();
    let mut floors: Vec<(Responder, Bus)> = [Wait::Sleep, Wait::Spin]
        .into_iter()
        .map(|wait| {
            let responder = canned_responder(sync_read.clone(), canned.clone(), wait);
            let mut bus = Bus::open(&responder.path, 57_600).expect("open the floor's pty at 57600");
            run(&mut bus, &goals, warm_for);
            (responder, bus)
        })
        .collect();
    let baseline_bin = support::baseline_binary();
    let mut emu = Emulator::start(&["--timing", "off"]);
    let mut baseline_emu = support::start_baseline(&["--timing", "off"]);
    let mut bus = Bus::open(emu.port(), 57_600).expect("open pty at 57600");
    let mut baseline_bus = baseline_emu.as_ref().map(|e| Bus::open(e.port(), 57_600).expect("open the baseline's pty at 57600"));
    velocity_mode(&mut bus);
    run(&mut bus, &goals, warm_for);
    if let Some(b) = baseline_bus.as_mut() {
        velocity_mode(b);
        run(b, &goals, warm_for);
    }
    // Slices of a quarter second, alternating, so all see the same machine.
    let (mut off, mut baseline_off) = (Run::default(), baseline_bus.as_ref().map(|_| Run::default()));
    let mut floor_runs: Vec<Run> = floors.iter().map(|_| Run::default()).collect();
    let slice = Duration::from_millis(250);
    while off.elapsed < run_for {
        off.extend(run(&mut bus, &goals, slice));
        for ((_, floor_bus), floor) in floors.iter_mut().zip(&mut floor_runs) {
            floor.extend(run(floor_bus, &goals, slice));
        }
        if let (Some(b), Some(other)) = (baseline_bus.as_mut(), baseline_off.as_mut()) {
            other.extend(run(b, &goals, slice));
        }
    }
    for (responder, floor_bus) in floors {
        drop(floor_bus);
        responder.stop();
    }
    let [sleeping_floor, spinning_floor] = <[Run; 2]>::try_from(floor_runs).unwrap_or_else(|_| unreachable!("two floors"));
    drop(bus);
    drop(baseline_bus);
    let off_exit_ok = emu.stop() && baseline_emu.as_mut().is_none_or(|e| e.stop());

    // 2. Wire timing at 4 Mbps.
    let mut emu = Emulator::start(&["--timing", "wire", "--baud", "4000000"]);
    let mut bus = Bus::open(emu.port(), WIRE_BAUD).expect("open pty at 4 Mbps");
    velocity_mode(&mut bus);
    let mut wire = Vec::new();
    for rdt_code in [250u8, 0] {
        for id in IDS {
            write(&mut bus, id, A_TORQUE, 0);
            write(&mut bus, id, A_RETURN_DELAY, rdt_code);
            write(&mut bus, id, A_TORQUE, 1);
            let back = bus.read_u8(id, A_RETURN_DELAY).unwrap_or_else(|e| panic!("read RDT of {id}: {e}")).data;
            assert_eq!(back, rdt_code, "Return Delay Time of ID {id}");
        }
        run(&mut bus, &goals, warm_for);
        let measured = run(&mut bus, &goals, run_for);
        let rdt_s = f64::from(rdt_code) * 2e-6;
        let predicted_cycle_s = cycle_bytes as f64 * BITS_PER_BYTE / f64::from(WIRE_BAUD) + IDS.len() as f64 * rdt_s;
        wire.push((rdt_code, measured, predicted_cycle_s));
    }
    drop(bus);
    let wire_exit_ok = emu.stop();

    // Report.
    let smoke = if full { "" } else { "  [smoke run, not a measurement]" };
    println!();
    println!("dynamixel2 control loop: Sync Read 8 × 8 B @128 + Sync Write 8 × 4 B @104 per cycle{smoke}");
    println!("wire bytes per cycle: sync read {sync_read_bytes} + 8 × reply {reply_bytes} + sync write {sync_write_bytes} = {cycle_bytes}");
    println!();
    println!("| run                                  | cycles | s    | cycles/s | median µs | p99 µs | target       | errors |");
    println!("|--------------------------------------|-------:|-----:|---------:|----------:|-------:|--------------|-------:|");
    println!(
        "| --timing off, 57600 nominal          | {:>6} | {:.2} | {:>8.0} | {:>9.1} | {:>6.1} | ≥ 20000: {:<3} | {:>6} |",
        off.cycles,
        off.elapsed.as_secs_f64(),
        off.rate(),
        off.median_us(),
        off.p99_us(),
        if off.rate() >= TARGET_RATE { "met" } else { "NOT" },
        off.errors
    );
    for (label, floor) in [("pty floor: canned, sleeping server  ", &sleeping_floor), ("pty floor: canned, spinning server  ", &spinning_floor)] {
        println!(
            "| {label} | {:>6} | {:.2} | {:>8.0} | {:>9.1} | {:>6.1} |              | {:>6} |",
            floor.cycles,
            floor.elapsed.as_secs_f64(),
            floor.rate(),
            floor.median_us(),
            floor.p99_us(),
            floor.errors
        );
    }
    // The faster floor is the least any pty emulator can cost this loop on this machine.
    let floor = if spinning_floor.rate() >= sleeping_floor.rate() { &spinning_floor } else { &sleeping_floor };
    println!("rate(climbsim) / rate(faster floor) = {:.3}", off.rate() / floor.rate());
    if let Some(b) = &baseline_off {
        println!(
            "| baseline (CLIMBSIM_BASELINE), same   | {:>6} | {:.2} | {:>8.0} | {:>9.1} | {:>6.1} |              | {:>6} |",
            b.cycles,
            b.elapsed.as_secs_f64(),
            b.rate(),
            b.median_us(),
            b.p99_us(),
            b.errors
        );
        println!("rate(climbsim) / rate(baseline) = {:.3}", off.rate() / b.rate());
    }
    println!();
    println!("| --timing wire, 4 Mbps      | cycles/s measured | cycles/s predicted | µs/cycle measured | µs/cycle predicted | extra µs/cycle | difference | ≤ 10 % | errors |");
    println!("|----------------------------|------------------:|-------------------:|------------------:|-------------------:|---------------:|-----------:|--------|-------:|");
    let mut wire_json = Vec::new();
    let mut wire_differences = Vec::new();
    for (rdt_code, measured, predicted_cycle_s) in &wire {
        let predicted_rate = 1.0 / predicted_cycle_s;
        let diff = (measured.rate() - predicted_rate) / predicted_rate;
        wire_differences.push((*rdt_code, diff));
        println!(
            "| RDT {:>3} ({:>3} µs per reply) | {:>17.1} | {:>18.1} | {:>17.1} | {:>18.1} | {:>14.1} | {:>+8.1} % | {:<6} | {:>6} |",
            rdt_code,
            u32::from(*rdt_code) * 2,
            measured.rate(),
            predicted_rate,
            1e6 / measured.rate(),
            predicted_cycle_s * 1e6,
            1e6 / measured.rate() - predicted_cycle_s * 1e6,
            diff * 100.0,
            if diff.abs() <= 0.10 { "met" } else { "NOT" },
            measured.errors
        );
        wire_json.push(serde_json::json!({
            "return_delay_time_code": rdt_code,
            "return_delay_time_us": u32::from(*rdt_code) * 2,
            "cycles": measured.cycles,
            "seconds": measured.elapsed.as_secs_f64(),
            "measured_cycles_per_s": measured.rate(),
            "predicted_cycles_per_s": predicted_rate,
            "measured_cycle_us": 1e6 / measured.rate(),
            "predicted_cycle_us": predicted_cycle_s * 1e6,
            "extra_us_per_cycle": 1e6 / measured.rate() - predicted_cycle_s * 1e6,
            "median_cycle_us": measured.median_us(),
            "p99_cycle_us": measured.p99_us(),
            "relative_difference": diff,
            "target_max_relative_difference": 0.10,
            "target_met": diff.abs() <= 0.10,
            "errors": measured.errors,
        }));
    }

    let errors = off.errors + sleeping_floor.errors + spinning_floor.errors + baseline_off.as_ref().map_or(0, |b| b.errors) + wire.iter().map(|w| w.1.errors).sum::<usize>();
    if full {
        let json = serde_json::json!({
            "bench": "loop_rate",
            "client": "dynamixel2 0.9.1",
            "cycle": "sync_read 8 ids x 8 bytes @128 + sync_write 8 x 4 bytes @104 (velocity mode, torque on)",
            "bytes": {
                "sync_read_instruction": sync_read_bytes,
                "status_reply_each": reply_bytes,
                "sync_write_instruction": sync_write_bytes,
                "per_cycle": cycle_bytes,
            },
            "timing_off_57600": {
                "cycles": off.cycles,
                "seconds": off.elapsed.as_secs_f64(),
                "cycles_per_s": off.rate(),
                "median_cycle_us": off.median_us(),
                "p99_cycle_us": off.p99_us(),
                "target_min_cycles_per_s": TARGET_RATE,
                "target_met": off.rate() >= TARGET_RATE,
                "errors": off.errors,
            },
            "pty_floor_canned_replies_sleeping_server": {
                "cycles_per_s": sleeping_floor.rate(),
                "median_cycle_us": sleeping_floor.median_us(),
                "p99_cycle_us": sleeping_floor.p99_us(),
                "errors": sleeping_floor.errors,
            },
            "pty_floor_canned_replies_spinning_server": {
                "cycles_per_s": spinning_floor.rate(),
                "median_cycle_us": spinning_floor.median_us(),
                "p99_cycle_us": spinning_floor.p99_us(),
                "errors": spinning_floor.errors,
            },
            "ratio_to_faster_floor": off.rate() / floor.rate(),
            "baseline_timing_off_57600": baseline_off.as_ref().map(|b| serde_json::json!({
                "binary": baseline_bin.map(|p| p.display().to_string()),
                "cycles_per_s": b.rate(),
                "median_cycle_us": b.median_us(),
                "errors": b.errors,
            })),
            "timing_wire_4mbps": wire_json,
            "emulator_exit_ok": off_exit_ok && wire_exit_ok,
        });
        let path = support::results_dir().join("loop_rate.json");
        std::fs::write(&path, serde_json::to_string_pretty(&json).expect("json") + "\n").expect("write results");
        println!("results: {}", path.display());
        use support::history::figure;
        let mut figures = vec![
            figure("timing_off_cycles_per_s", off.rate(), "1/s"),
            figure("pty_floor_cycles_per_s", sleeping_floor.rate(), "1/s"),
            figure("pty_spinning_floor_cycles_per_s", spinning_floor.rate(), "1/s"),
            figure("ratio_to_faster_floor", off.rate() / floor.rate(), "x"),
        ];
        figures.extend(baseline_off.as_ref().map(|b| figure("ratio_to_baseline", off.rate() / b.rate(), "x")));
        for (rdt_code, diff) in &wire_differences {
            figures.push(figure(format!("wire_rdt{rdt_code}_difference"), 100.0 * diff, "%"));
        }
        support::history::record("loop_rate", &figures);
    }
    assert!(off_exit_ok && wire_exit_ok, "climbsim did not exit 0 on SIGTERM");
    assert_eq!(errors, 0, "some Sync Read replies were missing or wrong: the numbers above are not valid");
}

fn write(bus: &mut Bus, id: u8, address: u16, value: u8) {
    bus.write_u8(id, address, value).unwrap_or_else(|e| panic!("write {value} to {address} of ID {id}: {e}"));
}

/// Torque off, Operating Mode 1 (velocity), torque on, on every servo.
fn velocity_mode(bus: &mut Bus) {
    for id in IDS {
        write(bus, id, A_TORQUE, 0);
        write(bus, id, A_OPERATING_MODE, 1);
        write(bus, id, A_TORQUE, 1);
    }
}

#[derive(Default)]
struct Run {
    cycles: usize,
    errors: usize,
    elapsed: Duration,
    cycle_ns: Vec<u64>,
}

impl Run {
    fn extend(&mut self, more: Run) {
        self.cycles += more.cycles;
        self.errors += more.errors;
        self.elapsed += more.elapsed;
        self.cycle_ns.extend(more.cycle_ns);
    }

    fn rate(&self) -> f64 {
        self.cycles as f64 / self.elapsed.as_secs_f64()
    }
    fn pct_us(&self, p: f64) -> f64 {
        let mut v = self.cycle_ns.clone();
        v.sort_unstable();
        v[((v.len() - 1) as f64 * p).round() as usize] as f64 / 1e3
    }
    fn median_us(&self) -> f64 {
        self.pct_us(0.5)
    }
    fn p99_us(&self) -> f64 {
        self.pct_us(0.99)
    }
}

/// Run the loop for `duration`. A cycle counts as an error unless all 8 servos answered, in
/// order, with 8 bytes each.
fn run(bus: &mut Bus, goals: &[SyncWriteData<u32>], duration: Duration) -> Run {
    let mut cycle_ns = Vec::with_capacity(100_000);
    let mut errors = 0;
    let mut samples: Vec<String> = Vec::new();
    let started = Instant::now();
    let mut last = started;
    while last.duration_since(started) < duration {
        let mut answered = 0usize;
        let mut next = 0usize;
        bus.sync_read_cb(&IDS, A_PRESENT_VELOCITY, READ_LEN, |reply| match reply {
            Ok(r) if r.motor_id == IDS[next] && r.data.len() == READ_LEN as usize => {
                answered += 1;
                next += 1;
            }
            Ok(r) => {
                note(&mut samples, format!("ID {} answered in slot of ID {} with {} bytes", r.motor_id, IDS[next], r.data.len()));
                next += 1;
            }
            Err(e) => {
                note(&mut samples, format!("slot of ID {}: {e}", IDS[next]));
                next += 1;
            }
        })
        .expect("sync read write");
        if answered != IDS.len() {
            errors += 1;
        }
        bus.sync_write_u32(A_GOAL_VELOCITY, goals).expect("sync write");
        let now = Instant::now();
        cycle_ns.push(now.duration_since(last).as_nanos() as u64);
        last = now;
    }
    for sample in &samples {
        eprintln!("sync read error (first of its kind): {sample}");
    }
    Run { cycles: cycle_ns.len(), errors, elapsed: last.duration_since(started), cycle_ns }
}

/// Keep the first few distinct error descriptions.
fn note(samples: &mut Vec<String>, text: String) {
    if samples.len() < 5 && !samples.contains(&text) {
        samples.push(text);
    }
}

/// How a canned responder waits for the next request.
#[derive(Clone, Copy)]
enum Wait {
    /// In read(2), as a simple server would.
    Sleep,
    /// Spinning on FIONREAD for up to [`CANNED_SPIN`] after each reply, then in read(2): what
    /// climbsim's pty thread does for a tight loop, without its bookkeeping.
    Spin,
}

/// How long the spinning responder spins after a reply (climbsim's longest spin).
const CANNED_SPIN: Duration = Duration::from_micros(250);

/// A canned responder: the slave's path, and the slave descriptor whose close ends it.
struct Responder {
    path: std::path::PathBuf,
    thread: std::thread::JoinHandle<()>,
    slave: std::fs::File,
}

impl Responder {
    /// Stop the thread and wait for it: once the client's and this last slave descriptor are
    /// closed, its next read(2) of the master (at the latest when its bounded spin ends) returns
    /// EIO.
    fn stop(self) {
        drop(self.slave);
        self.thread.join().expect("canned responder thread");
    }
}

/// A pty whose master side answers every Sync Read request (`sync_read`, byte for byte) with
/// `replies` in one write and ignores everything else: the least any emulator can cost on this
/// loop. The responder holds a descriptor of the slave until stopped (a master whose slaves have
/// all closed reads EIO).
fn canned_responder(sync_read: Vec<u8>, replies: Vec<u8>, wait: Wait) -> Responder {
    use nix::fcntl::OFlag;
    use std::os::fd::{AsFd, AsRawFd};
    let master = nix::pty::posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_CLOEXEC).expect("posix_openpt");
    nix::pty::grantpt(&master).expect("grantpt");
    nix::pty::unlockpt(&master).expect("unlockpt");
    let path = std::path::PathBuf::from(nix::pty::ptsname_r(&master).expect("ptsname"));
    let slave = std::fs::OpenOptions::new().read(true).write(true).open(&path).expect("open the slave");
    let thread = std::thread::Builder::new()
        .name("canned".into())
        .spawn(move || {
            let mut pending: Vec<u8> = Vec::new();
            let mut buf = [0u8; 4096];
            let mut spin_until: Option<Instant> = None;
            loop {
                if let Some(until) = spin_until {
                    let mut queued: libc::c_int = 0;
                    // SAFETY: FIONREAD writes one c_int through the pointer, valid for the call.
                    let rc = unsafe { libc::ioctl(master.as_raw_fd(), libc::FIONREAD, &mut queued) };
                    if rc == 0 && queued == 0 && Instant::now() < until {
                        std::hint::spin_loop();
                        continue;
                    }
                    spin_until = None;
                }
                match nix::unistd::read(master.as_fd(), &mut buf) {
                    Ok(0) | Err(_) => return,
                    Ok(n) => pending.extend_from_slice(&buf[..n]),
                }
                if matches!(wait, Wait::Spin) {
                    // Any request bytes: the rest of the cycle follows within microseconds.
                    spin_until = Some(Instant::now() + CANNED_SPIN);
                }
                while let Some(at) = pending.windows(sync_read.len()).position(|w| w == sync_read.as_slice()) {
                    pending.drain(..at + sync_read.len());
                    if nix::unistd::write(master.as_fd(), &replies).is_err() {
                        return;
                    }
                }
                // Keep only a tail that could still start a Sync Read.
                let keep_from = pending.len().saturating_sub(sync_read.len());
                pending.drain(..keep_from);
            }
        })
        .expect("spawn the canned responder");
    Responder { path, thread, slave }
}
