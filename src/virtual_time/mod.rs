//! Virtual time (`--clock virtual`): an unchanged external controller on the simulation's clock.
//!
//! climbsim preloads a shim (`shim/`, embedded: [`shim_path`]) into the controller's processes.
//! The shim answers their clock reads from a shared block ([`abi`]) and turns their sleeps and
//! waits into "blocked until T, or until bytes come". [`VirtualTime`] is climbsim's side: its
//! [`VirtualTime::advance_to`] is the scheduler. Time moves only when every controller thread is
//! blocked or has yielded and climbsim has read every byte the controller wrote; it then jumps to
//! the earliest of the next world tick, the next reply due on the port (a [`Timer`]) and the next
//! deadline a thread asked for. The pty session runs inside the scheduler (see
//! [`VirtualTime::drive`]), so a reply is written exactly at its wire-model time, with every
//! controller thread parked. The model in full: docs/virtual-time.md.
//!
//! A layer of its own below `transport`: it knows nothing of the bus or the world.

#[path = "../../shim/src/abi/mod.rs"]
pub mod abi;
mod block;
mod error;
mod futex;
mod hand_ons;
mod port;
mod preempt;
mod quiet;
mod real_world;
mod sensors;
mod shim_file;
mod signals;
mod timer;
mod turns;
mod watchdog;

use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Waker};
use std::time::Duration;

use abi::{NEVER, mode, release, state};
use block::Block;
pub use error::VtError;
use error::lock;
use futex::{futex_wait, wake};
pub use port::{PTY_FULL_FOR, PTY_HAND_OVER_WITHIN, PortLedger, await_pty_hand_over};
pub use sensors::SensorLedger;
pub use shim_file::{shim_bytes, shim_path};
pub use timer::Timer;

/// The model's knobs (docs/virtual-time.md, "What a busy loop costs").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VtSettings {
    /// Simulated time a clock read costs (about one vDSO read).
    pub clock_read_ns: u64,
    /// Simulated time any other intercepted call that did not block costs.
    pub syscall_ns: u64,
    /// The longest jump of a zero-timeout poll of the port when nothing is due on it.
    pub spin_cap_ns: u64,
    /// Wall time without an intercepted call after which a running controller thread that is
    /// not computing (blocked in a call the shim does not see) is stuck.
    pub stuck_after: Duration,
    /// Wall time a controller thread may compute without an intercepted call (`--compute-limit-s`:
    /// a model loaded at start) before the run fails.
    pub compute_limit: Duration,
    /// CLOCK_REALTIME at simulated time 0 (Unix seconds): fixed, so that runs repeat exactly.
    pub epoch_unix_s: u64,
    /// Each controller thread's CPU time is charged × this (`--controller-cpu F`); 0: the
    /// controller's computation is free (and the run deterministic).
    pub controller_cpu: f64,
    /// CPU time a thread may compute without a followed call before it is asked to give way
    /// (`--preempt-after-ms`; zero: never, preempt.rs).
    pub preempt_after: Duration,
}

impl Default for VtSettings {
    fn default() -> Self {
        Self {
            clock_read_ns: 25,
            syscall_ns: 1_000,
            spin_cap_ns: 100_000,
            stuck_after: Duration::from_secs(2),
            compute_limit: Duration::from_secs(60),
            epoch_unix_s: 1_704_067_200,
            controller_cpu: 0.0,
            preempt_after: Duration::from_nanos(abi::COMPUTE_QUANTUM_NS),
        }
    }
}

/// Wall time that simulated time may stand still while controller threads run (and none of
/// them computes) before the run fails as a livelock.
const LIVELOCK_AFTER: Duration = Duration::from_secs(5);

/// CLOCK_MONOTONIC at simulated time 0: not zero, which some programs take for "unset".
const MONOTONIC_BASE_NS: u64 = 1_000_000_000_000;
/// Charges are applied in batches of this much (a thread moves the clock at most this often).
const BATCH_NS: u64 = 1_000;

/// How long (wall time) the scheduler spins for a running controller thread to park before it
/// sleeps on the futex, and a parked controller thread for climbsim (a Python controller's
/// period, or the world's ticks between two, take a few hundred microseconds): the futex's
/// sleep and wake-up costs tens of microseconds on a VM whose idle vCPUs halt. Only while the
/// machine is quiet ([`quiet::Quiet`]).
const SPIN: Duration = Duration::from_micros(400);

