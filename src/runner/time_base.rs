//! The run's one choice of time base, assembled once: what every part that depends on it gets
//! from it — the bus's clock (reply timing), the clock that paces the world's ticks, how the
//! pty and the sensor server are served, what the controller's process is started with, how its
//! end is seen and what the summary says. `run`, `check`, `sweep` and `serve` ask
//! [`Timekeeping`]; none of them branches on the time base itself.
//!
//! - On the wall clock (or `speed` × it), the pty session and the sensor server are tasks of
//!   their own, the controller keeps its own clocks (scaled through libfaketime), and the world
//!   waits on the wall.
//! - On virtual time, one scheduler ([`VirtualTime`]) owns the clock: the pty session and the
//!   sensor server are futures it polls, each given its ledger only; the controller is started
//!   with the shim preloaded, into a reserved slot; the world's ticks wait for the controller.

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use serde_json::{Value, json};
use tracing::warn;

use crate::sensor_server::{SensorFeed, SensorServer, VirtualSensorServer};
use crate::transport::{Adapter, AdapterModel, BusHandle, Clock as BusClock, VirtualPort, serve_stream_through};
use crate::virtual_time::{EndOnDrop, Serves, VirtualTime, VtSettings};

use super::clock::{Clock, Pace, TimeBase, VirtualClock, WallClock};
use super::{During as _, Result};

/// The run's time base, assembled (see the module doc).
pub struct Timekeeping {
    bus_clock: BusClock,
    kind: Kind,
}

enum Kind {
    Wall,
    Virtual {
        scheduler: Arc<VirtualTime>,
        /// The run ends (every parked thread let go, the block removed) however it is left.
        _ends: EndOnDrop,
    },
}

impl Timekeeping {
    /// Assemble the time base `pace` asks for. Under virtual time the shared block is created
    /// here: it fails (a full /dev/shm) before anything starts.
    pub fn assemble(pace: &Pace) -> Result<Self> {
        Ok(match pace.time {
            TimeBase::Wall => Self { bus_clock: BusClock::scaled(pace.speed), kind: Kind::Wall },
            TimeBase::Virtual(settings) => Self::on_virtual_time(settings)?,
        })
    }

    fn on_virtual_time(settings: VtSettings) -> Result<Self> {
        let scheduler = VirtualTime::create(settings)?;
        let bus_clock = BusClock::on_virtual_time(Arc::clone(scheduler.port()));
        Ok(Self { bus_clock, kind: Kind::Virtual { _ends: scheduler.end_on_drop(), scheduler } })
    }

    fn scheduler(&self) -> Option<&Arc<VirtualTime>> {
        match &self.kind {
            Kind::Virtual { scheduler, .. } => Some(scheduler),
            Kind::Wall => None,
        }
    }

    /// Whether time is virtual (`summary.json`'s `clock`, a launch that preloads the shim).
    pub fn is_virtual(&self) -> bool {
        self.scheduler().is_some()
    }

    /// The bus's clock: reply timing and every timestamp of the run.
    pub fn bus_clock(&self) -> BusClock {
        self.bus_clock.clone()
    }

    /// What paces the world's ticks, for a loop on this thread or another.
    pub fn tick_source(&self) -> TickSource {
        match &self.kind {
            Kind::Wall => TickSource::Wall(self.bus_clock.clone()),
            Kind::Virtual { scheduler, .. } => TickSource::Virtual(Arc::clone(scheduler)),
        }
    }

    /// `serve`: the world waits while no controller is attached (one started by hand may come
    /// and go). Nothing to do on the wall clock, where the world keeps the wall's time anyway.
    pub fn wait_for_controllers(&self) {
        if let Some(scheduler) = self.scheduler() {
            scheduler.wait_for_controllers();
        }
    }

    /// Serve `feed` on an ephemeral localhost port; its base URL. On the wall clock the server is
    /// a task of the current runtime; under virtual time the scheduler answers each request at
    /// its simulated instant.
    pub async fn start_sensor_server(&self, feed: Arc<SensorFeed>) -> Result<String> {
        if let Some(scheduler) = self.scheduler() {
            let (server, url) = VirtualSensorServer::bind(feed, Arc::clone(scheduler.sensors())).during(|| "cannot start the sensor server".to_owned())?;
            scheduler.drive(Serves::Sensors, server);
            return Ok(url);
        }
        let server = SensorServer::bind(std::net::SocketAddr::from(([127, 0, 0, 1], 0))).await.during(|| "cannot start the sensor server".to_owned())?;
        let url = server.url().during(|| "the sensor server has no address".to_owned())?;
        spawn_logged("sensor server", server.run(feed));
        Ok(url)
    }

    /// Serve the pty: under virtual time inside the scheduler, at exact simulated instants, with
    /// the controller parked (and `None`); on the wall clock as `on_wall` starts it (a task, a
    /// thread of its own), whose result is returned.
    pub fn serve_pty<T>(&self, port: Arc<VirtualPort>, handle: Arc<BusHandle>, adapter: Adapter, on_wall: impl FnOnce(Arc<VirtualPort>, Arc<BusHandle>, Adapter) -> Result<T>) -> Result<Option<T>> {
        let Some(scheduler) = self.scheduler() else { return on_wall(port, handle, adapter).map(Some) };
        let stream = port.virtual_stream(Arc::clone(scheduler.port()));
        scheduler.drive(Serves::Port, async move {
            if let Err(error) = serve_stream_through(stream, handle, &port.line(), AdapterModel::new(adapter)).await {
                warn!(%error, "pty session ended");
            }
        });
        Ok(None)
    }

