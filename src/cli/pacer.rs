//! The pacer: advances a world on the wall clock (or N × the wall clock with `--speed N`), one
//! firmware tick per absolute deadline, and measures how well it kept that pace.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use climbsim::transport::{BusHandle, PhysicsPace};

/// Called on the pacer thread after every firmware tick, with the bus locked and the tick's time.
pub type TickHook = Box<dyn FnMut(&mut climbsim::bus::Bus, Duration) + Send>;

/// Advances the bus (and so the world) on its clock, one firmware tick per deadline.
pub struct Pacer {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<PhysicsPace>,
}

impl Pacer {
    pub fn start(handle: Arc<BusHandle>) -> Self {
        Self::start_with(handle, Box::new(|_, _| {}))
    }

    /// Like [`Pacer::start`], calling `hook` after every tick (camera, capture, events).
    pub fn start_with(handle: Arc<BusHandle>, mut hook: TickHook) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = Arc::clone(&stop);
        let period = handle.with_bus(|bus| bus.servos().first().map_or(Duration::from_millis(1), |s| s.control_period()));
        let thread = std::thread::spawn(move || {
            tighten_timer_slack();
            let clock = handle.clock();
            let mut pace = PhysicsPace { speed: clock.speed(), ..PhysicsPace::default() };
            let mut deadline = clock.now();
            while !stopping.load(Ordering::Relaxed) {
                deadline += period;
                // Deadlines are simulated time; the sleep is on the wall clock (a tenth of a
                // millisecond per tick at 10x).
                let wake = clock.instant(deadline);
                let now = Instant::now();
                if wake > now {
                    std::thread::sleep(wake - now);
                }
                pace.lateness.record(clock.now().saturating_sub(deadline));
                handle.tick(deadline, |bus| hook(bus, deadline));
                pace.ticks += 1;
                // Late by more than a tick: the world cannot keep up here. Start afresh from now
                // rather than run a burst of ticks to catch up.
                if clock.now() > deadline + period {
                    pace.overruns += 1;
                    deadline = clock.now();
                }
            }
            pace
        });
        Self { stop, thread }
    }

    /// Stop; how the world kept its pace.
    pub fn stop(self) -> PhysicsPace {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().unwrap_or_default()
    }
}

/// Linux lets a sleep end up to 50 µs late by default (timer slack): a tick at 20x is 50 µs.
fn tighten_timer_slack() {
    #[cfg(target_os = "linux")]
    // SAFETY: PR_SET_TIMERSLACK takes a plain integer and affects only the calling thread.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong);
    }
}