/// How long (wall time) the scheduler looks for bytes the controller wrote to the port without
/// sleeping, while the machine is quiet, before it waits for them in the kernel.
const IN_FLIGHT_SPIN: Duration = Duration::from_micros(100);

/// How often (wall time) the driven futures are polled when the controller sent nothing: for
/// clients climbsim does not follow.
const UNFOLLOWED_CLIENTS_EVERY: Duration = Duration::from_millis(5);

/// How [`VirtualTime::settle`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Settled {
    /// Every thread parked, with nothing left to read.
    Parked,
    /// A thread still runs, past the world's next tick (see [`VirtualTime::ran_past`]).
    RanPast,
}

/// A future climbsim runs inside the scheduler, and what it serves.
type Driven = (Serves, Pin<Box<dyn Future<Output = ()> + Send>>);

/// What a driven future serves: it is polled when that has something for it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Serves {
    /// The servo port (its bytes, its reply timers).
    Port,
    /// The sensor server's connections.
    Sensors,
}

/// What the scheduler did in a run (summary.json's `virtual_time.*`): the wall-time cost of
/// virtual time is mostly one hand-over per release.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct VtStats {
    /// Parked threads let go because their deadline (or spin target) came.
    pub released_at_deadline: u64,
    /// Parked threads let go because bytes came for them.
    pub released_for_data: u64,
    /// Reply (and other) timers fired.
    pub timers_fired: u64,
    /// Times simulated time jumped to a thread's deadline or a timer (not a world tick).
    pub jumps: u64,
    /// Turns given: a ready thread let run while no other did.
    pub turns: u64,
    /// Of the turns, those a parking thread handed on itself, without climbsim.
    pub turns_handed: u64,
    /// Signal timers (alarm, setitimer, timer_create) fired at a controller thread.
    pub signals_fired: u64,
    /// Threads asked to give way after computing a quantum without a call (preempt.rs), and
    /// the times they did.
    pub asked_to_give_way: u64,
    pub gave_way: u64,
    /// The controller wrote over the block (the run failed saying so): the counts the shim
    /// keeps there (`turns_handed`, and so `turns`; `gave_way`) are not read back.
    pub block_overwritten: bool,
}

/// climbsim's side of virtual time for one run.
pub struct VirtualTime {
    /// `serve`: the world waits while no controller is attached.
    waits_for_controller: AtomicBool,
    /// When the driven futures were last polled (wall clock).
    last_poll: Mutex<std::time::Instant>,
    /// Spin before sleeping on a futex: only where the controller has a core of its own.
    spin: bool,
    stats: Mutex<VtStats>,
    block: Arc<Block>,
    settings: VtSettings,
    /// The port session's timers, fired here at their instants.
    timers: Arc<timer::TimerWheel>,
    driven: Mutex<Vec<Driven>>,
    /// Handed to the pty and its session.
    port: Arc<PortLedger>,
    /// Handed to the sensor server.
    sensors: Arc<SensorLedger>,
    quiet: Mutex<quiet::Quiet>,
    real_world: Mutex<real_world::RealWorld>,
    /// Asks threads that compute without a call to give way (preempt.rs).
    preempter: Mutex<preempt::Preempter>,
    hand_ons: Mutex<hand_ons::HandOns>,
}

impl std::fmt::Debug for VirtualTime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualTime").field("block", &self.block.path()).field("now", &self.now()).finish()
    }
}

/// The pty session's timers (`timer.rs`'s wheel).
impl VirtualTime {
    fn next_timer(&self) -> u64 {
        self.timers.next_due()
    }

    /// Fire every timer due by `now`, then let the driven futures act on them.
    fn fire_timers(&self, now: u64) {
        let fired = self.timers.fire(now);
        lock(&self.stats).timers_fired += fired;
        // Timers are the port session's (its replies and its inter-byte gaps).
        self.poll_driven(Some(Serves::Port));
    }
}

