//! A wheel controller written as Rust programs usually are, for the virtual-time tests: std
//! threads and an `mpsc` channel on `dynamixel2`. It pings servos 1-8, then runs a 50 Hz loop
//! (Sync Read of the wheels' Present Velocity, Sync Write of their Goal Velocity) for 2 s, and
//! sends each cycle to a statistics thread that waits on the channel with a 7 ms timeout. std's
//! sleeps, channel waits and joins are futex system calls with absolute CLOCK_MONOTONIC
//! deadlines: on virtual time they are followed only through the shim's seccomp layer. With
//! `--until-stopped` it runs until SIGTERM (a `sigaction` handler that sets a flag), as services
//! do, and reports then.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const WHEELS: [u8; 4] = [1, 2, 3, 4];
const PRESENT_VELOCITY: u16 = 128;
const GOAL_VELOCITY: u16 = 104;

/// Set by SIGTERM (with `--until-stopped`).
static STOPPING: AtomicBool = AtomicBool::new(false);

extern "C" fn on_sigterm(_signal: libc::c_int) {
    STOPPING.store(true, Ordering::Relaxed);
}

struct Cycle {
    at_ms: f64,
    answered: usize,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let port = std::env::var("DXL_PORT")?;
    let baud: u32 = std::env::var("DXL_BAUD").unwrap_or_else(|_| "57600".into()).parse()?;
    let mut bus = dynamixel2::Bus::<Vec<u8>, Vec<u8>>::open(&port, baud)?;
    let found = (1..=8).filter(|&id| bus.ping(id).is_ok()).count();
    println!("ping 1-8: {found} found");

    let (to_stats, from_loop) = mpsc::channel::<Cycle>();
    let stats = std::thread::spawn(move || {
        let (mut cycles, mut timeouts, mut answered, mut last_ms) = (0, 0, 0, 0.0);
        loop {
            match from_loop.recv_timeout(Duration::from_millis(7)) {
                Ok(cycle) => {
                    cycles += 1;
                    answered += cycle.answered;
                    last_ms = cycle.at_ms;
                }
                Err(mpsc::RecvTimeoutError::Timeout) => timeouts += 1,
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            }
        }
        println!("stats: {cycles} cycles, {answered} replies, {timeouts} timeouts, last at {last_ms:.3} ms");
    });

    let until_stopped = std::env::args().any(|arg| arg == "--until-stopped");
    if until_stopped {
        // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
        unsafe { libc::signal(libc::SIGTERM, on_sigterm as *const () as libc::sighandler_t) };
    }
    let start = Instant::now();
    let mut next = start;
    let mut longest = Duration::ZERO;
    let mut previous = start;
    let mut cycle = 0u32;
    while if until_stopped { !STOPPING.load(Ordering::Relaxed) } else { cycle < 100 } {
        next += Duration::from_millis(20);
        let mut answered = 0;
        bus.sync_read_u32_cb(&WHEELS, PRESENT_VELOCITY, |reply| answered += usize::from(reply.is_ok()))?;
        let goal = (cycle % 50) * 2;
        let goals: Vec<_> = WHEELS.iter().map(|&motor_id| dynamixel2::instructions::SyncWriteData { motor_id, data: goal }).collect();
        bus.sync_write_u32(GOAL_VELOCITY, &goals)?;
        to_stats.send(Cycle { at_ms: start.elapsed().as_secs_f64() * 1e3, answered })?;
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
        let now = Instant::now();
        longest = longest.max(now - previous);
        previous = now;
        cycle += 1;
    }
    drop(to_stats);
    stats.join().map_err(|_| "the statistics thread panicked")?;
    if until_stopped {
        // Stopped, the report comes after the run's end, on the wall clock: no time of it is told.
        println!("loop: {cycle} cycles, longest period {:.3} ms", longest.as_secs_f64() * 1e3);
    } else {
        println!("loop: {cycle} cycles in {:.3} ms, longest period {:.3} ms", start.elapsed().as_secs_f64() * 1e3, longest.as_secs_f64() * 1e3);
    }
    Ok(())
}
