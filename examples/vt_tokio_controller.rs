//! A wheel controller written as async Rust programs usually are, for the virtual-time tests:
//! tokio's multi-thread runtime, the blocking bus (`dynamixel2`) on tokio's blocking pool, and a
//! statistics task fed over a `tokio::sync::mpsc` channel that it waits on with a 7 ms timeout.
//! It pings servos 1-8, then runs a 50 Hz loop (Sync Read of the wheels' Present Velocity, Sync
//! Write of their Goal Velocity) on `tokio::time::interval` for 2 s. tokio's workers park on
//! futexes, its timer is `epoll_wait`'s timeout, and a task woken from another thread is an
//! eventfd write: on virtual time all of them must be followed. With `--until-stopped` it runs
//! until SIGTERM (`tokio::signal`), as services do, and reports then.

use std::time::Duration;
use tokio::sync::mpsc;
use tokio::time::{Instant, MissedTickBehavior};

const WHEELS: [u8; 4] = [1, 2, 3, 4];
const PRESENT_VELOCITY: u16 = 128;
const GOAL_VELOCITY: u16 = 104;

type Bus = dynamixel2::Bus<Vec<u8>, Vec<u8>>;
type Error = Box<dyn std::error::Error + Send + Sync>;

struct Cycle {
    at_ms: f64,
    answered: usize,
}

/// One Sync Read and one Sync Write, on tokio's blocking pool: how many wheels answered.
async fn cycle(mut bus: Bus, goal: u32) -> Result<(Bus, usize), Error> {
    tokio::task::spawn_blocking(move || -> Result<(Bus, usize), Error> {
        let mut answered = 0;
        bus.sync_read_u32_cb(&WHEELS, PRESENT_VELOCITY, |reply| answered += usize::from(reply.is_ok()))?;
        let goals: Vec<_> = WHEELS.iter().map(|&motor_id| dynamixel2::instructions::SyncWriteData { motor_id, data: goal }).collect();
        bus.sync_write_u32(GOAL_VELOCITY, &goals)?;
        Ok((bus, answered))
    })
    .await?
}

async fn statistics(mut from_loop: mpsc::Receiver<Cycle>) {
    let (mut cycles, mut timeouts, mut answered, mut last_ms) = (0, 0, 0, 0.0);
    loop {
        match tokio::time::timeout(Duration::from_millis(7), from_loop.recv()).await {
            Ok(Some(cycle)) => {
                cycles += 1;
                answered += cycle.answered;
                last_ms = cycle.at_ms;
            }
            Ok(None) => break,
            Err(_elapsed) => timeouts += 1,
        }
    }
    println!("stats: {cycles} cycles, {answered} replies, {timeouts} timeouts, last at {last_ms:.3} ms");
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() -> Result<(), Error> {
    let port = std::env::var("DXL_PORT")?;
    let baud: u32 = std::env::var("DXL_BAUD").unwrap_or_else(|_| "57600".into()).parse()?;
    let (mut bus, found) = tokio::task::spawn_blocking(move || -> Result<(Bus, usize), Error> {
        let mut bus = Bus::open(&port, baud)?;
        let found = (1..=8).filter(|&id| bus.ping(id).is_ok()).count();
        Ok((bus, found))
    })
    .await??;
    println!("ping 1-8: {found} found");

    let (to_stats, from_loop) = mpsc::channel::<Cycle>(16);
    let stats = tokio::spawn(statistics(from_loop));

    let until_stopped = std::env::args().any(|arg| arg == "--until-stopped");
    let mut terminate = if until_stopped { Some(tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?) } else { None };
    let start = Instant::now();
    let mut period = tokio::time::interval(Duration::from_millis(20));
    period.set_missed_tick_behavior(MissedTickBehavior::Delay);
    let (mut longest, mut previous) = (Duration::ZERO, start);
    let mut n = 0u32;
    while until_stopped || n < 100 {
        match terminate.as_mut() {
            Some(terminate) => tokio::select! {
                _ = period.tick() => {}
                _ = terminate.recv() => break,
            },
            None => {
                period.tick().await;
            }
        }
        let now = Instant::now();
        longest = longest.max(now - previous);
        previous = now;
        let answered;
        (bus, answered) = cycle(bus, (n % 50) * 2).await?;
        to_stats.send(Cycle { at_ms: start.elapsed().as_secs_f64() * 1e3, answered }).await?;
        n += 1;
    }
    drop(to_stats);
    stats.await?;
    if until_stopped {
        // Stopped, the report comes after the run's end, on the wall clock: no time of it is told.
        println!("loop: {n} cycles, longest period {:.3} ms", longest.as_secs_f64() * 1e3);
    } else {
        println!("loop: {n} cycles in {:.3} ms, longest period {:.3} ms", start.elapsed().as_secs_f64() * 1e3, longest.as_secs_f64() * 1e3);
    }
    Ok(())
}