impl VirtualTime {
    pub fn create(settings: VtSettings) -> Result<Arc<Self>, VtError> {
        let block = Arc::new(Block::create()?);
        let header = &block.shared().header;
        header.abi.store(abi::ABI, Ordering::Relaxed);
        header.clock.realtime_epoch_ns.store(settings.epoch_unix_s.saturating_mul(1_000_000_000), Ordering::Relaxed);
        header.clock.monotonic_base_ns.store(MONOTONIC_BASE_NS, Ordering::Relaxed);
        header.clock.clock_read_ns.store(settings.clock_read_ns, Ordering::Relaxed);
        header.clock.syscall_ns.store(settings.syscall_ns, Ordering::Relaxed);
        header.clock.batch_ns.store(BATCH_NS, Ordering::Relaxed);
        header.clock.spin_cap_ns.store(settings.spin_cap_ns, Ordering::Relaxed);
        header.port.next_due_ns.store(NEVER, Ordering::Relaxed);
        header.climbsim_pid.store(std::process::id() as i32, Ordering::Relaxed);
        header.clock.cpu_factor_ppm.store((settings.controller_cpu.clamp(0.0, 1e6) * 1e6) as u64, Ordering::Relaxed);
        header.clock.give_way_after_ns.store(u64::try_from(settings.preempt_after.as_nanos()).unwrap_or(u64::MAX), Ordering::Relaxed);
        header.mode.store(mode::VIRTUAL, Ordering::Relaxed);
        // Slot 0 is the process climbsim starts (reserve_process).
        header.slots_high.store(1, Ordering::Relaxed);
        header.magic.store(abi::MAGIC, Ordering::Release);
        let timers = Arc::<timer::TimerWheel>::default();
        Ok(Arc::new(Self {
            port: Arc::new(PortLedger::new(Arc::clone(&block), Arc::clone(&timers))),
            sensors: Arc::new(SensorLedger::new(Arc::clone(&block))),
            waits_for_controller: AtomicBool::new(false),
            last_poll: Mutex::new(std::time::Instant::now()),
            spin: std::thread::available_parallelism().is_ok_and(|n| n.get() > 1),
            stats: Mutex::default(),
            block,
            settings,
            timers,
            driven: Mutex::default(),
            quiet: Mutex::new(quiet::Quiet::new()),
            real_world: Mutex::new(real_world::RealWorld::new()),
            preempter: Mutex::default(),
            hand_ons: Mutex::default(),
        }))
    }

    /// The servo port's ledger, for the pty and its session.
    pub fn port(&self) -> &Arc<PortLedger> {
        &self.port
    }

    /// The sensor connections' ledger, for the sensor server.
    pub fn sensors(&self) -> &Arc<SensorLedger> {
        &self.sensors
    }

    pub fn settings(&self) -> VtSettings {
        self.settings
    }

    pub fn stats(&self) -> VtStats {
        let stats = *lock(&self.stats);
        let asked_to_give_way = lock(&self.preempter).asked;
        if self.block_overwritten().is_some() {
            return VtStats { asked_to_give_way, block_overwritten: true, ..stats };
        }
        let handed = self.shared().header.turns.handed.load(Ordering::Relaxed);
        // Each time a thread gave way answered one of climbsim's requests: a count past them is
        // the controller's writing over the block (one that left the header whole), not a
        // preemption.
        let gave_way = self.shared().header.turns.gave_way.load(Ordering::Relaxed).min(asked_to_give_way);
        VtStats { turns: stats.turns.saturating_add(handed), turns_handed: handed, asked_to_give_way, gave_way, ..stats }
    }

    fn shared(&self) -> &abi::Shared {
        self.block.shared()
    }

    /// Simulated time now.
    pub fn now(&self) -> Duration {
        Duration::from_nanos(self.shared().header.clock.now_ns.load(Ordering::Acquire))
    }

    fn now_ns(&self) -> u64 {
        self.shared().header.clock.now_ns.load(Ordering::Acquire)
    }

    /// What a controller needs in its environment to run on this clock: the preload and the
    /// block's name.
    pub fn controller_env(&self) -> Result<Vec<(String, String)>, VtError> {
        let shim = shim_path()?;
        Ok(vec![("LD_PRELOAD".to_owned(), shim.display().to_string()), ("CLIMBSIM_VT".to_owned(), self.block.path().display().to_string())])
    }

    /// Hold the world while no controller process is attached (`serve`, whose controller is
    /// started by hand, may come and go): it goes on where it stopped when the next one starts.
    pub fn wait_for_controllers(&self) {
        self.waits_for_controller.store(true, Ordering::Relaxed);
    }

