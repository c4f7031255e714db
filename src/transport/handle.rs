//! What every transport shares with the bus: [`BusHandle`] (the bus under one lock, its trace,
//! statistics, transcript and [`Clock`]) and the clock itself.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use tracing::warn;

use crate::bus::{Bus, TraceWriter, Transaction};
use crate::protocol::RawPacket;
use crate::transcript::Recorder;
use crate::virtual_time::PortLedger;

use super::stats::{LineStats, LoopKey, PhysicsPace, ReportExtras, TimingReport};

/// The emulator's monotonic time base: every timestamp is a `Duration` of simulated time since
/// `origin`. Simulated time runs `speed` times as fast as the wall clock (`--speed N`, with the
/// controller's own clocks scaled alike); at the default 1 the two are the same. Under virtual
/// time it is the scheduler's clock instead (read through the port's ledger, which the reply
/// timing needs too), and the wall-clock methods do not apply.
#[derive(Debug, Clone)]
pub struct Clock {
    origin: Instant,
    /// Simulated time at `origin` (zero but for [`Clock::wall_from`]).
    offset: Duration,
    speed: f64,
    virtual_port: Option<Arc<PortLedger>>,
}

impl Default for Clock {
    fn default() -> Self {
        Self::scaled(1.0)
    }
}

impl Clock {
    /// A clock starting now whose time runs `speed` (> 0, finite) times the wall clock's rate.
    pub fn scaled(speed: f64) -> Self {
        let speed = if speed.is_finite() && speed > 0.0 { speed } else { 1.0 };
        Self { origin: Instant::now(), offset: Duration::ZERO, speed, virtual_port: None }
    }

    /// A clock on the wall's time that reads `now` at once and goes on from there: for what
    /// happens after a run on virtual time has ended (the controller's clean-up).
    pub fn wall_from(now: Duration) -> Self {
        Self { offset: now, ..Self::scaled(1.0) }
    }

    /// Simulated time as the virtual-time scheduler moves it (`--clock virtual`), read from
    /// the servo port's ledger.
    pub fn on_virtual_time(port: Arc<PortLedger>) -> Self {
        Self { origin: Instant::now(), offset: Duration::ZERO, speed: 1.0, virtual_port: Some(port) }
    }

    /// The port's ledger, if time is virtual: reply timing waits on its timers, not the wall's,
    /// and writes replies ahead of their instants.
    pub fn virtual_port(&self) -> Option<&Arc<PortLedger>> {
        self.virtual_port.as_ref()
    }

    pub fn speed(&self) -> f64 {
        self.speed
    }

    pub fn now(&self) -> Duration {
        match &self.virtual_port {
            Some(port) => port.now(),
            None => self.offset + self.origin.elapsed().mul_f64(self.speed),
        }
    }

    /// The wall-clock instant at which simulated time reaches `at`.
    pub fn instant(&self, at: Duration) -> Instant {
        self.origin + self.wall(at.saturating_sub(self.offset))
    }

    /// How long a span of simulated time lasts on the wall clock.
    pub fn wall(&self, simulated: Duration) -> Duration {
        simulated.div_f64(self.speed)
    }
}

/// The bus and what every transport shares with it.
pub struct BusHandle {
    bus: Mutex<Bus>,
    trace: Mutex<Option<TraceWriter>>,
    stats: Mutex<LineStats>,
    clock: Clock,
    /// `--record`: packets and ticks, appended under the bus lock so that their order in the
    /// transcript is the order the bus saw them in.
    recorder: Option<Arc<Recorder>>,
}

impl BusHandle {
    pub fn new(bus: Bus, trace: Option<TraceWriter>) -> Arc<Self> {
        Self::recording(bus, trace, None)
    }

    /// Like [`BusHandle::new`], recording the session into `recorder` if there is one.
    pub fn recording(bus: Bus, trace: Option<TraceWriter>, recorder: Option<Arc<Recorder>>) -> Arc<Self> {
        Self::with_clock(bus, trace, recorder, Clock::default())
    }

    /// Like [`BusHandle::recording`], on `clock` (e.g. [`Clock::scaled`] for `--speed`).
    pub fn with_clock(bus: Bus, trace: Option<TraceWriter>, recorder: Option<Arc<Recorder>>, clock: Clock) -> Arc<Self> {
        Arc::new(Self { bus: Mutex::new(bus), trace: Mutex::new(trace), stats: Mutex::new(LineStats::default()), clock, recorder })
    }

    pub fn recorder(&self) -> Option<&Arc<Recorder>> {
        self.recorder.as_ref()
    }

    /// One firmware tick of a world on the wall clock: advance the bus to `at`, run `observe` on
    /// it, and record the tick, all under one lock.
    pub fn tick<R>(&self, at: Duration, observe: impl FnOnce(&mut Bus) -> R) -> R {
        self.with_bus(|bus| {
            bus.advance(at);
            let result = observe(bus);
            if let Some(recorder) = &self.recorder {
                recorder.tick(at);
            }
            result
        })
    }

    pub fn clock(&self) -> Clock {
        self.clock.clone()
    }

    /// Run `f` with the bus locked. A panic elsewhere never leaves the bus unusable: the state is
    /// plain data, so a poisoned lock is taken over.
    pub fn with_bus<R>(&self, f: impl FnOnce(&mut Bus) -> R) -> R {
        let mut bus = self.bus.lock().unwrap_or_else(PoisonError::into_inner);
        f(&mut bus)
    }

    /// Run `f` on the line statistics.
    pub fn with_stats<R>(&self, f: impl FnOnce(&mut LineStats) -> R) -> R {
        let mut stats = self.stats.lock().unwrap_or_else(PoisonError::into_inner);
        f(&mut stats)
    }

    /// The timing report so far; `pace` is the pacer's, if a world runs on the wall clock.
    pub fn timing_report(&self, pace: &PhysicsPace) -> TimingReport {
        let watchdog_expiries = self.with_bus(|bus| bus.servos().iter().map(|s| s.watchdog_expiries()).sum());
        let pace = PhysicsPace { speed: self.clock.speed(), ..pace.clone() };
        let extra = ReportExtras { watchdog_expiries, pace };
        self.with_stats(|stats| stats.report(extra))
    }

    pub(super) fn handle(&self, packet: RawPacket, received_at: Duration, line_baud: Option<u32>, physical_wire: bool) -> Transaction {
        let key = LoopKey { instruction: packet.instruction, id: packet.id };
        let transaction = self.with_bus(|bus| {
            let transaction = if physical_wire { bus.handle_from_physical_wire(packet, received_at, line_baud) } else { bus.handle(packet, received_at, line_baud) };
            if let Some(recorder) = &self.recorder {
                recorder.packet(&transaction, line_baud);
            }
            transaction
        });
        self.with_stats(|stats| stats.request(received_at, key, transaction.wire_busy, transaction.baud_mismatch));
        let mut trace = self.trace.lock().unwrap_or_else(PoisonError::into_inner);
        if let Some(writer) = trace.as_mut()
            && let Err(error) = writer.record(&transaction)
        {
            warn!(%error, "bus trace write failed; tracing stopped");
            *trace = None;
        }
        transaction
    }
}