    /// What the controller's process is started with besides the run's own variables: under
    /// virtual time the shim's preload and the block's name.
    pub fn controller_env(&self) -> Result<Vec<(String, String)>> {
        Ok(match self.scheduler() {
            Some(scheduler) => scheduler.controller_env()?,
            None => Vec::new(),
        })
    }

    /// Simulated seconds per wall-clock second for the controller's own clocks (libfaketime
    /// scales them above 1; under virtual time the shim answers them): the bus clock's (1 on
    /// virtual time).
    pub fn controller_speed(&self) -> f64 {
        self.bus_clock.speed()
    }

    /// The controller's process is about to start: under virtual time, time holds until it has
    /// loaded the shim (it takes the reserved slot).
    pub fn before_launch(&self) {
        if let Some(scheduler) = self.scheduler() {
            scheduler.reserve_process();
        }
    }

    /// The controller's output will come through the pipe `inode` (see
    /// `VirtualTime::controller_output`).
    pub fn controller_output(&self, inode: u64) {
        if let Some(scheduler) = self.scheduler() {
            scheduler.controller_output(inode);
        }
    }

    /// The controller's process has started as `pid` (the watchdog follows it).
    pub fn launched(&self, pid: u32) {
        if let Some(scheduler) = self.scheduler() {
            scheduler.process_started(pid);
        }
    }

    /// Wait, at the run's end, for controller threads that ran on past the world's last tick to
    /// park, for at most `within`; whether they all did (on the wall clock nothing waits).
    pub fn await_parked(&self, within: Duration, stop: &AtomicBool) -> bool {
        self.scheduler().is_none_or(|scheduler| scheduler.await_parked(within, stop))
    }

    /// End virtual time: the controller's clean-up runs on the wall clock from here. What the
    /// controller wrote through the block's ring that the run did not read, for the session
    /// after the run; `None` on the wall clock, where nothing ends here.
    pub fn end(&self) -> Option<Vec<u8>> {
        let scheduler = self.scheduler()?;
        scheduler.end();
        Some(scheduler.port().take_ring_rest())
    }

    /// `summary.json`'s `clock` and `virtual_time.*`: what repeats between identical runs (the
    /// timers and signals fired at their simulated instants).
    pub fn summarise(&self, summary: &mut std::collections::BTreeMap<String, Value>) {
        summary.insert("clock".to_owned(), json!(if self.is_virtual() { "virtual" } else { "wall" }));
        let Some(scheduler) = self.scheduler() else { return };
        let stats = scheduler.stats();
        summary.insert("virtual_time.timers_fired".to_owned(), json!(stats.timers_fired));
        summary.insert("virtual_time.signals_fired".to_owned(), json!(stats.signals_fired));
        // Whether a thread was preempted: then the run repeats exactly only if what it computed
        // between its calls had no effect but its wait (docs/virtual-time.md).
        summary.insert("virtual_time.threads_gave_way".to_owned(), json!(stats.gave_way > 0));
        summary.insert("virtual_time.controller_cpu".to_owned(), json!(scheduler.settings().controller_cpu));
    }

    /// `scheduler.json`: how the host ran the controller's threads (the turns climbsim gave and
    /// the threads handed on, the clock's jumps, the threads let go at a deadline or for data).
    /// Not in the summary, which repeats between identical runs: these need not (a thread that
    /// finds the thread it joins already gone does not park, and takes no turn; in another run
    /// it parks, looks, and takes one). `None` on the wall clock.
    pub fn scheduler_counts(&self) -> Option<Value> {
        let stats = self.scheduler()?.stats();
        // Read back from a block the controller wrote over, they would be its bytes: null.
        let from_block = |count: u64| (!stats.block_overwritten).then_some(count);
        Some(json!({
            "turns": from_block(stats.turns),
            "turns_handed": from_block(stats.turns_handed),
            "jumps": stats.jumps,
            "released_at_deadline": stats.released_at_deadline,
            "released_for_data": stats.released_for_data,
            "asked_to_give_way": stats.asked_to_give_way,
            "gave_way": from_block(stats.gave_way),
        }))
    }
}

/// What paces a world's ticks, as the time base chose it; cheap to clone into a loop's thread.
#[derive(Clone)]
pub enum TickSource {
    /// Each tick waits for its instant on the wall clock (the bus's clock, so that ticks and
    /// replies share one time).
    Wall(BusClock),
    /// Each tick waits until the controller has done everything it had due before it.
    Virtual(Arc<VirtualTime>),
}

impl TickSource {
    /// The clock for one loop, stopped by `stop`.
    pub fn clock<'a>(&self, stop: &'a AtomicBool) -> Box<dyn Clock + 'a> {
        match self {
            Self::Wall(clock) => Box::new(WallClock::on(clock.clone())),
            Self::Virtual(scheduler) => Box::new(VirtualClock::new(Arc::clone(scheduler), stop)),
        }
    }

    /// Whether the controller's first process ended before `at`, as the shim saw it: under
    /// virtual time its end is seen at the simulated instant it happened (the same on every
    /// run). `None` on the wall clock, where the kernel says when.
    pub fn controller_ended_before(&self, at: Duration) -> Option<bool> {
        match self {
            Self::Wall(_) => None,
            Self::Virtual(scheduler) => Some(scheduler.first_process_ended_before(at)),
        }
    }
}

/// Run `future` to its end as a task of the current runtime, saying why if it failed.
pub fn spawn_logged<E: std::fmt::Display + Send + 'static>(what: &'static str, future: impl Future<Output = std::result::Result<(), E>> + Send + 'static) {
    tokio::spawn(async move {
        if let Err(error) = future.await {
            warn!(%error, "{what} ended");
        }
    });
}
