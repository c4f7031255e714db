//! A controller on `dynamixel2` (serial2 underneath: blocking reads with a poll timeout), for
//! the virtual-time tests: it opens `DXL_PORT` at `DXL_BAUD`, pings servo 1, reads and Sync
//! Reads the eight servos' Present Position, pings an absent ID, and prints each latency as
//! its own clock (`std::time::Instant`) measured it. Built by `cargo test` (examples are).

use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let port = std::env::var("DXL_PORT")?;
    let baud: u32 = std::env::var("DXL_BAUD").unwrap_or_else(|_| "57600".into()).parse()?;
    let mut bus = dynamixel2::Bus::<Vec<u8>, Vec<u8>>::open(&port, baud)?;
    let timed = |what: &str, started: Instant| println!("{what}: {:.1} us", started.elapsed().as_secs_f64() * 1e6);
    for attempt in 0..3 {
        let started = Instant::now();
        bus.ping(1)?;
        timed(&format!("ping 1 #{attempt}"), started);
    }
    let started = Instant::now();
    bus.read_u32(1, 132)?;
    timed("read_u32 1 present position", started);
    let started = Instant::now();
    let ids: Vec<u8> = (1..=8).collect();
    let mut answered = 0;
    bus.sync_read_u32_cb(&ids, 132, |reply| answered += usize::from(reply.is_ok()))?;
    timed(&format!("sync read 8 ({answered} answered)"), started);
    let started = Instant::now();
    let absent = bus.ping(42);
    timed(&format!("ping 42 ({})", if absent.is_err() { "no reply" } else { "answered" }), started);
    Ok(())
}
