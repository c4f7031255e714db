//! The one loop every run goes through: ask what is due next, wait for it on the [`Clock`],
//! bring the world (and whatever ticks with it) to that time, and keep account of how well the
//! clock's pace was kept. A lockstep run, an external controller's wall-clock run and `serve`'s
//! world differ only in their clock and their [`Ticked`].

use std::ops::ControlFlow;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use crate::bus::Bus;
use crate::transport::{BusHandle, PhysicsPace};

use super::clock::{Clock, ClockStop};
use super::time_base::TickSource;

/// What the loop drives: a world and what runs with it.
pub trait Ticked {
    /// The simulated time of the next tick, given the clock's time now; `None` ends the run.
    fn next_due(&mut self, now: Duration) -> Option<Duration>;
    /// Bring everything to `at`. `Break` ends the run after this tick.
    fn tick(&mut self, at: Duration) -> ControlFlow<()>;
    /// The clock fell more than a tick behind: start the schedule afresh from `now` rather than
    /// run a burst of ticks to catch up (a world on the wall clock; lockstep never falls behind).
    fn resync(&mut self, _now: Duration) {}
}

/// How the loop ended.
#[derive(Debug, Default)]
pub struct LoopEnd {
    /// Ticks run, ticks more than a tick late (overruns) and every tick's lateness.
    pub pace: PhysicsPace,
    /// `stop` was set before the run's end.
    pub interrupted: bool,
    /// The clock could not go on (a controller virtual time cannot follow): why.
    pub clock_failure: Option<String>,
}

/// Run `ticked` on `clock` until it has nothing more due, breaks, or `stop` is set.
pub fn run_ticks(clock: &mut dyn Clock, ticked: &mut dyn Ticked, stop: &AtomicBool) -> LoopEnd {
    let mut end = LoopEnd { pace: PhysicsPace { speed: clock.speed().unwrap_or(1.0), ..PhysicsPace::default() }, interrupted: false, clock_failure: None };
    let mut last = clock.now();
    loop {
        if stop.load(Ordering::Relaxed) {
            end.interrupted = true;
            break;
        }
        let Some(due) = ticked.next_due(clock.now()) else { break };
        match clock.wait_until(due) {
            Ok(late) => end.pace.lateness.record(late),
            Err(ClockStop::Interrupted) => {
                end.interrupted = true;
                break;
            }
            Err(ClockStop::Failed(why)) => {
                end.clock_failure = Some(why);
                break;
            }
        }
        let flow = ticked.tick(due);
        end.pace.ticks += 1;
        // Late by more than a tick: the world cannot keep up here.
        let step = due.saturating_sub(last);
        last = due;
        if clock.now() > due + step {
            end.pace.overruns += 1;
            last = clock.now();
            ticked.resync(last);
        }
        if flow.is_break() {
            break;
        }
    }
    end
}

/// Called after every firmware tick of a world behind a [`BusHandle`], with the bus locked and
/// the tick's time; `Break` ends the run.
pub type TickHook = Box<dyn FnMut(&mut Bus, Duration) -> ControlFlow<()> + Send>;

/// A world behind a [`BusHandle`] (shared with the transports that serve its bus), ticked every
/// firmware period until `end`, if it has one.
pub struct HandleTicks {
    handle: Arc<BusHandle>,
    hook: TickHook,
    period: Duration,
    last: Duration,
    end: Option<Duration>,
}

impl HandleTicks {
    pub fn new(handle: Arc<BusHandle>, hook: TickHook, end: Option<Duration>) -> Self {
        let period = handle.with_bus(|bus| bus.servos().first().map_or(Duration::from_millis(1), |s| s.control_period()));
        let last = handle.clock().now();
        Self { handle, hook, period, last, end }
    }
}

impl Ticked for HandleTicks {
    fn next_due(&mut self, _now: Duration) -> Option<Duration> {
        let due = self.last + self.period;
        self.last = due;
        self.end.is_none_or(|end| due <= end).then_some(due)
    }

    fn tick(&mut self, at: Duration) -> ControlFlow<()> {
        let hook = &mut self.hook;
        self.handle.tick(at, |bus| hook(bus, at))
    }

    fn resync(&mut self, now: Duration) {
        self.last = now;
    }
}

/// A world on its handle's clock (the wall clock, or virtual time) on a thread of its own, for as long as it is wanted (`serve`, whose
/// main thread waits for signals).
pub struct Pacer {
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<PhysicsPace>,
}

impl Pacer {
    /// Tick `handle`'s world on `source`'s clock, calling `hook` after every tick. Under virtual
    /// time the world follows whichever controller is attached.
    pub fn start(handle: Arc<BusHandle>, hook: TickHook, source: TickSource) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stopping = Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            let mut ticks = HandleTicks::new(Arc::clone(&handle), hook, None);
            run_ticks(&mut *source.clock(&stopping), &mut ticks, &stopping).pace
        });
        Self { stop, thread }
    }

    /// Stop; how the world kept its pace.
    pub fn stop(self) -> PhysicsPace {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.join().unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runner::clock::LockstepClock;

    /// Ticks every 3 ms to 10 ms, breaking at `break_at` if given.
    struct Every3ms {
        at: Vec<Duration>,
        break_at: Option<Duration>,
    }

    impl Ticked for Every3ms {
        fn next_due(&mut self, now: Duration) -> Option<Duration> {
            let due = now + Duration::from_millis(3);
            (due <= Duration::from_millis(10)).then_some(due)
        }
        fn tick(&mut self, at: Duration) -> ControlFlow<()> {
            self.at.push(at);
            if self.break_at == Some(at) { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
        }
    }

    #[test]
    fn the_loop_runs_what_is_due_until_nothing_is() {
        let mut ticked = Every3ms { at: Vec::new(), break_at: None };
        let end = run_ticks(&mut LockstepClock::default(), &mut ticked, &AtomicBool::new(false));
        assert_eq!(ticked.at, [3, 6, 9].map(Duration::from_millis));
        assert_eq!((end.pace.ticks, end.pace.overruns, end.interrupted), (3, 0, false));
    }

    #[test]
    fn a_break_or_a_stop_ends_the_loop() {
        let mut ticked = Every3ms { at: Vec::new(), break_at: Some(Duration::from_millis(6)) };
        run_ticks(&mut LockstepClock::default(), &mut ticked, &AtomicBool::new(false));
        assert_eq!(ticked.at, [3, 6].map(Duration::from_millis));
        let mut ticked = Every3ms { at: Vec::new(), break_at: None };
        let end = run_ticks(&mut LockstepClock::default(), &mut ticked, &AtomicBool::new(true));
        assert!(end.interrupted && ticked.at.is_empty());
    }
}
