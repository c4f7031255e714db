//! The seam between the one tick loop and what paces it: a [`Clock`] says what simulated time it
//! is and waits for the next tick's time to come.
//!
//! - [`LockstepClock`]: simulated time is wherever the world is; it never waits, so a run goes
//!   as fast as the CPU allows and is deterministic (the built-in controller, which talks to
//!   the bus in-process between ticks).
//! - [`WallClock`]: simulated time runs N × the wall clock (`--speed N`); each tick waits for
//!   its wall-clock instant, so an external controller, a person watching, or a real wire can
//!   keep up (external controllers, `serve`, a built-in controller shown live).
//!
//! - [`VirtualClock`]: simulated time moves only when the external controller's every thread is
//!   blocked (`--clock virtual`, src/virtual_time/): as fast as the CPU allows, and repeatable.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use crate::transport;
use crate::virtual_time::{VirtualTime, VtError, VtSettings};

/// How fast a wall-clock world runs, and how late it may fall behind before the run fails.
#[derive(Debug, Clone, Copy)]
pub struct Pace {
    /// Simulated seconds per wall-clock second (`--speed`).
    pub speed: f64,
    /// The 99th-percentile lateness (simulated time) of the world's ticks and of replies beyond
    /// which the run did not keep its pace (`--pace-tolerance-ms`).
    pub tolerance: Duration,
    /// Whose clock an external controller runs on (`--clock`).
    pub time: TimeBase,
}

impl Pace {
    /// `check`'s default: an external controller on simulated time (the tolerance does not
    /// apply: nothing is late on virtual time).
    pub fn virtual_time() -> Self {
        Self { speed: 1.0, tolerance: Duration::from_millis(10), time: TimeBase::Virtual(VtSettings::default()) }
    }
}

/// Whose clock an external controller runs on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TimeBase {
    /// The wall clock, or `speed` × it through libfaketime.
    Wall,
    /// The simulation's: the controller waits for the world and the world for the controller.
    Virtual(VtSettings),
}

/// Why a clock could not bring time to a tick.
#[derive(Debug)]
pub enum ClockStop {
    /// The run was asked to stop (the stop flag) while the clock waited.
    Interrupted,
    /// The clock cannot go on (under virtual time: a controller it cannot follow).
    Failed(String),
}

/// What paces a run's ticks.
pub trait Clock: Send {
    /// The simulated time now.
    fn now(&self) -> Duration;
    /// Wait until simulated time `due` has come; how late it came (simulated time; zero for a
    /// clock that does not wait).
    fn wait_until(&mut self, due: Duration) -> Result<Duration, ClockStop>;
    /// Simulated seconds per wall-clock second; `None` for a clock not tied to the wall.
    fn speed(&self) -> Option<f64>;
}

/// Simulated time is the last tick's: the loop never waits.
#[derive(Debug, Default, Clone, Copy)]
pub struct LockstepClock {
    now: Duration,
}

impl LockstepClock {
    /// A lockstep clock at `now` (the world's time when the loop starts).
    pub fn at(now: Duration) -> Self {
        Self { now }
    }
}

impl Clock for LockstepClock {
    fn now(&self) -> Duration {
        self.now
    }

    fn wait_until(&mut self, due: Duration) -> Result<Duration, ClockStop> {
        self.now = self.now.max(due);
        Ok(Duration::ZERO)
    }

    fn speed(&self) -> Option<f64> {
        None
    }
}

/// Simulated time runs `speed` × the wall clock from a start; each tick sleeps until its
/// wall-clock instant. The same [`transport::Clock`] times the bus's replies, so the world and
/// the wire agree on what time it is.
#[derive(Debug, Clone)]
pub struct WallClock {
    clock: transport::Clock,
}

impl WallClock {
    /// A wall clock starting now at `speed` × real time.
    pub fn scaled(speed: f64) -> Self {
        Self::on(transport::Clock::scaled(speed))
    }

    /// A wall clock on `clock` (the bus handle's, so that ticks and replies share one time).
    pub fn on(clock: transport::Clock) -> Self {
        tighten_timer_slack();
        Self { clock }
    }
}

impl Clock for WallClock {
    fn now(&self) -> Duration {
        self.clock.now()
    }

    fn wait_until(&mut self, due: Duration) -> Result<Duration, ClockStop> {
        // Deadlines are simulated time; the sleep is on the wall clock (a tenth of a millisecond
        // per tick at 10x).
        let wake = self.clock.instant(due);
        let now = Instant::now();
        if wake > now {
            std::thread::sleep(wake - now);
        }
        Ok(self.now().saturating_sub(due))
    }

    fn speed(&self) -> Option<f64> {
        Some(self.clock.speed())
    }
}

/// Simulated time as the virtual-time scheduler moves it: each tick waits until the external
/// controller has done everything it had due before it (src/virtual_time/). Never late.
pub struct VirtualClock<'a> {
    virtual_time: Arc<VirtualTime>,
    stop: &'a AtomicBool,
    /// The world's time: the last tick waited for. A controller may be ahead of it (it runs
    /// within the horizon; the world catches up, tick by tick, never late).
    world_now: Duration,
}

impl<'a> VirtualClock<'a> {
    pub fn new(virtual_time: Arc<VirtualTime>, stop: &'a AtomicBool) -> Self {
        let world_now = virtual_time.now();
        Self { virtual_time, stop, world_now }
    }
}

impl Clock for VirtualClock<'_> {
    fn now(&self) -> Duration {
        self.world_now
    }

    fn wait_until(&mut self, due: Duration) -> Result<Duration, ClockStop> {
        match self.virtual_time.advance_to(due, self.stop) {
            Ok(()) => {
                self.world_now = self.world_now.max(due);
                Ok(Duration::ZERO)
            }
            Err(VtError::Interrupted) => Err(ClockStop::Interrupted),
            Err(error) => Err(ClockStop::Failed(error.to_string())),
        }
    }

    fn speed(&self) -> Option<f64> {
        None
    }
}

/// Linux lets a sleep end up to 50 µs late by default (timer slack): a tick at 20x is 50 µs.
/// Set for the thread that makes the clock, which is the thread that runs the loop.
fn tighten_timer_slack() {
    #[cfg(target_os = "linux")]
    // SAFETY: PR_SET_TIMERSLACK takes a plain integer and affects only the calling thread.
    unsafe {
        libc::prctl(libc::PR_SET_TIMERSLACK, 1 as libc::c_ulong);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lockstep_clock_never_waits_and_never_goes_back() {
        let mut clock = LockstepClock::at(Duration::from_millis(1));
        assert_eq!(clock.wait_until(Duration::from_millis(5)).ok(), Some(Duration::ZERO));
        assert_eq!(clock.now(), Duration::from_millis(5));
        let _ = clock.wait_until(Duration::from_millis(3));
        assert_eq!(clock.now(), Duration::from_millis(5));
        assert_eq!(clock.speed(), None);
    }

    #[test]
    fn a_wall_clock_waits_for_its_instant() {
        let mut clock = WallClock::scaled(10.0);
        let started = Instant::now();
        // 50 ms simulated at 10x: 5 ms of wall time.
        let _ = clock.wait_until(Duration::from_millis(50));
        assert!(started.elapsed() >= Duration::from_millis(5), "{:?}", started.elapsed());
        assert!(clock.now() >= Duration::from_millis(50));
        assert_eq!(clock.speed(), Some(10.0));
    }
}