    fn controller_attached(&self) -> bool {
        self.shared().live_slots().iter().any(abi::Slot::is_live)
    }

    /// Hold time until the process about to be started has loaded the shim (it takes this slot).
    pub fn reserve_process(&self) {
        if !self.shared().slots[0].reserve_process() {
            tracing::warn!("virtual time: slot 0 was in use when the controller's process was to start; it starts unreserved");
        }
    }

    /// The pipe climbsim copies the controller's output from (an inode; 0: none), before the
    /// controller starts: the shim leaves a write to it that waits for room to the kernel
    /// (climbsim drains it in real time, and simulated time holds meanwhile).
    pub fn controller_output(&self, inode: u64) {
        self.shared().header.output_pipe.store(inode, Ordering::Release);
    }

    /// The reserved process's pid, once started (for the watchdog).
    pub fn process_started(&self, pid: u32) {
        let slot = &self.shared().slots[0];
        slot.pid.store(pid as i32, Ordering::Relaxed);
        slot.tid.store(pid as i32, Ordering::Relaxed);
    }

    /// The process climbsim started (slot 0's) has ended, as far as the shim saw it, at a
    /// simulated instant before `at`. Not at `at` itself: a world tick at the instant a thread
    /// is let go runs beside it, and whether that thread has ended by the tick's look is the
    /// host's race; every run sees such an end at the next tick.
    ///
    /// The process ends with its last thread, which need not be the first (a `pthread_exit`
    /// from main leaves the others running): every slot of its pid must have exited, and the
    /// latest of their ends is the process's.
    pub fn first_process_ended_before(&self, at: Duration) -> bool {
        let shared = self.shared();
        let first = &shared.slots[0];
        if first.state() != state::EXITED {
            return false;
        }
        let pid = first.pid.load(Ordering::Relaxed);
        let mut ended_ns = 0;
        for slot in shared.live_slots().iter().filter(|s| s.pid.load(Ordering::Relaxed) == pid) {
            if slot.is_live() {
                return false;
            }
            if slot.state() == state::EXITED {
                ended_ns = ended_ns.max(slot.exited_ns.load(Ordering::Relaxed));
            }
        }
        ended_ns < u64::try_from(at.as_nanos()).unwrap_or(NEVER)
    }

    /// Whether the controller has written over the block's header (a stray pointer, a program
    /// that maps it itself): nothing read back from the block can then be trusted — its clock,
    /// its threads' states, their ends — and the run fails saying so, rather than with whatever
    /// the scribbled words would say (a limit hit, a controller that never ended).
    fn block_overwritten(&self) -> Option<String> {
        let header = &self.shared().header;
        let intact = header.magic.load(Ordering::Acquire) == abi::MAGIC
            && header.abi.load(Ordering::Acquire) == abi::ABI
            && header.climbsim_pid.load(Ordering::Acquire) == std::process::id() as i32
            && matches!(header.mode.load(Ordering::Acquire), mode::VIRTUAL | mode::ENDING);
        (!intact).then(|| {
            format!(
                "virtual time: the controller wrote over virtual time's shared block ({}), whose header no longer reads as climbsim wrote it: nothing it holds (the clock, the threads' states) can be trusted, and the run cannot go on",
                self.block.path().display()
            )
        })
    }

    /// Bytes the controller sent that climbsim has not read yet (on the port or to the sensor
    /// server): simulated time cannot move until it has.
    fn held(&self) -> bool {
        let (port, sensors) = self.held_by();
        port || sensors
    }

    /// Whether bytes wait for climbsim on the port, and on the sensor connections.
    fn held_by(&self) -> (bool, bool) {
        (self.port.unread_by_climbsim(), self.sensors.unread_by_climbsim())
    }

    /// Run `future` inside the scheduler: polled whenever the controller is parked, never on a
    /// thread of its own (so it acts at exact simulated instants).
    pub fn drive(&self, serves: Serves, future: impl Future<Output = ()> + Send + 'static) {
        let mut future = Box::pin(future);
        // Polled once at once: up to its first wait, it sets itself up (the port says which
        // device it is) before any controller can use it.
        if future.as_mut().poll(&mut Context::from_waker(Waker::noop())).is_pending() {
            lock(&self.driven).push((serves, future));
        }
    }

    /// A guard that ends the run when dropped, whatever way the run is left (an error too):
    /// the driven futures hold this scheduler, so without [`VirtualTime::end`] neither they nor
    /// the block would ever go.
    pub fn end_on_drop(self: &Arc<Self>) -> EndOnDrop {
        EndOnDrop(Arc::clone(self))
    }

    /// The run is over: the shim goes back to the kernel for everything, and every parked
    /// thread is let go, so that the controller's clean-up runs (on the wall clock).
    pub fn end(&self) {
        let header = &self.shared().header;
        let mut wall = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: a valid timespec for the call.
        unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut wall) };
        header.clock.ending_wall_ns.store(wall.tv_sec as u64 * 1_000_000_000 + wall.tv_nsec as u64, Ordering::Release);
        header.mode.store(mode::ENDING, Ordering::Release);
        // The driven futures hold this scheduler (through their clocks): dropping them ends
        // the cycle, so that the block is removed when the run lets go of it.
        drop(std::mem::take(&mut *lock(&self.driven)));
        for slot in self.shared().live_slots() {
            match slot.state() {
                state::BLOCKED | state::YIELDED => slot.release.store(release::ENDING, Ordering::Relaxed),
                // Keeps the reason it was let go for.
                state::READY => {}
                _ => continue,
            }
            if slot.let_go_at_end() {
                wake(slot);
            }
        }
    }

    /// The scheduler: bring simulated time to `due` (a world tick), letting the controller run
    /// everything it has due before then, in order. Returns with every controller thread parked.
    pub fn advance_to(&self, due: Duration, stop: &AtomicBool) -> Result<(), VtError> {
        let due = u64::try_from(due.as_nanos()).unwrap_or(NEVER);
        let header = &self.shared().header;
        let mut watchdog = watchdog::Watchdog::new(watchdog::Limits { stuck_after: self.settings.stuck_after, compute_limit: self.settings.compute_limit, livelock_after: LIVELOCK_AFTER });
        // (Not while the world still catches up with where a controller that has gone left it.)
        while self.waits_for_controller.load(Ordering::Relaxed) && self.now_ns() < due && !self.controller_attached() {
            if stop.load(Ordering::Relaxed) {
                return Err(VtError::Interrupted);
            }
            // Clients that are not followed (a person's curl) are still answered meanwhile.
            self.poll_driven(None);
            let seen = header.turns.sched_word.load(Ordering::Acquire);
            if !self.controller_attached() {
                futex_wait(&header.turns.sched_word, seen, Duration::from_millis(20));
            }
        }
        loop {
            if let Some(why) = self.block_overwritten() {
                return Err(VtError::Stuck(why));
            }
            if let Some(why) = self.port.take_cannot_repeat() {
                return Err(VtError::Stuck(why));
            }
            // The world catches up with the controller before climbsim looks at anything the
            // controller sent: ticks may run while it runs, since it can see the world only
            // through replies and answers, which climbsim makes only here, with it parked.
            if self.now_ns() >= due {
                return Ok(());
            }
            let settled = self.settle(&mut watchdog, stop, due)?;
            // (What the controller did meanwhile may have been to write over the block: before
            // anything read from it is judged.)
            if let Some(why) = self.block_overwritten() {
                return Err(VtError::Stuck(why));
            }
            // Judged with every thread parked: the thread that met the refusal has printed
            // what it makes of it (judged at once, the run could end before it wrote).
            if settled == Settled::Parked
                && let Some(refusal) = abi::refused::describe(header.refused.load(Ordering::Acquire))
            {
                return Err(VtError::Stuck(refusal));
            }
            let now = self.now_ns();
            if now >= due {
                return Ok(());
            }
            // A thread may have moved the clock onto a timer's time (the horizon includes it):
            // that timer goes first.
            let next_timer = self.next_timer().min(self.next_signal_timer());
            if next_timer <= now {
                self.fire_all(now);
                continue;
            }
            // Replies written ahead show at their instants: a thread waiting on the port is let
            // go then (a spinning one moves there by itself if it runs first).
            let next_reply = next_timer.min(self.port.next_held_due(now));
            let plan = self.let_go_at(now, next_timer, next_reply);
            if plan.released {
                continue;
            }
            // fetch_max: a thread that woke by itself (a real descriptor, a peer) may have moved
            // the clock within the horizon meanwhile; time never goes back.
            if due <= plan.next {
                if plan.next < next_timer {
                    // The next instant is a thread's (or a held reply's), not climbsim's: jump
                    // there and let the thread go now. The world catches up tick by tick while it
                    // runs; what it sends is read once the world has reached its instant (see
                    // `settle`), so nothing it can see depends on the race.
                    lock(&self.stats).jumps += 1;
                    self.trace_jump(plan.next);
                    let now = header.clock.now_ns.fetch_max(plan.next, Ordering::AcqRel).max(plan.next);
                    self.let_go_at(now, next_timer, next_timer.min(self.port.next_held_due(now)));
                    return Ok(());
                }
                header.clock.now_ns.fetch_max(due, Ordering::AcqRel);
                return Ok(());
            }
            lock(&self.stats).jumps += 1;
            self.trace_jump(plan.next);
            let now = header.clock.now_ns.fetch_max(plan.next, Ordering::AcqRel).max(plan.next);
            self.fire_all(now);
        }
    }

    /// Wait until no controller thread runs and every byte it wrote has been read, running the
    /// driven futures meanwhile; or until the controller, parked, is at or past the world's
    /// next tick `due`: that tick runs first, and what the controller sent is read after it (a
    /// tick precedes whatever happens at its instant, and bytes sent at T meet the world as it
    /// is at T, however the two threads raced there).
    fn settle(&self, watchdog: &mut watchdog::Watchdog, stop: &AtomicBool, due: u64) -> Result<Settled, VtError> {
        let header = &self.shared().header;
        loop {
            // Every 10 ms of this loop, whichever way it goes round: the threads are judged.
            if watchdog.due() {
                watchdog.check(self.shared())?;
            }
            let mut preempter = lock(&self.preempter);
            if preempter.due() {
                preempter.check(self.shared());
            }
            let sleep_at_most = preempter.sleep_at_most(self.shared());
            drop(preempter);
            let seen = header.turns.sched_word.load(Ordering::Acquire);
            if !self.any_running() {
                // What the threads that ran wrote may have woken threads waiting on the real
                // world: they look before anything is decided.
                if !lock(&self.real_world).settled(self.shared()) {
                    continue;
                }
                // Threads ready at this instant run first, one at a time.
                if self.give_turn() {
                    continue;
                }
                if self.now_ns() >= due {
                    return Ok(Settled::Parked);
                }
                // The driven futures have something to do only when the controller sent bytes
                // (and after timers, which poll them themselves); clients climbsim does not
                // follow (a person's curl) are answered at least every few milliseconds.
                let (port, sensors) = self.held_by();
                if self.last_poll_long_ago() {
                    self.poll_driven(None);
                } else if port {
                    self.poll_driven(Some(Serves::Port));
                } else if sensors {
                    self.poll_driven(Some(Serves::Sensors));
                }
                if !self.held() {
                    return Ok(Settled::Parked);
                }
                if stop.load(Ordering::Relaxed) {
                    return Err(VtError::Interrupted);
                }
                // Sent, not yet handed over by the kernel (the pty's worker, loopback TCP):
                // microseconds, unless they were written where the shim cannot count them.
                self.wait_for_bytes_in_flight();
                watchdog.check_held(self.held_by())?;
                continue;
            }
            if let Some(why) = self.block_overwritten() {
                return Err(VtError::Stuck(why));
            }
            if stop.load(Ordering::Relaxed) || header.mode.load(Ordering::Acquire) != mode::VIRTUAL {
                return Err(VtError::Interrupted);
            }
            if self.ran_past(due) {
                return Ok(Settled::RanPast);
            }
            // A controller thread usually parks again within tens of microseconds: spin that
            // long before sleeping on the futex (its wake-up costs more on a VM).
            let spin = if self.spin && lock(&self.quiet).now() { SPIN } else { Duration::ZERO };
            header.spin.park_spin_ns.store(spin.as_nanos() as u64, Ordering::Relaxed);
            let spin_until = std::time::Instant::now() + spin;
            while header.turns.sched_word.load(Ordering::Acquire) == seen && !self.ran_past(due) && std::time::Instant::now() < spin_until {
                std::hint::spin_loop();
            }
            if header.turns.sched_word.load(Ordering::Acquire) != seen || self.ran_past(due) {
                continue;
            }
            futex_wait(&header.turns.sched_word, seen, sleep_at_most);
        }
    }

    /// A running thread has moved the clock itself past the world's next tick `due` (through
    /// replies written ahead, within the horizon): the tick runs now, beside it, rather than
    /// after it parks. Nothing it does can reach the world before the world is there: it sees
    /// the world only through replies made while it was parked, and what it sends is read once
    /// the world has caught up with its instant. Past, not at: a thread that ends at the tick's
    /// own instant must be seen ended by that tick. (Not with a refusal pending: that is judged
    /// with the thread parked, once it has said why.)
    fn ran_past(&self, due: u64) -> bool {
        let header = &self.shared().header;
        self.now_ns() > due && header.refused.load(Ordering::Acquire) == 0
    }

    /// Wait until no controller thread runs, without moving time or letting any go: at the
    /// run's end, so that the time it ended at and the stop signal find every thread parked
    /// (one may have run on past the world's last tick, and parks within microseconds). At most
    /// `within` of wall time: a thread still running then computes without calls, or is stuck,
    /// which the watchdog judges during the run, not here. Whether every thread parked.
    pub fn await_parked(&self, within: Duration, stop: &AtomicBool) -> bool {
        let header = &self.shared().header;
        let until = std::time::Instant::now() + within;
        loop {
            let seen = header.turns.sched_word.load(Ordering::Acquire);
            if !self.any_running() {
                return true;
            }
            if stop.load(Ordering::Relaxed) || std::time::Instant::now() >= until {
                return false;
            }
            futex_wait(&header.turns.sched_word, seen, Duration::from_millis(1));
        }
    }

    fn last_poll_long_ago(&self) -> bool {
        lock(&self.last_poll).elapsed() > UNFOLLOWED_CLIENTS_EVERY
    }

    /// Poll the driven futures that serve `only` (None: all).
    fn poll_driven(&self, only: Option<Serves>) {
        if only.is_none() {
            *lock(&self.last_poll) = std::time::Instant::now();
        }
        let mut list = std::mem::take(&mut *lock(&self.driven));
        let mut cx = Context::from_waker(Waker::noop());
        list.retain_mut(|(serves, future)| only.is_some_and(|only| only != *serves) || future.as_mut().poll(&mut cx).is_pending());
        let mut driven = lock(&self.driven);
        list.append(&mut driven);
        *driven = list;
    }

    /// Wait a moment for bytes the controller sent that the kernel has not handed over yet: on
    /// the port until its master is readable (1 ms at most), on a sensor connection 20 µs.
    fn wait_for_bytes_in_flight(&self) {
        match self.port.fds() {
            // Bytes in the ring are taken at the next poll, with no kernel in between (a session
            // that no longer takes them leaves them held, which the watchdog judges).
            Some(_) if self.shared().port_tx_ring_unread() > 0 => std::thread::yield_now(),
            Some(port) if self.held_by().0 => {
                let mut fds = [libc::pollfd { fd: port.master, events: libc::POLLIN, revents: 0 }];
                // The pty's worker hands bytes over within microseconds while both CPUs are
                // busy, and a sleep here lets this vCPU halt, whose wake-up costs tens of them:
                // looks without waiting first, giving the CPU up between them (the worker may
                // be queued on it), while the machine is quiet.
                if self.spin && lock(&self.quiet).now() {
                    let until = std::time::Instant::now() + IN_FLIGHT_SPIN;
                    while std::time::Instant::now() < until {
                        // SAFETY: one valid pollfd; a zero timeout never blocks.
                        if unsafe { libc::poll(fds.as_mut_ptr(), 1, 0) } != 0 {
                            return;
                        }
                        std::thread::yield_now();
                    }
                }
                // SAFETY: one valid pollfd.
                unsafe { libc::poll(fds.as_mut_ptr(), 1, 1) };
            }
            _ => std::thread::sleep(Duration::from_micros(20)),
        }
    }
}

/// Ends the run when dropped (see [`VirtualTime::end_on_drop`]).
pub struct EndOnDrop(Arc<VirtualTime>);

impl Drop for EndOnDrop {
    fn drop(&mut self) {
        self.0.end();
    }
}
